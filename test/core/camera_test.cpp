#include "nerfslam/core/camera.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include <opencv2/calib3d.hpp>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

Camera tumFr1() {
  Camera c = Camera::pinhole(640, 480, 517.306408, 516.469215, 318.643040, 255.313989);
  c.distortion_model = DistortionModel::kRadTan;
  c.distortion = {0.262383, -0.953104, -0.005358, 0.002628, 1.163314};
  return c;
}

Camera euroc() {
  Camera c = Camera::pinhole(752, 480, 458.654, 457.296, 367.215, 248.375);
  c.distortion_model = DistortionModel::kRadTan;
  c.distortion = {-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05};
  return c;
}

// A fisheye lens as calibrated for an Intel RealSense T265 (about 160 degrees across the diagonal
// image circle; the image corners look beyond 90 degrees and have no ray).
Camera fisheye() {
  Camera c = Camera::pinhole(848, 800, 286.181, 286.389, 416.938, 403.684);
  c.distortion_model = DistortionModel::kEquidistant;
  c.distortion = {-0.0110425, 0.0489719, -0.0459712, 0.00886949};
  return c;
}

// Angle from the optical axis a fisheye pixel sees, before undistortion (theta_d).
double thetaD(const Camera& c, const Eigen::Vector2d& px) {
  return std::hypot((px.x() - c.cx) / c.fx, (px.y() - c.cy) / c.fy);
}

// theta_d of a ray 89.999 degrees off axis: pixels further out look behind the camera.
double fisheyeLimit(const Camera& c) {
  const double th = 89.999 * M_PI / 180.0;
  return thetaD(c, c.project({std::sin(th), 0.0, std::cos(th)}));
}

std::vector<Camera> allCameras() {
  return {Camera::pinhole(640, 480, 525, 525, 319.5, 239.5), tumFr1(), euroc(), fisheye()};
}

// Pixels on a grid covering the whole image, corners included.
std::vector<Eigen::Vector2d> imageGrid(const Camera& c, int steps = 17) {
  std::vector<Eigen::Vector2d> out;
  for (int i = 0; i < steps; ++i)
    for (int j = 0; j < steps; ++j)
      out.emplace_back((c.width - 1) * double(i) / (steps - 1), (c.height - 1) * double(j) / (steps - 1));
  return out;
}

std::vector<Eigen::Vector3d> pointsInView(const Camera& c, int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d px(u(rng) * (c.width - 1), u(rng) * (c.height - 1));
    const Eigen::Vector3d ray = c.unproject(px);
    if (!ray.allFinite()) {  // fisheye pixels beyond 90 degrees
      --i;
      continue;
    }
    pts.push_back(ray * (0.5 + 10.0 * u(rng)));
  }
  return pts;
}

TEST(Camera, PixelRayPixelRoundTripOverWholeImage) {
  for (const Camera& c : allCameras()) {
    SCOPED_TRACE(c.describe());
    for (const auto& px : imageGrid(c)) {
      const Eigen::Vector3d ray = c.unproject(px);
      if (c.distortion_model == DistortionModel::kEquidistant && thetaD(c, px) >= fisheyeLimit(c)) {
        EXPECT_FALSE(ray.allFinite()) << px.transpose();  // beyond 90 degrees: no ray
        continue;
      }
      ASSERT_TRUE(ray.allFinite()) << px.transpose();
      EXPECT_DOUBLE_EQ(ray.z(), 1.0);
      const Eigen::Vector2d back = c.project(ray * 3.7);
      EXPECT_LT((back - px).norm(), 1e-6) << px.transpose();
    }
  }
}

TEST(Camera, PointPixelRayRoundTrip) {
  for (const Camera& c : allCameras()) {
    SCOPED_TRACE(c.describe());
    for (const auto& p : pointsInView(c, 200, 7)) {
      const Eigen::Vector3d ray = c.unproject(c.project(p));
      EXPECT_LT((ray - p / p.z()).norm(), 1e-9);
    }
  }
}

