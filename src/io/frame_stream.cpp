// Live frame sources (a V4L2 camera, a video file played as one) and the recording of a stream's
// frames as a folder dataset (include/nerfslam/io/frame_stream.h).
#include "nerfslam/io/frame_stream.h"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <fstream>
#include <sstream>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/image_io.h"

namespace nerfslam {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

FrameStream::~FrameStream() = default;

bool isCameraSpec(const std::string& spec) { return spec.rfind("camera:", 0) == 0; }

std::string cameraDevice(const std::string& spec) {
  const std::string d = isCameraSpec(spec) ? spec.substr(7) : spec;
  if (d.empty()) fail("--dataset {}: no device after 'camera:' (camera:/dev/videoN or camera:N)", spec);
  if (std::all_of(d.begin(), d.end(), [](unsigned char c) { return std::isdigit(c); }) && d.size() < 6)
    return "/dev/video" + d;
  return d;
}

namespace {

double steadySeconds() { return std::chrono::duration<double>(Clock::now().time_since_epoch()).count(); }

// The video devices present, for the message about one that is not.
std::string videoDevices() {
  std::vector<std::string> found;
  std::error_code ec;
  for (fs::directory_iterator it("/dev", ec), end; !ec && it != end; it.increment(ec))
    if (it->path().filename().string().rfind("video", 0) == 0) found.push_back(it->path().string());
  std::sort(found.begin(), found.end());
  std::string s;
  for (const auto& f : found) s += (s.empty() ? "" : ", ") + f;
  return s.empty() ? "none" : s;
}

class CameraStream : public FrameStream {
 public:
  CameraStream(std::string device, int width, int height) : device_(std::move(device)) {
    std::error_code ec;
    if (!fs::exists(device_, ec))
      fail("{}: no such camera device (camera:{}); the video devices here: {}", device_, device_, videoDevices());
    if (!cap_.open(device_, cv::CAP_V4L2) || !cap_.isOpened())
      fail("{}: the camera does not open through V4L2 (busy, not a capture device, or no permission)", device_);
    if (width > 0 && height > 0) {
      cap_.set(cv::CAP_PROP_FRAME_WIDTH, width);
      cap_.set(cv::CAP_PROP_FRAME_HEIGHT, height);
    }
    spdlog::info("camera {}: opened through V4L2, {}x{} at {:.1f} frames/s (as the driver reports)", device_,
                 cap_.get(cv::CAP_PROP_FRAME_WIDTH), cap_.get(cv::CAP_PROP_FRAME_HEIGHT), cap_.get(cv::CAP_PROP_FPS));
  }

  std::string name() const override { return device_; }

  bool read(StreamFrame& f, std::string& why) override {
    const auto t0 = Clock::now();
    bool ok = false;
    try {
      ok = cap_.read(f.image) && !f.image.empty();
    } catch (const cv::Exception& e) {
      why = fmt::format("{}: reading a frame failed ({})", device_, e.what());
      return false;
    }
    if (!ok) {
      why = fmt::format("{}: the camera stopped delivering frames (none after {:.1f} s; {} frames read)", device_,
                        std::chrono::duration<double>(Clock::now() - t0).count(), frames_);
      return false;
    }
    // The driver's buffer time when it gives one (from the first frame on), else the steady clock.
    if (frames_ == 0) driver_clock_ = cap_.get(cv::CAP_PROP_POS_MSEC) > 0;
    f.timestamp = driver_clock_ ? cap_.get(cv::CAP_PROP_POS_MSEC) / 1000.0 : steadySeconds();
    ++frames_;
    return true;
  }

 private:
  std::string device_;
  cv::VideoCapture cap_;
  bool driver_clock_ = false;
  size_t frames_ = 0;
};

class VideoFileStream : public FrameStream {
 public:
  VideoFileStream(fs::path file, bool pace) : file_(std::move(file)), pace_(pace) {
    std::error_code ec;
    if (!fs::is_regular_file(file_, ec)) fail("{}: no such video file", file_.string());
    if (!cap_.open(file_.string(), cv::CAP_FFMPEG) || !cap_.isOpened())
      fail("{}: cannot open the video (not a video file, or a codec OpenCV's FFmpeg backend does not have)",
           file_.string());
  }

  std::string name() const override { return file_.string(); }

  bool read(StreamFrame& f, std::string& why) override {
    why.clear();
    if (!cap_.read(f.image) || f.image.empty()) return false;  // the end of the file
    f.timestamp = cap_.get(cv::CAP_PROP_POS_MSEC) / 1000.0;
    if (pace_) {
      if (frames_ == 0) {
        start_ = Clock::now();
        t0_ = f.timestamp;
      }
      std::this_thread::sleep_until(
          start_ + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(f.timestamp - t0_)));
    }
    ++frames_;
    return true;
  }

 private:
  fs::path file_;
  bool pace_;
  cv::VideoCapture cap_;
  size_t frames_ = 0;
  Clock::time_point start_;
  double t0_ = 0;
};

}  // namespace

