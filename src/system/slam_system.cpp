#include "nerfslam/system/slam_system.h"

#include <algorithm>
#include <chrono>
#include <map>
#include <unordered_map>

#include <spdlog/spdlog.h>

#include "nerfslam/core/error.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/tracking/initializer.h"
#include "nerfslam/tracking/relocalizer.h"
#include "nerfslam/tracking/tracker.h"

namespace nerfslam {

const char* toString(TrackingState s) {
  switch (s) {
    case TrackingState::kNotInitialized:
      return "not_initialized";
    case TrackingState::kTracking:
      return "tracking";
    case TrackingState::kLost:
      return "lost";
  }
  return "?";
}

const char* toString(MapMode m) {
  switch (m) {
    case MapMode::kSlam:
      return "slam";
    case MapMode::kLocalize:
      return "localize";
    case MapMode::kExtend:
      return "extend";
  }
  return "?";
}

SlamSystem::SlamSystem(const Camera& camera, SystemOptions options)
    : SlamSystem(camera, std::move(options), nullptr, MapMode::kSlam) {}

SlamSystem::SlamSystem(const Camera& camera, SystemOptions options, std::unique_ptr<Map> map, MapMode mode)
    : camera_(camera), opt_(std::move(options)) {
  camera_.validate("camera");
  map_ = std::make_unique<Map>(camera_);
  if (map && mode != MapMode::kSlam) {  // a saved map (map_store.h): lost until relocalised in it
    if (map->numKeyframes() == 0) fail("SlamSystem: the map to {} has no keyframes", toString(mode));
    if (map->camera().width != camera_.width || map->camera().height != camera_.height)
      fail("SlamSystem: the map's camera is {}x{}, the images are {}x{}", map->camera().width, map->camera().height,
           camera_.width, camera_.height);
    map_ = std::move(map);
    map_mode_ = mode;
    state_ = TrackingState::kLost;
    initialized_once_ = true;
  }
  mapping_ = std::make_unique<MappingThread>(*map_, opt_.mapping, static_cast<std::size_t>(opt_.keyframe_queue));
  initializer_ = std::make_unique<Initializer>(opt_.tracking.initializer);
  tracker_ = std::make_unique<Tracker>(opt_.tracking.tracker);
  if (opt_.nerf.enabled) nerf_ = std::make_unique<NerfMapping>(*map_, mapping_->bus(), opt_.nerf);
  mapping_->start();
  if (nerf_) nerf_->start();
}

SlamSystem::~SlamSystem() {
  mapping_->stop();
  if (nerf_) nerf_->stop();
}

void SlamSystem::reset() {
  mapping_->waitIdle();
  map_->clear();
  initializer_->reset();
  tracker_ = std::make_unique<Tracker>(opt_.tracking.tracker);
  state_ = TrackingState::kNotInitialized;
  local_points_.clear();
  local_keyframes_.clear();
  local_version_ = ~0ull;
  reference_ = -1;
  last_matches_.clear();
  pre_init_frames_.clear();
  // Frames tracked against the discarded map lose their poses.
  for (auto& r : records_) {
    if (r.tracked) r.message = "discarded by reset";
    r.tracked = false;
  }
}

bool SlamSystem::initialize(const InitializationResult& r, const std::shared_ptr<const Frame>& cur, FrameRecord& rec) {
  auto ref = std::make_shared<const Frame>(initializer_->reference());
  KeyframeInsertion k0{ref, r.T_world_ref, {}};
  KeyframeInsertion k1{cur, r.T_world_cur, {}};
  const KeyframeId id0 = mapping_->insertNow(std::move(k0), false);
  const KeyframeId id1 = mapping_->insertNow(std::move(k1), false);
  std::vector<PointId> pts;
  for (const InitialPoint& p : r.points) {
    if (p.ref_feature < 0 || p.cur_feature < 0) continue;
    const PointId pid = map_->addPoint(p.p_world, {{id0, p.ref_feature}, {id1, p.cur_feature}});
    if (pid != kNoPoint) pts.push_back(pid);
  }
  mapping_->mapper().globalBundleAdjustment(20);
  // Median depth 1 in the reference keyframe after BA.
  const auto kf0 = map_->keyframe(id0);
  std::vector<double> z;
  for (const MapPoint& p : map_->points()) z.push_back((kf0->T_world_cam.inverse() * p.position).z());
  if (static_cast<int>(z.size()) < opt_.min_initial_points) {
    last_init_message_ =
        fmt::format("initialisation rejected: {} map points after BA (< {})", z.size(), opt_.min_initial_points);
    spdlog::info("{}", last_init_message_);
    map_->clear();
    initializer_->reset();
    return false;
  }
  std::nth_element(z.begin(), z.begin() + z.size() / 2, z.end());
  const double median = z[z.size() / 2];
  if (!(median > 0)) {
    map_->clear();
    initializer_->reset();
    return false;
  }
  map_->transform(Sim3(1.0 / median, SE3()));
  const SE3 T_cur = map_->keyframe(id1)->T_world_cam;
  tracker_->setPose(T_cur);
  state_ = TrackingState::kTracking;
  initialized_once_ = true;
  ++initializations_;
  init_model_ = r.model;
  reference_ = id1;
  frames_since_keyframe_ = 0;
  // The reference frame of the initialisation becomes tracked retroactively.
  for (auto& prev : records_)
    if (prev.index == r.ref_frame_id) {
      prev.tracked = true;
      prev.reference = id0;
      prev.T_ref_cam = SE3();
      prev.T_world_cam = map_->keyframe(id0)->T_world_cam;
      prev.keyframe = true;
    }
  // Frames between the two initialisation frames are tracked against the new map (pose prior
  // interpolated between the two keyframes).
  {
    const SE3 T0 = map_->keyframe(id0)->T_world_cam;
    buildLocalMap(id1);
    int n_back = 0;
    for (const auto& f : pre_init_frames_) {
      if (f->id <= r.ref_frame_id || f->id >= r.cur_frame_id) continue;
      const double s = double(f->id - r.ref_frame_id) / double(r.cur_frame_id - r.ref_frame_id);
      const SE3 prior = SE3::interpolate(T0, T_cur, s);
      tracker_->setPose(prior);
      const TrackingResult tr = tracker_->track(*f, local_points_, &prior);
      if (tr.quality == TrackingQuality::kLost) continue;
      for (auto& prev : records_)
        if (prev.index == f->id && !prev.tracked) {
          prev.tracked = true;
          prev.reference = id0;
          prev.T_ref_cam = T0.inverse() * tr.T_world_cam;
          prev.T_world_cam = tr.T_world_cam;
          prev.num_inliers = tr.num_inliers;
          prev.message = "tracked after initialisation";
          ++n_back;
        }
    }
    pre_init_frames_.clear();
    tracker_->setPose(T_cur);
    if (n_back > 0) spdlog::info("{} frames between the initialisation frames tracked against the new map", n_back);
  }
  rec.tracked = true;
  rec.keyframe = true;
  rec.reference = id1;
  rec.T_ref_cam = SE3();
  rec.T_world_cam = T_cur;
  rec.num_inliers = static_cast<int>(pts.size());
  rec.message =
      fmt::format("initialised ({}, {} points, parallax {:.1f} deg)", r.model, map_->numPoints(), r.parallax_deg);
  spdlog::info("frame {}: {}", rec.index, rec.message);
  return true;
}

KeyframeId SlamSystem::chooseReference(const std::vector<MapMatch>& matches) const {
  std::vector<PointId> ids;
  for (const auto& m : matches) ids.push_back(static_cast<PointId>(m.point_id));
  std::map<KeyframeId, int> counts;
  for (const MapPoint& p : map_->points(ids))
    for (const auto& [k, idx] : p.observations) ++counts[k];
  KeyframeId best = -1;
  int best_count = 0;
  for (const auto& [k, c] : counts)
    if (c > best_count || (c == best_count && k > best)) {
      best = k;
      best_count = c;
    }
  if (best < 0) {
    const auto last = map_->lastKeyframeId();
    return last ? *last : -1;
  }
  return best;
}

void SlamSystem::buildLocalMap(KeyframeId ref) {
  const uint64_t version = map_->version();
  if (version == local_version_ && ref == local_ref_) return;
  local_version_ = version;
  local_ref_ = ref;
  local_keyframes_.clear();
  if (ref >= 0) local_keyframes_.push_back(ref);
  for (const auto& [k, w] : map_->covisibleKeyframes(ref)) {
    if (static_cast<int>(local_keyframes_.size()) >= opt_.local_map_keyframes) break;
    local_keyframes_.push_back(k);
  }
  // Always include the newest keyframe (its points are the freshest).
  const auto last = map_->lastKeyframeId();
  if (last && std::find(local_keyframes_.begin(), local_keyframes_.end(), *last) == local_keyframes_.end())
    local_keyframes_.push_back(*last);
  local_points_.clear();
  for (const MapPoint& p : map_->points(map_->pointsSeenBy(local_keyframes_))) {
    if (p.descriptor.empty()) continue;
    TrackingMapPoint t;
    t.id = static_cast<uint64_t>(p.id);
    t.p_world = p.position;
    t.descriptor = p.descriptor;
    local_points_.push_back(std::move(t));
  }
}

FrameRecord SlamSystem::trackFrame(const cv::Mat& image, double timestamp, uint64_t index) {
  if (finished_) fail("SlamSystem::trackFrame after finish()");
  const auto t0 = std::chrono::steady_clock::now();
  FrameRecord rec;
  rec.index = index;
  rec.timestamp = timestamp;
  auto frame = std::make_shared<Frame>(extractFrame(image, camera_, opt_.tracking.features, index, timestamp));
  rec.num_features = static_cast<int>(frame->size());
  std::shared_ptr<const Frame> cframe = frame;
  auto finishRecord = [&]() -> FrameRecord {
    rec.state = state_;
    rec.tracking_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    records_.push_back(rec);
    return rec;
  };

  if (state_ == TrackingState::kNotInitialized) {
    if (frame->size() < 8) {
      rec.message = fmt::format("{} features: nothing to initialise from", frame->size());
      last_init_message_ = rec.message;
      return finishRecord();
    }
    pre_init_frames_.push_back(cframe);
    if (pre_init_frames_.size() > 300) pre_init_frames_.erase(pre_init_frames_.begin());
    const InitializationResult r = initializer_->addFrame(*frame);
    if (!r.success) {
      rec.message = r.reason;
      last_init_message_ = r.reason;
      return finishRecord();
    }
    initialize(r, cframe, rec);
    return finishRecord();
  }

  ++frames_since_keyframe_;
  KeyframeId ref = reference_;
  if (!map_->keyframe(ref)) ref = chooseReference(last_matches_);
  buildLocalMap(ref);
  TrackingResult res = tracker_->track(*frame, local_points_);
  if (res.quality == TrackingQuality::kLost) {
    // Relocalisation against the most recent keyframes.
    std::vector<RelocalizationCandidate> cands;
    auto ids = map_->keyframeIds();
    int max_candidates = opt_.relocalization_candidates;
    if (map_mode_ != MapMode::kSlam) {  // a loaded map: the camera may be anywhere in it, best-voted keyframes first
      const auto voted = keyframesByDescriptorVotes(*map_, *frame, opt_.relocalization_candidates);
      ids.insert(ids.end(), voted.rbegin(), voted.rend());
      max_candidates += static_cast<int>(voted.size());
    }
    for (auto it = ids.rbegin(); it != ids.rend() && static_cast<int>(cands.size()) < max_candidates; ++it) {
      const auto kf = map_->keyframe(*it);
      if (!kf || std::any_of(cands.begin(), cands.end(), [&](const auto& c) { return c.keyframe_id == uint64_t(*it); }))
        continue;
      RelocalizationCandidate c;
      c.keyframe_id = static_cast<uint64_t>(*it);
      c.T_world_cam = kf->T_world_cam;
      std::vector<PointId> pids;
      for (PointId p : kf->points)
        if (p != kNoPoint) pids.push_back(p);
      for (const MapPoint& p : map_->points(pids)) {
        if (p.descriptor.empty()) continue;
        TrackingMapPoint t;
        t.id = static_cast<uint64_t>(p.id);
        t.p_world = p.position;
        t.descriptor = p.descriptor;
        c.points.push_back(std::move(t));
      }
      cands.push_back(std::move(c));
    }
    const RelocalizationResult rl =
        relocalize(*frame, cands, opt_.tracking.relocalizer, opt_.tracking.tracker.optimizer);
    if (rl.success) {
      tracker_->setPose(rl.T_world_cam);
      buildLocalMap(static_cast<KeyframeId>(rl.keyframe_id));
      res = tracker_->track(*frame, local_points_, &rl.T_world_cam);
      if (res.quality != TrackingQuality::kLost) {
        ++relocalizations_;
        if (map_mode_ != MapMode::kSlam && relocalized_at_frame_ < 0) relocalized_at_frame_ = int64_t(index);
        spdlog::info("frame {}: relocalised against keyframe {} ({} inliers)", index, rl.keyframe_id, res.num_inliers);
      }
    } else {
      rec.message = "lost: " + (res.message.empty() ? std::string("too few inliers") : res.message) +
                    "; relocalisation: " + rl.reason;
    }
  }
  rec.num_inliers = res.num_inliers;
  if (res.quality == TrackingQuality::kLost) {
    if (state_ != TrackingState::kLost) spdlog::warn("frame {}: tracking lost ({})", index, rec.message);
    state_ = TrackingState::kLost;
    if (static_cast<int>(map_->numKeyframes()) <= opt_.reset_if_lost_with_keyframes && map_mode_ == MapMode::kSlam) {
      spdlog::warn("frame {}: lost with {} keyframes, reinitialising", index, map_->numKeyframes());
      reset();
      rec.message += " (map reset)";
    }
    return finishRecord();
  }
  state_ = TrackingState::kTracking;
  last_matches_ = res.matches;
  // Statistics for point culling: visible = projects into the image, found = inlier match.
  if (map_mode_ != MapMode::kLocalize) {
    std::vector<PointId> visible, found;
    const SE3 T_cw = res.T_world_cam.inverse();
    for (const auto& p : local_points_) {
      Eigen::Vector2d uv;
      if (camera_.projectInImage(T_cw * p.p_world, &uv)) visible.push_back(static_cast<PointId>(p.id));
    }
    for (const auto& m : res.matches) found.push_back(static_cast<PointId>(m.point_id));
    map_->increaseVisible(visible);
    map_->increaseFound(found);
  }
  reference_ = chooseReference(res.matches);
  const auto ref_kf = map_->keyframe(reference_);
  rec.tracked = true;
  rec.T_world_cam = res.T_world_cam;
  rec.reference = reference_;
  rec.T_ref_cam = ref_kf ? ref_kf->T_world_cam.inverse() * res.T_world_cam : res.T_world_cam;

  // Keyframe decision.
  KeyframeDecisionInput in;
  in.quality = res.quality;
  in.num_inliers = res.num_inliers;
  in.frames_since_last_keyframe = frames_since_keyframe_;
  in.median_scene_depth = res.median_depth > 0 ? res.median_depth : 1.0;
  double nearest = std::numeric_limits<double>::infinity();
  for (KeyframeId k : local_keyframes_) {
    const auto kf = map_->keyframe(k);
    if (kf) nearest = std::min(nearest, (kf->centre() - res.T_world_cam.translation()).norm());
  }
  in.distance_to_nearest_keyframe = std::isfinite(nearest) ? nearest : 0.0;
  if (ref_kf) {
    in.reference_keyframe_points = ref_kf->numTrackedPoints();
    std::vector<PointId> ref_pts(ref_kf->points.begin(), ref_kf->points.end());
    std::sort(ref_pts.begin(), ref_pts.end());
    for (const auto& m : res.matches)
      in.tracked_reference_points +=
          std::binary_search(ref_pts.begin(), ref_pts.end(), static_cast<PointId>(m.point_id));
  }
  in.mapping_idle = mapping_->idle();
  const KeyframeDecision d = decideKeyframe(in, opt_.tracking.keyframes);
  if (d.insert && map_mode_ != MapMode::kLocalize) {  // localisation never adds to the map
    KeyframeInsertion k;
    k.frame = cframe;
    k.T_world_cam = res.T_world_cam;
    for (const auto& m : res.matches) k.matches.emplace_back(m.feature, static_cast<PointId>(m.point_id));
    if (mapping_->submit(std::move(k))) {
      rec.keyframe = true;
      frames_since_keyframe_ = 0;
    }
  }
  rec.message = d.reason;
  spdlog::debug("frame {}: {} inliers / {} matches / {} candidates, rms {:.2f} px, {}{}", index, res.num_inliers,
                res.num_matches, res.num_candidates, res.rms_px, d.reason, rec.keyframe ? " -> keyframe" : "");
  return finishRecord();
}

void SlamSystem::finish(bool global_ba) {
  if (finished_) return;
  finished_ = true;
  mapping_->stop();
  if (global_ba && map_->numKeyframes() >= 2 && opt_.mapping.global_ba_iterations > 0 &&
      map_mode_ != MapMode::kLocalize) {
    const BaResult r = mapping_->mapper().globalBundleAdjustment(opt_.mapping.global_ba_iterations);
    spdlog::info("global BA: {} keyframes, {} points, rmse {:.2f} -> {:.2f} px, {} outliers, {:.0f} ms",
                 map_->numKeyframes(), map_->numPoints(), r.initial_rmse_px, r.final_rmse_px, r.outliers, r.time_ms);
  }
  if (nerf_) nerf_->stop();  // takes the last keyframes and the globally adjusted poses
}

Trajectory SlamSystem::trajectory() const {
  Trajectory out;
  for (const auto& r : records_) {
    if (!r.tracked) continue;
    const auto T_ref = map_->resolvePose(r.reference);
    out.push_back({r.timestamp, T_ref ? *T_ref * r.T_ref_cam : r.T_world_cam});
  }
  return out;
}

Trajectory SlamSystem::keyframeTrajectory() const {
  Trajectory out;
  for (const Keyframe& kf : map_->keyframes()) out.push_back({kf.timestamp(), kf.T_world_cam});
  return out;
}

}  // namespace nerfslam