TEST(Camera, FisheyePixelsBeyondNinetyDegreesHaveNoRay) {
  const Camera c = fisheye();
  const Eigen::Vector2d corner(0, 0);
  ASSERT_GT(thetaD(c, corner), 1.8);  // the lens maps 90 degrees to theta_d < 1.8
  EXPECT_FALSE(c.unproject(corner).allFinite());
  EXPECT_FALSE(c.undistortPoint(corner).allFinite());
  // 80 degrees off axis along +x is a valid pixel and unprojects back to 80 degrees.
  const double th = 80.0 * M_PI / 180.0;
  const Eigen::Vector2d px = c.project({std::sin(th), 0.0, std::cos(th)});
  ASSERT_TRUE(px.allFinite());
  const Eigen::Vector3d ray = c.unproject(px);
  EXPECT_NEAR(std::atan2(ray.x(), ray.z()), th, 1e-9);
}

TEST(Camera, PointsBehindTheCameraGiveNaN) {
  const Camera c = tumFr1();
  EXPECT_FALSE(c.project({0.1, 0.2, -1.0}).allFinite());
  EXPECT_FALSE(c.project({0.1, 0.2, 0.0}).allFinite());
  Eigen::Vector2d uv;
  EXPECT_FALSE(c.projectInImage({0.1, 0.2, -1.0}, &uv));
}

TEST(Camera, ProjectInImageHonoursBorder) {
  const Camera c = Camera::pinhole(640, 480, 500, 500, 319.5, 239.5);
  Eigen::Vector2d uv;
  // (0, 0, 1) -> the principal point.
  EXPECT_TRUE(c.projectInImage({0, 0, 1}, &uv, 10));
  EXPECT_NEAR(uv.x(), 319.5, 1e-12);
  // u = 5: inside the image, inside a 5-pixel border's edge, outside a 10-pixel border.
  const Eigen::Vector3d p((5 - 319.5) / 500, 0, 1);
  EXPECT_TRUE(c.projectInImage(p, &uv, 0));
  EXPECT_NEAR(uv.x(), 5.0, 1e-9);
  EXPECT_FALSE(c.projectInImage(p, &uv, 10));
  EXPECT_FALSE(c.projectInImage({-2.0, 0, 1}, &uv));  // u = -680
  EXPECT_FALSE(c.projectInImage({0, 0.6, 1}, &uv));   // v = 539.5
}

TEST(Camera, RadTanMatchesOpenCvProjectPoints) {
  for (const Camera& c : {tumFr1(), euroc()}) {
    SCOPED_TRACE(c.describe());
    const auto pts = pointsInView(c, 300, 11);
    std::vector<cv::Point3d> cv_pts;
    for (const auto& p : pts) cv_pts.emplace_back(p.x(), p.y(), p.z());
    std::vector<cv::Point2d> cv_px;
    cv::projectPoints(cv_pts, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), c.cvK(), c.cvDist(), cv_px);
    for (size_t i = 0; i < pts.size(); ++i) {
      const Eigen::Vector2d ours = c.project(pts[i]);
      EXPECT_NEAR(ours.x(), cv_px[i].x, 1e-9 * std::abs(cv_px[i].x) + 1e-12);
      EXPECT_NEAR(ours.y(), cv_px[i].y, 1e-9 * std::abs(cv_px[i].y) + 1e-12);
    }
  }
}

TEST(Camera, EquidistantMatchesOpenCvFisheyeProjectPoints) {
  const Camera c = fisheye();
  const auto pts = pointsInView(c, 300, 13);
  std::vector<cv::Point3d> cv_pts;
  for (const auto& p : pts) cv_pts.emplace_back(p.x(), p.y(), p.z());
  std::vector<cv::Point2d> cv_px;
  cv::fisheye::projectPoints(cv_pts, cv_px, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), c.cvK(), c.cvDist());
  for (size_t i = 0; i < pts.size(); ++i) {
    const Eigen::Vector2d ours = c.project(pts[i]);
    EXPECT_NEAR(ours.x(), cv_px[i].x, 1e-9 * std::abs(cv_px[i].x) + 1e-12);
    EXPECT_NEAR(ours.y(), cv_px[i].y, 1e-9 * std::abs(cv_px[i].y) + 1e-12);
  }
}