std::unique_ptr<FrameStream> openCameraStream(const std::string& device, int width, int height) {
  return std::make_unique<CameraStream>(device, width, height);
}

std::unique_ptr<FrameStream> openVideoFileStream(const fs::path& file, bool pace) {
  return std::make_unique<VideoFileStream>(file, pace);
}

// ---- StreamRecording

StreamRecording::StreamRecording(std::string device, fs::path folder, const Camera& camera, const fs::path& camera_yaml)
    : device_(std::move(device)), folder_(std::move(folder)), camera_(camera) {
  std::error_code ec;
  if (fs::exists(folder_, ec) && !fs::is_empty(folder_, ec))
    fail(
        "{}: the folder for the camera's frames already holds files (an earlier run's?): choose another --out, or "
        "move it away",
        folder_.string());
  ensureDirectory(folder_);
  std::ifstream in(camera_yaml, std::ios::binary);
  std::stringstream yaml;
  yaml << in.rdbuf();
  if (!in) fail("{}: cannot read the camera file to copy it to {}", camera_yaml.string(), folder_.string());
  writeStringAtomic(folder_ / "camera.yaml", yaml.str());
  writer_ = std::thread([this] { writerLoop(); });
}

StreamRecording::~StreamRecording() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    closing_ = true;
  }
  changed_.notify_all();
  if (writer_.joinable()) writer_.join();
}

static std::string framePath(size_t i) { return fmt::format("{:06d}.png", i); }

size_t StreamRecording::append(double timestamp, const cv::Mat& image) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [&] { return pending_.size() < kMaxPending || !write_error_.empty(); });
  return appendLocked(timestamp, image);
}

std::optional<size_t> StreamRecording::tryAppend(double timestamp, const cv::Mat& image) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (pending_.size() >= kMaxPending && write_error_.empty()) return std::nullopt;
  return appendLocked(timestamp, image);
}

size_t StreamRecording::appendLocked(double timestamp, const cv::Mat& image) {
  rethrowWriteError();
  const size_t i = stamps_.size();
  stamps_.push_back(timestamp);
  pending_.emplace_back(i, image);
  changed_.notify_all();
  return i;
}

void StreamRecording::rethrowWriteError() const {
  if (!write_error_.empty()) throw Error(write_error_);
}

void StreamRecording::writerLoop() {
  auto last_times = Clock::now();
  size_t times_written = 0;
  for (;;) {
    std::pair<size_t, cv::Mat> item;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [&] { return closing_ || !pending_.empty(); });
      if (pending_.empty()) return;  // closing, everything written
      item = pending_.front();
    }
    std::string error;
    try {
      writeImageAtomic(folder_ / framePath(item.first), item.second);
    } catch (const std::exception& e) {
      error = e.what();
    }
    std::vector<double> stamps;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      pending_.pop_front();
      if (!error.empty() && write_error_.empty()) write_error_ = error;
      if (error.empty()) written_ = item.first + 1;
      if (written_ > times_written && Clock::now() - last_times > std::chrono::seconds(2))
        stamps.assign(stamps_.begin(), stamps_.begin() + static_cast<std::ptrdiff_t>(written_));
    }
    changed_.notify_all();
    if (!stamps.empty()) {
      try {
        writeTimes(stamps);  // the frames on disk so far, so an interrupted recording still replays
        times_written = stamps.size();
      } catch (const std::exception& e) {
        spdlog::warn("{}", e.what());  // flush() writes it again and reports a lasting problem
      }
      last_times = Clock::now();
    }
  }
}

void StreamRecording::writeTimes(const std::vector<double>& stamps) const {
  std::string s;
  for (double t : stamps) s += fmt::format("{}\n", t);  // the shortest text that parses back to t
  writeStringAtomic(folder_ / "times.txt", s);
}

void StreamRecording::flush() {
  std::vector<double> stamps;
  {
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait(lock, [&] { return pending_.empty(); });
    rethrowWriteError();
    stamps = stamps_;
  }
  writeTimes(stamps);
}

size_t StreamRecording::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stamps_.size();
}

double StreamRecording::timestamp(size_t i) const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (i >= stamps_.size())
    fail("camera {}: frame index {} out of range ({} recorded)", device_.string(), i, stamps_.size());
  return stamps_[i];
}

std::string StreamRecording::imagePath(size_t i) const { return (folder_ / framePath(i)).string(); }

DatasetFrame StreamRecording::load(size_t i, ImageMode mode) const {
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (i >= stamps_.size())
      fail("camera {}: frame index {} out of range ({} recorded)", device_.string(), i, stamps_.size());
    changed_.wait(lock, [&] { return written_ > i || !write_error_.empty(); });
    if (written_ <= i) rethrowWriteError();
  }
  DatasetFrame f;
  f.index = i;
  f.timestamp = timestamp(i);
  f.path = imagePath(i);
  f.image = readImage(f.path, mode);
  return f;
}

}  // namespace nerfslam
