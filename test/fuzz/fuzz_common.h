#pragma once
// Shared helpers of the libFuzzer targets (see docs/fuzzing.md).
//
// Most parsers take a path, so a target writes its input into a per-process scratch folder laid out
// as the parser expects and calls it there. Inputs of targets that read several files are split
// into sections at the line kSectionSeparator: section k becomes file k of the target's list; files
// past the last section are absent (so the fuzzer also explores missing optional files).
//
// A nerfslam::Error is the expected outcome of bad input. Anything else (another exception, a
// crash, a sanitizer report, a leak, a timeout) is a finding.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

#include <spdlog/spdlog.h>

#include "nerfslam/core/error.h"

namespace nerfslam::fuzz {

namespace fs = std::filesystem;

inline constexpr std::string_view kSectionSeparator = "\n~~~~\n";

// A fresh folder under $TMPDIR (or /dev/shm, or /tmp), removed at exit.
inline const fs::path& scratchDir() {
  static const fs::path dir = [] {
    std::string base;
    if (const char* t = std::getenv("TMPDIR"); t && *t)
      base = t;
    else if (fs::is_directory("/dev/shm"))
      base = "/dev/shm";
    else
      base = "/tmp";
    std::string tmpl = base + "/nerfslam_fuzz_XXXXXX";
    if (!mkdtemp(tmpl.data())) {
      std::perror("mkdtemp");
      std::abort();
    }
    static struct Cleanup {
      fs::path p;
      ~Cleanup() {
        std::error_code ec;
        fs::remove_all(p, ec);
      }
    } cleanup{tmpl};
    return fs::path(tmpl);
  }();
  return dir;
}

// The shared real data: $NERFSLAM_DATA_DIR, else ../shared/data next to the source tree.
inline fs::path dataDir() {
  if (const char* d = std::getenv("NERFSLAM_DATA_DIR"); d && *d) return d;
  return fs::path(NERFSLAM_FUZZ_SOURCE_DIR) / ".." / "shared" / "data";
}

inline void writeBytes(const fs::path& path, std::string_view bytes) {
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!f) {
    std::fprintf(stderr, "fuzz harness: cannot write %s\n", path.c_str());
    std::abort();
  }
}

inline std::vector<std::string_view> splitSections(const uint8_t* data, size_t size) {
  std::string_view in(reinterpret_cast<const char*>(data), size);
  std::vector<std::string_view> out;
  while (true) {
    const size_t p = in.find(kSectionSeparator);
    if (p == std::string_view::npos) {
      out.push_back(in);
      return out;
    }
    out.push_back(in.substr(0, p));
    in.remove_prefix(p + kSectionSeparator.size());
  }
}

// Writes the sections to `files` under `root` (removing every file of the list first).
inline void writeSections(const fs::path& root, const std::vector<std::string>& files, const uint8_t* data,
                          size_t size) {
  std::error_code ec;
  for (const auto& f : files) fs::remove(root / f, ec);
  const auto sections = splitSections(data, size);
  for (size_t i = 0; i < sections.size() && i < files.size(); ++i) writeBytes(root / files[i], sections[i]);
}

inline void quietLogs() { spdlog::set_level(spdlog::level::off); }

// Runs `f`; a nerfslam::Error is an expected outcome, anything else propagates to libFuzzer
// (which reports an uncaught exception as a crash). With NERFSLAM_FUZZ_VERBOSE=1 in the environment
// the outcome is printed (to check what a seed or reproducer reaches).
template <typename F>
void expectOnlyError(F&& f) {
  static const bool verbose = [] {
    const char* v = std::getenv("NERFSLAM_FUZZ_VERBOSE");
    return v && *v && *v != '0';
  }();
  try {
    f();
    if (verbose) std::fprintf(stderr, "fuzz harness: accepted\n");
  } catch (const nerfslam::Error& e) {
    if (verbose) std::fprintf(stderr, "fuzz harness: Error: %s\n", e.what());
  }
}

}  // namespace nerfslam::fuzz