TEST(Camera, UndistortPointMatchesOpenCv) {
  const cv::TermCriteria tight(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 1000, 1e-15);
  for (const Camera& c : {tumFr1(), euroc(), fisheye()}) {
    SCOPED_TRACE(c.describe());
    // The central region, where OpenCV's fixed-point iteration converges for every model.
    std::vector<cv::Point2d> px;
    for (const auto& p : imageGrid(c, 9)) {
      const double du = (p.x() - c.cx) / c.width, dv = (p.y() - c.cy) / c.height;
      if (du * du + dv * dv < 0.16) px.emplace_back(p.x(), p.y());
    }
    ASSERT_GT(px.size(), 20u);
    std::vector<cv::Point2d> cv_ideal;
    if (c.distortion_model == DistortionModel::kEquidistant)
      cv::fisheye::undistortPoints(px, cv_ideal, c.cvK(), c.cvDist(), cv::noArray(), c.cvK(), tight);
    else
      cv::undistortPoints(px, cv_ideal, c.cvK(), c.cvDist(), cv::noArray(), c.cvK(), tight);
    for (size_t i = 0; i < px.size(); ++i) {
      const Eigen::Vector2d ours = c.undistortPoint({px[i].x, px[i].y});
      EXPECT_NEAR(ours.x(), cv_ideal[i].x, 1e-6);
      EXPECT_NEAR(ours.y(), cv_ideal[i].y, 1e-6);
      // distortPoint is the inverse.
      const Eigen::Vector2d back = c.distortPoint(ours);
      EXPECT_NEAR(back.x(), px[i].x, 1e-6);
      EXPECT_NEAR(back.y(), px[i].y, 1e-6);
    }
  }
}

TEST(Camera, NoDistortionIsIdentity) {
  const Camera c = Camera::pinhole(640, 480, 525, 525, 319.5, 239.5);
  EXPECT_FALSE(c.hasDistortion());
  EXPECT_TRUE(c.cvDist().empty());
  const Eigen::Vector2d px(12.25, 401.5);
  EXPECT_EQ(c.undistortPoint(px), px);
  EXPECT_EQ(c.distortPoint(px), px);
  const Eigen::Vector3d ray = c.unproject(px);
  EXPECT_NEAR(ray.x(), (12.25 - 319.5) / 525, 1e-15);
  EXPECT_NEAR(ray.y(), (401.5 - 239.5) / 525, 1e-15);
}

// The ideal image is a smooth known function; the distorted image samples it at each distorted
// pixel's ideal position. Undistorting must give the function back.
double pattern(double u, double v) { return 128.0 + 90.0 * std::sin(u / 20.0) * std::cos(v / 16.0); }

TEST(Camera, UndistortImageRecoversKnownContent) {
  for (const Camera& c : {tumFr1(), euroc(), fisheye()}) {
    SCOPED_TRACE(c.describe());
    cv::Mat distorted(c.height, c.width, CV_32FC1);
    for (int v = 0; v < c.height; ++v)
      for (int u = 0; u < c.width; ++u) {
        const Eigen::Vector2d ideal = c.undistortPoint({u, v});
        distorted.at<float>(v, u) = ideal.allFinite() ? float(pattern(ideal.x(), ideal.y())) : 0.f;
      }
    const cv::Mat out = c.undistortImage(distorted);
    ASSERT_EQ(out.size(), distorted.size());
    ASSERT_EQ(out.type(), CV_32FC1);
    double max_err = 0;
    int checked = 0;
    for (int v = 0; v < c.height; v += 3)
      for (int u = 0; u < c.width; u += 3) {
        const Eigen::Vector2d src = c.distortPoint({u, v});
        // Only pixels whose source lies well inside the distorted image.
        if (!(src.x() > 2 && src.y() > 2 && src.x() < c.width - 3 && src.y() < c.height - 3)) continue;
        // Beyond 60 degrees a fisheye squeezes the pinhole image by more than 4x, so bilinear
        // interpolation of the distorted image no longer resolves the pattern.
        if (c.unproject(src).head<2>().norm() > std::tan(60.0 * M_PI / 180.0)) continue;
        max_err = std::max(max_err, std::abs(out.at<float>(v, u) - pattern(u, v)));
        ++checked;
      }
    EXPECT_GT(checked, c.width * c.height / 9 / 3);
    std::printf("undistortImage %s: max |error| %.3f grey levels over %d pixels\n",
                toString(c.distortion_model).c_str(), max_err, checked);
    // Bilinear interpolation (|f''| <= 90/256 per px^2 before distortion) and 1/32 px map quantisation.
    EXPECT_LT(max_err, 1.0);
    // The same call again uses the cached maps and gives the same result.
    const cv::Mat again = c.undistortImage(distorted);
    EXPECT_EQ(cv::norm(out, again, cv::NORM_INF), 0.0);
  }
}

