#include "nerfslam/io/dataset.h"

#include <algorithm>
#include <cctype>
#include <cmath>

#include <spdlog/spdlog.h>

#include "dataset_internal.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/bag.h"
#include "nerfslam/io/image_io.h"

namespace nerfslam {

namespace fs = std::filesystem;
using io_detail::FrameEntry;
using io_detail::SequenceDataset;

Dataset::~Dataset() = default;

#ifndef NERFSLAM_HAVE_ROSBAG
bool bagSupported() { return false; }
void writeDatasetBag(const Dataset&, const fs::path& out, const BagWriteOptions&) {
  fail("{}: this nerfslam was built without ROS bag support (librosbag-storage-dev was not found at build time)",
       out.string());
}
#endif

cv::Mat Dataset::loadDepth(size_t) const { return {}; }

cv::Mat SequenceDataset::loadDepth(size_t i) const {
  const FrameEntry& e = at(i);
  if (e.depth.empty()) return {};
  const std::string name = e.depth.string();
  const cv::Mat raw = readImage(e.depth, ImageMode::kUnchanged);
  if (raw.channels() != 1 || (raw.depth() != CV_16U && raw.depth() != CV_32F))
    throw fieldError(name, "image", "depth must be a single-channel 16-bit or 32-bit float image");
  if (raw.cols != camera_.width || raw.rows != camera_.height)
    throw fieldError(
        name, "image",
        fmt::format("depth is {}x{} but the camera is {}x{}", raw.cols, raw.rows, camera_.width, camera_.height));
  cv::Mat depth;
  raw.convertTo(depth, CV_32F, depth_scale_);
  for (int y = 0; y < depth.rows; ++y) {
    const float* row = depth.ptr<float>(y);
    for (int x = 0; x < depth.cols; ++x)
      if (!std::isfinite(row[x]) || row[x] < 0.f)
        throw fieldError(name, "image",
                         fmt::format("depth at pixel ({}, {}) is {} (negative or not finite)", x, y, row[x]));
  }
  return depth;
}

std::vector<std::optional<SE3>> Dataset::groundTruthAll() const {
  std::vector<std::optional<SE3>> out;
  out.reserve(size());
  for (size_t i = 0; i < size(); ++i) out.push_back(groundTruth(i));
  return out;
}

namespace io_detail {

#ifndef NERFSLAM_HAVE_ROSBAG
std::unique_ptr<Dataset> openBag(const fs::path& file, const DatasetOptions&) {
  fail("{}: this nerfslam was built without ROS bag support (librosbag-storage-dev was not found at build time)",
       file.string());
}
#endif

const FrameEntry& SequenceDataset::at(size_t i) const {
  if (i >= frames_.size())
    fail("{} dataset {}: frame index {} out of range (size {})", kind_, root_.string(), i, frames_.size());
  return frames_[i];
}

double SequenceDataset::timestamp(size_t i) const { return at(i).timestamp; }
std::string SequenceDataset::imagePath(size_t i) const { return at(i).image.string(); }
std::optional<SE3> SequenceDataset::groundTruth(size_t i) const { return at(i).T_world_cam; }

DatasetFrame SequenceDataset::load(size_t i, ImageMode mode) const {
  const FrameEntry& e = at(i);
  DatasetFrame f;
  f.index = i;
  f.timestamp = e.timestamp;
  f.T_world_cam = e.T_world_cam;
  f.path = e.image.string();
  f.image = readImage(e.image, mode);
  if (f.image.cols != camera_.width || f.image.rows != camera_.height)
    fail(
        "{}: frame {} is {}x{} but the sequence's images (and camera) are {}x{}; the image size must "
        "not change mid-sequence",
        f.path, i, f.image.cols, f.image.rows, camera_.width, camera_.height);
  return f;
}

void SequenceDataset::finish(std::vector<FrameEntry> frames, std::optional<Camera> own_camera,
                             const std::string& camera_source, const DatasetOptions& opts,
                             const std::string& missing_camera_hint) {
  if (frames.empty()) fail("{} dataset {}: no frames", kind_, root_.string());
  if (opts.stride == 0) fail("dataset options: field 'stride': must be >= 1");
  std::vector<FrameEntry> kept;
  for (size_t i = opts.start; i < frames.size(); i += opts.stride) {
    if (opts.max_frames > 0 && kept.size() >= opts.max_frames) break;
    kept.push_back(std::move(frames[i]));
  }
  if (kept.empty())
    fail("{} dataset {}: no frames left after skipping the first {} of {}", kind_, root_.string(), opts.start,
         frames.size());
  for (size_t i = 1; i < kept.size(); ++i) {
    if (!(kept[i].timestamp > kept[i - 1].timestamp))
      fail("{}: timestamp {} of frame {} is not after the previous frame's ({})", kept[i].image.string(),
           numberForMessage(kept[i].timestamp, 9), i, numberForMessage(kept[i - 1].timestamp, 9));
  }
  frames_ = std::move(kept);
  has_gt_ = std::any_of(frames_.begin(), frames_.end(), [](const FrameEntry& e) { return e.T_world_cam.has_value(); });

  // The first image fixes the sequence's size.
  const cv::Mat first = readImage(frames_.front().image, ImageMode::kUnchanged);
  std::string source;
  if (opts.camera_override) {
    camera_ = loadCameraYaml(*opts.camera_override);
    source = opts.camera_override->string();
  } else if (own_camera) {
    camera_ = *own_camera;
    source = camera_source;
    if (camera_.width == 0 && camera_.height == 0) {
      camera_.width = first.cols;
      camera_.height = first.rows;
    }
  } else {
    fail("{}", missing_camera_hint.empty()
                   ? fmt::format("{} dataset {}: no camera calibration; pass a camera YAML ({})", kind_, root_.string(),
                                 opts.camera_option)
                   : missing_camera_hint);
  }
  if (camera_.width != first.cols || camera_.height != first.rows)
    fail("{}: camera is {}x{} but the images are {}x{} (first image {})", source, camera_.width, camera_.height,
         first.cols, first.rows, frames_.front().image.string());
  camera_.validate(source);
  spdlog::info(
      "opened {} dataset {}: {} frames, {}x{}, ground truth for {} frames", kind_, root_.string(), frames_.size(),
      camera_.width, camera_.height,
      std::count_if(frames_.begin(), frames_.end(), [](const FrameEntry& e) { return e.T_world_cam.has_value(); }));
}

}  // namespace io_detail

const std::vector<std::string>& datasetKinds() {
  static const std::vector<std::string> kinds = {"folder",     "tum",     "euroc",   "kitti", "transforms",
                                                 "middlebury", "strecha", "tsukuba", "video", "bag"};
  return kinds;
}

namespace {

std::string kindList() {
  std::string s;
  for (const auto& k : datasetKinds()) s += (s.empty() ? "" : ", ") + k;
  return s;
}

bool pathExists(const fs::path& p) {
  std::error_code ec;
  return fs::exists(p, ec);
}

bool hasParFile(const fs::path& dir) {
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string n = it->path().filename().string();
    if (n.size() > 8 && n.compare(n.size() - 8, 8, "_par.txt") == 0) return true;
  }
  return false;
}

bool hasImages(const fs::path& dir) {
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    if (it->is_regular_file(ec) && isImageExtension(it->path())) return true;
  return false;
}

}  // namespace

