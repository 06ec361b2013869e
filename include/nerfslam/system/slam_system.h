#pragma once
// Monocular SLAM: the tracking front end (tracking module) on the caller's thread and the mapping
// back end (MappingThread) on its own thread. trackFrame() never waits for mapping: keyframes are
// handed over through a bounded queue (dropped and counted when mapping is busy) and tracking reads
// the map through copies taken under the map's lock.
//
// Every tracked frame is stored relative to its reference keyframe, so the final trajectory follows
// the keyframes' bundle-adjusted poses (trajectory()).
//
// The system wires the threads; what tracking decides lives in tracking/ (tracking_policy.h: weak
// tracking, relocalisation candidates, the reference keyframe, the keyframe decision's geometry;
// mapping/place_recognition.h: the keyframe database a lost camera queries). A new map is written by the tracking
// thread with the mapping thread held (MappingThread::hold); its bundle adjustment and the frames between the two
// initialisation frames then run on the mapping thread, and the next trackFrame() (or finish())
// takes the result (pollInitialization).
#include <atomic>
#include <cstdint>
#include <future>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/mapping/loop_closing.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/mapping/mapping_thread.h"
#include "nerfslam/mapping/odometry.h"
#include "nerfslam/system/nerf_mapping.h"
#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/options.h"
#include "nerfslam/tracking/tracking_policy.h"

namespace nerfslam {

// System-level tuning of the tracking defaults: a keyframe may follow the previous one immediately
// (forward motion, e.g. KITTI at 10 Hz, needs one nearly every frame) and frames get 2000 features.
inline TrackingOptions systemTrackingDefaults() {
  TrackingOptions t;
  t.keyframes.min_frames_between = 1;
  t.features.max_features = 2000;
  return t;
}

struct SystemOptions {
  TrackingOptions tracking = systemTrackingDefaults();
  MappingOptions mapping;
  LoopClosingOptions loop_closing;
  int local_map_keyframes = 10;          // covisible keyframes whose points tracking matches against
  int keyframe_queue = 3;                // mapping input queue (keyframes beyond it are dropped)
  int relocalization_candidates = 5;     // keyframe-database candidates (and most recent keyframes) tried when lost
  bool relocalize_when_weak = true;      // also relocalise frames tracked with fewer than min_inliers_good inliers
  double relocalize_inlier_drop = 0.25;  // ... or with fewer than this fraction of the previous frame's inliers
  int min_initial_points = 50;           // initial points observed in both keyframes
  int reset_if_lost_with_keyframes = 3;  // lost with at most this many keyframes: reinitialise
  int frame_queue = 2;                   // frames between the reader and the tracking thread
  bool lockstep = true;                  // offline runs: the reader waits for tracking and mapping per frame
  NerfMappingOptions nerf;               // the NeRF mapping thread
  OdometryOptions odometry;              // wheel odometry, when given (SlamSystem::setOdometry)

