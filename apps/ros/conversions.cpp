#include "nerfslam_ros/conversions.h"

#include <algorithm>
#include <cmath>

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/image_encodings.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/io/camera_info.h"

namespace nerfslam::rosbridge {

namespace enc = sensor_msgs::image_encodings;

sensor_msgs::CameraInfo toCameraInfo(const Camera& camera, const std_msgs::Header& header) {
  sensor_msgs::CameraInfo info = cameraInfoFromCamera<sensor_msgs::CameraInfo>(camera);
  info.header = header;
  return info;
}

Camera fromCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& source) {
  return cameraFromCameraInfo(info, source);
}

geometry_msgs::Pose toPose(const SE3& T) {
  geometry_msgs::Pose p;
  p.position.x = T.translation().x();
  p.position.y = T.translation().y();
  p.position.z = T.translation().z();
  p.orientation.w = T.rotation().w();
  p.orientation.x = T.rotation().x();
  p.orientation.y = T.rotation().y();
  p.orientation.z = T.rotation().z();
  return p;
}

SE3 fromPose(const geometry_msgs::Pose& p) {
  const Eigen::Quaterniond q(p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z);
  if (!(q.norm() > 1e-9)) throw Error("geometry_msgs/Pose: orientation is not a rotation (zero quaternion)");
  return SE3(q, Eigen::Vector3d(p.position.x, p.position.y, p.position.z));
}

geometry_msgs::Transform toTransform(const SE3& T) {
  geometry_msgs::Transform t;
  t.translation.x = T.translation().x();
  t.translation.y = T.translation().y();
  t.translation.z = T.translation().z();
  t.rotation.w = T.rotation().w();
  t.rotation.x = T.rotation().x();
  t.rotation.y = T.rotation().y();
  t.rotation.z = T.rotation().z();
  return t;
}

SE3 fromTransform(const geometry_msgs::Transform& t) {
  const Eigen::Quaterniond q(t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z);
  if (!(q.norm() > 1e-9)) throw Error("geometry_msgs/Transform: rotation is not a rotation (zero quaternion)");
  return SE3(q, Eigen::Vector3d(t.translation.x, t.translation.y, t.translation.z));
}

geometry_msgs::TransformStamped toTransformStamped(const SE3& T_parent_child, const std::string& parent,
                                                   const std::string& child, const ros::Time& stamp) {
  geometry_msgs::TransformStamped ts;
  ts.header.stamp = stamp;
  ts.header.frame_id = parent;
  ts.child_frame_id = child;
  ts.transform = toTransform(T_parent_child);
  return ts;
}

const std::vector<std::string>& acceptedEncodings() {
  static const std::vector<std::string> kAccepted = {enc::MONO8, enc::MONO16, enc::BGR8,
                                                     enc::RGB8,  enc::BGRA8,  enc::RGBA8};
  return kAccepted;
}

bool isAcceptedEncoding(const std::string& encoding) {
  const auto& a = acceptedEncodings();
  return std::find(a.begin(), a.end(), encoding) != a.end();
}

std::string encodingForCvType(int cv_type) {
  switch (cv_type) {
    case CV_8UC1:
      return enc::MONO8;
    case CV_8UC3:
      return enc::BGR8;
    case CV_8UC4:
      return enc::BGRA8;
    case CV_16UC1:
      return enc::MONO16;
    case CV_32FC1:
      return enc::TYPE_32FC1;
    default:
      throw Error(
          fmt::format("sensor_msgs/Image: OpenCV image type {} has no supported ROS encoding "
                      "(CV_8UC1, CV_8UC3, CV_8UC4, CV_16UC1, CV_32FC1)",
                      cv::typeToString(cv_type)));
  }
}

cv::Mat fromImageMsg(const sensor_msgs::Image& msg, ImageTarget target) {
  if (!isAcceptedEncoding(msg.encoding)) {
    std::string list;
    for (const auto& e : acceptedEncodings()) list += (list.empty() ? "" : ", ") + e;
    throw Error(fmt::format("sensor_msgs/Image: encoding '{}' is not supported (accepted: {})", msg.encoding, list));
  }
  const int bytes_per_pixel = enc::numChannels(msg.encoding) * (enc::bitDepth(msg.encoding) / 8);
  if (msg.width == 0 || msg.height == 0 || msg.step < msg.width * static_cast<uint32_t>(bytes_per_pixel) ||
      msg.data.size() < static_cast<size_t>(msg.step) * msg.height)
    throw Error(fmt::format("sensor_msgs/Image: malformed {} image ({}x{}, step {}, {} bytes of data)", msg.encoding,
                            msg.width, msg.height, msg.step, msg.data.size()));

  cv_bridge::CvImageConstPtr in;
  try {
    in = cv_bridge::toCvCopy(msg);  // as stored
  } catch (const cv_bridge::Exception& e) {
    throw Error(fmt::format("sensor_msgs/Image ({}): {}", msg.encoding, e.what()));
  }
  cv::Mat src = in->image;
  if (msg.encoding == enc::MONO16) {
    cv::Mat m8;
    src.convertTo(m8, CV_8U, 1.0 / 256.0);
    src = m8;
  }
  const std::string& e = msg.encoding;
  cv::Mat out;
  if (target == ImageTarget::kGray8) {
    if (e == enc::MONO8 || e == enc::MONO16)
      out = src;
    else if (e == enc::BGR8)
      cv::cvtColor(src, out, cv::COLOR_BGR2GRAY);
    else if (e == enc::RGB8)
      cv::cvtColor(src, out, cv::COLOR_RGB2GRAY);
    else if (e == enc::BGRA8)
      cv::cvtColor(src, out, cv::COLOR_BGRA2GRAY);
    else
      cv::cvtColor(src, out, cv::COLOR_RGBA2GRAY);
  } else {
    if (e == enc::MONO8 || e == enc::MONO16)
      cv::cvtColor(src, out, cv::COLOR_GRAY2BGR);
    else if (e == enc::BGR8)
      out = src;
    else if (e == enc::RGB8)
      cv::cvtColor(src, out, cv::COLOR_RGB2BGR);
    else if (e == enc::BGRA8)
      cv::cvtColor(src, out, cv::COLOR_BGRA2BGR);
    else
      cv::cvtColor(src, out, cv::COLOR_RGBA2BGR);
  }
  return out;
}

sensor_msgs::ImagePtr toImageMsg(const cv::Mat& image, const std_msgs::Header& header) {
  if (image.empty()) throw Error("sensor_msgs/Image: cannot publish an empty image");
  return cv_bridge::CvImage(header, encodingForCvType(image.type()), image).toImageMsg();
}

}  // namespace nerfslam::rosbridge
