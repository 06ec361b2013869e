// NeRF / instant-ngp transforms.json. PATH is the json file, or a folder holding transforms.json
// (else transforms_train.json).
// Intrinsics: fl_x [fl_y] [cx cy] [w h], or camera_angle_x [camera_angle_y] (focal = 0.5 w /
// tan(0.5 angle)); w/h default to the first image's size. Principal point: instant-ngp and COLMAP
// place pixel centres at +0.5, OpenCV (ours) at 0, so cx_ours = cx - 0.5, and the default (image
// centre) is (w - 1) / 2. Distortion: k1 k2 [k3] p1 p2 (radtan) or, with camera_model
// "OPENCV_FISHEYE", k1 k2 k3 k4 (equidistant). aabb_scale defaults to 1.
// Frames: file_path relative to the json's folder, with or without extension; transform_matrix is
// camera-to-world in OpenGL axes (x right, y up, looking down -z) and is converted to OpenCV optical
// axes by right-multiplying with diag(1, -1, -1, 1). Timestamps: a frame's "timestamp" or "time"
// (seconds) when every frame has one, else index / 30 (or / DatasetOptions::fps).
// Per-frame intrinsics (instant-ngp allows them) must match the global ones: one camera per dataset.
// Depth: a frame's "depth_path" (instant-ngp) or "depth_file_path" (nerfstudio), z-depth in units of
// "integer_depth_scale" / "depth_unit_scale_factor" metres (1e-3 when the file gives neither).
// "scale" and "offset" (p_nerf = scale * p + offset; instant-ngp's 0.33 and 0.5 when one is missing)
// place the scene in the NeRF's unit cube.
#include <cmath>

#include <nlohmann/json.hpp>

#include "dataset_internal.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"
#include "nerfslam/io/image_io.h"