  template <class V>
  void visit(V& v) {
    v("tracking", tracking, "Tracking front end");
    v("mapping", mapping, "Mapping back end");
    v("loop_closing", loop_closing, "Loop closing thread: place recognition, Sim(3), essential-graph correction");
    v("nerf", nerf, "NeRF mapping thread (dense map)");
    v("odometry", odometry, "Wheel odometry (run --odometry): metric scale and the base-to-camera extrinsic");
    v("local_map_keyframes", local_map_keyframes, "Covisible keyframes forming the local map tracked against",
      check::range(1, 1000));
    v("keyframe_queue", keyframe_queue, "Keyframes queued for mapping before new ones are dropped",
      check::range(1, 1000));
    v("relocalization_candidates", relocalization_candidates,
      "Keyframes relocalisation tries: the keyframe database's best candidates where the camera may be anywhere "
      "(lost, or a loaded map), and as many of the most recent keyframes",
      check::range(1, 1000));
    v("relocalize_when_weak", relocalize_when_weak,
      "Also relocalise frames tracked with fewer than tracking.tracker.min_inliers_good inliers; the pose with "
      "more inliers wins");
    v("relocalize_inlier_drop", relocalize_inlier_drop,
      "With relocalize_when_weak: also relocalise a frame tracked with fewer than this fraction of the previous "
      "frame's inliers (a motion the motion model missed; 0: never)",
      check::range(0.0, 1.0));
    v("min_initial_points", min_initial_points,
      "Initial map points (seen in both keyframes) required to accept an initialisation", check::range(8, 100000));
    v("reset_if_lost_with_keyframes", reset_if_lost_with_keyframes,
      "Reinitialise when tracking is lost and the map has at most this many keyframes", check::range(0, 1000));
    v("frame_queue", frame_queue, "Frames buffered between the reader and the tracking thread", check::range(1, 1000));
    v("lockstep", lockstep,
      "Offline runs (not --realtime): the reader waits until each frame is tracked and mapping is idle "
      "(reproducible results; tracking itself never waits)");
  }
};

enum class TrackingState { kNotInitialized, kTracking, kLost };
const char* toString(TrackingState s);  // "not_initialized", "tracking", "lost"

// How a system uses the map it starts from (a saved map folder, system/map_store.h).
//   kSlam      no map: initialise and map as usual
//   kLocalize  start lost, relocalise in the map, then track against it without changing it (no
//              keyframes or points added, no tracking statistics, no global BA at finish)
//   kExtend    start lost, relocalise in the map, then map as usual (new keyframes and points)
enum class MapMode { kSlam, kLocalize, kExtend };
const char* toString(MapMode m);  // "slam", "localize", "extend"

struct FrameRecord {
  uint64_t index = 0;
  double timestamp = 0;
  TrackingState state = TrackingState::kNotInitialized;
  bool tracked = false;
  bool keyframe = false;  // submitted as a keyframe (and accepted by the mapping queue)
  int num_features = 0;
  int num_inliers = 0;
  SE3 T_world_cam;  // at tracking time
  KeyframeId reference = -1;
  SE3 T_ref_cam;
  double tracking_ms = 0;      // wall time of trackFrame
  double tracking_cpu_ms = 0;  // CPU time of the calling thread in trackFrame (independent of load)
  // Where that CPU time went: feature extraction (pyramid, FAST, descriptors), local map updates,
  // tracking against the local map (matching and pose optimisation), relocalisation attempts, and
  // the rest (keyframe decision, statistics for point culling).
  double extract_cpu_ms = 0, local_map_cpu_ms = 0, track_cpu_ms = 0, relocalize_cpu_ms = 0;
  bool relocalization_attempted = false;  // relocalize_cpu_ms is one attempt's
  FrameTimings extract_stages;            // the extraction's own stages (pyramid, FAST, descriptors)
  // Before a map exists: the initialiser's KLT tracking, and its model fits with the reconstruction.
  double init_klt_cpu_ms = 0, init_models_cpu_ms = 0;
  std::string message;
};

// The map's scale from odometry over time (SlamSystem::scaleHistory), one sample per new keyframe
// once the map exists: before the scale is applied the estimate over every keyframe pair, after it
// over the last kRecentScalePairs pairs (1 while the map keeps the odometry's scale).
struct ScaleSample {
  uint64_t frame = 0;
  double timestamp = 0;
  int keyframes = 0;
  ScaleEstimate estimate;      // metres per map unit of the map at that time
  double applied_scale = 1.0;  // product of the scales applied to the map so far
  bool applied = false;        // the scale was applied at this sample
};
constexpr int kRecentScalePairs = 20;

class SlamSystem {
 public:
  SlamSystem(const Camera& camera, SystemOptions options);
  // Starts from a loaded, non-empty map (e.g. LoadedMap::map; its camera must be `camera`) in `mode`
  // (kLocalize or kExtend); a null map or kSlam is the constructor above.
  SlamSystem(const Camera& camera, SystemOptions options, std::unique_ptr<Map> map, MapMode mode);
  ~SlamSystem();
  SlamSystem(const SlamSystem&) = delete;
  SlamSystem& operator=(const SlamSystem&) = delete;

  // Tracks one frame (8-bit grey or BGR, the camera's size) in the calling thread. Throws
  // nerfslam::Error for an image of the wrong size or type.
  FrameRecord trackFrame(const cv::Mat& image, double timestamp, uint64_t index);
  // Stops mapping (after the queued keyframes) and runs the global bundle adjustment.
  // stop_global_ba: checked after every iteration of the global BA; true ends it there.
  void finish(bool global_ba = true, const std::function<bool()>& stop_global_ba = {});

