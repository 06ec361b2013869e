#include "image_header.h"

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <cstring>
#include <string>

#include <fmt/format.h>

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
    size_t i = 8;  // after the signature: length (4, big-endian), type (4), data (length), CRC (4)
    while (true) {
      if (b.size() - i < 12) fail("{}: truncated PNG image (no IEND chunk; {} bytes)", path, b.size());
      const uint32_t n = be32(&b[i]);
      if (n > b.size() - i - 12)
        fail("{}: truncated PNG image: chunk '{}' at byte {} declares {} bytes but only {} follow", path,
             chunkName(&b[i + 4]), i, n, b.size() - i - 12);
      if (std::memcmp(&b[i + 4], "IEND", 4) == 0) return;
      i += 12 + size_t{n};
    }
  }
  if (format == ImageFormat::kJpeg) {
    const size_t window = std::min<size_t>(b.size(), 65536);
    for (size_t i = b.size() - 1; i > b.size() - window && i > 0; --i)
      if (b[i - 1] == 0xff && b[i] == 0xd9) return;
    fail("{}: truncated JPEG image (no end-of-image marker; {} bytes)", path, b.size());
  }
}

}  // namespace nerfslam::io_detail
