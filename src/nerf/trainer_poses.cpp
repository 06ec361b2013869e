// The trainer's pose refinement (TrainOptions::pose_refinement, pose_refine.h): which steps refine,
// the poses a step's rays are drawn from, and the update of the views' corrections.
#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/field.h"
#include "nerfslam/nerf/trainer.h"

namespace nerfslam::nerf {

SE3 Trainer::refinedViewPose(size_t i) const {
  if (i >= views_.size()) fail("NeRF training: no view {} (have {})", i, views_.size());
  return pose_corr_[i].isZero() ? views_[i].T_world_cam : pose_corr_[i].apply(views_[i].T_world_cam);
}

void Trainer::setViewPoseCorrection(size_t i, const PoseCorrection& c) {
  if (i >= views_.size()) fail("NeRF training: no view {} (have {})", i, views_.size());
  if (!c.finite()) throw fieldError(fmt::format("training view {}", i), "pose correction", "is not finite");
  pose_corr_[i] = c;
  pose_opt_.reset(i);
}

bool Trainer::refinesPosesThisStep() const {
  return opt_.pose_refinement && views_.size() >= 2 && step_ >= opt_.pose_refine_start &&
         (step_ - opt_.pose_refine_start) % opt_.pose_refine_interval == 0;
}

void Trainer::preparePoses(bool refine) {
  step_poses_.resize(views_.size());
  for (size_t i = 0; i < views_.size(); ++i) step_poses_[i] = refinedViewPose(i);
  if (!refine) return;
  const int levels = model_.field->config().n_levels;
  level_weights_.resize(size_t(levels));
  barfLevelWeights(levels, double(pose_steps_) / double(opt_.pose_c2f_steps), level_weights_.data());
}

// One Adam step of each view's correction from the mean gradient of its rays (grad: 6 per view, the
// threads' sums; rays: per view), a reset of corrections beyond the bounds, then the mean correction taken out.
void Trainer::stepPoses(const std::vector<double>& grad, const std::vector<int>& rays) {
  ++pose_steps_;
  const Eigen::Vector3d centre = model_.scene.toWorld(Eigen::Vector3d::Constant(0.5));
  // Translation per radian of rotation: the scene box's half-side in world units.
  const double scene_unit = 0.5 / model_.scene.scale;
  const double max_rot = opt_.pose_max_rotation_deg * M_PI / 180.0;
  std::vector<size_t> moved;
  for (size_t v = 0; v < views_.size(); ++v) {
    if (rays[v] == 0) continue;
    double g[6];
    for (size_t k = 0; k < 6; ++k) g[k] = grad[6 * v + k] / double(rays[v]);
    if (!std::all_of(g, g + 6, [](double x) { return std::isfinite(x); })) continue;
    pose_opt_.step(v, pose_corr_[v], g, opt_.pose_lr, scene_unit, opt_.pose_reg);
    const double dist = (views_[v].T_world_cam.translation() - centre).norm();
    const double max_t = opt_.pose_max_translation * std::max(dist, scene_unit);
    if (!pose_corr_[v].finite() || pose_corr_[v].rotation.norm() > max_rot ||
        pose_corr_[v].translation.norm() > max_t) {
      if (pose_resets_ < 3 || pose_resets_ % 100 == 0)  // the first, then every 100th (poseRefinementStats counts)
        spdlog::warn(
            "NeRF pose refinement: view {} diverged at step {} (rotation {:.2f} deg, translation {:.3g}); reset "
            "({} resets so far)",
            v, step_, pose_corr_[v].rotation.norm() * 180.0 / M_PI, pose_corr_[v].translation.norm(), pose_resets_ + 1);
      pose_corr_[v] = PoseCorrection{};
      pose_opt_.reset(v);
      ++pose_resets_;
      continue;
    }
    moved.push_back(v);
  }
  // The gauge: the field and every pose may move together; the given poses fix the frame.
  if (moved.size() < 2) return;
  PoseCorrection mean;
  for (size_t v = 0; v < views_.size(); ++v) {
    mean.rotation += pose_corr_[v].rotation / double(views_.size());
    mean.translation += pose_corr_[v].translation / double(views_.size());
  }
  for (auto& c : pose_corr_) {
    c.rotation -= mean.rotation;
    c.translation -= mean.translation;
  }
}

Trainer::PoseRefinementStats Trainer::poseRefinementStats() const {
  PoseRefinementStats s;
  s.resets = pose_resets_;
  s.steps = pose_steps_;
  std::vector<double> shifts;
  for (size_t v = 0; v < views_.size(); ++v) {
    std::vector<Eigen::Vector3f> pts;
    for (const auto& p : views_[v].points) pts.push_back(p.position);
    const double shift = medianReprojectionShiftPx(views_[v].camera, views_[v].T_world_cam, refinedViewPose(v), pts);
    if (shift >= 0) shifts.push_back(shift);
  }
  s.views = int(shifts.size());
  if (shifts.empty()) return s;
  s.max_shift_px = *std::max_element(shifts.begin(), shifts.end());
  std::nth_element(shifts.begin(), shifts.begin() + long(shifts.size() / 2), shifts.end());
  s.median_shift_px = shifts[shifts.size() / 2];
  return s;
}

}  // namespace nerfslam::nerf