  TrackingState state() const { return state_; }
  bool initialized() const { return initialized_once_; }
  // Mapping and loop closing idle (nothing queued or in progress).
  bool mappingIdle() const { return mapping_->idle() && (!loop_ || loop_->idle()); }
  void waitMappingIdle() const {
    mapping_->waitIdle();
    if (loop_) loop_->waitIdle();
  }
  // The loop closing thread (nullptr when options.loop_closing.enabled is false).
  const LoopClosing* loopClosing() const { return loop_.get(); }
  // The keyframe database relocalisation queries (shared with loop closing; always present).
  const PlaceRecognition& places() const { return *places_; }
  // Loop corrections the tracking thread has applied to its own state (pose, motion model, frames).
  uint64_t loopCorrectionsApplied() const { return loop_corrections_seen_; }
  const Map& map() const { return *map_; }
  Map& map() { return *map_; }
  KeyframeBus& keyframeBus() { return mapping_->bus(); }
  MappingThread& mapping() { return *mapping_; }
  // The NeRF mapping thread (nullptr when options.nerf.enabled is false). finish() stops it.
  NerfMapping* nerf() { return nerf_.get(); }
  const NerfMapping* nerf() const { return nerf_.get(); }
  // One record per frame handed to trackFrame(). The frames between the two initialisation frames
  // get their poses from the mapping thread: in records() and trajectory() from the first
  // trackFrame() after it has tracked them (the next one in lock-step runs), or finish().
  const std::vector<FrameRecord>& records() const { return records_; }
  // Tracked frames with poses resolved through their reference keyframes (current map).
  Trajectory trajectory() const;
  Trajectory keyframeTrajectory() const;
  uint64_t droppedKeyframes() const { return mapping_->droppedKeyframes(); }
  const std::string& lastInitMessage() const { return last_init_message_; }
  int initializationCount() const { return initializations_; }
  // Two-view model of the last successful initialisation ("fundamental" or "homography"; empty before).
  const std::string& initializationModel() const { return init_model_; }
  int relocalizations() const { return relocalizations_; }
  // Times the tracking thread rebuilt its local map (the other frames reuse it, refreshing positions).
  int64_t localMapRebuilds() const { return local_map_rebuilds_; }
  MapMode mapMode() const { return map_mode_; }
  // Localisation only, switchable at run time from any thread (e.g. a ROS service): while on, frames
  // are tracked and relocalised against the map but add no keyframes, no statistics and never reset
  // it; mapping and the NeRF finish what they were given. Started with MapMode::kLocalize it is on.
  void setLocalizationOnly(bool on) { localization_only_.store(on, std::memory_order_release); }
  bool localizationOnly() const { return localization_only_.load(std::memory_order_acquire); }
  // Index of the first frame relocalised in the loaded map (-1: not yet, or no loaded map).
  int64_t relocalizedAtFrame() const { return relocalized_at_frame_; }

  // Wheel odometry (mapping/odometry.h), before the first frame; not with a loaded map. At the first
  // frame after a new keyframe the map's scale is estimated (estimateScale); once valid it is applied
  // to the map (Map::transform), the tracker and the frames' poses, with the mapping thread held,
  // and bundle adjustment keeps it (LocalMapper::setOdometryActive). A reset starts over.
  void setOdometry(std::shared_ptr<const OdometryTrack> odometry);
  const OdometryTrack* odometry() const { return odometry_.get(); }
  bool metricScale() const { return metric_scale_; }
  int64_t scaleAppliedAtFrame() const { return scale_applied_at_frame_; }
  const std::vector<ScaleSample>& scaleHistory() const { return scale_history_; }

 private:
  // The mapping thread's result for a new map (initialize()), handed back through init_handoff_.
  struct InitHandoff {
    struct TrackedFrame {
      uint64_t index = 0;
      SE3 T_world_cam;
      int num_inliers = 0;
    };
    KeyframeId reference = -1;  // the first keyframe, the frames' reference (-1: nothing to apply)
    SE3 T_world_ref;            // its pose, T_world_cur the second keyframe's, after the bundle adjustment
    SE3 T_world_cur;
    std::vector<TrackedFrame> frames;  // the frames between the two initialisation frames that were tracked
  };

