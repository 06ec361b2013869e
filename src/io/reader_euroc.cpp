// EuRoC MAV / ASL layout: mav0/cam0/data.csv ("#timestamp [ns],filename"), images in
// mav0/cam0/data/, calibration in mav0/cam0/sensor.yaml (intrinsics [fu, fv, cu, cv],
// distortion_model radial-tangential | equidistant, distortion_coefficients, resolution, T_BS the
// camera-to-body transform as a row-major 4x4 `data` list). Ground truth: the body (IMU) pose from
// mav0/state_groundtruth_estimate0/data.csv (ns, p xyz, q wxyz, ...), interpolated at the image
// times (samples within 0.02 s), or else groundtruth_body_tum.txt (TUM format, body frame) in the
// dataset root, nearest within 0.02 s. Camera pose T_world_cam = T_world_body * T_BS.
// PATH may be the dataset root (holding mav0/) or mav0/ itself.
#include <yaml-cpp/yaml.h>

#include <spdlog/spdlog.h>

#include "dataset_internal.h"
#include "nerfslam/core/error.h"

namespace nerfslam::io_detail {

namespace {

constexpr double kGtTolerance = 0.02;  // seconds

std::vector<double> yamlNumbers(const YAML::Node& root, const std::string& key, const fs::path& file, size_t expected) {
  if (!root.IsMap()) throw fieldError(file.string(), key, "missing: the file is not a YAML map");
  const YAML::Node n = root[key];
  if (!n) throw fieldError(file.string(), key, "missing");
  std::vector<double> v;
  try {
    if (!n.IsSequence()) throw fieldError(file.string(), key, "expected a list of numbers");
    for (const auto& x : n) v.push_back(x.as<double>());
  } catch (const YAML::Exception& e) {
    throw fieldError(file.string(), key, std::string("expected a list of numbers: ") + e.what());
  }
  if (expected && v.size() != expected)
    throw fieldError(file.string(), key, fmt::format("expected {} numbers, found {}", expected, v.size()));
  return v;
}

struct Sensor {
  Camera camera;
  SE3 T_body_cam;
};

Sensor readSensorYaml(const fs::path& file) {
  YAML::Node y;
  try {
    y = YAML::Load(readYamlText(file));
  } catch (const YAML::Exception& e) {
    fail("{}: YAML syntax error: {}", file.string(), e.what());
  }
  const auto intr = yamlNumbers(y, "intrinsics", file, 4);
  const auto res = yamlNumbers(y, "resolution", file, 2);
  Sensor s;
  s.camera = Camera::pinhole(imageDimension(res[0], file.string(), "resolution"),
                             imageDimension(res[1], file.string(), "resolution"), intr[0], intr[1], intr[2], intr[3]);
  if (const YAML::Node m = y["camera_model"]; m && m.as<std::string>("") != "pinhole")
    throw fieldError(file.string(), "camera_model", "'" + m.as<std::string>("") + "' is not supported (pinhole only)");
  std::string model = "none";
  if (const YAML::Node m = y["distortion_model"]) model = m.as<std::string>("");
  if (model == "radial-tangential" || model == "radtan") {
    s.camera.distortion_model = DistortionModel::kRadTan;
    s.camera.distortion = yamlNumbers(y, "distortion_coefficients", file, 0);
  } else if (model == "equidistant") {
    s.camera.distortion_model = DistortionModel::kEquidistant;
    s.camera.distortion = yamlNumbers(y, "distortion_coefficients", file, 4);
  } else if (model != "none") {
    throw fieldError(file.string(), "distortion_model",
                     "'" + model + "' is not supported (radial-tangential, equidistant or none)");
  }
  const YAML::Node t = y["T_BS"];
  if (!t) throw fieldError(file.string(), "T_BS", "missing");
  if (!t.IsMap()) throw fieldError(file.string(), "T_BS", "expected a map with a 16-number 'data' list");
  const auto d = yamlNumbers(t, "data", file, 16);
  Eigen::Matrix4d T;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) T(r, c) = d[4 * r + c];
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  if ((R * R.transpose() - Eigen::Matrix3d::Identity()).norm() > 1e-3 || R.determinant() < 0)
    throw fieldError(file.string(), "T_BS.data", "the rotation part is not a rotation matrix");
  s.T_body_cam = SE3::fromMatrix(T);
  return s;
}

}  // namespace

std::unique_ptr<Dataset> openEuroc(const fs::path& root, const DatasetOptions& opts) {
  std::error_code ec;
  const fs::path mav0 = fs::is_directory(root / "mav0", ec) ? root / "mav0" : root;
  const fs::path base = (mav0 == root) ? root.parent_path() : root;  // holds groundtruth_body_tum.txt
  const fs::path cam_dir = mav0 / "cam0";
  const fs::path csv = cam_dir / "data.csv";

  std::vector<FrameEntry> frames;
  for (const Line& l : readDataLines(csv)) {
    const auto toks = splitTokens(l.text, true);
    if (toks.size() < 2)
      fail("{}:{}: expected 'timestamp [ns],filename', found '{}'", csv.string(), l.number, cutForMessage(l.text));
    // Nanoseconds as a double keep ~0.3 us precision at current epoch times: ample for association.
    FrameEntry e;
    e.timestamp = parseNumber(toks[0], csv, l.number, "timestamp [ns]") * 1e-9;
    e.image = cam_dir / "data" / toks[1];
    checkListedImage(e.image, csv, l.number);
    if (!frames.empty()) checkIncreasing(frames.back().timestamp, e.timestamp, csv, l.number);
    frames.push_back(std::move(e));
  }
  if (frames.empty()) fail("{}: no frames listed", csv.string());

  const fs::path sensor_file = cam_dir / "sensor.yaml";
  const Sensor sensor = readSensorYaml(sensor_file);

  const fs::path gt_csv = mav0 / "state_groundtruth_estimate0" / "data.csv";
  const fs::path gt_tum = base / "groundtruth_body_tum.txt";
  std::vector<TimedPose> traj;
  fs::path gt_file;
  bool interpolate = false;
  if (fs::exists(gt_csv, ec)) {
    traj = checkedTimes(readEurocTrajectory(gt_csv), gt_csv);
    gt_file = gt_csv;
    interpolate = true;
  } else if (fs::exists(gt_tum, ec)) {
    traj = checkedTimes(readTumTrajectory(gt_tum), gt_tum);
    gt_file = gt_tum;
  }
  if (!gt_file.empty()) {
    size_t n = 0;
    for (auto& f : frames) {
      const auto body =
          interpolate ? interpolatePose(traj, f.timestamp, kGtTolerance) : nearestPose(traj, f.timestamp, kGtTolerance);
      if (body) f.T_world_cam = *body * sensor.T_body_cam;
      n += body.has_value();
    }
    if (n < frames.size())
      spdlog::warn("{}: {} of {} frames have no ground truth within {} s", gt_file.string(), frames.size() - n,
                   frames.size(), kGtTolerance);
  }

  auto ds = std::make_unique<SequenceDataset>("euroc", root);
  ds->finish(std::move(frames), sensor.camera, sensor_file.string(), opts);
  return ds;
}

}  // namespace nerfslam::io_detail
