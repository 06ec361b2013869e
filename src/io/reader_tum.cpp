// TUM RGB-D layout: rgb.txt ("timestamp filename", '#' comments), optional groundtruth.txt
// ("timestamp tx ty tz qx qy qz qw", camera-to-world of the RGB optical frame), associated to each
// image by the nearest ground-truth time within 0.02 s (frames without one get no ground truth).
// Camera: camera.yaml in the folder (our synthetic sequences write one), else the override, else the
// Freiburg 1/2/3 calibration inferred from the folder name (rgbd_dataset_freiburg1_* ...).
#include <algorithm>
#include <cmath>

#include <spdlog/spdlog.h>

#include "dataset_internal.h"
#include "nerfslam/core/error.h"

namespace nerfslam::io_detail {

namespace {

constexpr double kGtTolerance = 0.02;  // seconds

// Kinect RGB calibrations published by TUM ("Intrinsic Camera Calibration of the Kinect",
// https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats), distortion d0..d4 = k1 k2 p1 p2 k3.
std::optional<Camera> freiburgPreset(int n) {
  Camera c;
  switch (n) {
    case 1:
      c = Camera::pinhole(640, 480, 517.306408, 516.469215, 318.643040, 255.313989);
      c.distortion = {0.262383, -0.953104, -0.005358, 0.002628, 1.163314};
      c.distortion_model = DistortionModel::kRadTan;
      return c;
    case 2:
      c = Camera::pinhole(640, 480, 520.908620, 521.007327, 325.141442, 249.701764);
      c.distortion = {0.231222, -0.784899, -0.003257, -0.000105, 0.917205};
      c.distortion_model = DistortionModel::kRadTan;
      return c;
    case 3:  // fr3 images are already undistorted.
      return Camera::pinhole(640, 480, 535.4, 539.2, 320.1, 247.6);
    default:
      return std::nullopt;
  }
}

int freiburgNumber(const fs::path& root) {
  fs::path p = fs::absolute(root).lexically_normal();
  if (p.filename().empty()) p = p.parent_path();  // trailing '/'
  // The sequence folder, or its parent (e.g. .../rgbd_dataset_freiburg1_xyz/ or fr1/xyz/).
  for (int depth = 0; depth < 2 && !p.filename().empty(); ++depth, p = p.parent_path()) {
    const std::string n = p.filename().string();
    for (int k = 1; k <= 3; ++k)
      if (n.find("freiburg" + std::to_string(k)) != std::string::npos) return k;
  }
  return 0;
}

}  // namespace

std::unique_ptr<Dataset> openTum(const fs::path& root, const DatasetOptions& opts) {
  const fs::path rgb_file = root / "rgb.txt";
  std::vector<FrameEntry> frames;
  std::error_code ec;
  for (const Line& l : readDataLines(rgb_file)) {
    const auto toks = splitTokens(l.text);
    if (toks.size() < 2)
      fail("{}:{}: expected 'timestamp filename', found '{}'", rgb_file.string(), l.number, cutForMessage(l.text));
    FrameEntry e;
    e.timestamp = parseNumber(toks[0], rgb_file, l.number, "timestamp");
    e.image = root / toks[1];
    checkListedImage(e.image, rgb_file, l.number);
    if (!frames.empty()) checkIncreasing(frames.back().timestamp, e.timestamp, rgb_file, l.number);
    frames.push_back(std::move(e));
  }
  if (frames.empty()) fail("{}: no frames listed", rgb_file.string());

  const fs::path gt_file = root / "groundtruth.txt";
  if (fs::exists(gt_file, ec)) {
    const auto traj = checkedTimes(readTumTrajectory(gt_file), gt_file);
    size_t n = 0;
    for (auto& f : frames) {
      f.T_world_cam = nearestPose(traj, f.timestamp, kGtTolerance);
      n += f.T_world_cam.has_value();
    }
    if (n < frames.size())
      spdlog::warn("{}: {} of {} frames have no ground truth within {} s", gt_file.string(), frames.size() - n,
                   frames.size(), kGtTolerance);
  }

  std::optional<Camera> cam;
  std::string source;
  const fs::path cam_file = root / "camera.yaml";
  if (!opts.camera_override) {
    if (fs::exists(cam_file, ec)) {
      cam = loadCameraYaml(cam_file);
      source = cam_file.string();
    } else if (int k = freiburgNumber(root)) {
      cam = freiburgPreset(k);
      source = fmt::format("TUM freiburg{} preset (from the folder name {})", k, root.string());
    }
  }
  auto ds = std::make_unique<SequenceDataset>("tum", root);
  ds->finish(std::move(frames), cam, source, opts,
             fmt::format("{}: no camera.yaml in the folder and the folder name does not name freiburg1/2/3; "
                         "give a camera YAML ({})",
                         root.string(), opts.camera_option));
  return ds;
}

}  // namespace nerfslam::io_detail
