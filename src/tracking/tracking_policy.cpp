#include "nerfslam/tracking/tracking_policy.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>

#include <fmt/format.h>
#include <Eigen/Geometry>

namespace nerfslam {

namespace {
// Fewer than inlier_drop x the previous frame's inliers.
bool inliersCollapsed(int num_inliers, int last_inliers, const WeakTrackingPolicy& p) {
  return double(num_inliers) < p.inlier_drop * double(last_inliers);
}
}  // namespace

bool relocalizeWeakTracking(const TrackingResult& tracked, int last_inliers, const WeakTrackingPolicy& policy) {
  return policy.relocalize_when_weak && tracked.quality != TrackingQuality::kLost &&
         (tracked.num_inliers < policy.min_inliers_good || inliersCollapsed(tracked.num_inliers, last_inliers, policy));
}

bool relocalizeAnywhere(bool loaded_map, bool localization_only, TrackingQuality quality) {
  return loaded_map || localization_only || quality == TrackingQuality::kLost;
}

RelocalizationChoice chooseRelocalizationKeyframes(const std::vector<KeyframeId>& keyframe_ids,
                                                   const std::vector<KeyframeId>& voted, int recent) {
  RelocalizationChoice c;
  c.keyframes.reserve(voted.size() + keyframe_ids.size());
  auto add = [&c](KeyframeId id) {
    if (std::find(c.keyframes.begin(), c.keyframes.end(), id) == c.keyframes.end()) c.keyframes.push_back(id);
  };
  for (KeyframeId id : voted) add(id);
  const size_t num_voted = c.keyframes.size();
  std::vector<KeyframeId> newest_first = keyframe_ids;
  std::sort(newest_first.begin(), newest_first.end(), std::greater<>());
  for (KeyframeId id : newest_first) add(id);
  c.max_candidates = num_voted + static_cast<size_t>(std::max(0, recent));
  return c;
}

bool relocalizedPoseWins(bool weak_retry, const TrackingResult& tracked, const TrackingResult& retracked) {
  return !(weak_retry && (retracked.quality == TrackingQuality::kLost || retracked.num_inliers <= tracked.num_inliers));
}

std::optional<std::string> refuseWeakPose(const TrackingResult& result, bool relocalized, bool after_loss,
                                          int last_inliers, const WeakTrackingPolicy& policy) {
  if (result.quality != TrackingQuality::kWeak || relocalized) return std::nullopt;
  const bool collapsed = policy.relocalize_when_weak && inliersCollapsed(result.num_inliers, last_inliers, policy);
  if (!after_loss && !collapsed) return std::nullopt;
  return fmt::format("lost: {} inliers {} ({}); relocalisation found no better pose", result.num_inliers,
                     after_loss ? "are too weak to recover from a loss" : "collapsed from",
                     after_loss ? fmt::format("< {}", policy.min_inliers_good) : std::to_string(last_inliers));
}

KeyframeId chooseReferenceKeyframe(const std::vector<MapMatch>& matches, const TrackingLocalMap& local) {
  std::map<KeyframeId, int> counts;
  for (const auto& m : matches) {
    const auto i = local.findPoint(m.point_id);
    if (!i) continue;
    for (int k = local.observer_begin[*i]; k < local.observer_begin[*i + 1]; ++k)
      ++counts[local.observers[static_cast<size_t>(k)]];
  }
  KeyframeId best = -1;
  int best_count = 0;
  for (const auto& [k, c] : counts)
    if (c > best_count || (c == best_count && k > best)) {
      best = k;
      best_count = c;
    }
  return best;
}

std::vector<uint64_t> visiblePoints(const TrackingLocalMap& local, const Camera& camera, const SE3& T_world_cam) {
  std::vector<uint64_t> out;
  const SE3 T_cw = T_world_cam.inverse();
  for (const auto& p : local.points) {
    Eigen::Vector2d uv;
    if (camera.projectInImage(T_cw * p.p_world, &uv)) out.push_back(p.id);
  }
  return out;
}

KeyframeDecisionInput keyframeDecisionInput(const TrackingResult& tracked, const TrackingLocalMap& local,
                                            KeyframeId reference, const std::optional<SE3>& last_keyframe_pose,
                                            int frames_since_keyframe, bool mapping_idle,
                                            const KeyframePolicyOptions& options) {
  KeyframeDecisionInput in;
  in.quality = tracked.quality;
  in.num_inliers = tracked.num_inliers;
  in.frames_since_last_keyframe = frames_since_keyframe;
  in.median_scene_depth = tracked.median_depth > 0 ? tracked.median_depth : 1.0;
  in.mapping_idle = mapping_idle;
  const Eigen::Vector3d centre = tracked.T_world_cam.translation();
  const Eigen::Vector3d axis = tracked.T_world_cam.rotation() * Eigen::Vector3d::UnitZ();
  const double min_cos = std::cos(options.covered_view_angle_deg * M_PI / 180.0);
  const double same_cos = std::cos(options.stopped_view_angle_deg * M_PI / 180.0);
  // A revisit is a return to the view of an older keyframe: the newest two, which exploration
  // extends from, do not count (as keyframe culling keeps them).
  const KeyframeId newest =
      local.keyframes.empty() ? 0 : *std::max_element(local.keyframes.begin(), local.keyframes.end());
  double nearest = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < local.keyframe_poses.size(); ++i) {
    const SE3& T = local.keyframe_poses[i];
    const double dist = (T.translation() - centre).norm();
    nearest = std::min(nearest, dist);
    const double cos_axes = (T.rotation() * Eigen::Vector3d::UnitZ()).dot(axis);
    if (cos_axes >= same_cos) in.distance_to_same_view = std::min(in.distance_to_same_view, dist);
    if (local.keyframes[i] < newest - 1 && cos_axes >= min_cos)
      in.distance_to_similar_view = std::min(in.distance_to_similar_view, dist);
  }
  if (last_keyframe_pose && (last_keyframe_pose->rotation() * Eigen::Vector3d::UnitZ()).dot(axis) >= same_cos)
    in.distance_to_same_view = std::min(in.distance_to_same_view, (last_keyframe_pose->translation() - centre).norm());
  in.distance_to_nearest_keyframe = std::isfinite(nearest) ? nearest : 0.0;
  const auto slot = local.findKeyframe(reference);
  if (!slot) return in;
  in.reference_keyframe_points = local.keyframe_num_points[*slot];
  in.reference_keyframe_established_points = local.keyframe_num_established[*slot];
  // Only the covered-view gate (off by default) asks which inliers the reference keyframe observes.
  if (options.covered_view_angle_deg > 0)
    for (const auto& m : tracked.matches) {
      const auto i = local.findPoint(m.point_id);
      if (!i) continue;
      const auto b = local.observers.begin() + local.observer_begin[*i],
                 e = local.observers.begin() + local.observer_begin[*i + 1];
      in.tracked_reference_points += std::find(b, e, reference) != e;
    }
  return in;
}

}  // namespace nerfslam
