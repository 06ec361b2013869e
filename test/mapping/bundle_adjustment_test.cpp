#include "nerfslam/mapping/bundle_adjustment.h"

#include <gtest/gtest.h>

#include <ceres/cost_function.h>
#include <ceres/manifold.h>

#include "nerfslam/core/error.h"

#include <random>

namespace nerfslam {
namespace {

// Cameras on an arc looking at a cloud of points around (0, 0, 5).
struct Scene {
  BaProblem truth;
  BaProblem noisy;
  std::vector<bool> is_outlier;
};

Scene makeScene(int n_cams, int n_points, double pixel_noise, double outlier_fraction, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> gauss(0, 1);
  std::uniform_real_distribution<double> uni(-1, 1);
  Scene s;
  BaProblem& t = s.truth;
  t.fx = t.fy = 500;
  t.cx = 320;
  t.cy = 240;
  for (int i = 0; i < n_cams; ++i) {
    const double a = -0.4 + 0.8 * i / std::max(1, n_cams - 1);
    const Eigen::Vector3d c(5 * std::sin(a), 0.3 * std::sin(3 * a), 5 - 5 * std::cos(a));
    // Look at (0, 0, 5).
    const Eigen::Vector3d z = (Eigen::Vector3d(0, 0, 5) - c).normalized();
    const Eigen::Vector3d x = Eigen::Vector3d::UnitY().cross(z).normalized();
    const Eigen::Vector3d y = z.cross(x);
    Eigen::Matrix3d R;
    R << x, y, z;
    t.cameras.push_back({SE3(R, c), i == 0});
  }
  for (int j = 0; j < n_points; ++j)
    t.points.push_back({Eigen::Vector3d(2 * uni(rng), 1.5 * uni(rng), 5 + 2 * uni(rng)), false});
  for (int i = 0; i < n_cams; ++i)
    for (int j = 0; j < n_points; ++j) {
      const Eigen::Vector3d pc = t.cameras[i].T_world_cam.inverse() * t.points[j].position;
      const Eigen::Vector2d uv(t.fx * pc.x() / pc.z() + t.cx, t.fy * pc.y() / pc.z() + t.cy);
      if (uv.x() < 0 || uv.y() < 0 || uv.x() > 640 || uv.y() > 480) continue;
      t.observations.push_back({i, j, uv, 1.0});
    }
  s.noisy = t;
  for (auto& o : s.noisy.observations) {
    const bool outlier = uni(rng) * 0.5 + 0.5 < outlier_fraction;
    s.is_outlier.push_back(outlier);
    if (outlier)
      o.uv += Eigen::Vector2d(uni(rng), uni(rng)) * 40.0 + Eigen::Vector2d(10, 10);
    else
      o.uv += Eigen::Vector2d(gauss(rng), gauss(rng)) * pixel_noise;
  }
  for (size_t i = 1; i < s.noisy.cameras.size(); ++i) {
    Vector6d xi;
    xi << 0.05 * gauss(rng), 0.05 * gauss(rng), 0.05 * gauss(rng), 0.01 * gauss(rng), 0.01 * gauss(rng),
        0.01 * gauss(rng);
    s.noisy.cameras[i].T_world_cam = s.noisy.cameras[i].T_world_cam * SE3::exp(xi);
  }
  for (auto& p : s.noisy.points) p.position += Eigen::Vector3d(gauss(rng), gauss(rng), gauss(rng)) * 0.05;
  return s;
}

TEST(BundleAdjustment, RecoversPosesAndPointsToNoiseLevelWithOutliers) {
  const double noise = 0.5;
  Scene s = makeScene(8, 300, noise, 0.05, 7);
  // Fix the second camera too: with noisy observations monocular BA has a free scale; fixing two
  // cameras fixes the gauge (7 dof) so poses are comparable directly.
  s.noisy.cameras[1].T_world_cam = s.truth.cameras[1].T_world_cam;
  s.noisy.cameras[1].fixed = true;
  BundleAdjustmentOptions opt;
  opt.max_iterations = 50;
  opt.refine_iterations = 20;
  opt.max_solver_time_s = 20;
  const BaResult r = bundleAdjust(s.noisy, opt);
  EXPECT_TRUE(r.converged);
  EXPECT_GT(r.initial_rmse_px, 5.0);
  // Inlier RMSE of 2-D Gaussian noise is noise * sqrt(2) (minus the dof absorbed by the fit).
  EXPECT_LT(r.final_rmse_px, noise * std::sqrt(2.0) * 1.05);
  EXPECT_GT(r.final_rmse_px, noise * std::sqrt(2.0) * 0.7);
  // Outliers found: most of the injected ones flagged, few inliers lost.
  int caught = 0, n_out = 0, false_alarm = 0;
  for (size_t k = 0; k < s.is_outlier.size(); ++k) {
    n_out += s.is_outlier[k];
    if (s.is_outlier[k] && !r.inlier[k]) ++caught;
    if (!s.is_outlier[k] && !r.inlier[k]) ++false_alarm;
  }
  EXPECT_GT(n_out, 20);
  EXPECT_GE(caught, n_out * 0.95);
  EXPECT_LT(false_alarm, 0.03 * (s.is_outlier.size() - n_out));
  for (size_t i = 0; i < s.truth.cameras.size(); ++i) {
    const SE3 d = s.truth.cameras[i].T_world_cam.inverse() * s.noisy.cameras[i].T_world_cam;
    EXPECT_LT(d.translation().norm(), 0.01) << "camera " << i;
    EXPECT_LT(d.log().tail<3>().norm(), 0.002) << "camera " << i;
  }
  double err = 0;
  for (size_t j = 0; j < s.truth.points.size(); ++j)
    err += (s.truth.points[j].position - s.noisy.points[j].position).norm();
  EXPECT_LT(err / s.truth.points.size(), 0.02);
}

TEST(BundleAdjustment, NoiseFreeConvergesToZeroError) {
  Scene s = makeScene(5, 100, 0.0, 0.0, 3);
  s.noisy.cameras[1].T_world_cam = s.truth.cameras[1].T_world_cam;
  s.noisy.cameras[1].fixed = true;
  BundleAdjustmentOptions opt;
  opt.max_iterations = 100;
  opt.max_solver_time_s = 20;
  const BaResult r = bundleAdjust(s.noisy, opt);
  EXPECT_LT(r.final_rmse_px, 1e-4);
  EXPECT_EQ(r.outliers, 0);
  for (size_t i = 0; i < s.truth.cameras.size(); ++i)
    EXPECT_TRUE(s.truth.cameras[i].T_world_cam.isApprox(s.noisy.cameras[i].T_world_cam, 1e-5)) << i;
}

// should_stop ends a solve after the iteration in which it turned true (a run stopped twice during
// its global BA): fewer iterations, and the parameters of the last step, which lowered the error.
TEST(BundleAdjustment, StopRequestEndsTheSolveAfterTheIterationInHand) {
  Scene full = makeScene(5, 100, 0.0, 0.0, 3);
  full.noisy.cameras[1].T_world_cam = full.truth.cameras[1].T_world_cam;
  full.noisy.cameras[1].fixed = true;
  Scene stopped = full;
  BundleAdjustmentOptions opt;
  opt.max_iterations = 100;
  opt.refine_iterations = 0;
  opt.max_solver_time_s = 20;
  opt.function_tolerance = 1e-12;
  const BaResult r_full = bundleAdjust(full.noisy, opt);
  int calls = 0;
  opt.should_stop = [&calls] { return ++calls >= 2; };
  const BaResult r_stop = bundleAdjust(stopped.noisy, opt);
  std::printf("full solve: %d iterations, rmse %.3g -> %.3g px; stopped: %d iterations, %.3g px\n", r_full.iterations,
              r_full.initial_rmse_px, r_full.final_rmse_px, r_stop.iterations, r_stop.final_rmse_px);
  EXPECT_GT(r_full.iterations, 3);
  EXPECT_LE(r_stop.iterations, 3);
  EXPECT_LT(r_stop.final_rmse_px, r_stop.initial_rmse_px);
  EXPECT_GT(r_stop.final_rmse_px, r_full.final_rmse_px);
}

TEST(BundleAdjustment, FixedCamerasAndPointsStayPut) {
  Scene s = makeScene(4, 50, 1.0, 0.0, 5);
  for (auto& p : s.noisy.points) p.fixed = true;
  const SE3 before0 = s.noisy.cameras[0].T_world_cam;
  const Eigen::Vector3d p0 = s.noisy.points[0].position;
  bundleAdjust(s.noisy, {});
  EXPECT_TRUE(before0.isApprox(s.noisy.cameras[0].T_world_cam, 1e-12));
  EXPECT_EQ(p0, s.noisy.points[0].position);
}

TEST(BundleAdjustment, RejectsBadIndices) {
  BaProblem p;
  p.cameras.push_back({});
  p.observations.push_back({0, 3, Eigen::Vector2d(1, 1), 1.0});
  EXPECT_THROW(bundleAdjust(p, {}), Error);
}

TEST(PoseManifold, PlusMinusConsistentAndMatchesSE3) {
  auto m = makePoseManifold();
  ASSERT_EQ(m->AmbientSize(), 7);
  ASSERT_EQ(m->TangentSize(), 6);
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0, 0.3);
  for (int trial = 0; trial < 50; ++trial) {
    Vector6d xi;
    for (int k = 0; k < 6; ++k) xi(k) = g(rng) * 3;
    const SE3 T = SE3::exp(xi);
    double x[7], y[7];
    poseToParams(T, x);
    EXPECT_TRUE(poseFromParams(x).isApprox(T, 1e-12));
    double delta[6], back[6];
    for (double& d : delta) d = g(rng) * 0.5;
    ASSERT_TRUE(m->Plus(x, delta, y));
    ASSERT_TRUE(m->Minus(y, x, back));
    for (int k = 0; k < 6; ++k) EXPECT_NEAR(back[k], delta[k], 1e-9);
    // Plus then Minus of zero is the identity.
    double zero[6] = {0, 0, 0, 0, 0, 0}, z[7];
    ASSERT_TRUE(m->Plus(x, zero, z));
    for (int k = 0; k < 7; ++k) EXPECT_NEAR(z[k], x[k], 1e-12);
    // PlusJacobian against central finite differences.
    double J[42];
    ASSERT_TRUE(m->PlusJacobian(x, J));
    const double h = 1e-6;
    for (int c = 0; c < 6; ++c) {
      double dp[6] = {0, 0, 0, 0, 0, 0}, dm[6] = {0, 0, 0, 0, 0, 0}, yp[7], ym[7];
      dp[c] = h;
      dm[c] = -h;
      m->Plus(x, dp, yp);
      m->Plus(x, dm, ym);
      for (int r = 0; r < 7; ++r) EXPECT_NEAR(J[r * 6 + c], (yp[r] - ym[r]) / (2 * h), 1e-6);
    }
  }
}

// The analytic Jacobians, projected on the pose manifold's tangent space, match central differences
// of the residual along the manifold (pose) and in space (point).
TEST(BundleAdjustment, ReprojectionJacobianMatchesFiniteDifferences) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uni(-1, 1);
  const auto manifold = makePoseManifold();
  for (int trial = 0; trial < 20; ++trial) {
    Vector6d xi;
    for (int k = 0; k < 6; ++k) xi(k) = (k < 3 ? 0.5 : 1.0) * uni(rng);
    const SE3 T_world_cam = SE3::exp(xi);
    const Eigen::Vector3d pc(uni(rng), uni(rng), 3 + uni(rng));  // in front of the camera
    Eigen::Vector3d pw = T_world_cam * pc;
    double x[7];
    poseToParams(T_world_cam, x);
    const Eigen::Vector2d uv(300 + 50 * uni(rng), 200 + 50 * uni(rng));
    const auto cost = makeReprojectionCost(uv, 1.5, 500, 480, 320, 240);
    const double* params[2] = {x, pw.data()};
    double r[2], J_pose[14], J_point[6];
    double* jac[2] = {J_pose, J_point};
    ASSERT_TRUE(cost->Evaluate(params, r, jac));
    double plus_jac[7 * 6];
    ASSERT_TRUE(manifold->PlusJacobian(x, plus_jac));
    const Eigen::Matrix<double, 2, 6> J_tangent = Eigen::Map<Eigen::Matrix<double, 2, 7, Eigen::RowMajor>>(J_pose) *
                                                  Eigen::Map<Eigen::Matrix<double, 7, 6, Eigen::RowMajor>>(plus_jac);
    auto residual = [&](const double* pose, const double* point) {
      const double* p[2] = {pose, point};
      Eigen::Vector2d out;
      EXPECT_TRUE(cost->Evaluate(p, out.data(), nullptr));
      return out;
    };
    const double h = 1e-6;
    for (int k = 0; k < 6; ++k) {
      double d[6] = {0, 0, 0, 0, 0, 0}, xp[7], xm[7];
      d[k] = h;
      manifold->Plus(x, d, xp);
      d[k] = -h;
      manifold->Plus(x, d, xm);
      const Eigen::Vector2d num = (residual(xp, pw.data()) - residual(xm, pw.data())) / (2 * h);
      EXPECT_NEAR(J_tangent(0, k), num(0), 1e-4 * (1 + std::abs(num(0)))) << "trial " << trial << " pose dir " << k;
      EXPECT_NEAR(J_tangent(1, k), num(1), 1e-4 * (1 + std::abs(num(1)))) << "trial " << trial << " pose dir " << k;
    }
    const Eigen::Map<Eigen::Matrix<double, 2, 3, Eigen::RowMajor>> Jp(J_point);
    for (int k = 0; k < 3; ++k) {
      Eigen::Vector3d pp = pw, pm = pw;
      pp(k) += h;
      pm(k) -= h;
      const Eigen::Vector2d num = (residual(x, pp.data()) - residual(x, pm.data())) / (2 * h);
      EXPECT_NEAR(Jp(0, k), num(0), 1e-4 * (1 + std::abs(num(0)))) << "trial " << trial << " point dir " << k;
      EXPECT_NEAR(Jp(1, k), num(1), 1e-4 * (1 + std::abs(num(1)))) << "trial " << trial << " point dir " << k;
    }
    // The residual itself is the scaled pixel error.
    const Eigen::Vector3d c = T_world_cam.inverse() * pw;
    EXPECT_NEAR(r[0] * 1.5, 500 * c.x() / c.z() + 320 - uv.x(), 1e-9);
    EXPECT_NEAR(r[1] * 1.5, 480 * c.y() / c.z() + 240 - uv.y(), 1e-9);
  }
}

}  // namespace
}  // namespace nerfslam

