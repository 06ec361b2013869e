#include "nerfslam/core/input_file.h"

#include <cerrno>
#include <cstring>
#include <vector>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace fs = std::filesystem;

InputFile openInputFile(const fs::path& path, std::string_view what) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (st.type() == fs::file_type::not_found) fail("{}: {} not found", path.string(), what);
  if (st.type() == fs::file_type::directory)
    fail("{}: is a directory{}", path.string(), what == "file" ? std::string() : ", not a " + std::string(what));
  InputFile f;
  errno = 0;
  f.stream.open(path, std::ios::in | std::ios::binary);
  if (!f.stream) fail("{}: cannot open ({})", path.string(), errno != 0 ? std::strerror(errno) : "reason unknown");
  if (st.type() == fs::file_type::regular) {
    const uintmax_t n = fs::file_size(path, ec);
    if (!ec) f.size = static_cast<uint64_t>(n);
  }
  return f;
}

void checkReadable(const std::istream& in, const fs::path& path) {
  if (in.bad()) fail("{}: read error ({})", path.string(), errno != 0 ? std::strerror(errno) : "reason unknown");
}

std::string readInputFile(const fs::path& path, std::string_view what, uint64_t max_bytes) {
  InputFile f = openInputFile(path, what);
  if (f.size && *f.size > max_bytes)
    fail("{}: {}, more than the {} a {} may have", path.string(), formatBytes(*f.size), formatBytes(max_bytes), what);
  std::string s;
  if (f.size) s.reserve(static_cast<size_t>(*f.size));
  std::vector<char> buf(1 << 16);
  errno = 0;
  while (f.stream) {
    f.stream.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    const auto n = static_cast<size_t>(f.stream.gcount());
    if (n == 0) break;
    if (s.size() + n > max_bytes)
      fail("{}: more than the {} a {} may have", path.string(), formatBytes(max_bytes), what);
    s.append(buf.data(), n);
  }
  checkReadable(f.stream, path);
  return s;
}

bool sameFile(const fs::path& a, const fs::path& b) {
  std::error_code ea, eb;
  const fs::path ca = fs::weakly_canonical(a, ea), cb = fs::weakly_canonical(b, eb);
  return !ea && !eb && ca == cb;
}

bool isInsideDirectory(const fs::path& path, const fs::path& dir) {
  std::error_code ep, ed;
  const fs::path p = fs::weakly_canonical(path, ep), d = fs::weakly_canonical(dir, ed);
  if (ep || ed) return false;
  auto pi = p.begin(), di = d.begin();
  for (; di != d.end(); ++di, ++pi) {
    if (di->empty()) continue;  // the trailing "" of "dir/"
    if (pi == p.end() || *pi != *di) return false;
  }
  return true;
}

std::string formatBytes(uint64_t bytes) {
  if (bytes < 1000) return fmt::format("{} bytes", bytes);
  static const char* kUnits[] = {"KB", "MB", "GB", "TB", "PB", "EB"};
  double v = static_cast<double>(bytes) / 1000.0;
  int u = 0;
  while (v >= 1000.0 && u < 5) {
    v /= 1000.0;
    ++u;
  }
  return fmt::format(v < 10 ? "{:.2f} {}" : v < 100 ? "{:.1f} {}" : "{:.0f} {}", v, kUnits[u]);
}

}  // namespace nerfslam
