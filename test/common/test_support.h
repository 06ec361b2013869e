#pragma once
// Shared test helpers: where the shared data lives, temporary directories, running the CLI.
#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>

#include <opencv2/core.hpp>

namespace nerfslam::test {

// ../shared/data next to the source tree, or $NERFSLAM_DATA_DIR when set.
std::filesystem::path dataDir();
// True when NERFSLAM_REQUIRE_DATA=1 (CI): a missing data folder is then a failure, not a skip.
bool dataRequired();
// The path of the built `nerfslam` binary.
std::filesystem::path cliPath();
// The repository this build was configured from (config/, docs/, test data generators).
std::filesystem::path sourceDir();

// A fresh directory under the system temp dir, removed (with contents) on destruction.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

// Writes `content` to `path` (binary, parents created): for building test inputs.
void writeText(const std::filesystem::path& path, const std::string& content);

// The message of the nerfslam::Error f throws; empty when it throws none (other exceptions escape).
std::string errorOf(const std::function<void()>& f);

struct CommandResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr interleaved
};
// Runs a shell command line and captures its output (stdout and stderr) and exit code
// (128 + signal when it was killed).
CommandResult runCommand(const std::string& command_line);
// Runs `nerfslam <args>` (args as one shell-quoted string) and captures its output and exit code.
CommandResult runCli(const std::string& args);

// A w x h 8-bit grey image of uniform random values (std::mt19937 seeded with `seed`).
cv::Mat noiseImage(int w, int h, uint32_t seed);

}  // namespace nerfslam::test

// In a TEST body: skips (fails under CI, NERFSLAM_REQUIRE_DATA=1) when `path` does not exist.
#define NERFSLAM_REQUIRE_PATH(path)                                                                            \
  if (!std::filesystem::exists(path)) {                                                                        \
    if (::nerfslam::test::dataRequired()) FAIL() << "required test data missing: " << (path);                  \
    GTEST_SKIP() << "test data not found: " << (path) << " (set NERFSLAM_DATA_DIR to the shared data folder)"; \
  }

// In a TEST body: resolves `sub` under the data dir into `var`, or skips (fails under CI) when absent.
#define NERFSLAM_REQUIRE_DATA(var, sub)                                  \
  const std::filesystem::path var = ::nerfslam::test::dataDir() / (sub); \
  NERFSLAM_REQUIRE_PATH(var)