std::string detectDatasetKind(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail("{}: dataset path not found", path.string());
  if (fs::is_regular_file(path, ec)) {
    if (path.extension() == ".json") return "transforms";
    if (io_detail::isVideoExtension(path)) return "video";
    if (path.extension() == ".bag") return "bag";
    fail("{}: a dataset is a folder (or a transforms.json file, a video file or a ROS bag)", path.string());
  }
  // TUM before transforms: `nerfslam synth` writes both rgb.txt and transforms.json, and the TUM
  // reading (camera.yaml, groundtruth.txt) is the primary one.
  if (pathExists(path / "mav0" / "cam0" / "data.csv") || pathExists(path / "cam0" / "data.csv")) return "euroc";
  if (pathExists(path / "rgb.txt")) return "tum";
  if (pathExists(path / "transforms.json") || pathExists(path / "transforms_train.json")) return "transforms";
  if (pathExists(path / "times.txt") &&
      (pathExists(path / "image_0") || pathExists(path / "image_l") || pathExists(path / "image_2")))
    return "kitti";
  if (pathExists(path / "cam_traj_truth.txt")) return "tsukuba";
  if (pathExists(path / "gt_dense_cameras")) return "strecha";
  if (hasParFile(path)) return "middlebury";
  if (hasImages(path)) return "folder";
  fail(
      "{}: cannot tell the dataset layout. Known kinds: euroc (mav0/cam0/data.csv), tum (rgb.txt), "
      "transforms (transforms.json or transforms_train.json), kitti (times.txt and "
      "image_0/ or image_l/), tsukuba (cam_traj_truth.txt and images/), strecha (gt_dense_cameras/ and "
      "images/), middlebury (*_par.txt), folder (image files directly in the folder). Give the kind "
      "explicitly as KIND:PATH with KIND one of: {}",
      path.string(), kindList());
}

