#include "nerfslam/tracking/sim3_solver.h"

#include <gtest/gtest.h>

#include <random>

namespace nerfslam {
namespace {

const Camera kCam = Camera::pinhole(640, 480, 500, 500, 319.5, 239.5);

Sim3 knownS12() {
  return Sim3(0.62, Eigen::Quaterniond(Eigen::AngleAxisd(0.35, Eigen::Vector3d(0.2, 1.0, -0.3).normalized())),
              Eigen::Vector3d(0.4, -0.15, 0.3));
}

Eigen::Vector2d project(const Eigen::Vector3d& p) { return {500 * p.x() / p.z() + 319.5, 500 * p.y() / p.z() + 239.5}; }

// n pairs seen by both keyframes; a fraction `outliers` of them wrong (p2 of another place, seen
// consistently in keyframe 2 so that only the test in keyframe 1 can reject them).
std::vector<Sim3Match> makeMatches(const Sim3& S12, int n, double outliers, uint32_t seed, std::vector<bool>* truth) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1), depth(2, 6);
  std::normal_distribution<double> px(0, 0.5);
  const Sim3 S21 = S12.inverse();
  std::vector<Sim3Match> m;
  truth->clear();
  while (int(m.size()) < n) {
    const double z = depth(rng);
    const Eigen::Vector3d p1(u(rng) * 0.6 * z, u(rng) * 0.45 * z, z);
    Sim3Match x;
    x.p1 = p1;
    x.p2 = S21 * p1;
    if (x.p2.z() < 0.5) continue;
    const bool bad = int(m.size()) < int(outliers * n);
    if (bad) {
      const double z2 = depth(rng) * S21.scale();
      x.p2 = Eigen::Vector3d(u(rng) * 0.6 * z2, u(rng) * 0.45 * z2, z2);
    }
    x.uv1 = project(x.p1) + Eigen::Vector2d(px(rng), px(rng));
    x.uv2 = project(x.p2) + Eigen::Vector2d(px(rng), px(rng));
    // Triangulated points are noisy too (0.3 % of depth).
    x.p1 *= 1.0 + 0.003 * u(rng);
    x.p2 *= 1.0 + 0.003 * u(rng);
    m.push_back(x);
    truth->push_back(!bad);
  }
  // Shuffle so outliers are not all first.
  std::vector<size_t> order(m.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::shuffle(order.begin(), order.end(), rng);
  std::vector<Sim3Match> out;
  std::vector<bool> t;
  for (size_t i : order) out.push_back(m[i]), t.push_back((*truth)[i]);
  *truth = t;
  return out;
}

double rotationErrorDeg(const Sim3& a, const Sim3& b) {
  return a.rotation().angularDistance(b.rotation()) * 180 / M_PI;
}

TEST(Sim3Solver, ClosedFormIsExactOnThreePoints) {
  const Sim3 S = knownS12();
  const std::vector<Eigen::Vector3d> p2 = {{0, 0, 3}, {1, 0.2, 4}, {-0.5, 1, 2.5}};
  std::vector<Eigen::Vector3d> p1;
  for (const auto& p : p2) p1.push_back(S * p);
  const auto est = alignPoints(p1, p2);
  ASSERT_TRUE(est.has_value());
  EXPECT_NEAR(est->scale(), S.scale(), 1e-9);
  EXPECT_LT(rotationErrorDeg(*est, S), 1e-7);
  EXPECT_LT((est->translation() - S.translation()).norm(), 1e-9);
  // Rigid: scale 1, and the rotation of a rigid motion is still recovered exactly.
  const Sim3 rigid(1.0, S.rotation(), S.translation());
  std::vector<Eigen::Vector3d> q1;
  for (const auto& p : p2) q1.push_back(rigid * p);
  const auto r = alignPoints(q1, p2, true);
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->scale(), 1.0);
  EXPECT_LT(rotationErrorDeg(*r, rigid), 1e-7);
}

