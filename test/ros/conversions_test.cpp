// Conversions between nerfslam types and ROS messages (no master needed).
#include <gtest/gtest.h>

#include <cmath>

#include <sensor_msgs/image_encodings.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam_ros/conversions.h"

namespace nerfslam::rosbridge {
namespace {

std_msgs::Header makeHeader() {
  std_msgs::Header h;
  h.frame_id = "cam";
  h.stamp = ros::Time(12, 345);
  h.seq = 7;
  return h;
}

void expectSameCamera(const Camera& a, const Camera& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  EXPECT_DOUBLE_EQ(a.fx, b.fx);
  EXPECT_DOUBLE_EQ(a.fy, b.fy);
  EXPECT_DOUBLE_EQ(a.cx, b.cx);
  EXPECT_DOUBLE_EQ(a.cy, b.cy);
  EXPECT_EQ(a.distortion_model, b.distortion_model);
  ASSERT_EQ(a.distortion.size(), b.distortion.size());
  for (size_t i = 0; i < a.distortion.size(); ++i) EXPECT_DOUBLE_EQ(a.distortion[i], b.distortion[i]);
}

TEST(RosCameraInfo, RadTanRoundTripAndLayout) {
  // TUM fr1 calibration (5 coefficients).
  Camera cam = Camera::pinhole(640, 480, 517.306408, 516.469215, 318.643040, 255.313989);
  cam.distortion_model = DistortionModel::kRadTan;
  cam.distortion = {0.262383, -0.953104, -0.005358, 0.002628, 1.163314};
  const auto info = toCameraInfo(cam, makeHeader());
  EXPECT_EQ(info.header.frame_id, "cam");
  EXPECT_EQ(info.header.stamp, ros::Time(12, 345));
  EXPECT_EQ(info.distortion_model, "plumb_bob");
  EXPECT_EQ(info.width, 640u);
  EXPECT_EQ(info.height, 480u);
  // Row-major K, identity R, P = [K | 0].
  const boost::array<double, 9> K = {517.306408, 0, 318.643040, 0, 516.469215, 255.313989, 0, 0, 1};
  EXPECT_EQ(info.K, K);
  const boost::array<double, 9> R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  EXPECT_EQ(info.R, R);
  const boost::array<double, 12> P = {517.306408, 0, 318.643040, 0, 0, 516.469215, 255.313989, 0, 0, 0, 1, 0};
  EXPECT_EQ(info.P, P);
  ASSERT_EQ(info.D.size(), 5u);
  EXPECT_DOUBLE_EQ(info.D[4], 1.163314);
  // Same matrix as the library's K().
  const Eigen::Matrix3d k = cam.K();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(info.K[3 * r + c], k(r, c));
  expectSameCamera(fromCameraInfo(info), cam);
}

TEST(RosCameraInfo, FourCoefficientRadTanPadsK3AndComesBack) {
  Camera cam = Camera::pinhole(752, 480, 458.654, 457.296, 367.215, 248.375);
  cam.distortion_model = DistortionModel::kRadTan;
  cam.distortion = {-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05};
  const auto info = toCameraInfo(cam, makeHeader());
  ASSERT_EQ(info.D.size(), 5u);
  EXPECT_EQ(info.D[4], 0.0);
  expectSameCamera(fromCameraInfo(info), cam);
}

TEST(RosCameraInfo, EquidistantAndNoDistortionRoundTrip) {
  Camera fish = Camera::pinhole(640, 480, 190.97, 190.97, 254.93, 256.89);
  fish.distortion_model = DistortionModel::kEquidistant;
  fish.distortion = {0.0034823, 0.000715, -0.0020532, 0.00020293};
  const auto fi = toCameraInfo(fish, makeHeader());
  EXPECT_EQ(fi.distortion_model, "equidistant");
  EXPECT_EQ(fi.D.size(), 4u);
  expectSameCamera(fromCameraInfo(fi), fish);

  const Camera plain = Camera::pinhole(1226, 370, 707.0912, 707.0912, 601.8873, 183.1104);
  const auto pi = toCameraInfo(plain, makeHeader());
  EXPECT_EQ(pi.distortion_model, "plumb_bob");
  EXPECT_EQ(pi.D, std::vector<double>(5, 0.0));
  expectSameCamera(fromCameraInfo(pi), plain);
}

TEST(RosCameraInfo, ProjectionAgreesAfterRoundTrip) {
  Camera cam = Camera::pinhole(640, 480, 500, 505, 320, 240);
  cam.distortion_model = DistortionModel::kRadTan;
  cam.distortion = {-0.2, 0.05, 0.001, -0.002, 0.01};
  const Camera back = fromCameraInfo(toCameraInfo(cam, makeHeader()));
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(0.3, -0.2, 2.0), Eigen::Vector3d(-0.5, 0.4, 1.5)}) {
    EXPECT_LT((cam.project(p) - back.project(p)).norm(), 1e-12);
  }
}

