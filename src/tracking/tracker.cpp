#include "nerfslam/tracking/tracker.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <ctime>

#include <fmt/format.h>

#include "nerfslam/core/timing.h"

namespace nerfslam {
namespace {

// Stage timings are thread CPU time (see FrameTimings).
double msSince(double t0) { return threadCpuMs() - t0; }

// Keeps matches in the three most populated bins of the rotation-difference histogram.
void rotationConsistency(const Frame& frame, const std::vector<TrackingMapPoint>& map, std::vector<MapMatch>* m) {
  constexpr int kBins = 30;
  std::array<std::vector<size_t>, kBins> hist;
  std::vector<char> keep(m->size(), 1);
  for (size_t i = 0; i < m->size(); ++i) {
    const double a = map[static_cast<size_t>((*m)[i].point_index)].angle;
    const double b = frame.keypoints[static_cast<size_t>((*m)[i].feature)].angle;
    if (a < 0 || b < 0) continue;  // unknown orientation: not judged
    double d = b - a;
    while (d < 0) d += 360;
    while (d >= 360) d -= 360;
    hist[static_cast<size_t>(std::min(kBins - 1, static_cast<int>(d * kBins / 360.0)))].push_back(i);
    keep[i] = 0;
  }
  std::array<int, kBins> order;
  for (int i = 0; i < kBins; ++i) order[static_cast<size_t>(i)] = i;
  std::sort(order.begin(), order.end(),
            [&](int a, int b) { return hist[static_cast<size_t>(a)].size() > hist[static_cast<size_t>(b)].size(); });
  const size_t top = hist[static_cast<size_t>(order[0])].size();
  for (int k = 0; k < 3; ++k) {
    const auto& bin = hist[static_cast<size_t>(order[static_cast<size_t>(k)])];
    if (k > 0 && bin.size() < 0.1 * top) break;  // ORB-SLAM: minor bins are noise
    for (size_t i : bin) keep[i] = 1;
  }
  std::vector<MapMatch> out;
  for (size_t i = 0; i < m->size(); ++i)
    if (keep[i]) out.push_back((*m)[i]);
  *m = std::move(out);
}

std::vector<PoseObservation> observations(const Frame& frame, const std::vector<TrackingMapPoint>& map,
                                          const std::vector<MapMatch>& matches) {
  std::vector<PoseObservation> obs(matches.size());
  for (size_t i = 0; i < matches.size(); ++i) {
    const size_t f = static_cast<size_t>(matches[i].feature);
    obs[i].p_world = map[static_cast<size_t>(matches[i].point_index)].p_world;
    obs[i].uv = frame.undistorted[f];
    obs[i].sigma = frame.level_scale[static_cast<size_t>(frame.keypoints[f].octave)];
  }
  return obs;
}

}  // namespace

const char* toString(TrackingQuality q) {
  switch (q) {
    case TrackingQuality::kGood:
      return "good";
    case TrackingQuality::kWeak:
      return "weak";
    case TrackingQuality::kLost:
      return "lost";
  }
  return "lost";
}

std::vector<MapMatch> matchByProjection(const Frame& frame, const std::vector<TrackingMapPoint>& local_map,
                                        const SE3& T_world_cam, double radius_px, const TrackerOptions& opt,
                                        int* num_candidates) {
  const SE3 Tcw = T_world_cam.inverse();
  const Eigen::Vector3d centre = T_world_cam.translation();
  std::vector<MapMatch> matches;
  std::vector<int> best_for_feature(frame.size(), -1);  // index into matches
  std::vector<int> best_dist_for_feature(frame.size(), 256);
  int n_cand = 0;
  std::vector<int> near;
  for (size_t pi = 0; pi < local_map.size(); ++pi) {
    const TrackingMapPoint& mp = local_map[pi];
    if (mp.descriptor.empty()) continue;
    const Eigen::Vector3d pc = Tcw * mp.p_world;
    if (pc.z() <= 0) continue;
    Eigen::Vector2d uv;
    if (!frame.camera.projectInImage(pc, &uv, 0.0)) continue;
    const double dist = (mp.p_world - centre).norm();
    if (mp.max_distance > 0 && (dist > 1.2 * mp.max_distance || dist < 0.8 * mp.min_distance)) continue;
    ++n_cand;
    const uint8_t* d = mp.descriptor.ptr<uint8_t>();
    int best = 256, second = 256, best_idx = -1, best_level = -1, second_level = -1;
    frame.featuresInArea(uv, radius_px, &near);
    for (int j : near) {
      const int dd = descriptorDistance(d, frame.descriptors.ptr<uint8_t>(j));
      if (dd < best) {
        second = best;
        second_level = best_level;
        best = dd;
        best_idx = j;
        best_level = frame.keypoints[static_cast<size_t>(j)].octave;
      } else if (dd < second) {
        second = dd;
        second_level = frame.keypoints[static_cast<size_t>(j)].octave;
      }
    }
    if (best_idx < 0 || best > opt.max_descriptor_distance) continue;
    // Ratio test only between candidates of one scale (ORB-SLAM): the same corner is often
    // detected on neighbouring levels with similar descriptors.
    if (second < 256 && best_level == second_level && best > opt.ratio * second) continue;
    const size_t f = static_cast<size_t>(best_idx);
    if (best_for_feature[f] >= 0) {  // a feature takes one map point: the closer descriptor wins
      if (best >= best_dist_for_feature[f]) continue;
      matches[static_cast<size_t>(best_for_feature[f])] = {best_idx, mp.id, static_cast<int>(pi)};
      best_dist_for_feature[f] = best;
      continue;
    }
    best_for_feature[f] = static_cast<int>(matches.size());
    best_dist_for_feature[f] = best;
    matches.push_back({best_idx, mp.id, static_cast<int>(pi)});
  }
  if (opt.check_orientation) rotationConsistency(frame, local_map, &matches);
  if (num_candidates) *num_candidates = n_cand;
  return matches;
}

Tracker::Tracker(TrackerOptions options) : opt_(options) {}

void Tracker::setPose(const SE3& T_world_cam, const SE3* T_world_prev) {
  has_pose_ = true;
  last_ = T_world_cam;
  has_velocity_ = T_world_prev != nullptr;
  velocity_ = T_world_prev ? T_world_prev->inverse() * T_world_cam : SE3();
}

void Tracker::scaleMotion(double s) {
  last_ = SE3(last_.rotation(), s * last_.translation());
  velocity_ = SE3(velocity_.rotation(), s * velocity_.translation());
}

void Tracker::transformMotion(const Sim3& S) {
  last_ = S.transformPose(last_);
  velocity_ = SE3(velocity_.rotation(), S.scale() * velocity_.translation());
}

SE3 Tracker::predictedPose() const { return has_velocity_ ? last_ * velocity_ : last_; }

TrackingResult Tracker::track(const Frame& frame, const std::vector<TrackingMapPoint>& local_map, const SE3* prior) {
  TrackingResult r;
  if (!prior && !has_pose_) {
    r.message = "no pose to predict from (call setPose after initialisation)";
    return r;
  }
  const Eigen::Matrix3d K = frame.camera.K();
  auto t0 = threadCpuMs();
  SE3 pose = prior ? *prior : predictedPose();

  // Coarse pass: wide window around the motion-model prediction.
  std::vector<MapMatch> m = matchByProjection(frame, local_map, pose, opt_.coarse_radius_px, opt_, &r.num_candidates);
  if (static_cast<int>(m.size()) < 2 * opt_.min_inliers_weak && !prior && has_pose_) {
    // The motion model failed (sudden stop/turn): zero velocity, much wider window.
    std::vector<MapMatch> m2 = matchByProjection(frame, local_map, last_, opt_.wide_radius_px, opt_, &r.num_candidates);
    if (m2.size() > m.size()) {
      m = std::move(m2);
      pose = last_;
      r.used_motion_model = false;
    }
  }
  r.timings.matching_ms += msSince(t0);
  if (static_cast<int>(m.size()) < opt_.min_inliers_weak) {
    r.num_matches = static_cast<int>(m.size());
    r.T_world_cam = pose;
    r.message = fmt::format("lost: {} matches < {} (of {} visible map points)", m.size(), opt_.min_inliers_weak,
                            r.num_candidates);
    return r;
  }
  t0 = threadCpuMs();
  PoseOptimizationResult o = optimizePose(K, observations(frame, local_map, m), pose, opt_.optimizer);
  r.timings.optimization_ms += msSince(t0);
  if (o.converged) pose = o.T_world_cam;

  // Fine pass: narrow window around the refined pose (recovers points the coarse pass missed).
  t0 = threadCpuMs();
  m = matchByProjection(frame, local_map, pose, opt_.fine_radius_px, opt_, &r.num_candidates);
  r.timings.matching_ms += msSince(t0);
  t0 = threadCpuMs();
  o = optimizePose(K, observations(frame, local_map, m), pose, opt_.optimizer);
  r.timings.optimization_ms += msSince(t0);

  r.num_matches = static_cast<int>(m.size());
  r.num_inliers = o.num_inliers;
  r.inlier_ratio = m.empty() ? 0 : static_cast<double>(o.num_inliers) / static_cast<double>(m.size());
  r.rms_px = o.rms_px;
  r.T_world_cam = o.converged ? o.T_world_cam : pose;
  std::vector<double> depths;
  const SE3 Tcw = r.T_world_cam.inverse();
  for (size_t i = 0; i < m.size(); ++i) {
    if (!o.inlier[i]) continue;
    r.matches.push_back(m[i]);
    depths.push_back((Tcw * local_map[static_cast<size_t>(m[i].point_index)].p_world).z());
  }
  if (!depths.empty()) {
    std::nth_element(depths.begin(), depths.begin() + static_cast<long>(depths.size() / 2), depths.end());
    r.median_depth = depths[depths.size() / 2];
  }
  if (o.converged && r.num_inliers >= opt_.min_inliers_good && r.inlier_ratio >= opt_.good_inlier_ratio)
    r.quality = TrackingQuality::kGood;
  else if (o.converged && r.num_inliers >= opt_.min_inliers_weak)
    r.quality = TrackingQuality::kWeak;
  else
    r.quality = TrackingQuality::kLost;
  r.message = fmt::format("{}: {} inliers / {} matches / {} visible, rms {:.2f} px", toString(r.quality), r.num_inliers,
                          r.num_matches, r.num_candidates, r.rms_px);
  if (r.quality != TrackingQuality::kLost) {
    velocity_ = last_.inverse() * r.T_world_cam;
    has_velocity_ = has_pose_;
    last_ = r.T_world_cam;
    has_pose_ = true;
  }
  return r;
}

KeyframeDecision decideKeyframe(const KeyframeDecisionInput& in, const KeyframePolicyOptions& opt) {
  KeyframeDecision d;
  if (in.quality == TrackingQuality::kLost) {
    d.reason = "tracking lost";
    return d;
  }
  if (in.num_inliers < opt.min_inliers) {
    d.reason = fmt::format("too few inliers ({} < {})", in.num_inliers, opt.min_inliers);
    return d;
  }
  const bool weak = in.quality == TrackingQuality::kWeak;
  if (in.median_scene_depth > 0 && in.distance_to_same_view < opt.stopped_distance_ratio * in.median_scene_depth) {
    d.reason = fmt::format("camera stopped: a keyframe within {:.4f} x depth looks the same way",
                           in.distance_to_same_view / in.median_scene_depth);
    return d;
  }
  if (in.frames_since_last_keyframe < opt.min_frames_between && !(weak && in.mapping_idle)) {
    d.reason = fmt::format("too soon ({} < {} frames)", in.frames_since_last_keyframe, opt.min_frames_between);
    return d;
  }
  // A covered view: a keyframe looking the same way is within the baseline (so none is beyond it
  // either), and tracking still finds most of what the reference keyframe sees (in forward motion an
  // older keyframe can be that close while the view ahead is already new).
  const double similar = in.median_scene_depth > 0 ? in.distance_to_similar_view / in.median_scene_depth : 0;
  const double tracked_ratio = in.reference_keyframe_points > 0
                                   ? static_cast<double>(in.tracked_reference_points) / in.reference_keyframe_points
                                   : 0.0;
  if (!weak && opt.covered_view_angle_deg > 0 && similar <= opt.min_distance_ratio &&
      tracked_ratio >= opt.covered_min_tracked_ratio) {
    d.reason =
        fmt::format("view covered: a keyframe within {:.3f} x depth looks within {:.0f} deg, covisibility {:.2f}",
                    similar, opt.covered_view_angle_deg, tracked_ratio);
    return d;
  }
  if (in.frames_since_last_keyframe >= opt.max_frames_between) {
    d.insert = true;
    d.reason = fmt::format("{} frames since the last keyframe", in.frames_since_last_keyframe);
    return d;
  }
  const double ratio = in.median_scene_depth > 0 ? in.distance_to_nearest_keyframe / in.median_scene_depth : 0;
  if (ratio > opt.min_distance_ratio) {
    d.insert = true;
    d.reason = fmt::format("baseline {:.3f} > {:.3f} x depth", ratio, opt.min_distance_ratio);
    return d;
  }
  if (in.reference_keyframe_established_points > 0 && in.mapping_idle &&
      in.num_inliers < opt.max_tracked_ratio * in.reference_keyframe_established_points) {
    d.insert = true;
    d.reason = fmt::format("inliers {} < {:.2f} x {} established points of the reference keyframe", in.num_inliers,
                           opt.max_tracked_ratio, in.reference_keyframe_established_points);
    return d;
  }
  if (weak && in.mapping_idle) {
    d.insert = true;
    d.reason = "tracking weak";
    return d;
  }
  d.reason = fmt::format("baseline {:.3f} <= {:.3f} x depth", ratio, opt.min_distance_ratio);
  return d;
}

}  // namespace nerfslam
