#include "nerfslam/system/slam_system.h"

#include <algorithm>
#include <chrono>
#include <future>
#include <optional>

#include <spdlog/spdlog.h>

#include "nerfslam/core/error.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/tracking/initializer.h"
#include "nerfslam/tracking/relocalizer.h"
#include "nerfslam/tracking/tracker.h"
#include "nerfslam/tracking/tracking_policy.h"

namespace nerfslam {

namespace {
// Thread CPU time since the previous call (or construction), in milliseconds.
class CpuLap {
 public:
  double operator()() {
    const double now = threadCpuMs(), ms = now - last_;
    last_ = now;
    return ms;
  }

 private:
  double last_ = threadCpuMs();
};
}  // namespace

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
  {
    // The keyframe database, for relocalisation and loop closing. A missing or bad vocabulary file
    // is an Error naming it (loadVocabulary).
    auto voc = std::make_shared<const Vocabulary>(loadVocabulary(vocabularyPath(opt_.loop_closing.vocabulary)));
    places_ = std::make_shared<PlaceRecognition>(voc);
    if (map_mode_ != MapMode::kSlam) {  // map folders do not store it: rebuilt from the keyframes
      Stopwatch sw;
      const size_t n = places_->addMapKeyframes(*map_);
      spdlog::info("keyframe database: not stored with the map, rebuilt from its {} keyframes in {:.0f} ms", n,
                   sw.elapsedMs());
    }
    if (opt_.loop_closing.enabled)
      loop_ = std::make_unique<LoopClosing>(*map_, mapping_.get(), std::move(voc), opt_.loop_closing, places_);
    // The loop closer adds the keyframes it is given (after its own query); the others are added here.
    mapping_->setKeyframeProcessed([this](KeyframeId id) {
      if (!loop_ || !loop_->submit(id)) {
        places_->eraseMissing(map_->keyframeIds());  // culled keyframes (the loop closer does this itself)
        places_->addKeyframe(*map_, id);
      }
    });
  }
  if (opt_.nerf.enabled) nerf_ = std::make_unique<NerfMapping>(*map_, mapping_->bus(), opt_.nerf);
  if (loop_) loop_->start();
  mapping_->start();
  if (nerf_) nerf_->start();
}

SlamSystem::~SlamSystem() {
  mapping_->stop();
  if (loop_) loop_->stop();
  if (nerf_) nerf_->stop();
}

