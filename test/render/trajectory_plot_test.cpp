// The trajectory plot: the plane of largest motion, ticks that span the trajectory, equal scale on
// both axes, every position inside the frame and drawn there.
#include <gtest/gtest.h>

#include <cmath>

#include "nerfslam/core/error.h"
#include "nerfslam/render/trajectory_plot.h"

namespace nerfslam {
namespace {

// A drive in the x-z plane (y is height, nearly constant), 40 m long and 12 m wide.
std::vector<Eigen::Vector3d> drive() {
  std::vector<Eigen::Vector3d> p;
  for (int i = 0; i <= 200; ++i) {
    const double s = i / 200.0;
    p.emplace_back(-5.0 + 12.0 * s * s, 0.05 * std::sin(9 * s), 3.0 + 40.0 * s);
  }
  return p;
}

TEST(TrajectoryPlot, ShowsThePlaneOfLargestMotionWithTicksSpanningIt) {
  const cv::Vec3b est_color(180, 119, 31);
  std::vector<Eigen::Vector3d> est = drive();
  for (auto& p : est) p += Eigen::Vector3d(0.3, 0.0, -0.4);
  TrajectoryPlotOptions o;
  o.title = "ATE";
  const TrajectoryPlot pl =
      plotTrajectories({{drive(), {150, 150, 150}, "ground truth"}, {est, est_color, "estimate"}}, o);
  ASSERT_EQ(pl.image.size(), cv::Size(o.width, o.height));
  EXPECT_EQ(pl.plane, "x-z plane");
  EXPECT_EQ(pl.axis_h, 0);
  EXPECT_EQ(pl.axis_v, 2);
  // The labelled ticks span every position on both axes, 1, 2 or 5 times a power of ten apart.
  double xlo = 1e9, xhi = -1e9, zlo = 1e9, zhi = -1e9;
  std::vector<Eigen::Vector3d> all = drive();
  all.insert(all.end(), est.begin(), est.end());
  for (const auto& p : all) {
    xlo = std::min(xlo, p.x()), xhi = std::max(xhi, p.x());
    zlo = std::min(zlo, p.z()), zhi = std::max(zhi, p.z());
  }
  ASSERT_GE(pl.h_ticks.size(), 2u);
  ASSERT_GE(pl.v_ticks.size(), 2u);
  EXPECT_LE(pl.h_ticks.front(), xlo);
  EXPECT_GE(pl.h_ticks.back(), xhi);
  EXPECT_LE(pl.v_ticks.front(), zlo);
  EXPECT_GE(pl.v_ticks.back(), zhi);
  const double step = pl.h_ticks[1] - pl.h_ticks[0];
  EXPECT_NEAR(pl.v_ticks[1] - pl.v_ticks[0], step, 1e-9);
  const double mant = step / std::pow(10.0, std::floor(std::log10(step) + 1e-9));
  EXPECT_TRUE(std::abs(mant - 1) < 1e-6 || std::abs(mant - 2) < 1e-6 || std::abs(mant - 5) < 1e-6) << step;
  // A 40 m drive: a handful of ticks, not hundreds.
  EXPECT_LE(pl.v_ticks.size(), 15u);
  // Equal scale: a tick step is as many pixels across as up.
  const cv::Point2d o0 = pl.toPixel({0, 0, 0}), ox = pl.toPixel({step, 0, 0}), oz = pl.toPixel({0, 0, step});
  EXPECT_NEAR(ox.x - o0.x, o0.y - oz.y, 1e-6);
  EXPECT_GT(ox.x - o0.x, 20.0);
  // Every estimated position is inside the frame and drawn in the estimate's colour there (within a
  // pixel), and nothing of that colour is outside the frame.
  int drawn = 0;
  for (size_t i = 0; i < est.size(); i += 10) {
    const cv::Point2d q = pl.toPixel(est[i]);
    ASSERT_TRUE(pl.frame.contains(cv::Point(int(q.x), int(q.y)))) << i;
    bool found = false;
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        const cv::Vec3b c = pl.image.at<cv::Vec3b>(int(std::lround(q.y)) + dy, int(std::lround(q.x)) + dx);
        found |= cv::norm(cv::Vec3i(c) - cv::Vec3i(est_color)) < 30;
      }
    drawn += found;
  }
  EXPECT_GE(drawn, 19) << "of 21 positions";
  cv::Mat mask;
  cv::inRange(pl.image, cv::Scalar(170, 110, 20), cv::Scalar(190, 130, 40), mask);
  mask(pl.frame).setTo(0);
  EXPECT_EQ(cv::countNonZero(mask), 0);
  // The frame's inside is mostly paper, the curves a few per cent of it.
  cv::Mat inside;
  cv::inRange(pl.image(pl.frame), cv::Scalar(250, 250, 250), cv::Scalar(255, 255, 255), inside);
  EXPECT_GT(cv::countNonZero(inside), pl.frame.area() / 2);
}

TEST(TrajectoryPlot, PicksTheTopViewOfARoomWalkAndRefusesNothing) {
  std::vector<Eigen::Vector3d> walk;
  for (int i = 0; i < 100; ++i)
    walk.emplace_back(std::cos(i * 0.05) * 2.0, std::sin(i * 0.05) * 1.5, 1.5 + 0.02 * (i % 3));
  TrajectoryPlotOptions o;
  o.width = 640;
  o.height = 480;
  o.unit = "map units";
  const TrajectoryPlot pl = plotTrajectories({{walk, {0, 0, 255}, "estimate"}}, o);
  EXPECT_EQ(pl.plane, "x-y plane");
  EXPECT_EQ(pl.image.size(), cv::Size(640, 480));
  for (const auto& p : walk) {
    EXPECT_LE(pl.h_ticks.front(), p.x());
    EXPECT_GE(pl.h_ticks.back(), p.x());
    EXPECT_LE(pl.v_ticks.front(), p.y());
    EXPECT_GE(pl.v_ticks.back(), p.y());
  }
  // A drive along z that climbs more than it turns: by extent the y-z plane; told that -y is up (a
  // camera's image "up"), the top view onto the ground, x-z.
  std::vector<Eigen::Vector3d> climb;
  for (int i = 0; i < 50; ++i) climb.emplace_back(0.01 * i, -0.05 * i, 1.0 * i);
  EXPECT_EQ(plotTrajectories({{climb, {0, 0, 255}, "estimate"}}, o).plane, "y-z plane");
  o.up = Eigen::Vector3d(0.05, -1.0, 0.1);
  EXPECT_EQ(plotTrajectories({{climb, {0, 0, 255}, "estimate"}}, o).plane, "x-z plane");
  o.up.reset();
  EXPECT_THROW(plotTrajectories({}, o), Error);
  EXPECT_THROW(plotTrajectories({{{}, {0, 0, 255}, "empty"}}, o), Error);
  o.width = 100;
  EXPECT_THROW(plotTrajectories({{walk, {0, 0, 255}, "estimate"}}, o), Error);
}

}  // namespace
}  // namespace nerfslam