namespace nerfslam::io_detail {

namespace {

using nlohmann::json;

double number(const json& j, const std::string& key, const fs::path& file, const std::string& where = "") {
  const json& v = j.at(key);
  if (!v.is_number()) throw fieldError(file.string(), where + key, "expected a number");
  const double x = v.get<double>();
  if (!std::isfinite(x)) throw fieldError(file.string(), where + key, "not finite");
  return x;
}

}  // namespace

std::unique_ptr<Dataset> openTransforms(const fs::path& path, const DatasetOptions& opts) {
  std::error_code ec;
  fs::path file = path;
  if (fs::is_directory(path, ec)) {
    file = path / "transforms.json";
    if (!fs::exists(file, ec)) file = path / "transforms_train.json";
    if (!fs::exists(file, ec)) fail("{}: no transforms.json or transforms_train.json in the folder", path.string());
  }
  json j;
  try {
    j = json::parse(readInputFile(file, "transforms.json file"));
  } catch (const json::exception& e) {
    fail("{}: JSON syntax error: {}", file.string(), e.what());
  }
  if (!j.is_object()) fail("{}: expected a JSON object at the top level", file.string());
  const fs::path dir = file.parent_path();

  if (!j.contains("frames") || !j["frames"].is_array())
    throw fieldError(file.string(), "frames", "missing or not a list");
  const json& jf = j["frames"];
  if (jf.empty()) throw fieldError(file.string(), "frames", "no frames");

  std::vector<FrameEntry> frames;
  bool all_timed = true;
  for (size_t i = 0; i < jf.size(); ++i) {
    const json& f = jf[i];
    const std::string where = fmt::format("frames[{}].", i);
    if (!f.is_object()) throw fieldError(file.string(), fmt::format("frames[{}]", i), "expected an object");
    if (!f.contains("file_path") || !f["file_path"].is_string())
      throw fieldError(file.string(), where + "file_path", "missing or not a string");
    const fs::path rel = f["file_path"].get<std::string>();
    auto img = resolveImage(dir / rel);
    if (!img) throw fieldError(file.string(), where + "file_path", "image " + (dir / rel).string() + " not found");
    if (!f.contains("transform_matrix") || !f["transform_matrix"].is_array() || f["transform_matrix"].size() < 3)
      throw fieldError(file.string(), where + "transform_matrix", "missing or not a 4x4 (or 3x4) list of rows");
    Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
    const json& m = f["transform_matrix"];
    for (int r = 0; r < static_cast<int>(std::min<size_t>(m.size(), 4)); ++r) {
      if (!m[r].is_array() || m[r].size() != 4)
        throw fieldError(file.string(), where + "transform_matrix", fmt::format("row {} is not 4 numbers", r));
      for (int c = 0; c < 4; ++c) {
        if (!m[r][c].is_number())
          throw fieldError(file.string(), where + "transform_matrix", fmt::format("row {} is not 4 numbers", r));
        T(r, c) = m[r][c].get<double>();
      }
    }
    if (!T.allFinite()) throw fieldError(file.string(), where + "transform_matrix", "not finite");
    const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
    if ((R * R.transpose() - Eigen::Matrix3d::Identity()).norm() > 1e-3 || R.determinant() < 0)
      throw fieldError(file.string(), where + "transform_matrix", "the rotation part is not a rotation matrix");
    FrameEntry e;
    e.image = *img;
    // OpenGL camera axes (y up, looking down -z) -> OpenCV optical axes (y down, z forward).
    e.T_world_cam = SE3::fromMatrix(T * Eigen::Vector4d(1, -1, -1, 1).asDiagonal());
    // Depth (instant-ngp's "depth_path", nerfstudio's "depth_file_path"), relative to the json's folder.
    for (const char* k : {"depth_path", "depth_file_path"}) {
      if (!f.contains(k)) continue;
      if (!f[k].is_string()) throw fieldError(file.string(), where + k, "not a string");
      const fs::path dp = dir / f[k].get<std::string>();
      std::error_code dec;
      if (!fs::is_regular_file(dp, dec))
        throw fieldError(file.string(), where + k, "depth image " + dp.string() + " not found");
      e.depth = dp;
      break;
    }
    for (const char* k : {"timestamp", "time"}) {
      if (f.contains(k)) {
        e.timestamp = number(f, k, file, where);
        break;
      }
    }
    all_timed = all_timed && (f.contains("timestamp") || f.contains("time"));
    // Per-frame intrinsics must agree with the global ones.
    for (const char* k : {"fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x"}) {
      if (f.contains(k) && (!j.contains(k) || std::abs(number(f, k, file, where) - number(j, k, file)) > 1e-9))
        throw fieldError(file.string(), where + k,
                         "per-frame intrinsics differing from the global ones are not supported");
    }
    frames.push_back(std::move(e));
  }
  if (!all_timed) {
    const double fps = opts.fps > 0 ? opts.fps : 30.0;
    for (size_t i = 0; i < frames.size(); ++i) frames[i].timestamp = static_cast<double>(i) / fps;
  }

  // Intrinsics.
  int w = 0, h = 0;
  if (j.contains("w") && j.contains("h")) {
    w = imageDimension(std::round(number(j, "w", file)), file.string(), "w");
    h = imageDimension(std::round(number(j, "h", file)), file.string(), "h");
  } else {
    const cv::Mat first = readImage(frames.front().image, ImageMode::kUnchanged);
    w = first.cols;
    h = first.rows;
  }
  double fx = 0, fy = 0;
  if (j.contains("fl_x")) {
    fx = number(j, "fl_x", file);
    fy = j.contains("fl_y") ? number(j, "fl_y", file) : fx;
  } else if (j.contains("camera_angle_x")) {
    const double ax = number(j, "camera_angle_x", file);
    if (!(ax > 0 && ax < M_PI)) throw fieldError(file.string(), "camera_angle_x", "must be in (0, pi)");
    fx = 0.5 * w / std::tan(0.5 * ax);
    fy = fx;
    if (j.contains("camera_angle_y")) {
      const double ay = number(j, "camera_angle_y", file);
      if (!(ay > 0 && ay < M_PI)) throw fieldError(file.string(), "camera_angle_y", "must be in (0, pi)");
      fy = 0.5 * h / std::tan(0.5 * ay);
    }
  } else if (!opts.camera_override) {
    throw fieldError(file.string(), "fl_x", "missing (and no camera_angle_x); give fl_x or camera_angle_x");
  }
  const double cx = j.contains("cx") ? number(j, "cx", file) - 0.5 : 0.5 * (w - 1);
  const double cy = j.contains("cy") ? number(j, "cy", file) - 0.5 : 0.5 * (h - 1);
  Camera cam = Camera::pinhole(w, h, fx, fy, cx, cy);
  auto coef = [&](const char* k) { return j.contains(k) ? number(j, k, file) : 0.0; };
  const std::string model = j.contains("camera_model") && j["camera_model"].is_string()
                                ? j["camera_model"].get<std::string>()
                                : std::string();
  if (model == "OPENCV_FISHEYE") {
    cam.distortion_model = DistortionModel::kEquidistant;
    cam.distortion = {coef("k1"), coef("k2"), coef("k3"), coef("k4")};
  } else if (coef("k1") != 0 || coef("k2") != 0 || coef("k3") != 0 || coef("p1") != 0 || coef("p2") != 0) {
    cam.distortion_model = DistortionModel::kRadTan;
    cam.distortion = {coef("k1"), coef("k2"), coef("p1"), coef("p2")};
    if (coef("k3") != 0) cam.distortion.push_back(coef("k3"));
  }

  auto ds = std::make_unique<SequenceDataset>("transforms", path);
  ds->aabb_scale_ = j.contains("aabb_scale") ? number(j, "aabb_scale", file) : 1.0;
  if (j.contains("scale") || j.contains("offset")) {
    Dataset::NerfScene ns;
    ns.scale = j.contains("scale") ? number(j, "scale", file) : 0.33;  // instant-ngp's defaults
    ns.offset = Eigen::Vector3d::Constant(0.5);
    if (!(ns.scale > 0)) throw fieldError(file.string(), "scale", "must be > 0");
    if (j.contains("offset")) {
      const json& o = j["offset"];
      if (!o.is_array() || o.size() != 3) throw fieldError(file.string(), "offset", "must be a list of 3 numbers");
      for (int k = 0; k < 3; ++k) {
        if (!o[size_t(k)].is_number() || !std::isfinite(o[size_t(k)].get<double>()))
          throw fieldError(file.string(), "offset", "must be a list of 3 finite numbers");
        ns.offset[k] = o[size_t(k)].get<double>();
      }
    }
    ds->nerf_scene_ = ns;
  }
  for (const char* k : {"integer_depth_scale", "depth_unit_scale_factor"}) {
    if (!j.contains(k)) continue;
    ds->depth_scale_ = number(j, k, file);
    if (!(ds->depth_scale_ > 0)) throw fieldError(file.string(), k, "must be > 0");
    break;
  }
  if (!(*ds->aabb_scale_ > 0)) throw fieldError(file.string(), "aabb_scale", "must be > 0");
  std::optional<Camera> own;
  if (fx > 0) own = cam;
  ds->finish(std::move(frames), own, file.string(), opts);
  return ds;
}

}  // namespace nerfslam::io_detail
