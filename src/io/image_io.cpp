#include "nerfslam/io/image_io.h"

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>

#include <opencv2/imgcodecs.hpp>

#include "image_header.h"
#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"

namespace nerfslam {

namespace fs = std::filesystem;

namespace {

// Larger than any camera we know (16384 per side, 64 megapixels: 3 bytes a pixel is 192 MB).
constexpr int64_t kMaxImageSide = 16384;
constexpr int64_t kMaxImagePixels = int64_t{64} << 20;
// The largest image file: 64 megapixels of 16-bit RGBA uncompressed are 512 MiB.
constexpr uint64_t kMaxImageFileBytes = uint64_t{1} << 30;

}  // namespace

cv::Mat readImage(const fs::path& path, ImageMode mode) {
  const std::string data = readInputFile(path, "image file", kMaxImageFileBytes);
  return decodeImage(std::vector<uchar>(data.begin(), data.end()), mode, path.string());
}

cv::Mat decodeImage(const std::vector<uchar>& bytes, ImageMode mode, const std::string& name) {
  if (bytes.empty()) fail("{}: empty image file", name);
  const auto header = io_detail::sniffImageHeader(bytes);
  if (!header) fail("{}: not a readable image (unknown format: PNG, JPEG, BMP, TIFF or PNM expected)", name);
  if (header->width > kMaxImageSide || header->height > kMaxImageSide ||
      header->width * header->height > kMaxImagePixels)
    fail("{}: {} header declares {}x{} pixels, more than this reader accepts ({} per side, {} megapixels)", name,
         io_detail::imageFormatName(header->format), header->width, header->height, kMaxImageSide,
         kMaxImagePixels >> 20);
  io_detail::checkImageComplete(bytes, header->format, name);
  if (header->format == io_detail::ImageFormat::kJpeg) io_detail::checkJpegData(bytes, name);
  int flags = cv::IMREAD_GRAYSCALE;
  if (mode == ImageMode::kColor) flags = cv::IMREAD_COLOR;
  if (mode == ImageMode::kUnchanged) flags = cv::IMREAD_UNCHANGED;
  cv::Mat image;
  try {
    image = cv::imdecode(bytes, flags);
  } catch (const cv::Exception& e) {
    fail("{}: cannot decode image: {}", name, e.what());
  }
  if (image.empty())
    fail("{}: corrupt {} image (the decoder could not read its data)", name,
         io_detail::imageFormatName(header->format));
  return image;
}

void writeImageAtomic(const fs::path& path, const cv::Mat& image, const std::vector<int>& params) {
  std::vector<uchar> bytes;
  bool ok = false;
  try {
    ok = cv::imencode(path.extension().string(), image, bytes, params);
  } catch (const cv::Exception& e) {
    fail("{}: cannot encode the image: {}", path.string(), e.what());
  }
  if (!ok) fail("{}: cannot encode the image (unknown extension or unsupported pixel type)", path.string());
  writeStringAtomic(path, std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
}

bool isImageExtension(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  static const char* kExts[] = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"};
  return std::any_of(std::begin(kExts), std::end(kExts), [&](const char* e) { return ext == e; });
}

bool naturalLess(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    const bool da = std::isdigit(static_cast<unsigned char>(a[i]));
    const bool db = std::isdigit(static_cast<unsigned char>(b[j]));
    if (da && db) {
      size_t ie = i, je = j;
      while (ie < a.size() && std::isdigit(static_cast<unsigned char>(a[ie]))) ++ie;
      while (je < b.size() && std::isdigit(static_cast<unsigned char>(b[je]))) ++je;
      // Compare by value: skip leading zeros, then by length, then digit-wise.
      size_t is = i, js = j;
      while (is + 1 < ie && a[is] == '0') ++is;
      while (js + 1 < je && b[js] == '0') ++js;
      if (ie - is != je - js) return ie - is < je - js;
      const int c = a.compare(is, ie - is, b, js, je - js);
      if (c != 0) return c < 0;
      // Equal values: fewer leading zeros first, so the order is total.
      if (ie - i != je - j) return ie - i < je - j;
      i = ie;
      j = je;
    } else {
      if (a[i] != b[j]) return static_cast<unsigned char>(a[i]) < static_cast<unsigned char>(b[j]);
      ++i;
      ++j;
    }
  }
  return a.size() - i < b.size() - j;
}

std::vector<fs::path> listImages(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) fail("{}: not a directory", dir.string());
  std::vector<fs::path> out;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->is_regular_file(ec) && isImageExtension(it->path())) out.push_back(it->path());
  }
  if (ec) fail("{}: cannot list directory: {}", dir.string(), ec.message());
  std::sort(out.begin(), out.end(), [](const fs::path& x, const fs::path& y) {
    return naturalLess(x.filename().string(), y.filename().string());
  });
  return out;
}

}  // namespace nerfslam
