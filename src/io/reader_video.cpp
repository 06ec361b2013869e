// A video file (OpenCV VideoCapture, FFmpeg backend: mp4, avi, mkv, ...). Opening decodes the
// whole file once: it counts the frames, takes each one's timestamp from the container
// (CAP_PROP_POS_MSEC) and checks that every frame has the first one's size. load(i) then decodes
// sequentially (the next frame is read, frames in between are grabbed, the last one read is kept;
// going further back reopens the file), under a mutex: a video is one stream. Camera: DatasetOptions::camera_override
// (a video has no calibration). No ground truth.
//
// Timestamps: must increase. A decoder flushing its last frames (H.264 with B-frames) reports 0 for
// them; such a 0 after the first frame is taken as the previous frame's time + 1 / the container's
// frame rate (counted in the log); any other stamp that does not increase is an error naming the
// frame.
#include <mutex>

#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "dataset_internal.h"
#include "nerfslam/core/error.h"

namespace nerfslam::io_detail {

namespace {

class VideoDataset : public Dataset {
 public:
  VideoDataset(fs::path file, const DatasetOptions& opts) : file_(std::move(file)) {
    if (!opts.camera_override)
      fail("{}: a video has no camera calibration; give a camera YAML ({})", file_.string(), opts.camera_option);
    if (opts.stride == 0) fail("dataset options: field 'stride': must be >= 1");
    open();
    const double fps = cap_.get(cv::CAP_PROP_FPS);
    std::vector<double> stamps;  // of every frame in the file
    cv::Mat frame;
    int first_w = 0, first_h = 0, flushed = 0;
    while (cap_.read(frame)) {
      const size_t n = stamps.size();
      if (n == 0) {
        first_w = frame.cols;
        first_h = frame.rows;
      } else if (frame.cols != first_w || frame.rows != first_h) {
        fail("{}: frame {} is {}x{}, the video's first frame is {}x{}: the video changes resolution", file_.string(), n,
             frame.cols, frame.rows, first_w, first_h);
      }
      double t = cap_.get(cv::CAP_PROP_POS_MSEC) / 1000.0;
      if (!std::isfinite(t)) fail("{}: frame {}: the container gives no timestamp", file_.string(), n);
      if (n > 0 && !(t > stamps.back())) {
        if (t == 0.0 && fps > 0 && std::isfinite(fps)) {
          t = stamps.back() + 1.0 / fps;  // a flushed frame without a stamp
          ++flushed;
        } else {
          fail("{}: field 'timestamp' of frame {}: {} s is not after the previous frame's ({} s)", file_.string(), n,
               numberForMessage(t, 6), numberForMessage(stamps.back(), 6));
        }
      }
      stamps.push_back(t);
    }
    if (stamps.empty())
      fail("{}: no frame could be decoded (not a video, or a codec OpenCV's FFmpeg backend does not have)",
           file_.string());
    if (flushed > 0)
      spdlog::warn("{}: {} frame(s) at the end without a container timestamp: given the previous one's + 1/{:.3f} s",
                   file_.string(), flushed, fps);
    for (size_t i = opts.start; i < stamps.size(); i += opts.stride) {
      if (opts.max_frames > 0 && index_.size() >= opts.max_frames) break;
      index_.push_back(i);
      stamps_.push_back(stamps[i]);
    }
    if (index_.empty())
      fail("video dataset {}: no frames left after skipping the first {} of {}", file_.string(), opts.start,
           stamps.size());
    camera_ = loadCameraYaml(*opts.camera_override);
    const std::string source = opts.camera_override->string();
    if (camera_.width != first_w || camera_.height != first_h)
      fail("{}: camera is {}x{} but the video's frames are {}x{} ({})", source, camera_.width, camera_.height, first_w,
           first_h, file_.string());
    camera_.validate(source);
    open();  // back to the first frame
    spdlog::info("opened video {}: {} frames ({} in the file), {}x{}, {:.3f} .. {:.3f} s", file_.string(),
                 index_.size(), stamps.size(), first_w, first_h, stamps_.front(), stamps_.back());
  }

  std::string kind() const override { return "video"; }
  const fs::path& root() const override { return file_; }
  const Camera& camera() const override { return camera_; }
  size_t size() const override { return index_.size(); }
  double timestamp(size_t i) const override { return stamps_.at(check(i)); }
  std::string imagePath(size_t i) const override { return file_.string() + "#" + std::to_string(index_.at(check(i))); }
  std::optional<SE3> groundTruth(size_t) const override { return std::nullopt; }
  bool hasGroundTruth() const override { return false; }

  DatasetFrame load(size_t i, ImageMode mode) const override {
    check(i);
    DatasetFrame f;
    f.index = i;
    f.timestamp = stamps_[i];
    f.path = imagePath(i);
    cv::Mat bgr;
    {
      std::lock_guard<std::mutex> lk(mutex_);
      const size_t want = index_[i];
      if (want + 1 == next_ && !last_.empty()) {
        bgr = last_.clone();  // the frame read last, asked for again
      } else {
        if (want < next_) open();
        while (next_ < want) {
          if (!cap_.grab()) fail("{}: the video ends at frame {}, before frame {}", file_.string(), next_, want);
          ++next_;
        }
        if (!cap_.read(bgr)) fail("{}: frame {} cannot be decoded", file_.string(), want);
        ++next_;
        last_ = bgr.clone();
      }
    }
    if (bgr.cols != camera_.width || bgr.rows != camera_.height)
      fail("{}: frame {} is {}x{} but the video's first frame (and camera) are {}x{}: the video changes resolution",
           file_.string(), index_[i], bgr.cols, bgr.rows, camera_.width, camera_.height);
    if (mode == ImageMode::kGray && bgr.channels() == 3)
      cv::cvtColor(bgr, f.image, cv::COLOR_BGR2GRAY);
    else if (mode == ImageMode::kColor && bgr.channels() == 1)
      cv::cvtColor(bgr, f.image, cv::COLOR_GRAY2BGR);
    else
      f.image = bgr;
    return f;
  }

 private:
  size_t check(size_t i) const {
    if (i >= index_.size())
      fail("video dataset {}: frame index {} out of range (size {})", file_.string(), i, index_.size());
    return i;
  }
  // (Re)opens the file at its first frame.
  void open() const {
    cap_.release();
    if (!cap_.open(file_.string(), cv::CAP_FFMPEG) || !cap_.isOpened())
      fail(
          "{}: cannot open the video (not a video file, or a container or codec OpenCV's FFmpeg backend does not "
          "have)",
          file_.string());
    next_ = 0;
    last_.release();
  }

  fs::path file_;
  Camera camera_;
  std::vector<size_t> index_;  // dataset frame -> frame of the file
  std::vector<double> stamps_;
  mutable std::mutex mutex_;
  mutable cv::VideoCapture cap_;
  mutable size_t next_ = 0;  // the file's frame the next read returns
  mutable cv::Mat last_;     // the frame read last (next_ - 1)
};

}  // namespace

bool isVideoExtension(const fs::path& path) {
  std::string e = path.extension().string();
  for (char& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  for (const char* v : {".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg"})
    if (e == v) return true;
  return false;
}

std::unique_ptr<Dataset> openVideo(const fs::path& file, const DatasetOptions& opts) {
  std::error_code ec;
  if (fs::is_directory(file, ec)) fail("{}: is a directory, not a video file", file.string());
  return std::make_unique<VideoDataset>(file, opts);
}

}  // namespace nerfslam::io_detail
