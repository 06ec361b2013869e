#pragma once
// Little-endian byte writer and bounds-checked reader for the tracking module's binary files
// (vocabulary, keyframe database). Private to src/tracking.
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>

#include "nerfslam/core/crc32.h"
#include "nerfslam/core/error.h"

namespace nerfslam::blob {

static_assert(sizeof(float) == 4, "32-bit floats");

class Writer {
 public:
  void bytes(const void* p, size_t n) { out_.append(static_cast<const char*>(p), n); }
  void u32(uint32_t v) {
    uint8_t b[4];
    for (int i = 0; i < 4; ++i) b[i] = uint8_t(v >> (8 * i));
    bytes(b, 4);
  }
  void u64(uint64_t v) {
    u32(uint32_t(v));
    u32(uint32_t(v >> 32));
  }
  void f32(float v) {
    uint32_t u;
    std::memcpy(&u, &v, 4);
    u32(u);
  }
  // Appends the CRC-32 of everything written so far and returns the finished blob.
  std::string finish() {
    u32(crc32(out_));
    return std::move(out_);
  }

 private:
  std::string out_;
};

// Reads fields of `data`, whose last 4 bytes (the CRC) are checked by the constructor. Every read
// names the field in its error when the data ends before it.
class Reader {
 public:
  Reader(std::string_view data, std::string name, std::string_view magic) : name_(std::move(name)) {
    if (data.size() < magic.size() || data.substr(0, magic.size()) != magic)
      throw fieldError(name_, "magic", "not a " + std::string(magic.substr(0, magic.find('\0'))) + " file");
    if (data.size() < magic.size() + 4) throw fieldError(name_, "crc32", "truncated: the file ends before it");
    body_ = data.substr(0, data.size() - 4);
    pos_ = magic.size();
    uint32_t stored = 0;
    for (int i = 0; i < 4; ++i) stored |= uint32_t(uint8_t(data[data.size() - 4 + size_t(i)])) << (8 * i);
    crc_ok_ = stored == crc32(body_);
  }
  // Call after the header fields (version first) so that a file of another version is reported
  // as such rather than as a checksum mismatch.
  void checkCrc() const {
    if (!crc_ok_) throw fieldError(name_, "crc32", "checksum mismatch: the file is truncated or corrupted");
  }
  size_t remaining() const { return body_.size() - pos_; }
  const std::string& name() const { return name_; }
  const char* take(size_t n, const std::string& field) {
    if (n > remaining())
      throw fieldError(name_, field,
                       "truncated: needs " + std::to_string(n) + " bytes, " + std::to_string(remaining()) + " left");
    const char* p = body_.data() + pos_;
    pos_ += n;
    return p;
  }
  uint32_t u32(const std::string& field) {
    const char* p = take(4, field);
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= uint32_t(uint8_t(p[i])) << (8 * i);
    return v;
  }
  uint64_t u64(const std::string& field) {
    const uint64_t lo = u32(field);
    return lo | (uint64_t(u32(field)) << 32);
  }
  float f32(const std::string& field) {
    const uint32_t u = u32(field);
    float v;
    std::memcpy(&v, &u, 4);
    return v;
  }
  // A count of records of `record_bytes` each that must fit in what is left (caps allocations).
  uint32_t count(const std::string& field, size_t record_bytes) {
    const uint32_t n = u32(field);
    if (record_bytes > 0 && size_t(n) > remaining() / record_bytes)
      throw fieldError(name_, field,
                       std::to_string(n) + " records of " + std::to_string(record_bytes) + " bytes do not fit in the " +
                           std::to_string(remaining()) + " bytes left");
    return n;
  }
  void expectEnd() const {
    if (remaining() != 0) throw fieldError(name_, "end", std::to_string(remaining()) + " unexpected trailing bytes");
  }

 private:
  std::string name_;
  std::string_view body_;
  size_t pos_ = 0;
  bool crc_ok_ = false;
};

}  // namespace nerfslam::blob
