#include "nerfslam/core/atomic_file.h"

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdlib>
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

// Temporary files of `path` left by processes that died mid-write (kill -9, power cut): named
// <stem>.tmp.<pid>.<n><ext> by uniqueSuffix() with a pid that no longer runs. Those of live
// processes (another writer of the same file) are left alone.
void removeStaleTemporaries(const fs::path& path) {
  const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
  const std::string prefix = path.stem().string() + ".tmp.", ext = path.extension().string();
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.size() <= prefix.size() + ext.size() || name.compare(0, prefix.size(), prefix) != 0 ||
        name.compare(name.size() - ext.size(), ext.size(), ext) != 0)
      continue;
    const std::string rest = name.substr(prefix.size(), name.size() - prefix.size() - ext.size());  // <pid>.<n>
    const size_t dot = rest.find('.');
    if (dot == 0 || dot == std::string::npos || rest.find_first_not_of("0123456789.") != std::string::npos) continue;
    const long pid = std::strtol(rest.substr(0, dot).c_str(), nullptr, 10);
    if (pid <= 0 || pid == static_cast<long>(::getpid())) continue;
    if (::kill(static_cast<pid_t>(pid), 0) == 0 || errno != ESRCH) continue;  // alive (or not ours to judge)
    std::error_code rm;
    fs::remove(it->path(), rm);
  }
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
  removeStaleTemporaries(path_);
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