TEST(RosCameraInfo, RefusesWhatACameraCannotRepresent) {
  auto info = toCameraInfo(Camera::pinhole(640, 480, 500, 500, 320, 240), makeHeader());
  auto expectRefused = [](const sensor_msgs::CameraInfo& i, const std::string& field) {
    try {
      fromCameraInfo(i, "test_info");
      ADD_FAILURE() << "accepted a camera_info with a bad " << field;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("test_info"), std::string::npos) << e.what();
    }
  };
  auto rational = info;
  rational.distortion_model = "rational_polynomial";
  rational.D = {0.1, 0.01, 0, 0, 0, 0.1, 0.01, 0};
  expectRefused(rational, "distortion_model");
  auto uncalibrated = info;
  uncalibrated.K = {};
  expectRefused(uncalibrated, "K");
  auto binned = info;
  binned.binning_x = 2;
  expectRefused(binned, "binning");
  auto roi = info;
  roi.roi.width = 100;
  roi.roi.height = 100;
  roi.roi.x_offset = 10;
  expectRefused(roi, "roi");
  auto wrong_d = info;
  wrong_d.D = {0.1, 0.2, 0.3};
  expectRefused(wrong_d, "D");
  auto empty = info;
  empty.width = 0;
  expectRefused(empty, "width");
}

TEST(RosPose, PoseAndTransformRoundTrip) {
  const SE3 T(Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, -0.5).normalized())),
              Eigen::Vector3d(1.5, -2.0, 0.25));
  EXPECT_TRUE(fromPose(toPose(T)).isApprox(T, 1e-12));
  EXPECT_TRUE(fromTransform(toTransform(T)).isApprox(T, 1e-12));
  const auto ts = toTransformStamped(T, "world", "cam", ros::Time(3.5));
  EXPECT_EQ(ts.header.frame_id, "world");
  EXPECT_EQ(ts.child_frame_id, "cam");
  EXPECT_EQ(ts.header.stamp, ros::Time(3.5));
  // tf semantics: the transform maps child-frame points into the parent frame, like T * p.
  const Eigen::Vector3d p(0.3, 0.1, 2.0);
  const auto& r = ts.transform.rotation;
  const Eigen::Quaterniond q(r.w, r.x, r.y, r.z);
  const Eigen::Vector3d t(ts.transform.translation.x, ts.transform.translation.y, ts.transform.translation.z);
  EXPECT_LT((q * p + t - T * p).norm(), 1e-12);
  geometry_msgs::Pose zero;
  zero.orientation.w = 0;
  EXPECT_THROW(fromPose(zero), Error);
}

cv::Mat testPattern(int type) {
  cv::Mat m(37, 53, type);
  cv::randu(m, cv::Scalar::all(0), cv::Scalar::all(CV_MAT_DEPTH(type) == CV_16U ? 65535 : 255));
  return m;
}

double maxAbsDiff(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return 1e9;
  return cv::norm(a, b, cv::NORM_INF);
}

TEST(RosImage, OutgoingEncodingsFollowTheCvType) {
  EXPECT_EQ(toImageMsg(testPattern(CV_8UC1), makeHeader())->encoding, "mono8");
  EXPECT_EQ(toImageMsg(testPattern(CV_8UC3), makeHeader())->encoding, "bgr8");
  EXPECT_EQ(toImageMsg(testPattern(CV_8UC4), makeHeader())->encoding, "bgra8");
  EXPECT_EQ(toImageMsg(testPattern(CV_16UC1), makeHeader())->encoding, "mono16");
  const auto msg = toImageMsg(testPattern(CV_8UC1), makeHeader());
  EXPECT_EQ(msg->header.frame_id, "cam");
  EXPECT_EQ(msg->width, 53u);
  EXPECT_EQ(msg->height, 37u);
  EXPECT_THROW(toImageMsg(testPattern(CV_8UC2), makeHeader()), Error);
  EXPECT_THROW(toImageMsg(cv::Mat(), makeHeader()), Error);
}

