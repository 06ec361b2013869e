// libFuzzer target for nerf/model_io.h loadModel (the versioned binary NeRF model file).
// The file ends with a CRC-32 of everything before it; a mutated input would almost never pass that
// check, so the target rewrites the last 4 bytes with the right CRC (little-endian) to reach the
// header and array parsing. The CRC check itself is exercised by inputs shorter than 4 bytes and by
// the unit tests.
#include <cstdint>
#include <string>

#include "fuzz_common.h"
#include "nerfslam/core/crc32.h"
#include "nerfslam/nerf/model_io.h"

using namespace nerfslam;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::quietLogs();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::scratchDir() / "model.nerf";
  std::string bytes(reinterpret_cast<const char*>(data), size);
  if (bytes.size() >= 4) {
    const uint32_t crc = crc32(bytes.data(), bytes.size() - 4);
    for (int i = 0; i < 4; ++i) bytes[bytes.size() - 4 + i] = static_cast<char>((crc >> (8 * i)) & 0xFF);
  }
  fuzz::writeBytes(path, bytes);
  fuzz::expectOnlyError([&] {
    nerf::NerfModel m = nerf::loadModel(path);
    volatile uint64_t sink = m.training_steps;
    (void)sink;
  });
  return 0;
}
