#pragma once
// A ROS sensor_msgs/CameraInfo -> Camera, with its checks, in one place for the bag reader
// (src/io/bag/dataset_bag.cpp) and the ROS nodes (apps/ros/conversions.cpp). A template over the
// message type, so the library's headers include no ROS header: any type with CameraInfo's fields
// (width, height, binning_x/_y, roi, K, D, distortion_model) converts.
#include <algorithm>
#include <cstdint>
#include <string>

#include <fmt/format.h>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"

namespace nerfslam {

// Throws an Error naming `source` and the field: an empty or huge image, binning, a region of
// interest, an uncalibrated K, a distortion model other than plumb_bob (4 or 5 coefficients, or none)
// and equidistant (4), or a camera Camera::validate refuses.
template <class CameraInfoMsg>
Camera cameraFromCameraInfo(const CameraInfoMsg& info, const std::string& source) {
  constexpr uint32_t kMaxSide = 16384;
  if (info.width == 0 || info.height == 0 || info.width > kMaxSide || info.height > kMaxSide)
    throw fieldError(source, "width/height",
                     fmt::format("image size {}x{} is empty or too large", info.width, info.height));
  if (info.binning_x > 1 || info.binning_y > 1)
    throw fieldError(source, "binning",
                     fmt::format("binning {}x{} is not supported (publish full-resolution calibration)", info.binning_x,
                                 info.binning_y));
  const bool full_roi =
      (info.roi.width == 0 && info.roi.height == 0) || (info.roi.x_offset == 0 && info.roi.y_offset == 0 &&
                                                        info.roi.width == info.width && info.roi.height == info.height);
  if (!full_roi)
    throw fieldError(source, "roi",
                     fmt::format("a region of interest ({}x{} at {},{}) is not supported", info.roi.width,
                                 info.roi.height, info.roi.x_offset, info.roi.y_offset));
  if (info.K[8] == 0.0) throw fieldError(source, "K", "the camera is uncalibrated (K is all zero)");
  Camera cam = Camera::pinhole(static_cast<int>(info.width), static_cast<int>(info.height), info.K[0], info.K[4],
                               info.K[2], info.K[5]);
  const std::string& model = info.distortion_model;
  const bool all_zero = std::all_of(info.D.begin(), info.D.end(), [](double d) { return d == 0.0; });
  if (model == "plumb_bob" || (model.empty() && info.D.empty())) {
    if (!all_zero) {
      if (info.D.size() != 4 && info.D.size() != 5)
        throw fieldError(source, "D",
                         fmt::format("plumb_bob needs 4 or 5 coefficients (k1 k2 p1 p2 [k3]), got {}", info.D.size()));
      cam.distortion_model = DistortionModel::kRadTan;
      cam.distortion.assign(info.D.begin(), info.D.end());
      if (cam.distortion.size() == 5 && cam.distortion[4] == 0.0) cam.distortion.resize(4);
    }
  } else if (model == "equidistant") {
    if (info.D.size() != 4)
      throw fieldError(source, "D",
                       fmt::format("equidistant needs 4 coefficients (k1 k2 k3 k4), got {}", info.D.size()));
    if (!all_zero) {
      cam.distortion_model = DistortionModel::kEquidistant;
      cam.distortion.assign(info.D.begin(), info.D.end());
    }
  } else {
    throw fieldError(source, "distortion_model",
                     fmt::format("'{}' is not supported (use plumb_bob or equidistant)", model.substr(0, 64)));
  }
  cam.validate(source);
  return cam;
}

// The other way: a CameraInfo message (no header; binning and ROI zero, i.e. full resolution) of a
// camera. plumb_bob carries k1 k2 p1 p2 k3 (k3 = 0 for a camera with four, all zero without
// distortion); equidistant its four.
template <class CameraInfoMsg>
CameraInfoMsg cameraInfoFromCamera(const Camera& camera) {
  CameraInfoMsg info;
  info.width = static_cast<uint32_t>(camera.width);
  info.height = static_cast<uint32_t>(camera.height);
  if (camera.distortion_model == DistortionModel::kEquidistant) {
    info.distortion_model = "equidistant";
    info.D.assign(camera.distortion.begin(), camera.distortion.end());
  } else {
    info.distortion_model = "plumb_bob";
    if (camera.distortion_model == DistortionModel::kRadTan)
      info.D.assign(camera.distortion.begin(), camera.distortion.end());
    info.D.resize(5, 0.0);
  }
  info.K = {camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0};
  info.R = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0};
  info.P = {camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0};
  info.binning_x = 0;
  info.binning_y = 0;
  info.roi.x_offset = 0;
  info.roi.y_offset = 0;
  info.roi.width = 0;
  info.roi.height = 0;
  info.roi.do_rectify = false;
  return info;
}

}  // namespace nerfslam
