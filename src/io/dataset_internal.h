#pragma once
// Private to the io module: the common frame-list dataset the readers build, and parsing helpers.
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/trajectory.h"

namespace nerfslam::io_detail {

namespace fs = std::filesystem;

struct FrameEntry {
  fs::path image;
  double timestamp = 0.0;
  std::optional<SE3> T_world_cam;
  fs::path depth;  // empty: none (transforms.json's depth_path / depth_file_path)
};

// A dataset that is a list of frames with one camera; every reader produces one.
class SequenceDataset : public Dataset {
 public:
  SequenceDataset(std::string kind, fs::path root) : kind_(std::move(kind)), root_(std::move(root)) {}

  std::string kind() const override { return kind_; }
  const fs::path& root() const override { return root_; }
  const Camera& camera() const override { return camera_; }
  size_t size() const override { return frames_.size(); }
  double timestamp(size_t i) const override;
  std::string imagePath(size_t i) const override;
  std::optional<SE3> groundTruth(size_t i) const override;
  bool hasGroundTruth() const override { return has_gt_; }
  DatasetFrame load(size_t i, ImageMode mode = ImageMode::kGray) const override;
  std::optional<double> aabbScale() const override { return aabb_scale_; }
  cv::Mat loadDepth(size_t i) const override;
  std::optional<NerfScene> nerfScene() const override { return nerf_scene_; }

  // Finishes opening: applies opts (start/stride/max_frames, camera override), checks the list is
  // non-empty and the timestamps strictly increase, decodes the first image and checks its size
  // against the camera. `own_camera` is the dataset's calibration (width/height 0: taken from the
  // first image); `camera_source` names where it came from, for messages. Without an own camera
  // and without an override, throws `missing_camera_hint`.
  void finish(std::vector<FrameEntry> frames, std::optional<Camera> own_camera, const std::string& camera_source,
              const DatasetOptions& opts, const std::string& missing_camera_hint = "");

  std::optional<double> aabb_scale_;
  double depth_scale_ = 1e-3;  // metres per depth-image unit (transforms.json)
  std::optional<NerfScene> nerf_scene_;

 private:
  const FrameEntry& at(size_t i) const;

  std::string kind_;
  fs::path root_;
  Camera camera_;
  std::vector<FrameEntry> frames_;
  bool has_gt_ = false;
};

// Readers. `root` exists; each throws nerfslam::Error naming the file on bad input.
std::unique_ptr<Dataset> openFolder(const fs::path& root, const DatasetOptions& opts);
std::unique_ptr<Dataset> openTum(const fs::path& root, const DatasetOptions& opts);
std::unique_ptr<Dataset> openEuroc(const fs::path& root, const DatasetOptions& opts);
std::unique_ptr<Dataset> openKitti(const fs::path& root, const DatasetOptions& opts);
std::unique_ptr<Dataset> openTransforms(const fs::path& root, const DatasetOptions& opts);
std::unique_ptr<Dataset> openMiddlebury(const fs::path& root, const DatasetOptions& opts);
std::unique_ptr<Dataset> openStrecha(const fs::path& root, const DatasetOptions& opts);
std::unique_ptr<Dataset> openTsukuba(const fs::path& root, const DatasetOptions& opts);
// A video file (reader_video.cpp); isVideoExtension: .mp4 .avi .mkv .mov .webm .m4v .mpg .mpeg.
std::unique_ptr<Dataset> openVideo(const fs::path& file, const DatasetOptions& opts);
bool isVideoExtension(const fs::path& path);
// A ROS 1 bag (bag/dataset_bag.cpp when librosbag_storage was found; else an Error saying the build
// has no bag support).
std::unique_ptr<Dataset> openBag(const fs::path& file, const DatasetOptions& opts);

// ---- parsing helpers (dataset_util.cpp) ----

// One line of a text file with its 1-based number.
struct Line {
  size_t number = 0;
  std::string text;
};
// Lines that are neither blank nor comments (first non-space character '#'), trimmed of whitespace
// as std::isspace defines it (so each holds at least one splitTokens token). Throws naming the
// file when it cannot be read.
std::vector<Line> readDataLines(const fs::path& file);
// Splits on whitespace and (when `commas`) commas.
std::vector<std::string> splitTokens(const std::string& s, bool commas = false);
// Parses a finite number; throws "FILE:LINE: WHAT 'tok' is not a number".
double parseNumber(const std::string& tok, const fs::path& file, size_t line, const std::string& what);
// Parses all tokens of a line as numbers; throws naming file and line when fewer than `min_count`.
std::vector<double> parseNumbers(const Line& line, const fs::path& file, size_t min_count, const std::string& what,
                                 bool commas = false);
// Throws "FILE:LINE: timestamp T is not after the previous one (P)" when t <= prev.
void checkIncreasing(double prev, double t, const fs::path& file, size_t line);

// An image width or height read as a number: must be a whole number in [1, 65535], checked before
// any conversion to int (a cast of 1e300 is undefined behaviour). Errors name `where` and `field`.
int imageDimension(double value, const std::string& where, const std::string& field);

struct TimedPose {
  double t = 0.0;
  SE3 pose;
};
// The poses of a trajectory read by io/trajectory.h; throws naming the file and data line when the
// timestamps do not strictly increase.
std::vector<TimedPose> checkedTimes(const Trajectory& traj, const fs::path& file);
// The pose nearest in time to t within `tol` seconds (trajectory sorted by time).
std::optional<SE3> nearestPose(const std::vector<TimedPose>& traj, double t, double tol);
// Geodesic interpolation between the samples bracketing t when they are at most 2 `tol` apart;
// else the nearest within `tol`.
std::optional<SE3> interpolatePose(const std::vector<TimedPose>& traj, double t, double tol);

// Image file `stem` + one of the image extensions, when `stem` itself has none; std::nullopt when
// no file exists; an Error naming the path when it is a directory.
std::optional<fs::path> resolveImage(const fs::path& path);
// "INDEX:LINE: image PATH not found" (or "... is a directory, not an image file") unless `image`
// exists and is not a directory.
void checkListedImage(const fs::path& image, const fs::path& index, size_t line);

// Reads a YAML file that may start with OpenCV's "%YAML:1.0" directive (yaml-cpp rejects it).
std::string readYamlText(const fs::path& file);

}  // namespace nerfslam::io_detail
