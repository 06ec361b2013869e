#include "nerfslam/io/ply_header.h"

#include <algorithm>
#include <charconv>
#include <sstream>

#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"

namespace nerfslam {
namespace fs = std::filesystem;

namespace {

constexpr size_t kMaxHeaderBytes = 64 * 1024;

// Bytes of a PLY scalar type; 0 for an unknown name.
uint64_t typeBytes(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

}  // namespace

PlyHeader checkPlyFile(const fs::path& path) {
  const std::string file = path.string();
  InputFile in = openInputFile(path, "PLY file");
  std::string head(kMaxHeaderBytes, '\0');
  in.stream.read(head.data(), static_cast<std::streamsize>(head.size()));
  head.resize(static_cast<size_t>(in.stream.gcount()));
  checkReadable(in.stream, path);
  PlyHeader h;
  size_t pos = 0, line_no = 0;
  bool ended = false;
  while (!ended) {
    const size_t eol = head.find('\n', pos);
    if (eol == std::string::npos) {
      if (line_no == 0) fail("{}: not a PLY file (no \"ply\" line)", file);
      fail("{}: PLY header without \"end_header\" in its first {}", file, formatBytes(kMaxHeaderBytes));
    }
    std::string line = head.substr(pos, eol - pos);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    pos = eol + 1;
    ++line_no;
    auto bad = [&](const std::string& what) {
      fail("{}: PLY header line {}: {} ('{}')", file, line_no, what, cutForMessage(line));
    };
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (line_no == 1) {
      if (line != "ply") fail("{}: not a PLY file (it does not start with a \"ply\" line)", file);
      continue;
    }
    if (word.empty() || word == "comment" || word == "obj_info") continue;
    if (word == "format") {
      std::string version;
      ls >> h.format >> version;
      if (h.format != "ascii" && h.format != "binary_little_endian" && h.format != "binary_big_endian")
        bad("unknown format (ascii, binary_little_endian or binary_big_endian expected)");
    } else if (word == "element") {
      PlyElement e;
      std::string count;
      ls >> e.name >> count;
      const auto r = std::from_chars(count.data(), count.data() + count.size(), e.count);
      if (e.name.empty() || count.empty() || r.ec != std::errc() || r.ptr != count.data() + count.size())
        bad("expected \"element NAME COUNT\" with a whole COUNT");
      h.elements.push_back(std::move(e));
    } else if (word == "property") {
      if (h.elements.empty()) bad("a property before any element");
      PlyElement& e = h.elements.back();
      std::string type, name;
      ls >> type;
      if (type == "list") {
        std::string count_type, item_type;
        ls >> count_type >> item_type >> name;
        const uint64_t cb = typeBytes(count_type);
        if (cb == 0 || typeBytes(item_type) == 0 || name.empty())
          bad("expected \"property list COUNT_TYPE ITEM_TYPE NAME\" with PLY types");
        e.min_bytes += cb;
        e.fixed_size = false;
      } else {
        ls >> name;
        const uint64_t b = typeBytes(type);
        if (b == 0 || name.empty()) bad("expected \"property TYPE NAME\" with a PLY type");
        e.min_bytes += b;
      }
      ++e.properties;
    } else if (word == "end_header") {
      ended = true;
    } else {
      bad("not a PLY header line");
    }
  }
  if (h.format.empty()) fail("{}: PLY header without a \"format\" line", file);
  h.header_bytes = pos;
  // The bytes after the header: the file's size when known, else what was read (a pipe's first
  // 64 KB; more may follow, so only a regular file's counts are checked).
  if (!in.size) return h;
  h.file_bytes = *in.size;
  uint64_t left = h.file_bytes - h.header_bytes;
  const bool ascii = h.format == "ascii";
  for (const PlyElement& e : h.elements) {
    // ASCII: at least a digit and a separator per property (the last separator may be missing).
    const uint64_t each = ascii ? 2 * static_cast<uint64_t>(e.properties) : e.min_bytes;
    if (each == 0) continue;
    const uint64_t room = ascii ? left + 1 : left;
    if (e.count > room / each) {
      const double bytes = static_cast<double>(e.count) * static_cast<double>(each);
      const std::string total = bytes < 1.8e19 ? formatBytes(static_cast<uint64_t>(bytes)) : "over 18 EB";
      if (ascii)
        fail("{}: the header declares {} '{}' elements of {} properties (at least {} in ASCII), but {} follow it", file,
             e.count, cutForMessage(e.name), e.properties, total, formatBytes(left));
      fail("{}: the header declares {} '{}' elements of {}{} bytes ({}), but {} follow it", file, e.count,
           cutForMessage(e.name), e.fixed_size ? "" : "at least ", each, total, formatBytes(left));
    }
    left -= std::min(left, e.count * each);
  }
  return h;
}

}  // namespace nerfslam
