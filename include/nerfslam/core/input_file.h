#pragma once
// Opening outside input for reading: every reader of a file the user named, or a dataset lists,
// goes through these, so the errors are the same everywhere and name the file:
//   "PATH: WHAT not found"                 (WHAT: "file", "NeRF model file", "image file", ...)
//   "PATH: is a directory, not a WHAT"     (std::ifstream opens a directory without complaint, and
//                                          reading it fails later with a misleading error, or
//                                          std::bad_alloc after seeking to its "end")
//   "PATH: cannot open (Permission denied)"
//   "PATH: read error (Input/output error)"
//   "PATH: 12.4 MB, more than the 1 MB a WHAT may have"   (readInputFile with a limit)
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <string>
#include <string_view>

namespace nerfslam {

struct InputFile {
  std::ifstream stream;          // open, binary
  std::optional<uint64_t> size;  // bytes, for a regular file (none for a pipe or a device)
};

// Opens `path` for reading (binary). `what` names the kind of file in the errors above.
InputFile openInputFile(const std::filesystem::path& path, std::string_view what = "file");

constexpr uint64_t kNoSizeLimit = std::numeric_limits<uint64_t>::max();

// The whole file. A file larger than `max_bytes` is refused before anything is read when its size
// is known, else as soon as more than that has been read.
std::string readInputFile(const std::filesystem::path& path, std::string_view what = "file",
                          uint64_t max_bytes = kNoSizeLimit);

// Fails with "PATH: read error (REASON)" when `in` is bad (an I/O error; eof and fail are not).
void checkReadable(const std::istream& in, const std::filesystem::path& path);

// Outputs over inputs. Paths are compared in their canonical form (symlinks and "..", resolved as far
// as they exist), so "out/../data/x.txt" is "data/x.txt"; an output need not exist yet.
// True when `a` and `b` name the same file.
bool sameFile(const std::filesystem::path& a, const std::filesystem::path& b);
// True when `path` is `dir` or lies inside it.
bool isInsideDirectory(const std::filesystem::path& path, const std::filesystem::path& dir);

// "532 bytes", "12.4 KB", "2.45 GB" (powers of 1000, as file managers print them).
std::string formatBytes(uint64_t bytes);

}  // namespace nerfslam
