#pragma once
// Similarity between two keyframes from matched map points, for loop closure (as ORB-SLAM's
// Sim3Solver): RANSAC over minimal sets of 3 point pairs solved in closed form (Horn 1987 /
// Umeyama 1991), with an inlier test by reprojection in BOTH keyframes (a pair is an inlier when
// S12 * p2 reprojects onto its observation in keyframe 1 and S12^-1 * p1 onto its observation in
// keyframe 2, each within chi2 x sigma^2), then a refinement of the similarity by Ceres on the
// inliers' reprojection errors in both images (Huber), twice, dropping outliers in between.
//
// Convention: S12 maps points of keyframe 2's camera frame into keyframe 1's (p1 = S12 * p2).
// Monocular maps drift in scale, so the scale is estimated unless fix_scale is set.
#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"

namespace nerfslam {

struct Sim3Match {
  Eigen::Vector3d p1, p2;         // the map point in keyframe 1's / keyframe 2's camera frame
  Eigen::Vector2d uv1, uv2;       // its observation in each keyframe (ideal pinhole pixels)
  double sigma1 = 1, sigma2 = 1;  // pixel standard deviation of each observation (pyramid level)
};

struct Sim3SolverOptions {
  double probability = 0.99;  // of drawing at least one all-inlier sample (adaptive iterations)
  int max_iterations = 300;   // RANSAC samples at most
  int min_inliers = 20;       // fewer: no solution
  double chi2 = 9.21;         // per image, 2 degrees of freedom, 99 %
  bool fix_scale = false;     // stereo / RGB-D maps: rigid transform only
  bool refine = true;         // Ceres refinement of the RANSAC estimate
  uint64_t seed = 1;          // of the sampling
};

struct Sim3Result {
  bool ok = false;
  Sim3 S12;
  std::vector<bool> inlier;  // per match
  int inliers = 0;
  int iterations = 0;      // RANSAC samples drawn
  int ransac_inliers = 0;  // before refinement
};

// Closed-form similarity p1 ~ S * p2 minimising sum |p1 - S p2|^2 over >= 3 pairs (rotation by
// SVD with the reflection fixed, scale by Umeyama's formula). nullopt for degenerate input: fewer
// than 3 pairs, or points (nearly) collinear.
std::optional<Sim3> alignPoints(const std::vector<Eigen::Vector3d>& p1, const std::vector<Eigen::Vector3d>& p2,
                                bool fix_scale = false);

// True when the pair passes the reprojection test in both keyframes under S12.
bool sim3Inlier(const Sim3Match& m, const Sim3& S12, const Camera& camera1, const Camera& camera2, double chi2);

// RANSAC + refinement. camera1/camera2: the keyframes' pinhole intrinsics (distortion ignored: the
// observations are ideal pixels).
Sim3Result solveSim3(const std::vector<Sim3Match>& matches, const Camera& camera1, const Camera& camera2,
                     const Sim3SolverOptions& options = {});

// Minimises the inliers' reprojection errors in both keyframes over S12 (Ceres, Huber of width
// sqrt(chi2)). Returns the refined similarity.
Sim3 refineSim3(const std::vector<Sim3Match>& matches, const std::vector<bool>& inlier, const Sim3& S12,
                const Camera& camera1, const Camera& camera2, double chi2, bool fix_scale);

}  // namespace nerfslam