void SlamSystem::reset() {
  waitMappingIdle();
  pollInitialization();  // frames tracked against the map being discarded are discarded with it below
  map_->clear();
  if (loop_) loop_->clear();  // idle: nothing is submitted while the tracking thread resets
  places_->clear();
  initializer_->reset();
  tracker_ = std::make_unique<Tracker>(opt_.tracking.tracker);
  state_ = TrackingState::kNotInitialized;
  local_ = TrackingLocalMap{};
  local_stale_frames_ = 0;
  last_inliers_ = 0;
  reference_ = -1;
  last_keyframe_pose_.reset();
  pre_init_frames_.clear();
  metric_scale_ = false;  // the new map starts without a scale
  applied_scale_ = 1.0;
  scale_checked_keyframe_ = -1;
  mapping_->mapper().setOdometryActive(false);
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
  KeyframeId id0 = -1, id1 = -1;
  size_t num_points = 0;
  {
    // The new map is written here, with the mapping thread held between two jobs (a no-op wait: it
    // is idle, nothing is submitted to it before a map exists).
    const MappingThread::Hold hold = mapping_->hold();
    id0 = mapping_->insertNow({std::make_shared<const Frame>(initializer_->reference()), r.T_world_ref, {}}, false);
    id1 = mapping_->insertNow({cur, r.T_world_cur, {}}, false);
    for (const InitialPoint& p : r.points) {
      if (p.ref_feature < 0 || p.cur_feature < 0) continue;
      num_points += map_->addPoint(p.p_world, {{id0, p.ref_feature}, {id1, p.cur_feature}}) != kNoPoint;
    }
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
  // frame as for any keyframe; pollInitialization() applies the result.
  std::vector<std::shared_ptr<const Frame>> between;
  for (const auto& f : pre_init_frames_)
    if (f->id > r.ref_frame_id && f->id < r.cur_frame_id) between.push_back(f);
  pre_init_frames_.clear();
  tracked_since_init_ = false;
  auto result = std::make_shared<std::promise<InitHandoff>>();
  init_handoff_ = result->get_future();
  // A task that throws breaks the promise (pollInitialization then applies nothing).
  mapping_->submitTask(
      [this, result, id0, id1, between = std::move(between), ref_id = r.ref_frame_id, cur_id = r.cur_frame_id] {
        result->set_value(adjustNewMap(id0, id1, between, ref_id, cur_id));
      });
  rec.tracked = true;
  rec.keyframe = true;
  rec.reference = id1;
  rec.T_ref_cam = SE3();
  rec.T_world_cam = T_cur;
  rec.num_inliers = static_cast<int>(num_points);
  rec.message =
      fmt::format("initialised ({}, {} points, parallax {:.1f} deg)", r.model, map_->numPoints(), r.parallax_deg);
  spdlog::info("frame {}: {}", rec.index, rec.message);
  return true;
}

SlamSystem::InitHandoff SlamSystem::adjustNewMap(KeyframeId id0, KeyframeId id1,
                                                 const std::vector<std::shared_ptr<const Frame>>& between,
                                                 uint64_t ref_frame_id, uint64_t cur_frame_id) {
  InitHandoff out;
  mapping_->mapper().globalBundleAdjustment(20);
  const auto kf0 = map_->keyframe(id0);
  const auto kf1 = map_->keyframe(id1);
  if (!kf0 || !kf1) return out;  // nothing to hand back (reference -1)
  out.reference = id0;
  out.T_world_ref = kf0->T_world_cam;
  out.T_world_cur = kf1->T_world_cam;
  TrackingLocalMap m;
  if (between.empty() || !map_->localMapForTracking(id1, opt_.local_map_keyframes, &m, true)) return out;
  // Pose prior interpolated between the two keyframes.
  Tracker tracker(opt_.tracking.tracker);
  for (const auto& f : between) {
    const double s = double(f->id - ref_frame_id) / double(cur_frame_id - ref_frame_id);
    const SE3 prior = SE3::interpolate(out.T_world_ref, out.T_world_cur, s);
    tracker.setPose(prior);
    const TrackingResult tr = tracker.track(*f, m.points, &prior);
    if (tr.quality == TrackingQuality::kLost) continue;
    out.frames.push_back({f->id, tr.T_world_cam, tr.num_inliers});
  }
  if (!out.frames.empty())
    spdlog::info("{} frames between the initialisation frames tracked against the new map", out.frames.size());
  return out;
}

void SlamSystem::pollInitialization() {
  if (!init_handoff_.valid() || init_handoff_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
  InitHandoff d;
  try {
    d = init_handoff_.get();
  } catch (const std::future_error&) {
    return;  // the task failed (the mapping thread logged why): the frames stay untracked
  }
  if (d.reference < 0) return;
  for (const InitHandoff::TrackedFrame& f : d.frames)
    for (auto& prev : records_)
      if (prev.index == f.index && !prev.tracked) {
        prev.tracked = true;
        prev.reference = d.reference;
        prev.T_ref_cam = d.T_world_ref.inverse() * f.T_world_cam;
        prev.T_world_cam = f.T_world_cam;
        prev.num_inliers = f.num_inliers;
        prev.message = "tracked after initialisation";
      }
  // No frame tracked against the map yet: start from the adjusted pose of the newest keyframe.
  if (!tracked_since_init_ && state_ == TrackingState::kTracking) tracker_->setPose(d.T_world_cur);
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
  pollInitialization();  // what the mapping thread finished for a new map (initialize())
  updateOdometryScale(index, timestamp);
  FrameRecord rec;
  rec.index = index;
  rec.timestamp = timestamp;
  const auto frame =
      std::make_shared<const Frame>(extractFrame(image, camera_, opt_.tracking.features, index, timestamp));
  rec.num_features = static_cast<int>(frame->size());
  rec.extract_cpu_ms = threadCpuMs() - cpu0;
  rec.extract_stages = frame->timings;
  const bool localize_only = localizationOnly();
  if (state_ == TrackingState::kNotInitialized)
    initializeFrom(frame, localize_only, rec);
  else
    trackAgainstMap(frame, localize_only, rec);
  rec.state = state_;
  rec.tracking_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  rec.tracking_cpu_ms = threadCpuMs() - cpu0;
  records_.push_back(rec);
  return rec;
}

void SlamSystem::initializeFrom(const std::shared_ptr<const Frame>& frame, bool localize_only, FrameRecord& rec) {
  if (localize_only) {  // no map to localise in, and none may be built
    rec.message = "localisation only: no map";
    return;
  }
  if (frame->size() < 8) {
    rec.message = fmt::format("{} features: nothing to initialise from", frame->size());
    last_init_message_ = rec.message;
    return;
  }
  pre_init_frames_.push_back(frame);
  if (pre_init_frames_.size() > 300) pre_init_frames_.erase(pre_init_frames_.begin());
  const InitializationResult r = initializer_->addFrame(*frame);
  rec.init_klt_cpu_ms = r.klt_cpu_ms;
  rec.init_models_cpu_ms = r.models_cpu_ms;
  if (!r.success) {
    rec.message = r.reason;
    last_init_message_ = r.reason;
    return;
  }
  initialize(r, frame, rec);
}

WeakTrackingPolicy SlamSystem::weakTrackingPolicy() const {
  WeakTrackingPolicy p;
  p.relocalize_when_weak = opt_.relocalize_when_weak;
  p.inlier_drop = opt_.relocalize_inlier_drop;
  p.min_inliers_good = opt_.tracking.tracker.min_inliers_good;
  return p;
}

void SlamSystem::trackAgainstMap(const std::shared_ptr<const Frame>& frame, bool localize_only, FrameRecord& rec) {
  ++frames_since_keyframe_;
  tracked_since_init_ = true;
  CpuLap lap;
  applyLoopCorrections();
  buildLocalMap(reference_, false);
  applyLoopCorrections();  // one that landed while the local map was read
  rec.local_map_cpu_ms = lap();
  const bool had_pose = tracker_->hasPose();
  const SE3 pose_before = tracker_->lastPose();  // restored when a weak pose is refused below
  TrackingResult res = tracker_->track(*frame, local_.points);
  rec.track_cpu_ms = lap();
  const WeakTrackingPolicy weak = weakTrackingPolicy();
  const bool weak_retry = relocalizeWeakTracking(res, last_inliers_, weak);
  bool relocalized = false;
  if (res.quality == TrackingQuality::kLost || weak_retry) {
    relocalized = relocalizeFrame(*frame, weak_retry, localize_only, res, rec);
    rec.relocalize_cpu_ms = lap();
    rec.relocalization_attempted = true;
  }
  if (const auto refused = refuseWeakPose(res, relocalized, state_ == TrackingState::kLost, last_inliers_, weak)) {
    rec.message = *refused;
    res.quality = TrackingQuality::kLost;
    if (had_pose) tracker_->setPose(pose_before);
  }
  if (res.quality != TrackingQuality::kLost) pose_map_version_ = local_.version;
  rec.num_inliers = res.num_inliers;
  last_inliers_ = res.quality == TrackingQuality::kLost ? 0 : res.num_inliers;
  if (res.quality == TrackingQuality::kLost) {
    if (state_ != TrackingState::kLost) spdlog::warn("frame {}: tracking lost ({})", rec.index, rec.message);
    state_ = TrackingState::kLost;
    if (static_cast<int>(map_->numKeyframes()) <= opt_.reset_if_lost_with_keyframes && map_mode_ == MapMode::kSlam &&
        !localize_only) {
      spdlog::warn("frame {}: lost with {} keyframes, reinitialising", rec.index, map_->numKeyframes());
      reset();
      rec.message += " (map reset)";
    }
    return;
  }
  state_ = TrackingState::kTracking;
  if (!localize_only) {  // statistics for point culling: visible = projects into the image, found = inlier
    std::vector<PointId> visible, found;
    for (uint64_t id : visiblePoints(local_, camera_, res.T_world_cam)) visible.push_back(static_cast<PointId>(id));
    for (const auto& m : res.matches) found.push_back(static_cast<PointId>(m.point_id));
    map_->increaseVisible(visible);
    map_->increaseFound(found);
  }
  reference_ = chooseReferenceKeyframe(res.matches, local_);
  if (reference_ < 0) reference_ = map_->lastKeyframeId().value_or(-1);
  // The reference keyframe's pose from the local map (no keyframe copies on this thread).
  const auto ref_slot = local_.findKeyframe(reference_);
  const std::optional<SE3> ref_pose = ref_slot ? local_.keyframe_poses[*ref_slot] : map_->resolvePose(reference_);
  rec.tracked = true;
  rec.T_world_cam = res.T_world_cam;
  rec.reference = reference_;
  rec.T_ref_cam = ref_pose ? ref_pose->inverse() * res.T_world_cam : res.T_world_cam;
  submitIfKeyframe(frame, res, localize_only, rec);
}

bool SlamSystem::relocalizeFrame(const Frame& frame, bool weak_retry, bool localize_only, TrackingResult& res,
                                 FrameRecord& rec) {
  const std::vector<KeyframeId> ids = map_->keyframeIds();
  std::vector<KeyframeId> voted;
  if (relocalizeAnywhere(map_mode_ != MapMode::kSlam, localize_only, res.quality)) {
    RelocalizationQuery q;
    q.max_candidates = static_cast<size_t>(opt_.relocalization_candidates);
    voted = places_->relocalizationCandidates(*map_, places_->bagOfWords(frame), q);
  }
  const RelocalizationChoice choice = chooseRelocalizationKeyframes(ids, voted, opt_.relocalization_candidates);
  const RelocalizationResult rl =
      relocalize(frame, map_->relocalizationCandidates(choice.keyframes, choice.max_candidates),
                 opt_.tracking.relocalizer, opt_.tracking.tracker.optimizer);
  if (!rl.success) {
    spdlog::debug("frame {}: relocalisation failed; keyframe-database candidates [{}]: {}", frame.id,
                  fmt::join(voted, ", "), rl.reason);
    if (!weak_retry)
      rec.message = "lost: " + (res.message.empty() ? std::string("too few inliers") : res.message) +
                    "; relocalisation: " + rl.reason;
    return false;
  }
  const KeyframeId ref_before = local_.ref;
  tracker_->setPose(rl.T_world_cam);
  buildLocalMap(static_cast<KeyframeId>(rl.keyframe_id));
  TrackingResult again = tracker_->track(frame, local_.points, &rl.T_world_cam);
  if (!relocalizedPoseWins(weak_retry, res, again)) {
    // The weak pose stands: the tracker and the local map go back to it.
    tracker_->setPose(res.T_world_cam);
    buildLocalMap(ref_before);
    return false;
  }
  const int tracked_inliers = res.num_inliers;
  res = std::move(again);
  if (res.quality == TrackingQuality::kLost) return false;
  ++relocalizations_;
  if (map_mode_ != MapMode::kSlam && relocalized_at_frame_ < 0) relocalized_at_frame_ = int64_t(frame.id);
  spdlog::info("frame {}: relocalised against keyframe {} ({} inliers{})", frame.id, rl.keyframe_id, res.num_inliers,
               weak_retry ? fmt::format("; tracking had {}", tracked_inliers) : std::string());
  return true;
}

void SlamSystem::submitIfKeyframe(const std::shared_ptr<const Frame>& frame, const TrackingResult& res,
                                  bool localize_only, FrameRecord& rec) {
  const KeyframeDecisionInput in = keyframeDecisionInput(
      res, local_, reference_, last_keyframe_pose_, frames_since_keyframe_, mapping_->idle(), opt_.tracking.keyframes);
  const KeyframeDecision d = decideKeyframe(in, opt_.tracking.keyframes);
  if (d.insert && !localize_only) {  // localisation never adds to the map
    KeyframeInsertion k;
    k.frame = frame;
    k.T_world_cam = res.T_world_cam;
    for (const auto& m : res.matches) k.matches.emplace_back(m.feature, static_cast<PointId>(m.point_id));
    if (mapping_->submit(std::move(k))) {
      rec.keyframe = true;
      frames_since_keyframe_ = 0;
      last_keyframe_pose_ = res.T_world_cam;
    }
  }
  rec.message = d.reason;
  spdlog::debug("frame {}: {} inliers / {} matches / {} candidates, rms {:.2f} px, {}{}", rec.index, res.num_inliers,
                res.num_matches, res.num_candidates, res.rms_px, d.reason, rec.keyframe ? " -> keyframe" : "");
}

void SlamSystem::applyLoopCorrections() {
  if (!loop_ || loop_->corrections() == loop_corrections_seen_) return;
  std::vector<LoopCorrection> corrections;
  if (!loop_->correctionsSince(&loop_corrections_seen_, &corrections)) return;
  for (const LoopCorrection& c : corrections) {
    if (c.delta.empty()) continue;
    // The tracker moves with its reference keyframe (else the newest corrected one), unless its
    // last pose was tracked against a copy of the map that already had the correction (a frame
    // tracked or relocalised while the loop closer wrote the map).
    auto it = c.delta.find(reference_);
    if (it == c.delta.end()) it = std::prev(c.delta.end());
    const Sim3& d = it->second;
    if (pose_map_version_ <= c.map_version_before) {
      if (tracker_->hasPose()) tracker_->transformMotion(d);
      if (last_keyframe_pose_) last_keyframe_pose_ = d.transformPose(*last_keyframe_pose_);
    }
    // Frames are kept relative to their reference keyframe: its scale correction scales them.
    for (auto& r : records_) {
      const auto dr = c.delta.find(r.reference);
      if (dr == c.delta.end()) continue;
      r.T_ref_cam = SE3(r.T_ref_cam.rotation(), dr->second.scale() * r.T_ref_cam.translation());
    }
    spdlog::info("tracking: loop correction applied (the reference keyframe {} moved by scale {:.4f})", it->first,
                 d.scale());
  }
  local_ = TrackingLocalMap{};
  buildLocalMap(reference_, true);  // at the corrected positions
  pose_map_version_ = local_.version;
}

void SlamSystem::setOdometry(std::shared_ptr<const OdometryTrack> odometry) {
  if (!records_.empty()) fail("SlamSystem::setOdometry after the first frame");
  if (odometry && map_mode_ != MapMode::kSlam)
    fail("odometry with a loaded map ({} mode) is not supported: the map keeps the scale it was saved with",
         toString(map_mode_));
  auto hold = mapping_->hold();
  odometry_ = std::move(odometry);
  mapping_->mapper().setOdometry(odometry_);
}

void SlamSystem::updateOdometryScale(uint64_t index, double timestamp) {
  if (!odometry_ || map_mode_ != MapMode::kSlam || state_ == TrackingState::kNotInitialized || init_handoff_.valid())
    return;
  const auto last = map_->lastKeyframeId();
  if (!last || *last == scale_checked_keyframe_) return;
  scale_checked_keyframe_ = *last;
  const auto kfs = map_->keyframePoses();
  ScaleSample smp;
  smp.frame = index;
  smp.timestamp = timestamp;
  smp.keyframes = static_cast<int>(kfs.size());
  smp.estimate = estimateScale(kfs, *odometry_, metric_scale_ ? kRecentScalePairs : 0);
  if (!metric_scale_ && smp.estimate.valid) {
    applyScale(smp.estimate.scale);
    smp.applied = true;
    scale_applied_at_frame_ = static_cast<int64_t>(index);
    spdlog::info(
        "odometry: map scale {:.4f} m per unit from {} keyframe pairs ({} inliers, {:.2f} m of odometry, "
        "spread {:.1f} %), applied at frame {}",
        smp.estimate.scale, smp.estimate.pairs, smp.estimate.inliers, smp.estimate.path_m, 100 * smp.estimate.spread,
        index);
  }
  smp.applied_scale = applied_scale_;
  scale_history_.push_back(smp);
}

void SlamSystem::applyScale(double s) {
  auto hold = mapping_->hold();  // no bundle adjustment between the map's copy and its update
  map_->transform(Sim3(s, SE3()));
  tracker_->scaleMotion(s);
  const auto scaled = [s](SE3& T) { T = SE3(T.rotation(), s * T.translation()); };
  for (auto& r : records_) {
    scaled(r.T_world_cam);
    scaled(r.T_ref_cam);
  }
  if (last_keyframe_pose_) scaled(*last_keyframe_pose_);
  local_ = TrackingLocalMap{};  // rebuilt at the scaled positions
  applied_scale_ *= s;
  metric_scale_ = true;
  mapping_->mapper().setOdometryActive(true);
}

void SlamSystem::finish(bool global_ba, const std::function<bool()>& stop_global_ba) {
  if (finished_) return;
  finished_ = true;
  mapping_->stop();
  if (loop_) loop_->stop();  // the keyframes queued for it are looked at first
  pollInitialization();
  map_->flushTrackingStatistics();  // statistics queued while the mapping thread held the map
  if (global_ba && map_->numKeyframes() >= 2 && opt_.mapping.global_ba_iterations > 0 &&
      map_mode_ != MapMode::kLocalize) {
    spdlog::info("global BA: started on {} keyframes and {} points", map_->numKeyframes(), map_->numPoints());
    const BaResult r = mapping_->mapper().globalBundleAdjustment(opt_.mapping.global_ba_iterations, stop_global_ba);
    const bool stopped = stop_global_ba && stop_global_ba();
    spdlog::info(
        "global BA: {} keyframes, {} points, rmse {:.2f} -> {:.2f} px, {} outliers, {} iterations, {:.0f} ms{}",
        map_->numKeyframes(), map_->numPoints(), r.initial_rmse_px, r.final_rmse_px, r.outliers, r.iterations,
        r.time_ms, stopped ? " (stopped early by a second signal)" : "");
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