TEST(Camera, UndistortImageRejectsWrongSize) {
  const Camera c = tumFr1();
  EXPECT_THROW(c.undistortImage(cv::Mat(100, 100, CV_8UC1)), Error);
  EXPECT_THROW(c.undistortImage(cv::Mat()), Error);
}

TEST(Camera, UndistortedKeepsKAndDropsDistortion) {
  const Camera c = tumFr1();
  const Camera u = c.undistorted();
  EXPECT_EQ(u.K(), c.K());
  EXPECT_EQ(u.width, c.width);
  EXPECT_EQ(u.distortion_model, DistortionModel::kNone);
  EXPECT_TRUE(u.distortion.empty());
  EXPECT_NO_THROW(u.validate());
  // A point seen by the ideal camera lands where undistortPoint puts the distorted pixel.
  const Eigen::Vector3d p(0.3, -0.2, 1.5);
  EXPECT_LT((u.project(p) - c.undistortPoint(c.project(p))).norm(), 1e-6);
}

TEST(Camera, ScaledIsPixelCentreAware) {
  for (const Camera& c : allCameras()) {
    SCOPED_TRACE(c.describe());
    for (double s : {0.5, 0.25, 2.0}) {
      const Camera h = c.scaled(s);
      EXPECT_EQ(h.width, static_cast<int>(std::lround(c.width * s)));
      EXPECT_EQ(h.height, static_cast<int>(std::lround(c.height * s)));
      for (const auto& p : pointsInView(c, 50, 3)) {
        const Eigen::Vector2d full = c.project(p);
        const Eigen::Vector2d small = h.project(p);
        EXPECT_NEAR(small.x(), (full.x() + 0.5) * s - 0.5, 1e-9);
        EXPECT_NEAR(small.y(), (full.y() + 0.5) * s - 0.5, 1e-9);
      }
    }
  }
  // Half-size image: the top-left 2x2 block (centre 0.5, 0.5 at full size) is pixel 0 at half size.
  const Camera c = Camera::pinhole(640, 480, 500, 500, 319.5, 239.5);
  const Camera h = c.scaled(0.5);
  EXPECT_DOUBLE_EQ(h.cx, 159.5);
  EXPECT_DOUBLE_EQ(h.cy, 119.5);
  EXPECT_DOUBLE_EQ(h.fx, 250.0);
  EXPECT_THROW(c.scaled(0.0), Error);
  EXPECT_THROW(c.scaled(-1.0), Error);
}

TEST(Camera, CvMatricesMatch) {
  const Camera c = tumFr1();
  const cv::Mat K = c.cvK();
  ASSERT_EQ(K.type(), CV_64F);
  for (int r = 0; r < 3; ++r)
    for (int col = 0; col < 3; ++col) EXPECT_EQ(K.at<double>(r, col), c.K()(r, col));
  const cv::Mat D = c.cvDist();
  ASSERT_EQ(D.rows, 1);
  ASSERT_EQ(D.cols, 5);
  for (int i = 0; i < 5; ++i) EXPECT_EQ(D.at<double>(0, i), c.distortion[i]);
}

