// Headless previews: points land where the chosen view projects them, the automatic view fits the
// content, and `nerfslam render-preview` draws clouds, trajectories and keyframes from files.
#include <limits>

#include <gtest/gtest.h>

#include <fstream>

#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/preview.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/render/trajectory.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

TEST(Preview, PointsLandWhereTheViewProjectsThem) {
  PreviewScene s;
  PreviewCloud c;
  c.points = {{1.0f, 0.0f, 0.5f}, {-0.8f, 0.3f, -0.4f}, {0.0f, 0.0f, 0.0f}};
  c.colors.resize(3);
  c.colors[0] = cv::Vec3b(0, 0, 255);
  c.colors[1] = cv::Vec3b(0, 255, 0);
  c.colors[2] = cv::Vec3b(255, 0, 0);
  s.clouds.push_back(c);
  PreviewOptions o;
  o.width = 200;
  o.height = 150;
  o.point_size = 5;
  o.legend = false;
  o.eye = Eigen::Vector3d(0, -5, 0);
  o.target = Eigen::Vector3d(0, 0, 0);
  const cv::Mat img = renderPreview(s, o);
  ASSERT_EQ(img.size(), cv::Size(200, 150));
  const double f = 75.0 / std::tan(30.0 * M_PI / 180.0);
  const Camera cam = Camera::pinhole(200, 150, f, f, 99.5, 74.5);
  const SE3 T_world_cam = lookAt(*o.eye, *o.target);
  for (size_t i = 0; i < c.points.size(); ++i) {
    const Eigen::Vector2d uv = cam.project(T_world_cam.inverse() * c.points[i].cast<double>());
    const cv::Vec3b px =
        img.at<cv::Vec3b>(static_cast<int>(std::lround(uv.y())), static_cast<int>(std::lround(uv.x())));
    EXPECT_EQ(px, c.colors[i]) << "point " << i << " at " << uv.transpose();
  }
  // Only the three 5x5 dots differ from the background.
  cv::Mat diff;
  cv::absdiff(img, cv::Scalar(o.background[0], o.background[1], o.background[2]), diff);
  cv::Mat gray;
  cv::cvtColor(diff, gray, cv::COLOR_BGR2GRAY);
  EXPECT_NEAR(cv::countNonZero(gray), 75, 10);
}

TEST(Preview, AutomaticViewFitsEverything) {
  PreviewScene s;
  PreviewCloud c;
  cv::RNG rng(4);
  for (int i = 0; i < 2000; ++i)
    c.points.emplace_back(rng.uniform(-3.f, 5.f), rng.uniform(10.f, 12.f), rng.uniform(0.f, 2.f));
  s.clouds.push_back(c);
  PreviewTrajectory t;
  for (int i = 0; i < 50; ++i) t.poses.push_back(SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(i * 0.1, 11, 1)));
  s.trajectories.push_back(t);
  PreviewOptions o;
  o.width = 320;
  o.height = 240;
  Eigen::Vector3d eye, target;
  autoView(s, o, &eye, &target);
  const double f = 120.0 / std::tan(30.0 * M_PI / 180.0);
  const Camera cam = Camera::pinhole(320, 240, f, f, 159.5, 119.5);
  const SE3 T_cam_world = lookAt(eye, target).inverse();
  for (const auto& p : c.points) {
    Eigen::Vector2d uv;
    EXPECT_TRUE(cam.projectInImage(T_cam_world * p.cast<double>(), &uv)) << p.transpose();
  }
  EXPECT_GT(eye.z(), target.z());  // from above
  EXPECT_THROW(renderPreview(PreviewScene{}, o), Error);
  o.width = 0;
  EXPECT_THROW(renderPreview(s, o), Error);
  // Non-finite options are refused, not drawn as an empty image.
  const double nan = std::numeric_limits<double>::quiet_NaN();
  o.width = 320;
  for (int k = 0; k < 5; ++k) {
    SCOPED_TRACE(k);
    PreviewOptions bad = o;
    if (k == 0) bad.up = Eigen::Vector3d(nan, 0, 1);
    if (k == 1) bad.point_size = static_cast<float>(nan);
    if (k == 2) bad.frustum_size = nan;
    if (k == 3) bad.eye = Eigen::Vector3d(nan, 0, 0), bad.target = Eigen::Vector3d::Zero();
    if (k == 4) bad.up = Eigen::Vector3d::Zero();
    EXPECT_THROW(renderPreview(s, bad), Error);
  }
}

