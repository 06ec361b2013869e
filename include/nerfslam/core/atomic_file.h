#pragma once
// Atomic file output: everything is written to a temporary file in the destination's directory,
// flushed to disk, then renamed over the destination. A crash or kill at any point leaves either the
// previous file or the complete new one, never a half-written file.
#include <filesystem>
#include <functional>
#include <ostream>
#include <string_view>

namespace nerfslam {

// Calls `writer` on a stream to the temporary file, then commits. Throws nerfslam::Error naming
// `path` if the directory is unwritable, the writer throws, or the stream fails.
void writeFileAtomic(const std::filesystem::path& path, const std::function<void(std::ostream&)>& writer);
void writeStringAtomic(const std::filesystem::path& path, std::string_view content);

// For writers that insist on a file name (cv::imwrite, PCL): write to tempPath(), then commit().
// The destructor removes the temporary file if commit() was not reached.
class AtomicOutput {
 public:
  explicit AtomicOutput(std::filesystem::path path);
  ~AtomicOutput();
  AtomicOutput(const AtomicOutput&) = delete;
  AtomicOutput& operator=(const AtomicOutput&) = delete;

  // Same directory and extension as the destination (some writers pick the format by extension).
  const std::filesystem::path& tempPath() const { return temp_; }
  const std::filesystem::path& path() const { return path_; }
  // fsyncs the temporary file, renames it over the destination, fsyncs the directory, and removes
  // temporary files of the same destination left by processes that died while writing it.
  void commit();

 private:
  std::filesystem::path path_;
  std::filesystem::path temp_;
  bool committed_ = false;
};

// Creates `dir` (and parents) or throws an Error naming it, e.g. when the parent is unwritable.
void ensureDirectory(const std::filesystem::path& dir);

}  // namespace nerfslam
