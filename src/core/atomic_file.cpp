#include "nerfslam/core/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <random>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace fs = std::filesystem;

namespace {

std::string uniqueSuffix() {
  static std::atomic<unsigned> counter{0};
  return fmt::format(".tmp.{}.{}", static_cast<long>(::getpid()), counter.fetch_add(1));
}

void fsyncPath(const fs::path& p, bool directory) {
  int fd = ::open(p.c_str(), directory ? (O_RDONLY | O_DIRECTORY) : O_RDONLY);
  if (fd < 0) return;  // best effort for directories on filesystems that refuse it
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0 && !directory) fail("{}: cannot flush to disk: {}", p.string(), std::strerror(err));
}

}  // namespace

void ensureDirectory(const fs::path& dir) {
  if (dir.empty()) return;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    fail("{}: cannot create output directory: {}", dir.string(), ec ? ec.message() : "not a directory");
}

AtomicOutput::AtomicOutput(fs::path path) : path_(std::move(path)) {
  fs::path dir = path_.has_parent_path() ? path_.parent_path() : fs::path(".");
  if (!fs::is_directory(dir)) fail("{}: output directory '{}' does not exist", path_.string(), dir.string());
  temp_ = dir / (path_.stem().string() + uniqueSuffix() + path_.extension().string());
}

AtomicOutput::~AtomicOutput() {
  if (!committed_) {
    std::error_code ec;
    fs::remove(temp_, ec);
  }
}

void AtomicOutput::commit() {
  if (!fs::exists(temp_)) fail("{}: nothing was written (temporary file {} missing)", path_.string(), temp_.string());
  fsyncPath(temp_, false);
  std::error_code ec;
  fs::rename(temp_, path_, ec);
  if (ec) fail("{}: cannot replace file: {}", path_.string(), ec.message());
  committed_ = true;
  fsyncPath(path_.has_parent_path() ? path_.parent_path() : fs::path("."), true);
}

void writeFileAtomic(const fs::path& path, const std::function<void(std::ostream&)>& writer) {
  AtomicOutput out(path);
  {
    std::ofstream os(out.tempPath(), std::ios::binary | std::ios::trunc);
    if (!os) fail("{}: cannot open for writing: {}", path.string(), std::strerror(errno));
    writer(os);
    os.flush();
    if (!os) fail("{}: write failed (disk full?)", path.string());
  }
  out.commit();
}

void writeStringAtomic(const fs::path& path, std::string_view content) {
  writeFileAtomic(path,
                  [&](std::ostream& os) { os.write(content.data(), static_cast<std::streamsize>(content.size())); });
}

}  // namespace nerfslam