TEST(Preview, ParsesViewsAndColours) {
  Eigen::Vector3d e, t;
  parseView("eye=1,2,3,target=0,0.5,-1", &e, &t);
  EXPECT_EQ(e, Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(t, Eigen::Vector3d(0, 0.5, -1));
  parseView("target=0,0,0, eye=4,5,6", &e, &t);
  EXPECT_EQ(e, Eigen::Vector3d(4, 5, 6));
  EXPECT_THROW(parseView("eye=1,2,target=0,0,0", &e, &t), Error);
  EXPECT_THROW(parseView("1,2,3", &e, &t), Error);
  EXPECT_THROW(parseView("eye=1,2,3,target=1,2,3", &e, &t), Error);
  EXPECT_EQ(parseColor("#ff8000"), cv::Vec3b(0, 128, 255));
  EXPECT_THROW(parseColor("chartreuse"), Error);
}

// A synthetic room without its ceiling: back-projected depth as a coloured dense cloud, GT and a drifting estimate as
// trajectories, every 50th GT pose as keyframes; drawn through the CLI.
TEST(Preview, ReadsDoublePositionsAndColoursByObservations) {
  // The SLAM runner's map_points.ply: ASCII, double x/y/z, an int observation count per point.
  test::TempDir tmp;
  {
    std::ofstream os(tmp / "map.ply");
    os << "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
          "property double z\nproperty int observations\nend_header\n"
          "0.5 -0.25 2.125 2\n1 2 3 40\n-1 0 4 3\n";
  }
  const PreviewCloud c = loadPointCloudPly(tmp / "map.ply");
  ASSERT_EQ(c.points.size(), 3u);
  EXPECT_FLOAT_EQ(c.points[0].x(), 0.5f);
  EXPECT_FLOAT_EQ(c.points[0].y(), -0.25f);
  EXPECT_FLOAT_EQ(c.points[0].z(), 2.125f);
  ASSERT_EQ(c.colors.size(), 3u);
  EXPECT_NE(c.colors[0], c.colors[1]) << "2 and 40 observations must get different colours";
}

TEST(Preview, PlyWithoutPositionsIsAnError) {
  test::TempDir tmp;
  {
    std::ofstream os(tmp / "bad.ply");
    os << "ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nproperty float b\nend_header\n1 2\n";
  }
  try {
    loadPointCloudPly(tmp / "bad.ply");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.ply"), std::string::npos) << e.what();
  }
}

TEST(PreviewCli, DrawsCloudTrajectoriesAndKeyframes) {
  if (!fs::exists(test::cliPath())) GTEST_SKIP() << "nerfslam binary not built";
  test::TempDir tmp;
  SynthOptions so;
  so.frames = 300;
  so.width = 160;
  so.height = 120;
  so.textures = "procedural";
  SequenceRenderer seq(so);
  pcl::PointCloud<pcl::PointXYZRGB> cloud;
  for (int i : {0, 100, 200, 299}) {
    const SynthFrame f = seq.render(i);
    for (int v = 0; v < f.depth.rows; v += 2)
      for (int u = 0; u < f.depth.cols; u += 2) {
        const float z = f.depth.at<float>(v, u);
        const Eigen::Vector3d X = f.T_world_cam * (seq.camera().unproject({u, v}) * z);
        if (X.z() > 2.5) continue;  // no ceiling: a "dollhouse" view into the room
        pcl::PointXYZRGB p;
        p.x = static_cast<float>(X.x()), p.y = static_cast<float>(X.y()), p.z = static_cast<float>(X.z());
        const cv::Vec3b c = f.bgr.at<cv::Vec3b>(v, u);
        p.b = c[0], p.g = c[1], p.r = c[2];
        cloud.push_back(p);
      }
  }
  ASSERT_EQ(pcl::io::savePLYFileBinary((tmp / "cloud.ply").string(), cloud), 0);
  Trajectory gt, est, kf;
  for (int i = 0; i < 300; ++i) {
    gt.push_back({seq.timestamp(i), seq.pose(i)});
    est.push_back({seq.timestamp(i),
                   SE3(seq.pose(i).rotation(), seq.pose(i).translation() + Eigen::Vector3d(0.002 * i, 0, 0.3))});
    if (i % 50 == 0) kf.push_back(gt.back());
  }
  writeTumTrajectory(tmp / "gt.txt", gt);
  writeTumTrajectory(tmp / "est.txt", est);
  writeTumTrajectory(tmp / "kf.txt", kf);
  const fs::path out = tmp / "preview.png";
  auto r = test::runCli("render-preview --points '" + (tmp / "cloud.ply").string() + "' --trajectory '" +
                        (tmp / "gt.txt").string() + ":green' --trajectory '" + (tmp / "est.txt").string() +
                        ":#ff00ff' --keyframes '" + (tmp / "kf.txt").string() +
                        "' --frustum-size 0.02 --size 400x300 --out '" + out.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const cv::Mat img = cv::imread(out.string());
  ASSERT_EQ(img.size(), cv::Size(400, 300));
  int magenta = 0, green = 0;
  for (int v = 0; v < img.rows; ++v)
    for (int u = 40; u < img.cols; ++u) {  // skip the legend
      const cv::Vec3b c = img.at<cv::Vec3b>(v, u);
      magenta += c == cv::Vec3b(255, 0, 255);
      green += c == parseColor("green");
    }
  EXPECT_GT(magenta, 20) << "estimated trajectory not drawn";
  EXPECT_GT(green, 20) << "ground-truth trajectory not drawn";
  if (const char* keep = std::getenv("NERFSLAM_KEEP_PREVIEW"))
    fs::copy_file(out, keep, fs::copy_options::overwrite_existing);

  r = test::runCli("render-preview --points '" + (tmp / "missing.ply").string() + "' --out '" + out.string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("missing.ply"), std::string::npos) << r.output;
  r = test::runCli("render-preview --trajectory '" + (tmp / "gt.txt").string() + "' --view 'eye=1,2' --out '" +
                   out.string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--view"), std::string::npos) << r.output;
  r = test::runCli("render-preview --trajectory '" + (tmp / "gt.txt").string() + "' --size 0x0 --out '" + out.string() +
                   "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--size"), std::string::npos) << r.output;
  for (const char* bad :
       {"--up nan,0,1", "--point-size nan", "--frustum-size inf", "--view eye=nan,0,0,target=0,0,0"}) {
    r = test::runCli("render-preview --trajectory '" + (tmp / "gt.txt").string() + "' " + bad + " --out '" +
                     out.string() + "'");
    // Refused by the command (exit 1, "error: ...") or, for a number option, by the command line's
    // finite-number check (CLI11's exit code for a refused value, naming the option).
    EXPECT_NE(r.exit_code, 0) << bad;
    const std::string flag = std::string(bad).substr(0, std::string(bad).find(' '));
    EXPECT_TRUE(r.output.find("error") != std::string::npos ||
                r.output.find(flag + ": must be a finite number") != std::string::npos)
        << bad << ": " << r.output;
  }
}

// A box room (z up, 6 x 4 x 2.6 m) as cameras looking along +x reconstruct it: red floor, grey
// walls but the one behind them (x = -3), blue ceiling, as points every 5 cm.
PreviewCloud boxRoom() {
  PreviewCloud c;
  auto add = [&](const Eigen::Vector3f& p, const cv::Vec3b& col) {
    c.points.push_back(p);
    c.colors.push_back(col);
  };
  for (float x = -3; x <= 3; x += 0.05f)
    for (float y = -2; y <= 2; y += 0.05f) {
      add({x, y, 0.f}, {0, 0, 220});   // floor
      add({x, y, 2.6f}, {220, 0, 0});  // ceiling
    }
  for (float z = 0; z <= 2.6f; z += 0.05f) {
    for (float x = -3; x <= 3; x += 0.05f) add({x, -2.f, z}, {128, 128, 128}), add({x, 2.f, z}, {128, 128, 128});
    for (float y = -2; y <= 2; y += 0.05f) add({3.f, y, z}, {128, 128, 128});
  }
  return c;
}

int countColor(const cv::Mat& img, const cv::Vec3b& c) {
  cv::Mat mask;
  cv::inRange(img, cv::Scalar(c[0], c[1], c[2]), cv::Scalar(c[0], c[1], c[2]), mask);
  return cv::countNonZero(mask);
}

// 320x240 without a legend: the overview tests' pictures.
PreviewOptions smallOverviewOptions() {
  PreviewOptions o;
  o.width = 320;
  o.height = 240;
  o.legend = false;
  return o;
}

TEST(Preview, OverviewOfARoomLooksInFromAboveWithoutTheCeiling) {
  const PreviewCloud room = boxRoom();
  // A handheld walk at 1.5 m along the far wall, looking at it (+x).
  std::vector<SE3> cams;
  for (int i = 0; i < 20; ++i)
    cams.push_back(lookAt({0.2 * std::sin(i * 0.3), -1.0 + 0.1 * i, 1.5}, {3.0, 0.3 * std::cos(i * 0.2), 1.2}));
  PreviewOptions o = smallOverviewOptions();
  const Overview ov = overviewViewpoint(room.points, cams, o);
  EXPECT_FALSE(ov.traversal);
  ASSERT_TRUE(ov.max_height.has_value());
  EXPECT_GT(*ov.max_height, 1.5);
  EXPECT_LT(*ov.max_height, 2.6);
  // Outside the room, above it, behind the cameras (they look along +x), looking at its middle.
  EXPECT_LT(ov.eye.x(), -3.0);
  EXPECT_GT(ov.eye.z(), 2.6);
  EXPECT_LT((ov.target - Eigen::Vector3d(0, 0, 0.9)).norm(), 0.6) << ov.target.transpose();
  // Drawn from there: the floor shows, the ceiling does not.
  PreviewScene s;
  s.clouds.push_back(room);
  o.eye = ov.eye;
  o.target = ov.target;
  o.max_height = ov.max_height;
  const cv::Mat img = renderPreview(s, o);
  if (const char* keep = std::getenv("NERFSLAM_KEEP_PREVIEW")) cv::imwrite(keep, img);
  EXPECT_GT(countColor(img, {0, 0, 220}), img.total() / 8) << "floor pixels";
  EXPECT_EQ(countColor(img, {220, 0, 0}), 0) << "ceiling pixels";
  // The automatic view of the same cloud sees mostly the ceiling.
  o.eye.reset();
  o.target.reset();
  o.max_height.reset();
  const cv::Mat outside = renderPreview(s, o);
  EXPECT_LT(countColor(outside, {0, 0, 220}), img.total() / 50);
}

TEST(Preview, OverviewOfAnObjectShowsItAndTheCamerasAroundIt) {
  // A 0.3 m object (z up) photographed from half a ring of cameras at 1 m, 0.4 m above it.
  PreviewCloud object;
  for (float x = -0.15f; x <= 0.15f; x += 0.01f)
    for (float y = -0.15f; y <= 0.15f; y += 0.01f)
      for (float z : {0.f, 0.3f}) object.points.emplace_back(x, y, z);
  std::vector<SE3> cams;
  for (int i = 0; i < 19; ++i) {
    const double a = M_PI * i / 18.0;
    cams.push_back(lookAt({std::cos(a), std::sin(a), 0.55}, {0, 0, 0.15}));
  }
  PreviewOptions o = smallOverviewOptions();
  const Overview ov = overviewViewpoint(object.points, cams, o);
  EXPECT_FALSE(ov.traversal);
  EXPECT_FALSE(ov.max_height.has_value());
  EXPECT_LT((ov.target - Eigen::Vector3d(0, 0, 0.15)).norm(), 0.05) << ov.target.transpose();
  EXPECT_GT(ov.up.z(), 0.99) << ov.up.transpose();
  // Photos taken rotated (the Middlebury ring's): an up from the cameras' axes would be horizontal;
  // the overview still looks down onto the object from above the ring.
  PreviewOptions rolled = o;
  rolled.up = Eigen::Vector3d(1, 0, 0);
  const Overview ovr = overviewViewpoint(object.points, cams, rolled);
  EXPECT_GT(ovr.up.z(), 0.99) << ovr.up.transpose();
  EXPECT_GT(ovr.eye.z(), 0.55) << "above the cameras";
  // Every camera and the object are drawn: within the field of view from the eye.
  const Eigen::Vector3d axis = (ov.target - ov.eye).normalized();
  const double half_fov = 0.5 * o.fov_deg * M_PI / 180.0;
  for (const auto& T : cams) {
    const Eigen::Vector3d d = (T.translation() - ov.eye).normalized();
    EXPECT_LT(std::acos(std::min(1.0, d.dot(axis))), half_fov) << T.translation().transpose();
  }
  PreviewScene s;
  s.clouds.push_back(object);
  s.trajectories.push_back({cams, {0, 0, 255}, "cameras"});
  o.eye = ov.eye;
  o.target = ov.target;
  o.up = ov.up;
  const cv::Mat img = renderPreview(s, o);
  if (const char* keep = std::getenv("NERFSLAM_KEEP_PREVIEW")) cv::imwrite(keep, img);
  EXPECT_GT(countColor(img, {0, 0, 255}), 200) << "trajectory pixels";
}

TEST(Preview, OverviewOfADriveLooksAheadFromBehindTheStart) {
  // A street along +y (z up): 80 m of road and house fronts either side, a car driving 40 m along it
  // from y = 0.
  PreviewCloud street;
  for (float y = -10; y <= 70; y += 0.5f)
    for (float x = -8; x <= 8; x += 0.5f) street.points.emplace_back(x, y, 0.f);
  for (float y = -10; y <= 70; y += 0.5f)
    for (float z = 0; z <= 8; z += 0.5f) street.points.emplace_back(-8.f, y, z), street.points.emplace_back(8.f, y, z);
  std::vector<SE3> cams;
  for (int i = 0; i <= 40; ++i) cams.push_back(lookAt({0.1 * std::sin(i * 0.1), double(i), 1.6}, {0, i + 10.0, 1.6}));
  PreviewOptions o;
  const Overview ov = overviewViewpoint(street.points, cams, o);
  EXPECT_TRUE(ov.traversal);
  EXPECT_FALSE(ov.max_height.has_value());
  EXPECT_LT(ov.eye.y(), 0.0) << "behind the start";
  EXPECT_GT(ov.eye.z(), 1.6 + 5.0) << "above the car";
  EXPECT_GT(ov.target.y(), 5.0) << "ahead of the start";
  EXPECT_LT(std::abs(ov.target.x()), 2.0);
  EXPECT_THROW(overviewViewpoint({}, cams, o), Error);
  EXPECT_THROW(overviewViewpoint(street.points, {}, o), Error);
}

}  // namespace
}  // namespace nerfslam
