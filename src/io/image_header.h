#pragma once
// The image formats readImage accepts, recognised by signature, and the size their headers declare,
// read before anything is decoded: a corrupt header must not make the decoder allocate gigabytes.
#include <cstdint>
#include <optional>
#include <vector>

namespace nerfslam::io_detail {

struct ImageHeader {
  const char* format = "";  // "PNG", "JPEG", "BMP", "TIFF", "PNM"
  int64_t width = -1;       // -1: not found in the bytes (the decoder reports the damage)
  int64_t height = -1;
};

// PNG, JPEG, BMP, TIFF (classic, not BigTIFF) and binary or ASCII PNM (P1-P6), by their first
// bytes; nullopt for anything else (OpenCV would decode more formats, which we do not accept).
std::optional<ImageHeader> sniffImageHeader(const std::vector<uint8_t>& b);

}  // namespace nerfslam::io_detail