std::unique_ptr<Dataset> openDataset(const std::string& kind_in, const fs::path& path, const DatasetOptions& opts) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail("{}: dataset path not found", path.string());
  const std::string kind = kind_in.empty() ? detectDatasetKind(path) : kind_in;
  if (kind == "transforms") return io_detail::openTransforms(path, opts);
  if (kind == "video") return io_detail::openVideo(path, opts);
  if (kind == "bag") return io_detail::openBag(path, opts);
  if (!fs::is_directory(path, ec)) fail("{}: a {} dataset must be a folder", path.string(), kind);
  if (kind == "folder") return io_detail::openFolder(path, opts);
  if (kind == "tum") return io_detail::openTum(path, opts);
  if (kind == "euroc") return io_detail::openEuroc(path, opts);
  if (kind == "kitti") return io_detail::openKitti(path, opts);
  if (kind == "middlebury") return io_detail::openMiddlebury(path, opts);
  if (kind == "strecha") return io_detail::openStrecha(path, opts);
  if (kind == "tsukuba") return io_detail::openTsukuba(path, opts);
  fail("unknown dataset kind '{}' (valid kinds: {})", cutForMessage(kind), kindList());
}

DatasetSpec parseDatasetSpec(const std::string& spec) {
  if (spec.empty()) fail("empty dataset spec; expected [KIND:]PATH with KIND one of: {}", kindList());
  // "kind:PATH" when the part before the first ':' is a lower-case word and the whole spec is not
  // itself an existing path.
  const size_t colon = spec.find(':');
  if (colon != std::string::npos && colon > 0 && !pathExists(spec)) {
    const std::string kind = spec.substr(0, colon);
    if (std::all_of(kind.begin(), kind.end(), [](unsigned char c) { return std::isalnum(c) || c == '_'; })) {
      if (kind == "camera")
        fail(
            "'{}' is a live camera, a stream of frames: `nerfslam run` reads it (and records its frames as a "
            "folder dataset), other commands need a dataset",
            cutForMessage(spec));
      if (std::find(datasetKinds().begin(), datasetKinds().end(), kind) == datasetKinds().end())
        fail("unknown dataset kind '{}' in '{}' (valid kinds: {})", cutForMessage(kind), cutForMessage(spec),
             kindList());
      const std::string path = spec.substr(colon + 1);
      if (path.empty()) fail("dataset spec '{}' has no path after '{}:'", spec, kind);
      return {kind, fs::path(path)};
    }
  }
  return {std::string(), fs::path(spec)};
}

std::unique_ptr<Dataset> openDataset(const std::string& spec, const DatasetOptions& opts) {
  const DatasetSpec parsed = parseDatasetSpec(spec);
  return openDataset(parsed.kind, parsed.path, opts);
}

}  // namespace nerfslam
