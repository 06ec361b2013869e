#pragma once
// The header of a PLY file from outside (`render-preview --points`), read and checked against the
// file's size before a PLY reader allocates what it declares. PCL's reader allocates a declared
// element count before it finds the data short: a 1.3 KB file declaring 200 M vertices took 2.4 GB
// and 11 s to be refused.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace nerfslam {

struct PlyElement {
  std::string name;
  uint64_t count = 0;
  int properties = 0;      // scalar and list properties
  uint64_t min_bytes = 0;  // binary: the bytes of one element with every list empty
  bool fixed_size = true;  // no list property: every element takes min_bytes
};

struct PlyHeader {
  std::string format;         // "ascii", "binary_little_endian" or "binary_big_endian"
  uint64_t header_bytes = 0;  // up to and including the "end_header" line
  uint64_t file_bytes = 0;
  std::vector<PlyElement> elements;
};

// Reads and checks the header of `path`: the "ply" magic, a known format, element and property lines
// PLY defines, "end_header" within the first 64 KB, and every element count within what the bytes
// after the header can hold (binary: count x the element's smallest size; ASCII: at least 2 bytes, a
// digit and a separator, per property). Throws an Error naming the file, and for a count the element
// and the count: "cloud.ply: the header declares 200000000 'vertex' elements of 12 bytes (2.40 GB),
// but 120 bytes follow it".
PlyHeader checkPlyFile(const std::filesystem::path& path);

}  // namespace nerfslam
