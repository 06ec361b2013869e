#pragma once
// Essential-graph optimisation over Sim(3), the correction step of loop closure (as ORB-SLAM's
// OptimizeEssentialGraph): vertices are keyframe poses as similarities, edges relative
// similarities measured before the loop was found (spanning tree, strong covisibility) or by the
// loop's Sim(3) solver (loop edges). Ceres spreads the loop's correction, scale included, over the
// graph; one vertex stays fixed (the gauge).
//
// Conventions (core/pose.h): a vertex S_world_kf maps points of the keyframe's camera frame into
// the world, x -> s R x + t. A keyframe posed by tracking is S_world_kf = Sim3(1, T_world_cam).
// After the optimisation its camera pose is correctedPose(S) = (R, t), and a map point p_world
// anchored to it moves to correctPoint(p_world, S_before, S_after) = S_after * S_before^-1 * p_world
// (its scale corrected with the keyframe's).
// An edge (i, j) measures S_ij = S_world_i^-1 * S_world_j (maps points of j's frame into i's).
// Residual: (t_e, angle-axis of R_e, ln s_e) of S_ij^-1 * S_world_i^-1 * S_world_j, times
// sqrt(weight): zero when the two vertices agree with the measurement.
#include <cstdint>
#include <map>
#include <vector>

#include "nerfslam/core/pose.h"

namespace nerfslam {

enum class PoseGraphEdgeKind { kSpanningTree, kCovisibility, kLoop };

struct PoseGraphEdge {
  uint64_t i = 0, j = 0;
  Sim3 S_ij;            // measured S_world_i^-1 * S_world_j
  double weight = 1.0;  // information scale of the whole 7-vector residual
  PoseGraphEdgeKind kind = PoseGraphEdgeKind::kSpanningTree;
};

struct PoseGraphOptions {
  int max_iterations = 20;  // Levenberg-Marquardt iterations (ORB-SLAM: 20)
  bool fix_scale = false;   // stereo / RGB-D maps: SE(3) only
  int threads = 1;
};

struct PoseGraphResult {
  std::map<uint64_t, Sim3> S_world_kf;  // corrected vertices (the fixed one unchanged)
  double initial_cost = 0, final_cost = 0;
  int iterations = 0;
  bool usable = false;  // Ceres reported a usable solution
};

// The edge measuring the current relative pose of two vertices (spanning tree / covisibility edges
// are made this way from the poses before the correction).
PoseGraphEdge measuredEdge(uint64_t i, uint64_t j, const Sim3& S_world_i, const Sim3& S_world_j, double weight,
                           PoseGraphEdgeKind kind);

// Optimises every vertex but `fixed` (which must be one). Throws nerfslam::Error when an edge
// names a vertex that is not given, an edge joins a vertex to itself, or a weight is not positive.
PoseGraphResult optimizeEssentialGraph(const std::map<uint64_t, Sim3>& S_world_kf,
                                       const std::vector<PoseGraphEdge>& edges, uint64_t fixed,
                                       const PoseGraphOptions& options = {});

SE3 correctedPose(const Sim3& S_world_kf);
Eigen::Vector3d correctPoint(const Eigen::Vector3d& p_world, const Sim3& S_world_kf_before,
                             const Sim3& S_world_kf_after);

}  // namespace nerfslam