TEST(Sim3Solver, DegenerateSamplesAreRefused) {
  EXPECT_FALSE(alignPoints({{0, 0, 1}, {1, 1, 1}}, {{0, 0, 1}, {1, 1, 1}}).has_value());
  // Collinear.
  EXPECT_FALSE(alignPoints({{0, 0, 1}, {1, 0, 1}, {2, 0, 1}}, {{0, 0, 2}, {1, 0, 2}, {2, 0, 2}}).has_value());
  EXPECT_FALSE(alignPoints({{0, 0, 1}, {0, 0, 1}, {0, 0, 1}}, {{1, 0, 2}, {1, 0, 2}, {1, 0, 2}}).has_value());
}

TEST(Sim3Solver, InlierTestUsesBothKeyframes) {
  const Sim3 S = knownS12();
  Sim3Match m;
  m.p1 = {0.3, -0.2, 3.0};
  m.p2 = S.inverse() * m.p1;
  m.uv1 = project(m.p1);
  m.uv2 = project(m.p2);
  EXPECT_TRUE(sim3Inlier(m, S, kCam, kCam, 9.21));
  Sim3Match off1 = m;
  off1.uv1.x() += 4;  // 4 px > sqrt(9.21) px
  EXPECT_FALSE(sim3Inlier(off1, S, kCam, kCam, 9.21));
  off1.sigma1 = 2;  // a coarser pyramid level tolerates it
  EXPECT_TRUE(sim3Inlier(off1, S, kCam, kCam, 9.21));
  Sim3Match off2 = m;
  off2.uv2.y() -= 4;
  EXPECT_FALSE(sim3Inlier(off2, S, kCam, kCam, 9.21));
}

class Sim3Outliers : public ::testing::TestWithParam<double> {};

TEST_P(Sim3Outliers, RecoversKnownTransform) {
  const Sim3 S = knownS12();
  std::vector<bool> truth;
  const auto m = makeMatches(S, 120, GetParam(), 17, &truth);
  const Sim3Result r = solveSim3(m, kCam, kCam);
  ASSERT_TRUE(r.ok);
  EXPECT_NEAR(r.S12.scale(), S.scale(), 0.01 * S.scale());
  EXPECT_LT(rotationErrorDeg(r.S12, S), 0.3);
  EXPECT_LT((r.S12.translation() - S.translation()).norm(), 0.02);
  int true_in = 0, found = 0, false_in = 0;
  for (size_t i = 0; i < m.size(); ++i) {
    true_in += truth[i];
    found += truth[i] && r.inlier[i];
    false_in += !truth[i] && r.inlier[i];
  }
  EXPECT_GE(found, int(0.95 * true_in));
  EXPECT_EQ(false_in, 0);
  EXPECT_EQ(r.inliers, found + false_in);
  EXPECT_LE(r.iterations, 300);
}

INSTANTIATE_TEST_SUITE_P(OutlierRatios, Sim3Outliers, ::testing::Values(0.3, 0.4, 0.5));

TEST(Sim3Solver, RefinementImprovesTheMinimalEstimate) {
  const Sim3 S = knownS12();
  std::vector<bool> truth;
  const auto m = makeMatches(S, 80, 0.0, 5, &truth);
  Sim3SolverOptions o;
  o.refine = false;
  const Sim3Result raw = solveSim3(m, kCam, kCam, o);
  const Sim3Result refined = solveSim3(m, kCam, kCam);
  ASSERT_TRUE(raw.ok && refined.ok);
  auto err = [&](const Sim3& x) { return (x.inverse() * S).log().norm(); };
  EXPECT_LE(err(refined.S12), err(raw.S12));
  EXPECT_GE(refined.inliers, raw.inliers);
}

TEST(Sim3Solver, TooFewInliersIsNoSolution) {
  const Sim3 S = knownS12();
  std::vector<bool> truth;
  const auto m = makeMatches(S, 60, 0.8, 3, &truth);  // 12 good pairs < min_inliers 20
  const Sim3Result r = solveSim3(m, kCam, kCam);
  EXPECT_FALSE(r.ok);
  const Sim3Result none = solveSim3({}, kCam, kCam);
  EXPECT_FALSE(none.ok);
}

}  // namespace
}  // namespace nerfslam
