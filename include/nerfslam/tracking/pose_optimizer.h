#pragma once
// Robust motion-only pose refinement: Gauss-Newton on SE3 (left perturbation of T_cam_world) with
// a Huber loss on reprojection errors in ideal pinhole pixels, in rounds that re-classify outliers
// by a chi-square test (ORB-SLAM's 4 x 10 scheme). Own Eigen code: it is on the per-frame hot path.
#include <vector>

#include <Eigen/Core>

#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"

namespace nerfslam {

struct PoseObservation {
  Eigen::Vector3d p_world;
  Eigen::Vector2d uv;  // ideal (undistorted) pixels
  double sigma = 1.0;  // pixel standard deviation (scale of the keypoint's pyramid level)
};

struct PoseOptimizerOptions {
  int rounds = 4;
  int iterations_per_round = 10;
  double chi2_threshold = 5.991;  // 95% of chi2 with 2 dof, on whitened errors
  double huber_delta = 2.4477;    // sqrt(5.991)
  template <class V>
  void visit(V& v) {
    v("rounds", rounds, "Outlier re-classification rounds", check::range(1, 20));
    v("iterations_per_round", iterations_per_round, "Gauss-Newton iterations per round", check::range(1, 100));
    v("chi2_threshold", chi2_threshold, "Chi-square outlier threshold (2 dof)", check::positive<double>());
    v("huber_delta", huber_delta, "Huber loss width (whitened pixels)", check::positive<double>());
  }
};

struct PoseOptimizationResult {
  SE3 T_world_cam;
  std::vector<char> inlier;
  int num_inliers = 0;
  double rms_px = 0;  // RMS reprojection error of the inliers
  bool converged = false;
};

// fx fy cx cy: ideal pinhole intrinsics.
PoseOptimizationResult optimizePose(const Eigen::Matrix3d& K, const std::vector<PoseObservation>& observations,
                                    const SE3& T_world_cam_init, const PoseOptimizerOptions& options = {});

}  // namespace nerfslam
