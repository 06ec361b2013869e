#include "nerfslam/tracking/pose_optimizer.h"

#include <gtest/gtest.h>

#include <random>

namespace nerfslam {
namespace {

TEST(PoseOptimizer, RecoversPerturbedPoseWith30PercentOutliers) {
  Eigen::Matrix3d K;
  K << 600, 0, 320, 0, 600, 240, 0, 0, 1;
  const SE3 T_true(Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d(0.2, 1, 0.1).normalized())),
                   Eigen::Vector3d(0.4, -0.2, 1.0));
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  std::normal_distribution<double> noise(0, 0.7);
  std::vector<PoseObservation> obs;
  std::vector<char> truth;
  const SE3 Tcw = T_true.inverse();
  while (obs.size() < 300) {
    const Eigen::Vector3d pc(3 * u(rng), 2 * u(rng), 4 + 3 * u(rng));
    const Eigen::Vector2d uv = (K * pc).hnormalized();
    if (uv.x() < 0 || uv.x() > 640 || uv.y() < 0 || uv.y() > 480) continue;
    PoseObservation o;
    o.p_world = T_true * pc;
    const bool outlier = obs.size() % 10 < 3;  // 30%
    o.uv = outlier ? Eigen::Vector2d(320 + 300 * u(rng), 240 + 220 * u(rng))
                   : uv + Eigen::Vector2d(noise(rng), noise(rng));
    obs.push_back(o);
    truth.push_back(!outlier);
  }
  (void)Tcw;
  Vector6d d;
  d << 0.1, -0.08, 0.12, 0.04, -0.05, 0.03;  // ~4 degrees, ~17 cm
  const SE3 T_init = T_true * SE3::exp(d);
  const PoseOptimizationResult r = optimizePose(K, obs, T_init);
  ASSERT_TRUE(r.converged);
  const Vector6d err = (T_true.inverse() * r.T_world_cam).log();
  EXPECT_LT(err.head<3>().norm(), 0.01);              // < 1 cm
  EXPECT_LT(err.tail<3>().norm() * 180 / M_PI, 0.1);  // < 0.1 degree
  int wrong = 0;
  for (size_t i = 0; i < obs.size(); ++i) wrong += (r.inlier[i] != truth[i]);
  EXPECT_LT(wrong, 12);  // 5% of noisy inliers fall outside the 95% chi2 gate by construction
  EXPECT_LT(r.rms_px, 1.2);
  EXPECT_GT(r.num_inliers, 190);
}

TEST(PoseOptimizer, TooFewObservationsDoesNotConverge) {
  Eigen::Matrix3d K = Eigen::Matrix3d::Identity();
  PoseObservation o;
  o.p_world = Eigen::Vector3d(0, 0, 1);
  o.uv = Eigen::Vector2d(0, 0);
  const PoseOptimizationResult r = optimizePose(K, {o}, SE3());
  EXPECT_FALSE(r.converged);
  EXPECT_EQ(r.num_inliers, 0);
}

}  // namespace
}  // namespace nerfslam