namespace nerfslam {
namespace {

// Monocular BA cannot see the scale: a map shrunk to 0.6 about the fixed first camera reprojects
// exactly. Relative translations between consecutive cameras (odometry, in metres, 2 % noise) pull
// it back to metric, and a wrong (slipping) one is held off by its Huber loss.
TEST(BundleAdjustment, RelativeTranslationsSetTheScale) {
  Scene s = makeScene(8, 200, 0.5, 0.0, 11);
  BaProblem pb = s.truth;
  std::mt19937 rng(3);
  std::normal_distribution<double> gauss(0, 1);
  for (auto& o : pb.observations) o.uv += Eigen::Vector2d(gauss(rng), gauss(rng)) * 0.5;
  const Eigen::Vector3d c0 = pb.cameras[0].T_world_cam.translation();
  const auto shrink = [&](const Eigen::Vector3d& p) -> Eigen::Vector3d { return c0 + 0.6 * (p - c0); };
  for (auto& c : pb.cameras) c.T_world_cam = SE3(c.T_world_cam.rotation(), shrink(c.T_world_cam.translation()));
  for (auto& p : pb.points) p.position = shrink(p.position);
  BaProblem plain = pb;
  for (size_t i = 1; i < pb.cameras.size(); ++i) {
    const SE3 rel = s.truth.cameras[i - 1].T_world_cam.inverse() * s.truth.cameras[i].T_world_cam;
    const double d = rel.translation().norm();
    Eigen::Vector3d t =
        rel.translation() + 0.02 / std::sqrt(3.0) * d * Eigen::Vector3d(gauss(rng), gauss(rng), gauss(rng));
    if (i == 4) t *= 1.8;  // a slipping wheel
    pb.relative_translations.push_back({static_cast<int>(i - 1), static_cast<int>(i), t, 0.02 * d + 0.005, 2.0});
  }
  BundleAdjustmentOptions opt;
  opt.max_iterations = 50;
  opt.refine_iterations = 20;
  opt.max_solver_time_s = 20;
  bundleAdjust(plain, opt);
  bundleAdjust(pb, opt);
  const auto pathRatio = [&](const BaProblem& p) {
    double est = 0, gt = 0;
    for (size_t i = 1; i < p.cameras.size(); ++i) {
      est += (p.cameras[i].T_world_cam.translation() - p.cameras[i - 1].T_world_cam.translation()).norm();
      gt += (s.truth.cameras[i].T_world_cam.translation() - s.truth.cameras[i - 1].T_world_cam.translation()).norm();
    }
    return est / gt;
  };
  std::printf("path ratio without odometry %.4f, with %.4f\n", pathRatio(plain), pathRatio(pb));
  EXPECT_NEAR(pathRatio(plain), 0.6, 0.01) << "without odometry the scale stays where it was";
  EXPECT_NEAR(pathRatio(pb), 1.0, 0.02);
  // The cameras' centres within 2 % of the 4 m arc (the odometry's noise accumulates along it).
  for (size_t i = 0; i < s.truth.cameras.size(); ++i)
    EXPECT_LT((pb.cameras[i].T_world_cam.translation() - s.truth.cameras[i].T_world_cam.translation()).norm(), 0.08)
        << i;
  BaProblem bad = pb;
  bad.relative_translations[0].camera_j = 99;
  EXPECT_THROW(bundleAdjust(bad, opt), Error);
}

}  // namespace
}  // namespace nerfslam
