#include "nerfslam/mapping/triangulation.h"

#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

#include <random>

namespace nerfslam {
namespace {

Eigen::Vector2d project(const Eigen::Matrix3d& K, const SE3& T_world_cam, const Eigen::Vector3d& X) {
  const Eigen::Vector3d p = K * (T_world_cam.inverse() * X);
  return p.hnormalized();
}

TEST(Triangulation, DltExactAndMatchesOpenCv) {
  Eigen::Matrix3d K;
  K << 600, 0, 320, 0, 600, 240, 0, 0, 1;
  const SE3 T1 = SE3::exp((Vector6d() << 0.1, -0.2, 0.05, 0.02, -0.1, 0.03).finished());
  const SE3 T2 = SE3::exp((Vector6d() << 0.6, -0.1, 0.2, -0.03, 0.05, 0.01).finished());
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1, 1);
  cv::Mat P1, P2;
  Eigen::Matrix<double, 3, 4> e1 = T1.inverse().matrix3x4(), e2 = T2.inverse().matrix3x4();
  cv::eigen2cv(e1, P1);
  cv::eigen2cv(e2, P2);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d X(u(rng), u(rng), 4 + u(rng));
    const Eigen::Vector2d x1 = project(K, T1, X), x2 = project(K, T2, X);
    const Eigen::Vector2d n1 = (K.inverse() * x1.homogeneous()).hnormalized();
    const Eigen::Vector2d n2 = (K.inverse() * x2.homogeneous()).hnormalized();
    const auto Y = triangulateDlt(T1, T2, n1, n2);
    ASSERT_TRUE(Y);
    EXPECT_LT((*Y - X).norm(), 1e-9);
    cv::Mat pts4;
    cv::triangulatePoints(P1, P2, cv::Mat(cv::Point2d(n1.x(), n1.y())), cv::Mat(cv::Point2d(n2.x(), n2.y())), pts4);
    const Eigen::Vector3d cvX(pts4.at<double>(0) / pts4.at<double>(3), pts4.at<double>(1) / pts4.at<double>(3),
                              pts4.at<double>(2) / pts4.at<double>(3));
    EXPECT_LT((cvX - *Y).norm(), 1e-6);
    // Epipolar constraint from the poses.
    const Eigen::Matrix3d F = fundamentalFromPoses(T1, T2, K);
    EXPECT_LT(epipolarDistance(F, x1, x2), 1e-6);
  }
}

TEST(Triangulation, NoisyAccuracyMatchesFirstOrderPrediction) {
  // 1 px noise per view, 0.5 m baseline at 5 m depth, f = 600.
  Eigen::Matrix3d K;
  K << 600, 0, 320, 0, 600, 240, 0, 0, 1;
  const SE3 T1;
  const SE3 T2(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.5, 0, 0));
  std::mt19937 rng(2);
  std::normal_distribution<double> g(0, 1.0);
  std::uniform_real_distribution<double> u(-1, 1);
  double sq = 0;
  int n = 0;
  for (int i = 0; i < 2000; ++i) {
    const Eigen::Vector3d X(u(rng), u(rng), 5);
    const Eigen::Vector2d x1 = project(K, T1, X) + Eigen::Vector2d(g(rng), g(rng));
    const Eigen::Vector2d x2 = project(K, T2, X) + Eigen::Vector2d(g(rng), g(rng));
    TriangulationChecks c;
    c.max_error_sigma = 100;
    const auto r = triangulateChecked(T1, T2, K, x1, x2, 1.0, 1.0, c);
    ASSERT_TRUE(r);
    sq += (r->position - X).squaredNorm();
    ++n;
  }
  const double rms = std::sqrt(sq / n);
  // Disparity noise is sqrt(2) px; depth error z^2 / (f b) * sqrt(2) dominates the position error.
  const double predicted = 25.0 / (600 * 0.5) * std::sqrt(2.0);
  EXPECT_GT(rms, 0.8 * predicted);
  EXPECT_LT(rms, 1.25 * predicted);
}

TEST(Triangulation, ChecksRejectBadGeometry) {
  Eigen::Matrix3d K;
  K << 600, 0, 320, 0, 600, 240, 0, 0, 1;
  const SE3 T1;
  const SE3 T2(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.5, 0, 0));
  const Eigen::Vector3d X(0.2, 0.1, 5);
  TriangulationChecks c;
  // Good point passes.
  EXPECT_TRUE(triangulateChecked(T1, T2, K, project(K, T1, X), project(K, T2, X), 1, 1, c));
  // Too little parallax: a far point (0.5 m baseline at 100 m is 0.29 deg).
  const Eigen::Vector3d far(0.2, 0.1, 100);
  EXPECT_FALSE(triangulateChecked(T1, T2, K, project(K, T1, far), project(K, T2, far), 1, 1, c));
  c.min_parallax_deg = 0.1;
  EXPECT_TRUE(triangulateChecked(T1, T2, K, project(K, T1, far), project(K, T2, far), 1, 1, c));
  // Behind the cameras: mirrored disparity.
  c.min_parallax_deg = 1.0;
  const Eigen::Vector2d a = project(K, T1, X), b = project(K, T2, X);
  EXPECT_FALSE(triangulateChecked(T1, T2, K, a, a + (a - b), 1, 1, c));
  // Off the epipolar line by 10 px: reprojection check fails.
  EXPECT_FALSE(triangulateChecked(T1, T2, K, a, b + Eigen::Vector2d(0, 10), 1, 1, c));
}

}  // namespace
}  // namespace nerfslam