TEST(RosImage, AcceptedEncodingsConvertLikeOpenCV) {
  const cv::Mat bgr = testPattern(CV_8UC3);
  cv::Mat gray, rgb, bgra, rgba;
  cv::cvtColor(bgr, gray, cv::COLOR_BGR2GRAY);
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  cv::cvtColor(bgr, bgra, cv::COLOR_BGR2BGRA);
  cv::cvtColor(bgr, rgba, cv::COLOR_BGR2RGBA);
  const auto h = makeHeader();

  // bgr8 / rgb8 / bgra8 / rgba8 -> BGR exactly, -> gray as cv::cvtColor does.
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*toImageMsg(bgr, h), ImageTarget::kBgr8), bgr), 0);
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*toImageMsg(bgr, h), ImageTarget::kGray8), gray), 0);
  auto rgb_msg = toImageMsg(rgb, h);
  rgb_msg->encoding = "rgb8";
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*rgb_msg, ImageTarget::kBgr8), bgr), 0);
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*rgb_msg, ImageTarget::kGray8), gray), 0);
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*toImageMsg(bgra, h), ImageTarget::kBgr8), bgr), 0);
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*toImageMsg(bgra, h), ImageTarget::kGray8), gray), 0);
  auto rgba_msg = toImageMsg(rgba, h);
  rgba_msg->encoding = "rgba8";
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*rgba_msg, ImageTarget::kBgr8), bgr), 0);
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*rgba_msg, ImageTarget::kGray8), gray), 0);

  // mono8 -> gray unchanged, -> BGR with three equal channels.
  const auto mono = toImageMsg(gray, h);
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*mono, ImageTarget::kGray8), gray), 0);
  cv::Mat gray3;
  cv::cvtColor(gray, gray3, cv::COLOR_GRAY2BGR);
  EXPECT_EQ(maxAbsDiff(fromImageMsg(*mono, ImageTarget::kBgr8), gray3), 0);

  // mono16 -> 8 bits by value / 256, rounded to nearest (ties to even, as cvRound), pixel by pixel.
  const cv::Mat m16 = testPattern(CV_16UC1);
  const cv::Mat g8 = fromImageMsg(*toImageMsg(m16, h), ImageTarget::kGray8);
  ASSERT_EQ(g8.type(), CV_8UC1);
  for (int r = 0; r < m16.rows; ++r)
    for (int c = 0; c < m16.cols; ++c) {
      const int expected = std::min(255, static_cast<int>(std::nearbyint(m16.at<uint16_t>(r, c) / 256.0)));
      ASSERT_LE(std::abs(g8.at<uint8_t>(r, c) - expected), 0) << r << "," << c;
    }
}

TEST(RosImage, RefusedEncodingsNameTheEncoding) {
  const auto h = makeHeader();
  for (const std::string e : {"bayer_rggb8", "yuv422", "16UC1", "32FC1", "8UC3", "mono12"}) {
    auto msg = toImageMsg(testPattern(CV_8UC1), h);
    msg->encoding = e;
    EXPECT_FALSE(isAcceptedEncoding(e)) << e;
    try {
      fromImageMsg(*msg, ImageTarget::kGray8);
      ADD_FAILURE() << "accepted encoding " << e;
    } catch (const Error& err) {
      const std::string what = err.what();
      EXPECT_NE(what.find("'" + e + "'"), std::string::npos) << what;
      EXPECT_NE(what.find("mono8"), std::string::npos) << "the message lists the accepted encodings: " << what;
    }
  }
  for (const std::string e : {"mono8", "mono16", "bgr8", "rgb8", "bgra8", "rgba8"}) EXPECT_TRUE(isAcceptedEncoding(e));
}

TEST(RosImage, MalformedMessagesAreRefused) {
  auto msg = toImageMsg(testPattern(CV_8UC3), makeHeader());
  msg->data.resize(msg->data.size() / 2);
  EXPECT_THROW(fromImageMsg(*msg, ImageTarget::kBgr8), Error);
  auto bad_step = toImageMsg(testPattern(CV_8UC3), makeHeader());
  bad_step->step = bad_step->width;  // one byte per pixel for a 3-channel encoding
  EXPECT_THROW(fromImageMsg(*bad_step, ImageTarget::kBgr8), Error);
}

}  // namespace
}  // namespace nerfslam::rosbridge
