// libFuzzer target for io/ply_header.h checkPlyFile, the check `render-preview` makes before PCL
// reads a cloud. Beyond "an Error or nothing", a file it accepts must hold what its header declares
// (binary: every element's count x its smallest size after the header; ASCII: 2 bytes a property),
// since that is what keeps PCL from allocating a declared count: an accepted header that declares
// more is a finding.
#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include "fuzz_common.h"
#include "nerfslam/io/ply_header.h"

using namespace nerfslam;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::quietLogs();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto dir = fuzz::scratchDir();
  fuzz::writeSections(dir, {"cloud.ply"}, data, size);
  PlyHeader h;
  try {
    h = checkPlyFile(dir / "cloud.ply");
  } catch (const Error&) {
    return 0;
  }
  // What the accepted header promises, in 128-bit arithmetic so that nothing wraps.
  const bool ascii = h.format == "ascii";
  unsigned __int128 need = 0;
  for (const PlyElement& e : h.elements)
    need += static_cast<unsigned __int128>(e.count) * (ascii ? 2 * static_cast<uint64_t>(e.properties) : e.min_bytes);
  const unsigned __int128 have = h.file_bytes - h.header_bytes + (ascii ? h.elements.size() : 0);
  if (h.header_bytes > h.file_bytes || need > have) {
    std::fprintf(stderr, "accepted a header declaring more than the file holds (%llu header bytes of %llu)\n",
                 static_cast<unsigned long long>(h.header_bytes), static_cast<unsigned long long>(h.file_bytes));
    std::abort();
  }
  return 0;
}
