#include "nerfslam/system/slam_system.h"

#include <algorithm>
#include <chrono>
#include <map>
#include <mutex>
#include <optional>
#include <unordered_map>

#include <spdlog/spdlog.h>

#include "nerfslam/core/error.h"
#include "nerfslam/core/timing.h"
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
    localization_only_ = mode == MapMode::kLocalize;
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
  mergeDeferred();  // frames tracked against the map being discarded are discarded with it below
  deferred_pose_.reset();
  map_->clear();
  initializer_->reset();
  tracker_ = std::make_unique<Tracker>(opt_.tracking.tracker);
  state_ = TrackingState::kNotInitialized;
  local_ = TrackingLocalMap{};
  local_stale_frames_ = 0;
  last_inliers_ = 0;
  reference_ = -1;
  last_keyframe_pose_.reset();
  last_matches_.clear();
  pre_init_frames_.clear();
  // Frames tracked against the discarded map lose their poses.
  for (auto& r : records_) {
    if (r.tracked) r.message = "discarded by reset";
    r.tracked = false;
  }
}

bool SlamSystem::initialize(const InitializationResult& r, const std::shared_ptr<const Frame>& cur, FrameRecord& rec) {
  // The initialiser's points are already scaled to median depth 1 in the reference camera.
  int usable = 0;
  for (const InitialPoint& p : r.points) usable += p.ref_feature >= 0 && p.cur_feature >= 0;
  if (usable < opt_.min_initial_points) {
    last_init_message_ = fmt::format("initialisation rejected: {} points observed in both keyframes (< {})", usable,
                                     opt_.min_initial_points);
    spdlog::info("{}", last_init_message_);
    initializer_->reset();
    return false;
  }
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
  const SE3 T_cur = r.T_world_cur;
  tracker_->setPose(T_cur);
  state_ = TrackingState::kTracking;
  initialized_once_ = true;
  ++initializations_;
  init_model_ = r.model;
  reference_ = id1;
  frames_since_keyframe_ = 0;
  last_keyframe_pose_ = T_cur;
  // The reference frame of the initialisation becomes tracked retroactively.
  for (auto& prev : records_)
    if (prev.index == r.ref_frame_id) {
      prev.tracked = true;
      prev.reference = id0;
      prev.T_ref_cam = SE3();
      prev.T_world_cam = r.T_world_ref;
      prev.keyframe = true;
    }
  // The two-keyframe bundle adjustment, and tracking the frames between the two initialisation
  // frames against the adjusted map, run on the mapping thread (it has nothing else to do yet): the
  // tracking thread goes on with the next frame. Offline (lockstep) runs wait for it before the next
  // frame as for any keyframe; the poses come back through mergeDeferred().
  std::vector<std::shared_ptr<const Frame>> between;
  for (const auto& f : pre_init_frames_)
    if (f->id > r.ref_frame_id && f->id < r.cur_frame_id) between.push_back(f);
  pre_init_frames_.clear();
  tracked_since_init_ = false;
  mapping_->submitTask(
      [this, id0, id1, between = std::move(between), ref_id = r.ref_frame_id, cur_id = r.cur_frame_id]() {
        DeferredInitResult out;
        mapping_->mapper().globalBundleAdjustment(20);
        const auto kf0 = map_->keyframe(id0);
        const auto kf1 = map_->keyframe(id1);
        if (!kf0 || !kf1) return;  // nothing to hand back
        out.reference = id0;
        out.T_world_ref = kf0->T_world_cam;
        out.T_world_cur = kf1->T_world_cam;
        TrackingLocalMap m;
        if (!between.empty() && map_->localMapForTracking(id1, opt_.local_map_keyframes, &m, true)) {
          // Pose prior interpolated between the two keyframes.
          Tracker tracker(opt_.tracking.tracker);
          for (const auto& f : between) {
            const double s = double(f->id - ref_id) / double(cur_id - ref_id);
            const SE3 prior = SE3::interpolate(out.T_world_ref, out.T_world_cur, s);
            tracker.setPose(prior);
            const TrackingResult tr = tracker.track(*f, m.points, &prior);
            if (tr.quality == TrackingQuality::kLost) continue;
            out.frames.push_back({f->id, tr.T_world_cam, tr.num_inliers});
          }
          if (!out.frames.empty())
            spdlog::info("{} frames between the initialisation frames tracked against the new map", out.frames.size());
        }
        std::lock_guard<std::mutex> lock(deferred_mutex_);
        deferred_ = std::move(out);
      });
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

void SlamSystem::mergeDeferred() const {
  std::optional<DeferredInitResult> d;
  {
    std::lock_guard<std::mutex> lock(deferred_mutex_);
    d.swap(deferred_);
  }
  if (!d) return;
  for (const DeferredFrame& f : d->frames)
    for (auto& prev : records_)
      if (prev.index == f.index && !prev.tracked) {
        prev.tracked = true;
        prev.reference = d->reference;
        prev.T_ref_cam = d->T_world_ref.inverse() * f.T_world_cam;
        prev.T_world_cam = f.T_world_cam;
        prev.num_inliers = f.num_inliers;
        prev.message = "tracked after initialisation";
      }
  deferred_pose_ = d->T_world_cur;
}

KeyframeId SlamSystem::chooseReference(const std::vector<MapMatch>& matches) const {
  // The matched points are local-map points: their observers are in local_ (no map lock needed).
  std::map<KeyframeId, int> counts;
  for (const auto& m : matches) {
    const auto it = std::lower_bound(local_.points.begin(), local_.points.end(), m.point_id,
                                     [](const TrackingMapPoint& p, uint64_t id) { return p.id < id; });
    if (it == local_.points.end() || it->id != m.point_id) continue;
    const size_t i = static_cast<size_t>(it - local_.points.begin());
    for (int k = local_.observer_begin[i]; k < local_.observer_begin[i + 1]; ++k) ++counts[local_.observers[size_t(k)]];
  }
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

void SlamSystem::buildLocalMap(KeyframeId ref, bool wait) {
  // A frame may go on with the local map it has while the mapping thread holds the map's lock, at
  // most this many frames in a row (then it waits: the local map must not fall far behind).
  constexpr int kMaxStaleFrames = 8;
  const bool must = wait || local_.empty() || local_stale_frames_ >= kMaxStaleFrames;
  if (ref != local_.ref || map_->structureVersion() != local_.structure_version) {
    TrackingLocalMap m;
    if (map_->localMapForTracking(ref, opt_.local_map_keyframes, &m, must)) {
      ++local_map_rebuilds_;
      local_ = std::move(m);
      local_stale_frames_ = 0;
      return;
    }
    if (!must) {  // the lock was taken, or ref is gone: go on with what we have for now
      ++local_stale_frames_;
      return;
    }
    // `ref` is no longer in the map (culled): build around the newest keyframe.
    const auto last = map_->lastKeyframeId();
    if (last && map_->localMapForTracking(*last, opt_.local_map_keyframes, &m, true)) local_ = std::move(m);
    local_stale_frames_ = 0;
  } else if (map_->version() != local_.version) {
    if (map_->refreshLocalMap(&local_, must))
      local_stale_frames_ = 0;
    else
      ++local_stale_frames_;
  }
}

FrameRecord SlamSystem::trackFrame(const cv::Mat& image, double timestamp, uint64_t index) {
  if (finished_) fail("SlamSystem::trackFrame after finish()");
  const auto t0 = std::chrono::steady_clock::now();
  const double cpu0 = threadCpuMs();
  mergeDeferred();  // what the mapping thread finished for a new map (initialize())
  if (deferred_pose_) {
    // No frame tracked against the map yet: start from the adjusted pose of the newest keyframe.
    if (!tracked_since_init_ && state_ == TrackingState::kTracking) tracker_->setPose(*deferred_pose_);
    deferred_pose_.reset();
  }
  FrameRecord rec;
  rec.index = index;
  rec.timestamp = timestamp;
  auto frame = std::make_shared<Frame>(extractFrame(image, camera_, opt_.tracking.features, index, timestamp));
  rec.num_features = static_cast<int>(frame->size());
  rec.extract_cpu_ms = threadCpuMs() - cpu0;
  rec.extract_stages = frame->timings;
  std::shared_ptr<const Frame> cframe = frame;
  auto finishRecord = [&]() -> FrameRecord {
    rec.state = state_;
    rec.tracking_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    rec.tracking_cpu_ms = threadCpuMs() - cpu0;
    records_.push_back(rec);
    return rec;
  };

  const bool localize_only = localizationOnly();
  if (state_ == TrackingState::kNotInitialized) {
    if (localize_only) {  // no map to localise in, and none may be built
      rec.message = "localisation only: no map";
      return finishRecord();
    }
    if (frame->size() < 8) {
      rec.message = fmt::format("{} features: nothing to initialise from", frame->size());
      last_init_message_ = rec.message;
      return finishRecord();
    }
    pre_init_frames_.push_back(cframe);
    if (pre_init_frames_.size() > 300) pre_init_frames_.erase(pre_init_frames_.begin());
    const InitializationResult r = initializer_->addFrame(*frame);
    rec.init_klt_cpu_ms = r.klt_cpu_ms;
    rec.init_models_cpu_ms = r.models_cpu_ms;
    if (!r.success) {
      rec.message = r.reason;
      last_init_message_ = r.reason;
      return finishRecord();
    }
    initialize(r, cframe, rec);
    return finishRecord();
  }

  ++frames_since_keyframe_;
  tracked_since_init_ = true;
  double lap = threadCpuMs();
  auto lapMs = [&lap] {
    const double now = threadCpuMs(), ms = now - lap;
    lap = now;
    return ms;
  };
  buildLocalMap(reference_, false);
  rec.local_map_cpu_ms = lapMs();
  const bool had_pose = tracker_->hasPose();
  const SE3 pose_before = tracker_->lastPose();  // restored when a weak pose is refused below
  TrackingResult res = tracker_->track(*frame, local_.points);
  rec.track_cpu_ms = lapMs();
  bool relocalised = false;
  // Relocalisation when lost, and when tracking is weak for want of inliers (a wide baseline or a
  // sudden motion the motion model missed, as between the photos of a multi-view set): the pose with
  // more inliers wins.
  const bool weak_retry = opt_.relocalize_when_weak && res.quality != TrackingQuality::kLost &&
                          (res.num_inliers < opt_.tracking.tracker.min_inliers_good ||
                           double(res.num_inliers) < opt_.relocalize_inlier_drop * double(last_inliers_));
  if (res.quality == TrackingQuality::kLost || weak_retry) {
    // Relocalisation against the most recent keyframes.
    std::vector<RelocalizationCandidate> cands;
    auto ids = map_->keyframeIds();
    int max_candidates = opt_.relocalization_candidates;
    // A loaded map, localisation only, or lost: the camera may be anywhere in the map, so the
    // keyframes that share the most descriptors with the frame are tried too (best-voted first).
    if (map_mode_ != MapMode::kSlam || localize_only || res.quality == TrackingQuality::kLost) {
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
      const TrackingResult before = res;
      const KeyframeId ref_before = local_.ref;
      tracker_->setPose(rl.T_world_cam);
      buildLocalMap(static_cast<KeyframeId>(rl.keyframe_id));
      TrackingResult again = tracker_->track(*frame, local_.points, &rl.T_world_cam);
      if (weak_retry && (again.quality == TrackingQuality::kLost || again.num_inliers <= before.num_inliers)) {
        // The weak pose stands: the tracker and the local map go back to it.
        tracker_->setPose(before.T_world_cam);
        buildLocalMap(ref_before);
      } else {
        res = std::move(again);
        if (res.quality != TrackingQuality::kLost) {
          relocalised = true;
          ++relocalizations_;
          if (map_mode_ != MapMode::kSlam && relocalized_at_frame_ < 0) relocalized_at_frame_ = int64_t(index);
          spdlog::info("frame {}: relocalised against keyframe {} ({} inliers{})", index, rl.keyframe_id,
                       res.num_inliers,
                       weak_retry ? fmt::format("; tracking had {}", before.num_inliers) : std::string());
        }
      }
    } else if (!weak_retry) {
      rec.message = "lost: " + (res.message.empty() ? std::string("too few inliers") : res.message) +
                    "; relocalisation: " + rl.reason;
    }
    rec.relocalize_cpu_ms = lapMs();
  }
  // Weak evidence is not enough where the motion model cannot be trusted: right after a loss, or
  // when the inliers collapsed and relocalisation found nothing better (a jump or a gap in the
  // input). Such a pose is most likely wrong and, once in a keyframe, would corrupt the map: the
  // frame is lost instead, and the tracker goes back to where it was.
  if (res.quality == TrackingQuality::kWeak && !relocalised) {
    const bool after_loss = state_ == TrackingState::kLost;
    const bool collapsed =
        opt_.relocalize_when_weak && double(res.num_inliers) < opt_.relocalize_inlier_drop * double(last_inliers_);
    if (after_loss || collapsed) {
      rec.message = fmt::format(
          "lost: {} inliers {} ({}); relocalisation found no better pose", res.num_inliers,
          after_loss ? "are too weak to recover from a loss" : "collapsed from",
          after_loss ? fmt::format("< {}", opt_.tracking.tracker.min_inliers_good) : std::to_string(last_inliers_));
      res.quality = TrackingQuality::kLost;
      if (had_pose) tracker_->setPose(pose_before);
    }
  }
  rec.num_inliers = res.num_inliers;
  last_inliers_ = res.quality == TrackingQuality::kLost ? 0 : res.num_inliers;
  if (res.quality == TrackingQuality::kLost) {
    if (state_ != TrackingState::kLost) spdlog::warn("frame {}: tracking lost ({})", index, rec.message);
    state_ = TrackingState::kLost;
    if (static_cast<int>(map_->numKeyframes()) <= opt_.reset_if_lost_with_keyframes && map_mode_ == MapMode::kSlam &&
        !localize_only) {
      spdlog::warn("frame {}: lost with {} keyframes, reinitialising", index, map_->numKeyframes());
      reset();
      rec.message += " (map reset)";
    }
    return finishRecord();
  }
  state_ = TrackingState::kTracking;
  last_matches_ = res.matches;
  // Statistics for point culling: visible = projects into the image, found = inlier match.
  if (!localize_only) {
    std::vector<PointId> visible, found;
    const SE3 T_cw = res.T_world_cam.inverse();
    for (const auto& p : local_.points) {
      Eigen::Vector2d uv;
      if (camera_.projectInImage(T_cw * p.p_world, &uv)) visible.push_back(static_cast<PointId>(p.id));
    }
    for (const auto& m : res.matches) found.push_back(static_cast<PointId>(m.point_id));
    map_->increaseVisible(visible);
    map_->increaseFound(found);
  }
  reference_ = chooseReference(res.matches);
  // The reference keyframe's pose and points from the local map (no keyframe copies on this thread).
  const auto ref_it = std::find(local_.keyframes.begin(), local_.keyframes.end(), reference_);
  const bool ref_local = ref_it != local_.keyframes.end();
  const size_t ref_slot = static_cast<size_t>(ref_it - local_.keyframes.begin());
  std::optional<SE3> ref_pose;
  if (ref_local)
    ref_pose = local_.keyframe_poses[ref_slot];
  else
    ref_pose = map_->resolvePose(reference_);
  rec.tracked = true;
  rec.T_world_cam = res.T_world_cam;
  rec.reference = reference_;
  rec.T_ref_cam = ref_pose ? ref_pose->inverse() * res.T_world_cam : res.T_world_cam;

  // Keyframe decision.
  KeyframeDecisionInput in;
  in.quality = res.quality;
  in.num_inliers = res.num_inliers;
  in.frames_since_last_keyframe = frames_since_keyframe_;
  in.median_scene_depth = res.median_depth > 0 ? res.median_depth : 1.0;
  double nearest = std::numeric_limits<double>::infinity();
  const Eigen::Vector3d axis = res.T_world_cam.rotation() * Eigen::Vector3d::UnitZ();
  const double min_cos = std::cos(opt_.tracking.keyframes.covered_view_angle_deg * M_PI / 180.0);
  const double same_cos = std::cos(opt_.tracking.keyframes.stopped_view_angle_deg * M_PI / 180.0);
  // A revisit is a return to the view of an older keyframe: the newest two, which exploration
  // extends from, do not count (as keyframe culling keeps them).
  const KeyframeId newest =
      local_.keyframes.empty() ? 0 : *std::max_element(local_.keyframes.begin(), local_.keyframes.end());
  for (size_t i = 0; i < local_.keyframe_poses.size(); ++i) {
    const SE3& T = local_.keyframe_poses[i];
    const double dist = (T.translation() - res.T_world_cam.translation()).norm();
    nearest = std::min(nearest, dist);
    const double cos_axes = (T.rotation() * Eigen::Vector3d::UnitZ()).dot(axis);
    if (cos_axes >= same_cos) in.distance_to_same_view = std::min(in.distance_to_same_view, dist);
    if (local_.keyframes[i] < newest - 1 && cos_axes >= min_cos)
      in.distance_to_similar_view = std::min(in.distance_to_similar_view, dist);
  }
  if (last_keyframe_pose_ && (last_keyframe_pose_->rotation() * Eigen::Vector3d::UnitZ()).dot(axis) >= same_cos)
    in.distance_to_same_view =
        std::min(in.distance_to_same_view, (last_keyframe_pose_->translation() - res.T_world_cam.translation()).norm());
  in.distance_to_nearest_keyframe = std::isfinite(nearest) ? nearest : 0.0;
  if (ref_local) {
    in.reference_keyframe_points = local_.keyframe_num_points[ref_slot];
    in.reference_keyframe_established_points = local_.keyframe_num_established[ref_slot];
    // Only the covered-view gate (off by default) asks which inliers the reference keyframe observes.
    if (opt_.tracking.keyframes.covered_view_angle_deg > 0)
      for (const auto& m : res.matches) {
        const auto it = std::lower_bound(local_.points.begin(), local_.points.end(), m.point_id,
                                         [](const TrackingMapPoint& p, uint64_t id) { return p.id < id; });
        if (it == local_.points.end() || it->id != m.point_id) continue;
        const size_t i = static_cast<size_t>(it - local_.points.begin());
        const auto b = local_.observers.begin() + local_.observer_begin[i],
                   e = local_.observers.begin() + local_.observer_begin[i + 1];
        in.tracked_reference_points += std::find(b, e, reference_) != e;
      }
  }
  in.mapping_idle = mapping_->idle();
  const KeyframeDecision d = decideKeyframe(in, opt_.tracking.keyframes);
  if (d.insert && !localize_only) {  // localisation never adds to the map
    KeyframeInsertion k;
    k.frame = cframe;
    k.T_world_cam = res.T_world_cam;
    for (const auto& m : res.matches) k.matches.emplace_back(m.feature, static_cast<PointId>(m.point_id));
    if (mapping_->submit(std::move(k))) {
      rec.keyframe = true;
      frames_since_keyframe_ = 0;
      last_keyframe_pose_ = res.T_world_cam;
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
  mergeDeferred();
  map_->flushTrackingStatistics();  // statistics queued while the mapping thread held the map
  if (global_ba && map_->numKeyframes() >= 2 && opt_.mapping.global_ba_iterations > 0 &&
      map_mode_ != MapMode::kLocalize) {
    const BaResult r = mapping_->mapper().globalBundleAdjustment(opt_.mapping.global_ba_iterations);
    spdlog::info("global BA: {} keyframes, {} points, rmse {:.2f} -> {:.2f} px, {} outliers, {:.0f} ms",
                 map_->numKeyframes(), map_->numPoints(), r.initial_rmse_px, r.final_rmse_px, r.outliers, r.time_ms);
  }
  if (nerf_) nerf_->stop();  // takes the last keyframes and the globally adjusted poses
}

Trajectory SlamSystem::trajectory() const {
  mergeDeferred();
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
