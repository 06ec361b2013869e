#pragma once
// Bundle adjustment with Ceres. Cameras are SE(3) poses parametrised on the Ceres manifold
// ProductManifold<QuaternionManifold, EuclideanManifold<3>> over (q_cam_world, t_cam_world); points
// are 3-vectors in the world frame; observations are ideal (undistorted) pinhole pixels. A robust
// Huber loss is used, observations whose error exceeds the outlier threshold after the first solve
// are removed and the problem is solved again.
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"

namespace ceres {
class CostFunction;
class Manifold;
}  // namespace ceres

namespace nerfslam {

// The pose parametrisation used by bundleAdjust: x = (qw qx qy qz tx ty tz) of T_cam_world = T_world_cam^-1,
// on the manifold ProductManifold<QuaternionManifold, EuclideanManifold<3>> (tangent size 6).
void poseToParams(const SE3& T_world_cam, double* x);
SE3 poseFromParams(const double* x);
std::unique_ptr<ceres::Manifold> makePoseManifold();
// The reprojection residual bundleAdjust uses, with analytic Jacobians: parameter blocks (pose x as
// above, 7; world point, 3), residual (projection - uv) / sigma (2).
std::unique_ptr<ceres::CostFunction> makeReprojectionCost(const Eigen::Vector2d& uv, double sigma, double fx, double fy,
                                                          double cx, double cy);

struct BundleAdjustmentOptions {
  double huber_px = 2.45;      // Huber loss width in pixels (sqrt of chi2(2 dof, 95%) = 5.99)
  double outlier_px = 2.45;    // observations with error above this (x sigma) are removed
  int max_iterations = 5;      // per solve (ORB-SLAM local BA: 5 + 10)
  int refine_iterations = 10;  // second solve after outlier removal (0: none)
  int num_threads = 1;
  double max_solver_time_s = 1.0;    // per solve
  double function_tolerance = 1e-3;  // a solve stops when an iteration lowers the cost by less (relative)
  // Not an option: when set and true after an iteration, the solve ends there with the parameters of
  // its last successful step (a run stopped a second time ends its global BA early).
  std::function<bool()> should_stop;

  template <class V>
  void visit(V& v) {
    v("huber_px", huber_px, "Huber loss width in pixels", check::positive<double>());
    v("outlier_px", outlier_px, "Reprojection error (pixels, per unit sigma) above which an observation is an outlier",
      check::positive<double>());
    v("max_iterations", max_iterations, "Levenberg-Marquardt iterations of the first solve", check::range(1, 1000));
    v("refine_iterations", refine_iterations, "Iterations of the solve after outlier removal (0: none)",
      check::range(0, 1000));
    v("num_threads", num_threads, "Ceres threads", check::range(1, 64));
    v("max_solver_time_s", max_solver_time_s, "Wall-clock limit of one solve", check::positive<double>());
    v("function_tolerance", function_tolerance, "Relative cost decrease below which a solve stops",
      check::positive<double>());
  }
};

struct BaProblem {
  struct Camera {
    SE3 T_world_cam;
    bool fixed = false;
  };
  struct Point {
    Eigen::Vector3d position = Eigen::Vector3d::Zero();
    bool fixed = false;
  };
  struct Observation {
    int camera = 0;
    int point = 0;
    Eigen::Vector2d uv = Eigen::Vector2d::Zero();  // ideal pinhole pixel
    double sigma = 1.0;                            // pixel standard deviation (pyramid scale)
  };
  // A measured translation of camera j in camera i's frame (e.g. wheel odometry, mapping/odometry.h):
  // residual (R_cam_i_world (c_j - c_i) - t_ij) / sigma (3), under a Huber loss of width `huber`.
  struct RelativeTranslation {
    int camera_i = 0, camera_j = 0;
    Eigen::Vector3d t_ij = Eigen::Vector3d::Zero();
    double sigma = 1.0;
    double huber = 2.0;
  };
  double fx = 1, fy = 1, cx = 0, cy = 0;  // pinhole intrinsics of the ideal camera
  std::vector<Camera> cameras;
  std::vector<Point> points;
  std::vector<Observation> observations;
  std::vector<RelativeTranslation> relative_translations;
};

struct BaResult {
  bool converged = false;
  double initial_rmse_px = 0;  // over all observations with positive depth
  double final_rmse_px = 0;    // over the inlier observations
  int iterations = 0;
  int outliers = 0;
  std::vector<bool> inlier;  // per observation
  double time_ms = 0;
};

// The relative-translation residual bundleAdjust uses: parameter blocks (pose i, pose j as above),
// residual (3) as BaProblem::RelativeTranslation says.
std::unique_ptr<ceres::CostFunction> makeRelativeTranslationCost(const Eigen::Vector3d& t_ij, double sigma);

// Optimises `problem` in place (non-fixed cameras and points). Throws nerfslam::Error on indices out
// of range. A problem without free parameters or observations returns immediately.
BaResult bundleAdjust(BaProblem& problem, const BundleAdjustmentOptions& options);

// Reprojection error (pixels) of one observation with the problem's current state; +inf when the
// point is behind the camera.
double reprojectionError(const BaProblem& problem, const BaProblem::Observation& obs);

}  // namespace nerfslam
