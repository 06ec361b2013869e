#include "nerfslam/mapping/pose_graph.h"

#include <gtest/gtest.h>

#include <cmath>

#include "test_support.h"

namespace nerfslam {
namespace {

// n keyframes around a circle of radius 5 m, looking along it.
std::map<uint64_t, Sim3> circle(int n) {
  std::map<uint64_t, Sim3> gt;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    const Eigen::Matrix3d R = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    gt[uint64_t(i)] =
        Sim3(1.0, Eigen::Quaterniond(R), Eigen::Vector3d(5 * std::cos(a), 5 * std::sin(a), 0.3 * std::sin(3 * a)));
  }
  return gt;
}

double meanPositionError(const std::map<uint64_t, Sim3>& a, const std::map<uint64_t, Sim3>& b) {
  double e = 0;
  for (const auto& [id, S] : a) e += (S.translation() - b.at(id).translation()).norm();
  return e / double(a.size());
}

// Odometry with a per-step drift in rotation, translation and scale (as monocular tracking), chained
// from the true first pose; the loop edge from the truth, as a loop closure's Sim(3) gives it.
struct DriftedLoop {
  std::map<uint64_t, Sim3> gt, drifted;
  std::vector<PoseGraphEdge> edges;
};
DriftedLoop makeDriftedLoop(int n) {
  DriftedLoop d;
  d.gt = circle(n);
  const Sim3 drift(1.012, Eigen::Quaterniond(Eigen::AngleAxisd(0.006, Eigen::Vector3d(0.3, 0.2, 1).normalized())),
                   Eigen::Vector3d(0.01, -0.005, 0.004));
  d.drifted[0] = d.gt[0];
  for (int i = 1; i < n; ++i) {
    const Sim3 rel = d.gt[uint64_t(i - 1)].inverse() * d.gt[uint64_t(i)] * drift;
    d.drifted[uint64_t(i)] = d.drifted[uint64_t(i - 1)] * rel;
  }
  for (int i = 1; i < n; ++i)
    d.edges.push_back(measuredEdge(uint64_t(i - 1), uint64_t(i), d.drifted[uint64_t(i - 1)], d.drifted[uint64_t(i)],
                                   1.0, PoseGraphEdgeKind::kSpanningTree));
  for (int i = 2; i < n; i += 3)  // covisibility edges two apart
    d.edges.push_back(measuredEdge(uint64_t(i - 2), uint64_t(i), d.drifted[uint64_t(i - 2)], d.drifted[uint64_t(i)],
                                   0.5, PoseGraphEdgeKind::kCovisibility));
  d.edges.push_back(measuredEdge(uint64_t(n - 1), 0, d.gt[uint64_t(n - 1)], d.gt[0], 10.0, PoseGraphEdgeKind::kLoop));
  return d;
}

TEST(PoseGraph, LoopEdgeRemovesInjectedDrift) {
  const DriftedLoop d = makeDriftedLoop(40);
  const double before = meanPositionError(d.drifted, d.gt);
  const double scale_before = d.drifted.at(39).scale();
  ASSERT_GT(before, 0.5);  // the injected drift is visible
  ASSERT_GT(scale_before, 1.5);
  const PoseGraphResult r = optimizeEssentialGraph(d.drifted, d.edges, 0);
  ASSERT_TRUE(r.usable);
  EXPECT_LT(r.final_cost, r.initial_cost);
  const double after = meanPositionError(r.S_world_kf, d.gt);
  EXPECT_LT(after, 0.15 * before) << "before " << before << " m, after " << after << " m";
  // The last keyframe is back next to the first, at the first's scale.
  EXPECT_NEAR(r.S_world_kf.at(39).scale(), 1.0, 0.05);
  EXPECT_LT((r.S_world_kf.at(39).translation() - d.gt.at(39).translation()).norm(), 0.1);
  // The fixed vertex has not moved.
  EXPECT_TRUE(correctedPose(r.S_world_kf.at(0)).isApprox(correctedPose(d.gt.at(0)), 1e-12));
  EXPECT_EQ(r.S_world_kf.at(0).scale(), 1.0);
}

TEST(PoseGraph, FixedScaleOptimisesRigidly) {
  const DriftedLoop d = makeDriftedLoop(30);
  PoseGraphOptions o;
  o.fix_scale = true;
  const PoseGraphResult r = optimizeEssentialGraph(d.drifted, d.edges, 0, o);
  ASSERT_TRUE(r.usable);
  for (const auto& [id, S] : r.S_world_kf) EXPECT_EQ(S.scale(), d.drifted.at(id).scale());
  EXPECT_LT(r.final_cost, r.initial_cost);
}

TEST(PoseGraph, ConsistentGraphStaysPut) {
  const auto gt = circle(12);
  std::vector<PoseGraphEdge> edges;
  for (uint64_t i = 1; i < 12; ++i)
    edges.push_back(measuredEdge(i - 1, i, gt.at(i - 1), gt.at(i), 1.0, PoseGraphEdgeKind::kSpanningTree));
  edges.push_back(measuredEdge(11, 0, gt.at(11), gt.at(0), 1.0, PoseGraphEdgeKind::kLoop));
  const PoseGraphResult r = optimizeEssentialGraph(gt, edges, 5);
  ASSERT_TRUE(r.usable);
  EXPECT_LT(meanPositionError(r.S_world_kf, gt), 1e-9);
  EXPECT_LT(r.final_cost, 1e-18);
}

TEST(PoseGraph, CorrectionMovesPointsWithTheirKeyframe) {
  const Sim3 before(1.0, SE3(Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ())), {1, 2, 3}));
  const Sim3 after(0.5, Eigen::Quaterniond(Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitY())), {0, 1, 0});
  const Eigen::Vector3d p_cam(0.2, -0.1, 4.0);
  const Eigen::Vector3d p = correctPoint(before * p_cam, before, after);
  EXPECT_LT((p - after * p_cam).norm(), 1e-12);  // same place in the keyframe's (scaled) frame
  const SE3 T = correctedPose(after);
  EXPECT_LT((T.translation() - after.translation()).norm(), 1e-15);
  EXPECT_LT(T.rotation().angularDistance(after.rotation()), 1e-12);
}

TEST(PoseGraph, RefusesBadGraphs) {
  const auto gt = circle(4);
  const auto edge = [&](uint64_t i, uint64_t j, double w) {
    return measuredEdge(i, j, gt.at(i), gt.at(j), w, PoseGraphEdgeKind::kCovisibility);
  };
  EXPECT_NE(test::errorOf([&] { optimizeEssentialGraph(gt, {edge(0, 1, 1)}, 9); }).find("fixed vertex 9"),
            std::string::npos);
  PoseGraphEdge e = edge(0, 1, 1);
  e.j = 7;
  EXPECT_NE(test::errorOf([&] { optimizeEssentialGraph(gt, {e}, 0); }).find("7 is not a vertex"), std::string::npos);
  EXPECT_NE(test::errorOf([&] { optimizeEssentialGraph(gt, {edge(2, 2, 1)}, 0); }).find("to itself"),
            std::string::npos);
  EXPECT_NE(test::errorOf([&] { optimizeEssentialGraph(gt, {edge(0, 1, 0)}, 0); }).find("weight"), std::string::npos);
}

}  // namespace
}  // namespace nerfslam