TEST(Camera, DescribeNamesEverything) {
  const std::string d = tumFr1().describe();
  EXPECT_NE(d.find("640x480"), std::string::npos) << d;
  EXPECT_NE(d.find("radtan"), std::string::npos) << d;
  EXPECT_NE(d.find("517.306408"), std::string::npos) << d;
  EXPECT_NE(d.find("1.163314"), std::string::npos) << d;
  EXPECT_EQ(toString(DistortionModel::kEquidistant), "equidistant");
  EXPECT_EQ(toString(DistortionModel::kNone), "none");
}

// validate(): each rejection names the source and the field.
void expectInvalid(const Camera& c, const std::string& field) {
  try {
    c.validate("cams/front.yaml");
    ADD_FAILURE() << "accepted invalid camera, expected an error about " << field;
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("cams/front.yaml"), std::string::npos) << msg;
    EXPECT_NE(msg.find("'" + field + "'"), std::string::npos) << msg;
  }
}

TEST(Camera, ValidateRejectsBadCameras) {
  const Camera good = tumFr1();
  EXPECT_NO_THROW(good.validate("x"));
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  Camera c;
  c = good, c.width = 0, expectInvalid(c, "width");
  c = good, c.width = -640, expectInvalid(c, "width");
  c = good, c.height = 0, expectInvalid(c, "height");
  c = good, c.fx = 0, expectInvalid(c, "fx");
  c = good, c.fx = -500, expectInvalid(c, "fx");
  c = good, c.fy = -1, expectInvalid(c, "fy");
  c = good, c.fx = nan, expectInvalid(c, "fx");
  c = good, c.fy = inf, expectInvalid(c, "fy");
  c = good, c.cx = nan, expectInvalid(c, "cx");
  c = good, c.cy = inf, expectInvalid(c, "cy");
  c = good, c.cx = 700, expectInvalid(c, "cx");
  c = good, c.cx = -3, expectInvalid(c, "cx");
  c = good, c.cy = 480, expectInvalid(c, "cy");
  c = good, c.distortion = {0.1, 0.2, 0.3}, expectInvalid(c, "distortion");
  c = good, c.distortion = {0.1, 0.2, 0.3, 0.4, 0.5, 0.6}, expectInvalid(c, "distortion");
  c = good, c.distortion[1] = nan, expectInvalid(c, "distortion");
  c = good, c.distortion_model = DistortionModel::kEquidistant, expectInvalid(c, "distortion");
  c = good, c.distortion_model = DistortionModel::kNone, expectInvalid(c, "distortion");
  EXPECT_NO_THROW(euroc().validate());
  EXPECT_NO_THROW(fisheye().validate());
}

}  // namespace
}  // namespace nerfslam

namespace nerfslam {
namespace {

TEST(CalibrationDifference, NamesTheFirstFieldThatDiffersWithBothValues) {
  Camera a = Camera::pinhole(640, 480, 525, 525, 319.5, 239.5);
  Camera b = a;
  EXPECT_FALSE(calibrationDifference(a, b));
  b.fx = 525 * (1 + 1e-12);  // rounding in a file is the same calibration
  EXPECT_FALSE(calibrationDifference(a, b));
  b.fx = 520;
  auto d = calibrationDifference(a, b);
  ASSERT_TRUE(d);
  EXPECT_EQ(d->field, "fx");
  EXPECT_EQ(d->a, "525");
  EXPECT_EQ(d->b, "520");
  b = a;
  b.height = 470;
  d = calibrationDifference(a, b);
  ASSERT_TRUE(d);
  EXPECT_EQ(d->field, "height");
  b = a;
  b.distortion_model = DistortionModel::kRadTan;
  b.distortion = {0.1, 0, 0, 0};
  d = calibrationDifference(a, b);
  ASSERT_TRUE(d);
  EXPECT_EQ(d->field, "distortion_model");
  a.distortion_model = DistortionModel::kRadTan;
  a.distortion = {0.1, 0, 0, 0.001};
  d = calibrationDifference(a, b);
  ASSERT_TRUE(d);
  EXPECT_EQ(d->field, "distortion");
  EXPECT_EQ(d->a, "[0.1, 0, 0, 0.001]");
}

}  // namespace
}  // namespace nerfslam
