#pragma once
// Conversions between nerfslam types and ROS 1 messages (the ROS layer only; the library never
// includes ROS headers).
//
// Camera <-> sensor_msgs/CameraInfo
//   The Camera describes the raw (distorted) image. CameraInfo carries it as K + D with
//   distortion_model "plumb_bob" (radtan k1 k2 p1 p2 k3; a camera without distortion is written as
//   plumb_bob with five zeros) or "equidistant" (k1 k2 k3 k4). R is the identity (monocular) and
//   P = [K | 0], so image_proc's rectified image is Camera::undistorted().
//   Reading back: plumb_bob with all-zero D -> no distortion; 5 coefficients with k3 == 0 -> 4.
//   rational_polynomial and other models, binning, a partial ROI, zero K or size are refused
//   (nerfslam::Error naming the field).
//
// SE3 <-> geometry_msgs/Pose, geometry_msgs/Transform(Stamped)
//   T_parent_child: the pose of `child` in `parent` (tf's transform from child to parent).
//
// cv::Mat <-> sensor_msgs/Image (cv_bridge)
//   Out: CV_8UC1 -> mono8, CV_8UC3 -> bgr8, CV_8UC4 -> bgra8, CV_16UC1 -> mono16, CV_32FC1 ->
//        32FC1 (depth); other types are refused.
//   In:  accepted encodings are mono8, mono16, bgr8, rgb8, bgra8, rgba8; they are converted to the
//        requested target (8-bit gray or 8-bit BGR). mono16 is reduced to 8 bits by value / 256 (rounded to nearest).
//        Anything else (bayer_*, yuv422, 16UC1 depth, 32FC1, ...) is refused with an Error naming
//        the encoding and listing the accepted ones.
#include <string>
#include <vector>

#include <geometry_msgs/Pose.h>
#include <geometry_msgs/Transform.h>
#include <geometry_msgs/TransformStamped.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/Header.h>
#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"

namespace nerfslam::rosbridge {

// ---- Camera ----
sensor_msgs::CameraInfo toCameraInfo(const Camera& camera, const std_msgs::Header& header);
// Throws nerfslam::Error (naming `source` and the field) for what a Camera cannot represent.
Camera fromCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& source = "camera_info");

// ---- Poses ----
geometry_msgs::Pose toPose(const SE3& T);
SE3 fromPose(const geometry_msgs::Pose& pose);
geometry_msgs::Transform toTransform(const SE3& T);
SE3 fromTransform(const geometry_msgs::Transform& t);
geometry_msgs::TransformStamped toTransformStamped(const SE3& T_parent_child, const std::string& parent,
                                                   const std::string& child, const ros::Time& stamp);

// ---- Images ----
enum class ImageTarget {
  kGray8,  // CV_8UC1
  kBgr8,   // CV_8UC3, BGR order
};
// The encodings fromImageMsg accepts.
const std::vector<std::string>& acceptedEncodings();
bool isAcceptedEncoding(const std::string& encoding);
// The ROS encoding toImageMsg uses for an OpenCV type; throws for unsupported types.
std::string encodingForCvType(int cv_type);
// Converts (copies) `msg` to the target format. Throws nerfslam::Error for a refused encoding or a
// malformed message (data size / step inconsistent with width and height).
cv::Mat fromImageMsg(const sensor_msgs::Image& msg, ImageTarget target);
// Wraps (copies) `image` into a message with the encoding of encodingForCvType.
sensor_msgs::ImagePtr toImageMsg(const cv::Mat& image, const std_msgs::Header& header);

}  // namespace nerfslam::rosbridge
