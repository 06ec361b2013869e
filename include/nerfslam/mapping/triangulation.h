#pragma once
// Multi-view geometry on keyframe poses for the mapping thread: the fundamental matrix between two
// posed cameras, world-frame DLT triangulation, and the checks a new map point must pass (parallax,
// positive depth in both cameras, reprojection error within the keypoint's pyramid sigma).
#include <optional>

#include <Eigen/Core>

#include "nerfslam/core/pose.h"

namespace nerfslam {

// F with x2^T F x1 = 0 for ideal pixels x1 in camera 1 and x2 in camera 2 (same intrinsics K).
Eigen::Matrix3d fundamentalFromPoses(const SE3& T_world_cam1, const SE3& T_world_cam2, const Eigen::Matrix3d& K);
// Distance (pixels) of x2 from the epipolar line F x1.
double epipolarDistance(const Eigen::Matrix3d& F, const Eigen::Vector2d& x1, const Eigen::Vector2d& x2);

// Linear triangulation (homogeneous DLT, SVD) of normalised image points n = K^-1 [u v 1] (x, y).
// Returns the world point, or std::nullopt when the solution is at infinity.
std::optional<Eigen::Vector3d> triangulateDlt(const SE3& T_world_cam1, const SE3& T_world_cam2,
                                              const Eigen::Vector2d& n1, const Eigen::Vector2d& n2);

struct TriangulationChecks {
  double min_parallax_deg = 1.0;  // angle between the two viewing rays at the point
  double max_error_sigma = 2.45;  // reprojection error in each view <= this * sigma (px)
};

struct TriangulatedPoint {
  Eigen::Vector3d position;
  double parallax_deg = 0;
  double error1_px = 0, error2_px = 0;
};

// Triangulates ideal pixels uv1, uv2 (intrinsics K, pixel sigmas s1, s2) and applies the checks.
std::optional<TriangulatedPoint> triangulateChecked(const SE3& T_world_cam1, const SE3& T_world_cam2,
                                                    const Eigen::Matrix3d& K, const Eigen::Vector2d& uv1,
                                                    const Eigen::Vector2d& uv2, double s1, double s2,
                                                    const TriangulationChecks& checks);

}  // namespace nerfslam
