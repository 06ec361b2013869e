// libFuzzer target for io/image_io.h readImage. The first input byte picks the file extension
// (png, jpg, bmp, tif, pgm, ppm) and the decoding mode; the rest is the file's content.
#include <cstdint>
#include <string>

#include "fuzz_common.h"
#include "nerfslam/io/image_io.h"

using namespace nerfslam;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::quietLogs();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  static const char* const kExt[] = {".png", ".jpg", ".bmp", ".tif", ".pgm", ".ppm"};
  static const ImageMode kModes[] = {ImageMode::kGray, ImageMode::kColor, ImageMode::kUnchanged};
  const auto path = fuzz::scratchDir() / (std::string("image") + kExt[data[0] % 6]);
  const ImageMode mode = kModes[(data[0] / 6) % 3];
  fuzz::writeBytes(path, std::string_view(reinterpret_cast<const char*>(data + 1), size - 1));
  fuzz::expectOnlyError([&] {
    const cv::Mat img = readImage(path, mode);
    volatile int sink = img.rows + img.cols;
    (void)sink;
  });
  return 0;
}
