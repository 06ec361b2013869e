#include "image_header.h"

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <cstring>
#include <string>
#include <utility>

#include <fmt/format.h>
#include <zlib.h>

#include "nerfslam/core/crc32.h"
#include "nerfslam/core/error.h"

namespace nerfslam::io_detail {
namespace {

uint32_t be16(const uint8_t* p) { return (uint32_t{p[0]} << 8) | p[1]; }
uint32_t be32(const uint8_t* p) { return (be16(p) << 16) | be16(p + 2); }
uint32_t le16(const uint8_t* p) { return (uint32_t{p[1]} << 8) | p[0]; }
uint32_t le32(const uint8_t* p) { return (le16(p + 2) << 16) | le16(p); }

bool startsWith(const std::vector<uint8_t>& b, const char* sig, size_t n) {
  return b.size() >= n && std::memcmp(b.data(), sig, n) == 0;
}

// Width and height from the first start-of-frame marker (any SOFn: C0-CF but C4 DHT, C8 JPG, CC DAC).
void jpegSize(const std::vector<uint8_t>& b, ImageHeader* h) {
  size_t i = 2;
  while (i + 4 <= b.size() && b[i] == 0xff) {
    const uint8_t m = b[i + 1];
    if (m == 0xff) {  // fill byte
      ++i;
      continue;
    }
    if ((m >= 0xd0 && m <= 0xd9) || m == 0x01) {  // markers without a length
      i += 2;
      continue;
    }
    const size_t len = be16(&b[i + 2]);
    if (m >= 0xc0 && m <= 0xcf && m != 0xc4 && m != 0xc8 && m != 0xcc) {
      if (i + 9 <= b.size()) {
        h->height = be16(&b[i + 5]);
        h->width = be16(&b[i + 7]);
      }
      return;
    }
    if (len < 2) return;
    i += 2 + len;
  }
}

// Tags 256 (ImageWidth) and 257 (ImageLength) of the first IFD, SHORT or LONG.
void tiffSize(const std::vector<uint8_t>& b, bool little, ImageHeader* h) {
  auto u16 = [&](size_t o) { return little ? le16(&b[o]) : be16(&b[o]); };
  auto u32 = [&](size_t o) { return little ? le32(&b[o]) : be32(&b[o]); };
  const size_t ifd = u32(4);
  if (ifd > b.size() || b.size() - ifd < 2) return;
  const size_t n = u16(ifd);
  for (size_t k = 0; k < n; ++k) {
    const size_t e = ifd + 2 + 12 * k;
    if (e > b.size() || b.size() - e < 12) return;
    const uint32_t tag = u16(e), type = u16(e + 2);
    if (tag != 256 && tag != 257) continue;
    int64_t v = -1;
    if (type == 3) v = u16(e + 8);  // SHORT
    if (type == 4) v = u32(e + 8);  // LONG
    (tag == 256 ? h->width : h->height) = v;
  }
}

// P1-P6: magic, then width and height as decimal tokens, '#' comments to the end of a line.
void pnmSize(const std::vector<uint8_t>& b, ImageHeader* h) {
  size_t i = 2;
  int64_t v[2] = {-1, -1};
  for (int64_t& out : v) {
    while (i < b.size() && (std::isspace(b[i]) || b[i] == '#')) {
      if (b[i] == '#')
        while (i < b.size() && b[i] != '\n' && b[i] != '\r') ++i;
      else
        ++i;
    }
    std::string digits;
    while (i < b.size() && std::isdigit(b[i]) && digits.size() < 12) digits.push_back(static_cast<char>(b[i++]));
    if (digits.empty()) return;
    out = std::strtoll(digits.c_str(), nullptr, 10);
  }
  h->width = v[0];
  h->height = v[1];
}

// A PNG chunk type for a message: its four letters, or hex when they are not letters.
std::string chunkName(const uint8_t* t) {
  if (std::all_of(t, t + 4, [](uint8_t c) { return std::isalpha(c); })) return std::string(t, t + 4);
  return fmt::format("0x{:02x}{:02x}{:02x}{:02x}", t[0], t[1], t[2], t[3]);
}

// The bytes of filtered pixel rows (a filter byte, then the row) an IHDR declares: what the image's
// zlib stream must inflate to. 0 when the IHDR is not one libpng accepts (the decoder says why).
uint64_t pngRowBytes(const std::vector<uint8_t>& b) {
  if (b.size() < 33 || std::memcmp(&b[12], "IHDR", 4) != 0) return 0;
  const uint64_t w = be32(&b[16]), h = be32(&b[20]);
  const int depth = b[24], color = b[25], interlace = b[28];
  const int channels = color == 0 ? 1 : color == 2 ? 3 : color == 3 ? 1 : color == 4 ? 2 : color == 6 ? 4 : 0;
  if (channels == 0 || (depth != 1 && depth != 2 && depth != 4 && depth != 8 && depth != 16) || interlace > 1) return 0;
  const uint64_t bits = uint64_t(channels) * uint64_t(depth);
  auto rows = [&](uint64_t pw, uint64_t ph) { return pw == 0 || ph == 0 ? 0 : ph * (1 + (pw * bits + 7) / 8); };
  if (interlace == 0) return rows(w, h);
  // Adam7: the seven passes' first column and row and their steps.
  static const int kPass[7][4] = {{0, 0, 8, 8}, {4, 0, 8, 8}, {0, 4, 4, 8}, {2, 0, 4, 4},
                                  {0, 2, 2, 4}, {1, 0, 2, 2}, {0, 1, 1, 2}};
  uint64_t total = 0;
  for (const auto& p : kPass) {
    const uint64_t pw = w > uint64_t(p[0]) ? (w - p[0] + p[2] - 1) / p[2] : 0;
    const uint64_t ph = h > uint64_t(p[1]) ? (h - p[1] + p[3] - 1) / p[3] : 0;
    total += rows(pw, ph);
  }
  return total;
}

// Inflates the IDAT chunks (to a scratch buffer, not kept) and refuses data that does not decompress
// or holds fewer rows than the header declares: libpng reports the latter only on stderr, or as a
// "benign" error OpenCV lets pass, and a PNG cut short and re-terminated with IEND has valid chunks.
void checkPngPixelData(const std::vector<uint8_t>& b, const std::vector<std::pair<size_t, size_t>>& idat,
                       const std::string& path) {
  const uint64_t expected = pngRowBytes(b);
  if (expected == 0) return;
  if (idat.empty()) fail("{}: corrupt PNG image: no IDAT chunk (no pixel data)", path);
  z_stream z{};
  if (inflateInit(&z) != Z_OK) fail("{}: cannot check the PNG image: zlib failed to start", path);
  std::vector<uint8_t> out(1 << 16);
  uint64_t total = 0;
  int ret = Z_OK;
  std::string error;
  for (const auto& [offset, length] : idat) {
    z.next_in = const_cast<Bytef*>(b.data() + offset);
    z.avail_in = static_cast<uInt>(length);
    do {
      z.next_out = out.data();
      z.avail_out = static_cast<uInt>(out.size());
      ret = inflate(&z, Z_NO_FLUSH);
      total += out.size() - z.avail_out;
      if (ret == Z_NEED_DICT || ret == Z_DATA_ERROR || ret == Z_MEM_ERROR || ret == Z_STREAM_ERROR)
        error = z.msg ? z.msg : "error " + std::to_string(ret);
    } while (error.empty() && ret != Z_STREAM_END && total < expected && (z.avail_in > 0 || z.avail_out == 0));
    if (!error.empty() || ret == Z_STREAM_END || total >= expected) break;
  }
  inflateEnd(&z);
  if (!error.empty()) fail("{}: corrupt PNG image: its pixel data does not decompress (zlib: {})", path, error);
  if (total < expected)
    fail("{}: truncated PNG image: its pixel data holds {} of the {} bytes of rows its header declares", path, total,
         expected);
}

}  // namespace

const char* imageFormatName(ImageFormat f) {
  switch (f) {
    case ImageFormat::kPng:
      return "PNG";
    case ImageFormat::kJpeg:
      return "JPEG";
    case ImageFormat::kBmp:
      return "BMP";
    case ImageFormat::kTiff:
      return "TIFF";
    case ImageFormat::kPnm:
      return "PNM";
  }
  return "?";
}

std::optional<ImageHeader> sniffImageHeader(const std::vector<uint8_t>& b) {
  ImageHeader h;
  if (startsWith(b, "\x89PNG\r\n\x1a\n", 8)) {
    h.format = ImageFormat::kPng;
    if (b.size() >= 24 && std::memcmp(&b[12], "IHDR", 4) == 0) {
      h.width = be32(&b[16]);
      h.height = be32(&b[20]);
    }
  } else if (startsWith(b, "\xff\xd8\xff", 3)) {
    h.format = ImageFormat::kJpeg;
    jpegSize(b, &h);
  } else if (startsWith(b, "BM", 2)) {
    h.format = ImageFormat::kBmp;
    if (b.size() >= 26) {
      if (le32(&b[14]) == 12) {  // OS/2 BITMAPCOREHEADER: 16-bit sizes
        h.width = le16(&b[18]);
        h.height = le16(&b[20]);
      } else {
        h.width = std::abs(static_cast<int64_t>(static_cast<int32_t>(le32(&b[18]))));
        h.height = std::abs(static_cast<int64_t>(static_cast<int32_t>(le32(&b[22]))));  // negative: top-down
      }
    }
  } else if (startsWith(b, "II*\0", 4) || startsWith(b, "MM\0*", 4)) {
    h.format = ImageFormat::kTiff;
    if (b.size() >= 8) tiffSize(b, b[0] == 'I', &h);
  } else if (b.size() >= 3 && b[0] == 'P' && b[1] >= '1' && b[1] <= '6' && std::isspace(b[2])) {
    h.format = ImageFormat::kPnm;
    pnmSize(b, &h);
  } else {
    return std::nullopt;
  }
  return h;
}

void checkImageComplete(const std::vector<uint8_t>& b, ImageFormat format, const std::string& path) {
  if (format == ImageFormat::kPng) {
    std::vector<std::pair<size_t, size_t>> idat;  // offset and length of each IDAT chunk's data
    size_t i = 8;  // after the signature: length (4, big-endian), type (4), data (length), CRC (4)
    while (true) {
      if (b.size() - i < 12) fail("{}: truncated PNG image (no IEND chunk; {} bytes)", path, b.size());
      const uint32_t n = be32(&b[i]);
      if (n > b.size() - i - 12)
        fail("{}: truncated PNG image: chunk '{}' at byte {} declares {} bytes but only {} follow", path,
             chunkName(&b[i + 4]), i, n, b.size() - i - 12);
      if (crc32(&b[i + 4], 4 + size_t{n}) != be32(&b[i + 8 + n]))
        fail("{}: corrupt PNG image: chunk '{}' at byte {} fails its CRC check", path, chunkName(&b[i + 4]), i);
      if (std::memcmp(&b[i + 4], "IDAT", 4) == 0) idat.emplace_back(i + 8, n);
      if (std::memcmp(&b[i + 4], "IEND", 4) == 0) break;
      i += 12 + size_t{n};
    }
    checkPngPixelData(b, idat, path);
    return;
  }
  if (format == ImageFormat::kJpeg) {
    const size_t window = std::min<size_t>(b.size(), 65536);
    for (size_t i = b.size() - 1; i > b.size() - window && i > 0; --i)
      if (b[i - 1] == 0xff && b[i] == 0xd9) return;
    fail("{}: truncated JPEG image (no end-of-image marker; {} bytes)", path, b.size());
  }
}

}  // namespace nerfslam::io_detail
