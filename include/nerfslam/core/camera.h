#pragma once
// Pinhole camera with optional radial-tangential (k1 k2 p1 p2 [k3], OpenCV "plumb_bob") or
// equidistant fisheye (k1 k2 k3 k4, OpenCV fisheye / Kalibr "equidistant") distortion.
// Pixel convention: OpenCV's (the centre of the top-left pixel is (0, 0)).
//
// Camera YAML (ours; written by saveCameraYaml and `nerfslam calibrate`, presets in config/camera/):
//
//   model: pinhole                 # the only projection model
//   width: 640                     # image size in pixels
//   height: 480
//   fx: 517.306408                 # focal lengths and principal point in pixels
//   fy: 516.469215
//   cx: 318.643040
//   cy: 255.313989
//   distortion_model: radtan       # none | radtan | equidistant (optional, default none)
//   distortion: [0.262383, -0.953104, -0.005358, 0.002628, 1.163314]
//                                  # radtan: k1 k2 p1 p2 [k3]; equidistant: k1 k2 k3 k4; none: [] or absent
//
// Unknown keys are an error (with a "did you mean" hint). loadCameraYaml also reads the ROS
// camera_info calibration YAML written by camera_calibration (image_width, image_height, camera_name,
// camera_matrix, distortion_model plumb_bob | equidistant, distortion_coefficients,
// rectification_matrix, projection_matrix): the format is detected from the keys. The camera
// describes the raw (unrectified) image, i.e. camera_matrix + distortion_coefficients;
// rational_polynomial (8 coefficients) is refused.
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace nerfslam {

enum class DistortionModel { kNone, kRadTan, kEquidistant };
std::string toString(DistortionModel m);  // "none", "radtan", "equidistant"

class Camera {
 public:
  int width = 0;
  int height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  DistortionModel distortion_model = DistortionModel::kNone;
  std::vector<double> distortion;  // radtan: 4 or 5 coefficients; equidistant: 4; none: empty

  static Camera pinhole(int width, int height, double fx, double fy, double cx, double cy);

  // Throws nerfslam::Error naming `source` and the offending field (fx <= 0, NaN, sizes <= 0,
  // wrong number of distortion coefficients, principal point far outside the image, ...).
  void validate(const std::string& source = "camera") const;

  Eigen::Matrix3d K() const;
  cv::Mat cvK() const;     // 3x3 CV_64F
  cv::Mat cvDist() const;  // 1xN CV_64F (empty when kNone)
  bool hasDistortion() const;

  // Camera-frame point -> distorted pixel. Points with z <= 0 give NaN.
  Eigen::Vector2d project(const Eigen::Vector3d& p_cam) const;
  // As project(), false when z <= 0 or the pixel falls outside the image (with `border` pixels margin).
  bool projectInImage(const Eigen::Vector3d& p_cam, Eigen::Vector2d* uv, double border = 0.0) const;
  // Distorted pixel -> ray (x, y, 1) in the camera frame (undistortion by damped Newton iteration,
  // residual < 1e-7 px). NaN when the pixel has no ray: a fisheye pixel at or beyond 90 degrees off
  // axis, or a pixel far outside the image where the radtan polynomial is not invertible.
  Eigen::Vector3d unproject(const Eigen::Vector2d& uv) const;
  // Distorted pixel <-> ideal (undistorted) pinhole pixel with the same K.
  Eigen::Vector2d undistortPoint(const Eigen::Vector2d& uv) const;
  Eigen::Vector2d distortPoint(const Eigen::Vector2d& uv_ideal) const;
  // Resamples an image to the ideal pinhole camera `undistorted()` (bilinear, black where the source
  // falls outside the image). The remap tables are cached per camera (thread-safe, last 8 cameras).
  // Throws an Error when the image size differs from the camera's.
  cv::Mat undistortImage(const cv::Mat& image) const;
  // Same K and size, no distortion.
  Camera undistorted() const;
  // Intrinsics for an image resized by `factor` (e.g. 0.5 for a pyramid level), pixel-centre aware:
  // f' = f * factor, c' = (c + 0.5) * factor - 0.5, size rounded; distortion unchanged.
  Camera scaled(double factor) const;

  std::string describe() const;  // one line for logs
};

// The first calibration field in which two cameras differ (width, height, fx, fy, cx, cy,
// distortion_model, distortion; numbers compared up to a relative 1e-9, i.e. up to rounding in
// files), with both values as text; nullopt when they are the same calibration. The one comparison
// of calibrations: a saved map against the camera given, a ROS camera_info against the map's.
struct CalibrationDifference {
  std::string field, a, b;
};
std::optional<CalibrationDifference> calibrationDifference(const Camera& a, const Camera& b);

// Loads our camera YAML or a ROS camera_info calibration YAML (as written by camera_calibration),
// detected from the keys. Validates; errors name the file and field.
Camera loadCameraYaml(const std::filesystem::path& path);
// Writes our camera YAML atomically.
void saveCameraYaml(const Camera& camera, const std::filesystem::path& path);

}  // namespace nerfslam
