// Camera YAML: our format and ROS camera_info calibration files (see the comment in camera.h).
#include <algorithm>
#include <cmath>
#include <set>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"

namespace nerfslam {

namespace {

const std::vector<std::string> kOurKeys = {"model", "width", "height",           "fx",        "fy",
                                           "cx",    "cy",    "distortion_model", "distortion"};
const std::vector<std::string> kRosKeys = {"image_width",          "image_height",     "camera_name",
                                           "camera_matrix",        "distortion_model", "distortion_coefficients",
                                           "rectification_matrix", "projection_matrix"};

YAML::Node required(const YAML::Node& map, const std::string& key, const std::string& file) {
  const YAML::Node n = map[key];
  if (!n || n.IsNull()) throw fieldError(file, key, "missing");
  return n;
}

int readInt(const YAML::Node& map, const std::string& key, const std::string& file) {
  int v = 0;
  const YAML::Node n = required(map, key, file);
  if (!options_detail::parseScalar(n, v))
    throw fieldError(file, key, "expected an integer, got " + options_detail::describeNode(n));
  return v;
}

double readDouble(const YAML::Node& map, const std::string& key, const std::string& file) {
  double v = 0;
  const YAML::Node n = required(map, key, file);
  if (!options_detail::parseScalar(n, v))
    throw fieldError(file, key, "expected a number, got " + options_detail::describeNode(n));
  if (!std::isfinite(v)) throw fieldError(file, key, fmt::format("must be a finite number (got {})", v));
  return v;
}

std::string readString(const YAML::Node& map, const std::string& key, const std::string& file) {
  std::string v;
  const YAML::Node n = required(map, key, file);
  if (!options_detail::parseScalar(n, v))
    throw fieldError(file, key, "expected a string, got " + options_detail::describeNode(n));
  return v;
}

std::vector<double> readNumberList(const YAML::Node& n, const std::string& field, const std::string& file) {
  if (!n.IsSequence())
    throw fieldError(file, field, "expected a list of numbers, got " + options_detail::describeNode(n));
  std::vector<double> out;
  for (size_t i = 0; i < n.size(); ++i) {
    double v = 0;
    if (!options_detail::parseScalar(n[i], v))
      throw fieldError(file, field,
                       fmt::format("element {}: expected a number, got {}", i, options_detail::describeNode(n[i])));
    if (!std::isfinite(v))
      throw fieldError(file, field, fmt::format("element {} must be a finite number (got {})", i, v));
    out.push_back(v);
  }
  return out;
}

// ROS matrix: {rows: R, cols: C, data: [R*C numbers]}.
std::vector<double> readRosMatrix(const YAML::Node& map, const std::string& key, const std::string& file,
                                  int expect_rows, int expect_cols) {
  const YAML::Node m = required(map, key, file);
  if (!m.IsMap())
    throw fieldError(file, key, "expected a map with rows, cols and data, got " + options_detail::describeNode(m));
  const int rows = readInt(m, "rows", file + ": " + key);
  const int cols = readInt(m, "cols", file + ": " + key);
  const std::vector<double> data = readNumberList(required(m, "data", file + ": " + key), key + ".data", file);
  if (static_cast<int>(data.size()) != rows * cols)
    throw fieldError(
        file, key + ".data",
        fmt::format("has {} numbers but rows x cols = {} x {} = {}", data.size(), rows, cols, rows * cols));
  if ((expect_rows > 0 && rows != expect_rows) || (expect_cols > 0 && cols != expect_cols))
    throw fieldError(
        file, key,
        fmt::format("expected a {}x{} matrix, got {}x{}", expect_rows > 0 ? std::to_string(expect_rows) : "N",
                    expect_cols > 0 ? std::to_string(expect_cols) : "N", rows, cols));
  return data;
}

DistortionModel parseOurDistortionModel(const std::string& s, const std::string& file) {
  if (s == "none") return DistortionModel::kNone;
  if (s == "radtan") return DistortionModel::kRadTan;
  if (s == "equidistant") return DistortionModel::kEquidistant;
  throw fieldError(
      file, "distortion_model",
      "'" + s + "' is not one of: none, radtan, equidistant" + didYouMean(s, {"none", "radtan", "equidistant"}));
}

Camera loadOurs(const YAML::Node& root, const std::string& file) {
  for (const auto& key : yamlKeys(root)) {
    bool known = false;
    for (const auto& k : kOurKeys) known = known || k == key;
    if (!known) throw fieldError(file, key, "unknown key" + didYouMean(key, kOurKeys));
  }
  const std::string model = readString(root, "model", file);
  if (model != "pinhole")
    throw fieldError(file, "model", "'" + model + "' is not supported (the only model is 'pinhole')");
  Camera c;
  c.width = readInt(root, "width", file);
  c.height = readInt(root, "height", file);
  c.fx = readDouble(root, "fx", file);
  c.fy = readDouble(root, "fy", file);
  c.cx = readDouble(root, "cx", file);
  c.cy = readDouble(root, "cy", file);
  const YAML::Node dm = root["distortion_model"];
  c.distortion_model = (!dm || dm.IsNull()) ? DistortionModel::kNone
                                            : parseOurDistortionModel(readString(root, "distortion_model", file), file);
  const YAML::Node d = root["distortion"];
  if (d && !d.IsNull()) c.distortion = readNumberList(d, "distortion", file);
  if (c.distortion_model == DistortionModel::kNone && !c.distortion.empty() && (!dm || dm.IsNull()))
    throw fieldError(file, "distortion_model", "missing (coefficients are given, so say radtan or equidistant)");
  return c;
}

Camera loadRos(const YAML::Node& root, const std::string& file) {
  // camera_calibration writes exactly these keys; anything else is most likely a typo.
  for (const auto& key : yamlKeys(root)) {
    bool known = false;
    for (const auto& k : kRosKeys) known = known || k == key;
    if (!known) throw fieldError(file, key, "unknown key in a ROS camera_info file" + didYouMean(key, kRosKeys));
  }
  Camera c;
  c.width = readInt(root, "image_width", file);
  c.height = readInt(root, "image_height", file);
  const std::vector<double> K = readRosMatrix(root, "camera_matrix", file, 3, 3);
  if (K[1] != 0.0) throw fieldError(file, "camera_matrix", fmt::format("skew {} is not supported (must be 0)", K[1]));
  if (K[3] != 0.0 || K[6] != 0.0 || K[7] != 0.0 || K[8] != 1.0)
    throw fieldError(file, "camera_matrix", "must be [fx 0 cx; 0 fy cy; 0 0 1]");
  c.fx = K[0];
  c.cx = K[2];
  c.fy = K[4];
  c.cy = K[5];
  const std::string model = readString(root, "distortion_model", file);
  const std::vector<double> D = readRosMatrix(root, "distortion_coefficients", file, 1, 0);
  if (model == "plumb_bob") {
    c.distortion_model = DistortionModel::kRadTan;
  } else if (model == "equidistant") {
    c.distortion_model = DistortionModel::kEquidistant;
  } else if (model == "rational_polynomial") {
    throw fieldError(file, "distortion_model",
                     "'rational_polynomial' (8-coefficient) distortion is not supported; recalibrate with plumb_bob "
                     "(5 coefficients) or equidistant, e.g. with `nerfslam calibrate`");
  } else {
    throw fieldError(file, "distortion_model",
                     "'" + model + "' is not supported (plumb_bob or equidistant)" +
                         didYouMean(model, {"plumb_bob", "equidistant"}));
  }
  c.distortion = D;
  // Rectified streams often carry plumb_bob with no coefficients: that is an ideal pinhole.
  if (D.empty()) c.distortion_model = DistortionModel::kNone;
  // Present in every file camera_calibration writes; checked for shape so a damaged file is noticed.
  if (root["rectification_matrix"]) readRosMatrix(root, "rectification_matrix", file, 3, 3);
  if (root["projection_matrix"]) readRosMatrix(root, "projection_matrix", file, 3, 4);
  return c;
}

}  // namespace

Camera loadCameraYaml(const std::filesystem::path& path) {
  const std::string file = path.string();
  const YAML::Node root = loadYamlFile(path);
  if (!root.IsMap())
    fail("{}: expected a camera description (a YAML map), got {}", file, options_detail::describeNode(root));
  const bool ros = root["camera_matrix"] || root["image_width"] || root["distortion_coefficients"];
  Camera c = ros ? loadRos(root, file) : loadOurs(root, file);
  c.validate(file);
  return c;
}

void saveCameraYaml(const Camera& camera, const std::filesystem::path& path) {
  camera.validate(path.string());
  std::string s;
  s += "# nerfslam camera (format: include/nerfslam/core/camera.h)\n";
  s += "model: pinhole\n";
  s += fmt::format("width: {}\nheight: {}\n", camera.width, camera.height);
  s += fmt::format("fx: {}\nfy: {}\ncx: {}\ncy: {}\n", formatDouble(camera.fx), formatDouble(camera.fy),
                   formatDouble(camera.cx), formatDouble(camera.cy));
  s += "distortion_model: " + toString(camera.distortion_model) + "\n";
  s += "distortion: [";
  for (size_t i = 0; i < camera.distortion.size(); ++i) s += (i ? ", " : "") + formatDouble(camera.distortion[i]);
  s += "]\n";
  writeStringAtomic(path, s);
}

}  // namespace nerfslam