  // Before a map exists: the initialiser's attempt with this frame, and the map it makes.
  void initializeFrom(const std::shared_ptr<const Frame>& frame, bool localize_only, FrameRecord& rec);
  bool initialize(const InitializationResult& r, const std::shared_ptr<const Frame>& frame, FrameRecord& rec);
  // On the mapping thread (a task from initialize()): the new map's bundle adjustment, then the
  // frames between the two initialisation frames tracked against it.
  InitHandoff adjustNewMap(KeyframeId id0, KeyframeId id1, const std::vector<std::shared_ptr<const Frame>>& between,
                           uint64_t ref_frame_id, uint64_t cur_frame_id);
  // Applies the mapping thread's InitHandoff once it is ready (a no-op before and after): the poses
  // of the frames between the two initialisation frames into records_, and, while no frame has been
  // tracked against the map, the adjusted pose of the second keyframe to the tracker.
  void pollInitialization();
  // Once a map exists: tracking against the local map, relocalisation, the keyframe decision.
  void trackAgainstMap(const std::shared_ptr<const Frame>& frame, bool localize_only, FrameRecord& rec);
  // Relocalises a lost or weakly tracked frame; true when the relocalised pose replaced `res`.
  bool relocalizeFrame(const Frame& frame, bool weak_retry, bool localize_only, TrackingResult& res, FrameRecord& rec);
  void submitIfKeyframe(const std::shared_ptr<const Frame>& frame, const TrackingResult& res, bool localize_only,
                        FrameRecord& rec);
  WeakTrackingPolicy weakTrackingPolicy() const;
  void reset();
  // The loop closer's corrections since the last call, applied to the tracker's pose and motion
  // model, the frames' poses relative to their reference keyframes and the local map (tracking
  // thread; never waits).
  void applyLoopCorrections();
  // At a new keyframe: the odometry's scale estimate, applied once valid (setOdometry).
  void updateOdometryScale(uint64_t index, double timestamp);
  void applyScale(double s);
  // `wait` = false: never waits for the map lock (the local map may then stay as it was).
  void buildLocalMap(KeyframeId ref, bool wait = true);

  Camera camera_;
  SystemOptions opt_;
  std::unique_ptr<Map> map_;
  std::unique_ptr<MappingThread> mapping_;
  std::shared_ptr<PlaceRecognition> places_;  // the keyframe database (loop closing and relocalisation)
  std::unique_ptr<LoopClosing> loop_;         // after mapping_: stopped and destroyed first
  uint64_t loop_corrections_seen_ = 0;
  uint64_t pose_map_version_ = 0;      // Map::version() of the local map the tracker's pose was last tracked against
  std::unique_ptr<NerfMapping> nerf_;  // after mapping_: unsubscribes from its bus first
  std::unique_ptr<Initializer> initializer_;
  std::unique_ptr<Tracker> tracker_;
  TrackingState state_ = TrackingState::kNotInitialized;
  bool initialized_once_ = false;
  int initializations_ = 0, relocalizations_ = 0;
  std::string last_init_message_;
  std::string init_model_;
  std::vector<FrameRecord> records_;
  // Valid from initialize() until pollInitialization() has applied it.
  std::future<InitHandoff> init_handoff_;
  bool tracked_since_init_ = false;  // a frame was tracked against the map since initialize()
  // Local map cache (buildLocalMap): rebuilt when the map's structure or the reference changes,
  // refreshed when BA moved poses and points, kept when the map's lock is taken (stale frames).
  TrackingLocalMap local_;
  int local_stale_frames_ = 0;
  int64_t local_map_rebuilds_ = 0;
  int last_inliers_ = 0;  // inliers of the last tracked frame (0: the last frame was not tracked)
  KeyframeId reference_ = -1;
  std::vector<std::shared_ptr<const Frame>> pre_init_frames_;  // tracked retroactively after initialisation
  int frames_since_keyframe_ = 0;
  // Pose of the last keyframe this thread made: it counts for the stopped-camera rule before the
  // mapping thread has put it into the map (and so into the local map).
  std::optional<SE3> last_keyframe_pose_;
  bool finished_ = false;
  std::atomic<bool> localization_only_{false};
  MapMode map_mode_ = MapMode::kSlam;  // kLocalize / kExtend: started from a loaded map
  int64_t relocalized_at_frame_ = -1;
  std::shared_ptr<const OdometryTrack> odometry_;
  bool metric_scale_ = false;
  double applied_scale_ = 1.0;
  int64_t scale_applied_at_frame_ = -1;
  KeyframeId scale_checked_keyframe_ = -1;
  std::vector<ScaleSample> scale_history_;
};

}  // namespace nerfslam
