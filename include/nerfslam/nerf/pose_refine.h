#pragma once
// Pose refinement by the field (BARF, Lin et al. 2021, on a hash grid): each training view carries a
// small correction of the pose it was given (its anchor, e.g. the bundle-adjusted keyframe pose),
// learnt from the photometric loss through the sample positions of its rays.
//
// The correction is a rotation vector w about the camera centre and a translation t of the centre,
// both in world coordinates: the refined pose is R' = exp(w) R, c' = c + t. A sample of a ray of the
// view at NeRF-space position p (camera centre o, the sample's distance along the ray held) moves, to
// first order, by scale * t + w x (p - o), so dL/dt = scale * sum g and dL/dw = sum (p - o) x g, with
// g the loss gradient at the sample in NeRF space (NeRF space = scale * world + offset: rotations are
// the same in both).
//
// Coarse to fine: the position gradient reads the hash-grid levels through BARF's window, level l
// weighted by (1 - cos(pi * clamp(a - l, 0, 1))) / 2 with a growing from 1 to the number of levels
// over the first refinement steps; the fine levels, whose gradients alias, join last.
#include <array>
#include <vector>

#include <Eigen/Core>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/nerf/adam.h"

namespace nerfslam::nerf {

struct PoseCorrection {
  Eigen::Vector3d rotation = Eigen::Vector3d::Zero();     // world rotation vector about the camera centre
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();  // of the camera centre, world units
  SE3 apply(const SE3& T_world_cam) const;
  bool finite() const { return rotation.allFinite() && translation.allFinite(); }
  bool isZero() const { return rotation.isZero(0) && translation.isZero(0); }
};

// BARF's window over n_levels hash-grid levels at progress in [0, 1] (0: level 0 only; 1: all).
void barfLevelWeights(int n_levels, double progress, float* weights);

// Adds to grad[0..3) (rotation) and grad[3..6) (translation, world units) one ray's samples:
// origin: the camera centre in NeRF space; pos: count NeRF-space sample positions (x, y, z);
// dL_dpos: the loss gradient at each sample in NeRF space; scene_scale: NeRF units per world unit.
void accumulatePoseGradient(const Eigen::Vector3f& origin, const float* pos, const float* dL_dpos, int count,
                            double scene_scale, double grad[6]);

// Adam over each view's six correction parameters (adam.h's adamEntry with the field's Adam
// constants), with an L2 pull towards no correction.
class PoseOptimizer {
 public:
  explicit PoseOptimizer(const AdamOptions& adam) : adam_(adam), bias_(adam) {}
  // One update of `c` from grad[0..6) (mean per ray) plus reg * 2 * params; the rotation's learning
  // rate is lr, the translation's lr * translation_scale (world units per radian).
  void step(size_t view, PoseCorrection& c, const double grad[6], double lr, double translation_scale, double reg);
  void reset(size_t view);

 private:
  struct State {
    std::array<float, 6> m{}, v{};
    uint32_t t = 0;
  };
  AdamOptions adam_;
  AdamBiasTable bias_;
  std::vector<State> state_;
};

// How far a refined pose moves a view's points in its image: the median over the points that project
// into the image at both poses of the distance between their projections, in pixels (-1 without
// such points).
double medianReprojectionShiftPx(const Camera& camera, const SE3& anchor, const SE3& refined,
                                 const std::vector<Eigen::Vector3f>& points);

}  // namespace nerfslam::nerf
