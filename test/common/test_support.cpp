#include "test_support.h"

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <random>

#include "nerfslam/core/error.h"

namespace nerfslam::test {
namespace fs = std::filesystem;

fs::path dataDir() {
  if (const char* env = std::getenv("NERFSLAM_DATA_DIR"); env && *env) return fs::path(env);
  return fs::path(NERFSLAM_SOURCE_DIR) / ".." / "shared" / "data";
}

bool dataRequired() {
  const char* env = std::getenv("NERFSLAM_REQUIRE_DATA");
  return env && std::string(env) == "1";
}

fs::path cliPath() { return fs::path(NERFSLAM_CLI_PATH); }

fs::path sourceDir() { return fs::path(NERFSLAM_SOURCE_DIR); }

TempDir::TempDir() {
  static std::atomic<int> counter{0};
  path_ = fs::temp_directory_path() / ("nerfslam_test_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
  fs::remove_all(path_);
  fs::create_directories(path_);
}

TempDir::~TempDir() {
  std::error_code ec;
  fs::permissions(path_, fs::perms::owner_all, fs::perm_options::add, ec);
  fs::remove_all(path_, ec);
}

std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

void writeText(const fs::path& path, const std::string& content) {
  if (path.has_parent_path()) fs::create_directories(path.parent_path());
  std::ofstream os(path, std::ios::binary | std::ios::trunc);
  os << content;
}

CommandResult runCommand(const std::string& command_line) {
  CommandResult r;
  FILE* p = ::popen((command_line + " 2>&1").c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.output.append(buf.data(), n);
  int status = ::pclose(p);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return r;
}

CommandResult runCli(const std::string& args) { return runCommand("'" + cliPath().string() + "' " + args); }

cv::Mat noiseImage(int w, int h, uint32_t seed) {
  cv::Mat img(h, w, CV_8U);
  std::mt19937 rng(seed);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) img.at<uint8_t>(y, x) = static_cast<uint8_t>(rng() & 255);
  return img;
}

}  // namespace nerfslam::test
