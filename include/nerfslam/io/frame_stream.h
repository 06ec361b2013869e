#pragma once
// Live frame sources and their recording. A live camera (`run --dataset camera:/dev/videoN`) is a
// stream, not a random-access Dataset: frames come at the device's rate, once. `nerfslam run` reads
// a FrameStream and records every frame that reaches tracking into a StreamRecording, which is a
// Dataset (kind "camera") of the frames recorded so far: the end-of-run outputs load frames from it
// by index, and its folder is a `folder:` dataset that replays the run.
//
//   auto cam = openCameraStream("/dev/video0", 640, 480);
//   StreamFrame f;
//   std::string why;
//   while (cam->read(f, why)) ...        // false: ended (why empty) or failed (why says how)
//
// The capture source is injectable (RunOptions::open_stream): openVideoFileStream plays a video
// file through the same VideoCapture path, and tests implement FrameStream themselves.
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/io/dataset.h"

namespace nerfslam {

struct StreamFrame {
  double timestamp = 0.0;  // seconds, the source's capture clock
  cv::Mat image;           // 8-bit BGR or grey, as delivered
};

class FrameStream {
 public:
  virtual ~FrameStream();
  // The device or file, for messages ("/dev/video0").
  virtual std::string name() const = 0;
  // Blocks until the next frame. true: `f` holds it. false: the stream is over; `why` is empty when
  // it ended normally (a file's last frame) and says what failed otherwise, naming the source.
  virtual bool read(StreamFrame& f, std::string& why) = 0;
};

// True for a "camera:DEVICE" dataset spec.
bool isCameraSpec(const std::string& spec);
// The device of "camera:/dev/videoN" or "camera:N" (then "/dev/videoN"). Throws an Error for an
// empty device.
std::string cameraDevice(const std::string& spec);

// A V4L2 camera through OpenCV's VideoCapture (CAP_V4L2), asked for width x height (the
// calibration's; the frames are checked by the caller). Timestamps: the driver's buffer time
// (CAP_PROP_POS_MSEC, the kernel's monotonic clock) when it gives one, else the steady clock when
// the frame is returned. read() fails, naming the device and the seconds waited, when the device
// stops delivering (OpenCV's V4L2 read waits 10 s for a frame; the environment's
// OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT changes that) or errs. Throws an Error naming the device when it does not exist or
// does not open.
std::unique_ptr<FrameStream> openCameraStream(const std::string& device, int width, int height);

// A video file played as a camera through the same VideoCapture path (CAP_FFMPEG): timestamps from
// the container, delivered at that rate when `pace` (as a camera would), else as fast as decoded;
// read() returns false with an empty `why` after the last frame. Throws an Error naming the file
// when it does not open.
std::unique_ptr<FrameStream> openVideoFileStream(const std::filesystem::path& file, bool pace);

// The frames of a stream that reached tracking, written as a `folder:` dataset while the run goes:
// FOLDER/000000.png, 000001.png, ... (lossless), times.txt (one timestamp per image, written so it
// parses back to the identical double) and camera.yaml (the calibration file's bytes). PNGs are
// written by a thread of its own (append() blocks only when kMaxPending frames wait), each
// atomically; times.txt is replaced atomically at most every 2 s and at flush(). As a Dataset (kind
// "camera", root() the device) it holds the frames appended so far, load(i) reading frame i's PNG
// once it is written.
class StreamRecording : public Dataset {
 public:
  static constexpr size_t kMaxPending = 64;

  // `folder` must not exist or be empty (an Error otherwise: the old frames would be replayed with
  // the new ones). `camera_yaml`: the calibration file, copied in.
  StreamRecording(std::string device, std::filesystem::path folder, const Camera& camera,
                  const std::filesystem::path& camera_yaml);
  ~StreamRecording() override;

  // Records the next frame and returns its index. Throws the Error of a write that failed. Waits
  // while kMaxPending frames wait for the writer.
  size_t append(double timestamp, const cv::Mat& image);
  // As append, but never waits: nullopt (nothing recorded) while kMaxPending frames wait for the
  // writer, i.e. while the disk is slower than the camera (the tracking thread's call: it must not
  // wait for the disk, and drops the frame instead).
  std::optional<size_t> tryAppend(double timestamp, const cv::Mat& image);
  // Waits until every frame is on disk and writes times.txt. Throws the Error of a write that failed.
  void flush();
  const std::filesystem::path& folder() const { return folder_; }

  std::string kind() const override { return "camera"; }
  const std::filesystem::path& root() const override { return device_; }
  const Camera& camera() const override { return camera_; }
  size_t size() const override;
  double timestamp(size_t i) const override;
  std::string imagePath(size_t i) const override;
  std::optional<SE3> groundTruth(size_t) const override { return std::nullopt; }
  bool hasGroundTruth() const override { return false; }
  DatasetFrame load(size_t i, ImageMode mode = ImageMode::kGray) const override;

 private:
  void writerLoop();
  void writeTimes(const std::vector<double>& stamps) const;
  void rethrowWriteError() const;                               // under mutex_
  size_t appendLocked(double timestamp, const cv::Mat& image);  // under mutex_, room checked

  std::filesystem::path device_, folder_;
  Camera camera_;
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  std::vector<double> stamps_;  // every appended frame's
  size_t written_ = 0;          // frames 0 .. written_-1 are on disk
  std::deque<std::pair<size_t, cv::Mat>> pending_;
  std::string write_error_;
  bool closing_ = false;
  std::thread writer_;
};

}  // namespace nerfslam
