#include "nerfslam/nerf/pose_refine.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>

namespace nerfslam::nerf {

SE3 PoseCorrection::apply(const SE3& T_world_cam) const {
  const double angle = rotation.norm();
  const Eigen::Matrix3d dR =
      angle > 0 ? Eigen::AngleAxisd(angle, rotation / angle).toRotationMatrix() : Eigen::Matrix3d::Identity();
  return SE3(Eigen::Quaterniond(dR) * T_world_cam.rotation(), T_world_cam.translation() + translation);
}

void barfLevelWeights(int n_levels, double progress, float* weights) {
  const double a = 1.0 + std::clamp(progress, 0.0, 1.0) * double(n_levels - 1);
  for (int l = 0; l < n_levels; ++l) {
    const double x = std::clamp(a - double(l), 0.0, 1.0);
    weights[l] = float(0.5 * (1.0 - std::cos(M_PI * x)));
  }
}

void accumulatePoseGradient(const Eigen::Vector3f& origin, const float* pos, const float* dL_dpos, int count,
                            double scene_scale, double grad[6]) {
  Eigen::Vector3d gw = Eigen::Vector3d::Zero(), gt = Eigen::Vector3d::Zero();
  for (int k = 0; k < count; ++k) {
    const Eigen::Vector3d g(dL_dpos[3 * k], dL_dpos[3 * k + 1], dL_dpos[3 * k + 2]);
    if (g.isZero(0)) continue;
    const Eigen::Vector3d v(pos[3 * k] - origin.x(), pos[3 * k + 1] - origin.y(), pos[3 * k + 2] - origin.z());
    gw += v.cross(g);
    gt += g;
  }
  for (int d = 0; d < 3; ++d) {
    grad[d] += gw[d];
    grad[3 + d] += scene_scale * gt[d];
  }
}

void PoseOptimizer::step(size_t view, PoseCorrection& c, const double grad[6], double lr, double translation_scale,
                         double reg) {
  if (view >= state_.size()) state_.resize(view + 1);
  State& s = state_[view];
  // The translation is learnt in radian-like units (t / translation_scale), so one learning rate
  // moves both by a similar share of the image.
  float p[6], g[6];
  for (int k = 0; k < 6; ++k) {
    const double unit = k < 3 ? 1.0 : translation_scale;
    p[k] = float((k < 3 ? c.rotation[k] : c.translation[k - 3]) / unit);
    g[k] = float(grad[k] * unit + 2.0 * reg * p[k]);
  }
  adamEntry<6>(p, s.m.data(), s.v.data(), g, &s.t, float(lr), adam_, bias_);
  for (int k = 0; k < 6; ++k)
    (k < 3 ? c.rotation[k] : c.translation[k - 3]) = double(p[k]) * (k < 3 ? 1.0 : translation_scale);
}

void PoseOptimizer::reset(size_t view) {
  if (view < state_.size()) state_[view] = State{};
}

double medianReprojectionShiftPx(const Camera& camera, const SE3& anchor, const SE3& refined,
                                 const std::vector<Eigen::Vector3f>& points) {
  const SE3 a_inv = anchor.inverse(), r_inv = refined.inverse();
  std::vector<double> shift;
  for (const auto& p : points) {
    Eigen::Vector2d ua, ur;
    if (!camera.projectInImage(a_inv * p.cast<double>(), &ua) || !camera.projectInImage(r_inv * p.cast<double>(), &ur))
      continue;
    shift.push_back((ua - ur).norm());
  }
  if (shift.empty()) return -1.0;
  std::nth_element(shift.begin(), shift.begin() + long(shift.size() / 2), shift.end());
  return shift[shift.size() / 2];
}

}  // namespace nerfslam::nerf
