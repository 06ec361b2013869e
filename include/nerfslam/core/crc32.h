#pragma once
// CRC-32 (IEEE 802.3, the polynomial of zlib and PNG), the checksum of the map folder's files and of
// NeRF model files. crc32(b, m, crc32(a, n)) continues a checksum over a second piece of data.
#include <cstddef>
#include <cstdint>
#include <string_view>

namespace nerfslam {

uint32_t crc32(const void* data, size_t n, uint32_t crc = 0);
inline uint32_t crc32(std::string_view s, uint32_t crc = 0) { return crc32(s.data(), s.size(), crc); }

}  // namespace nerfslam
