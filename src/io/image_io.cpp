#include "nerfslam/io/image_io.h"

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>

#include <fmt/format.h>
#include <opencv2/imgcodecs.hpp>

#include "image_header.h"
#include "nerfslam/core/error.h"

namespace nerfslam {

namespace fs = std::filesystem;

namespace {

// Larger than any camera we know (16384 per side, 64 megapixels: 3 bytes a pixel is 192 MB).
constexpr int64_t kMaxImageSide = 16384;
constexpr int64_t kMaxImagePixels = int64_t{64} << 20;

bool startsWith(const std::vector<uchar>& b, const unsigned char* sig, size_t n) {
  return b.size() >= n && std::memcmp(b.data(), sig, n) == 0;
}

// A PNG chunk type for a message: its four letters, or hex when they are not letters.
std::string chunkName(const uchar* t) {
  if (std::all_of(t, t + 4, [](uchar c) { return std::isalpha(c); })) return std::string(t, t + 4);
  return fmt::format("0x{:02x}{:02x}{:02x}{:02x}", t[0], t[1], t[2], t[3]);
}

// OpenCV decodes a cut-off PNG or JPEG into a partly grey image with only a libpng/libjpeg warning,
// so look for the format's end marker. PNG: walk the chunks to IEND, each declared length within
// the bytes that follow (libpng would allocate and clear a declared 1 GB text chunk before finding
// the file short). JPEG: EOI (FF D9, possibly followed by padding or an appended trailer; searched in
// the last 64 KiB).
void checkComplete(const std::vector<uchar>& b, const fs::path& path) {
  static const unsigned char kPng[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  static const unsigned char kJpeg[3] = {0xff, 0xd8, 0xff};
  if (startsWith(b, kPng, 8)) {
    size_t i = 8;  // length (4, big-endian), type (4), data (length), CRC (4)
    while (true) {
      if (b.size() - i < 12) fail("{}: truncated PNG image (no IEND chunk; {} bytes)", path.string(), b.size());
      const uint64_t n = (uint64_t{b[i]} << 24) | (uint64_t{b[i + 1]} << 16) | (uint64_t{b[i + 2]} << 8) | b[i + 3];
      if (n > b.size() - i - 12)
        fail("{}: truncated PNG image: chunk '{}' at byte {} declares {} bytes but only {} follow", path.string(),
             chunkName(&b[i + 4]), i, n, b.size() - i - 12);
      if (std::memcmp(&b[i + 4], "IEND", 4) == 0) return;
      i += 12 + n;
    }
  } else if (startsWith(b, kJpeg, 3)) {
    const size_t window = std::min<size_t>(b.size(), 65536);
    bool found = false;
    for (size_t i = b.size() - 1; i > b.size() - window && i > 0; --i) {
      if (b[i - 1] == 0xff && b[i] == 0xd9) {
        found = true;
        break;
      }
    }
    if (!found) fail("{}: truncated JPEG image (no end-of-image marker; {} bytes)", path.string(), b.size());
  }
}

}  // namespace

cv::Mat readImage(const fs::path& path, ImageMode mode) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) fail("{}: image file not found", path.string());
  std::ifstream in(path, std::ios::binary);
  if (!in) fail("{}: cannot open image file", path.string());
  std::vector<uchar> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) fail("{}: read error", path.string());
  if (bytes.empty()) fail("{}: empty image file", path.string());
  const auto header = io_detail::sniffImageHeader(bytes);
  if (!header) fail("{}: not a readable image (unknown format: PNG, JPEG, BMP, TIFF or PNM expected)", path.string());
  if (header->width > kMaxImageSide || header->height > kMaxImageSide ||
      header->width * header->height > kMaxImagePixels)
    fail("{}: {} header declares {}x{} pixels, more than this reader accepts ({} per side, {} megapixels)",
         path.string(), header->format, header->width, header->height, kMaxImageSide, kMaxImagePixels >> 20);
  checkComplete(bytes, path);
  int flags = cv::IMREAD_GRAYSCALE;
  if (mode == ImageMode::kColor) flags = cv::IMREAD_COLOR;
  if (mode == ImageMode::kUnchanged) flags = cv::IMREAD_UNCHANGED;
  cv::Mat image;
  try {
    image = cv::imdecode(bytes, flags);
  } catch (const cv::Exception& e) {
    fail("{}: cannot decode image: {}", path.string(), e.what());
  }
  if (image.empty()) fail("{}: not a readable image (unknown format or corrupt data)", path.string());
  return image;
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
