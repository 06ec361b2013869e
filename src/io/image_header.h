#pragma once
// Checks of an image file's bytes before OpenCV decodes them: the formats readImage accepts,
// recognised by signature; the size their headers declare (a corrupt header must not make the
// decoder allocate gigabytes); and that a PNG or JPEG is complete.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace nerfslam::io_detail {

enum class ImageFormat { kPng, kJpeg, kBmp, kTiff, kPnm };
const char* imageFormatName(ImageFormat f);  // "PNG", "JPEG", "BMP", "TIFF", "PNM"

struct ImageHeader {
  ImageFormat format = ImageFormat::kPng;
  int64_t width = -1;  // -1: not found in the bytes (the decoder reports the damage)
  int64_t height = -1;
};

// PNG, JPEG, BMP, TIFF (classic, not BigTIFF) and binary or ASCII PNM (P1-P6), by their first
// bytes; nullopt for anything else (OpenCV would decode more formats, which we do not accept).
std::optional<ImageHeader> sniffImageHeader(const std::vector<uint8_t>& b);

// OpenCV decodes a cut-off PNG or JPEG into a partly grey image with only a libpng/libjpeg warning,
// so look for the format's end. PNG: walk the chunks to IEND, each declared length within the bytes
// that follow (libpng would allocate and clear a declared 1 GB text chunk before finding the file
// short). JPEG: EOI (FF D9, possibly followed by padding or an appended trailer; searched in the
// last 64 KiB). Other formats pass. Throws Error naming `path`.
// PNG: each chunk's CRC is checked too (a flipped byte anywhere in the file).
void checkImageComplete(const std::vector<uint8_t>& b, ImageFormat format, const std::string& path);

// Decodes the JPEG's entropy data with libjpeg (at 1/8 scale) and throws an Error naming `path` on
// a warning that means damaged pixels ("corrupt JPEG image: Corrupt JPEG data: premature end of data
// segment", "... bad Huffman code", "... N extraneous bytes before marker 0xd9") or a decoding error
// (jpeg_check.cpp).
void checkJpegData(const std::vector<uint8_t>& b, const std::string& path);

}  // namespace nerfslam::io_detail
