#pragma once
// The sparse SLAM map: keyframes (pose, the tracked Frame with its features and image pyramid, and
// the map point seen by each keypoint), map points (position, observations, representative
// descriptor, mean viewing direction) and the covisibility between keyframes (number of shared
// points, derived from the observations).
//
// Ownership and locking: the Map owns everything behind one std::shared_mutex. Every read returns a
// copy (a Keyframe copy shares its immutable Frame through a shared_ptr), every write is one short
// exclusive section, so a reader never sees a half-updated pose. The mapping thread optimises copies
// and publishes the result in one call (applyUpdate), which bumps version(). Features of a keyframe
// are immutable once inserted; only its pose and keypoint->point associations change.
//
// The tracking thread never waits for the lock (SlamSystem::buildLocalMap): it reads its local map
// with localMapForTracking / refreshLocalMap (one shared-lock section each, no MapPoint copies)
// with wait = false, going on with the map it has when a writer holds the lock, and its
// statistics (increaseVisible/Found) are queued when the lock is taken and applied later.
// structureVersion() tells it when the point list must be rebuilt (keyframes, points or
// observations inserted or erased) rather than refreshed (poses and positions moved by BA).
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/mapping/observation_map.h"
#include "nerfslam/mapping/odometry.h"
#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/local_map.h"
#include "nerfslam/tracking/relocalizer.h"
#include "nerfslam/tracking/tracker.h"

namespace nerfslam {

using PointId = int64_t;
using ObservationMap = SortedVectorMap<KeyframeId, int>;
constexpr PointId kNoPoint = -1;

struct Keyframe {
  KeyframeId id = -1;
  SE3 T_world_cam;
  std::shared_ptr<const Frame> frame;  // features, descriptors, pyramid; never modified
  std::vector<PointId> points;         // per keypoint: the map point it observes, or kNoPoint
  bool fixed = false;                  // gauge keyframe (the first), never moved by BA

  double timestamp() const { return frame ? frame->timestamp : 0.0; }
  uint64_t frameId() const { return frame ? frame->id : 0; }
  Eigen::Vector3d centre() const { return T_world_cam.translation(); }
  int numTrackedPoints() const;
};

struct MapPoint {
  PointId id = -1;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // mean unit viewing direction (point - centre)
  cv::Mat descriptor;                                 // 1 x 32 CV_8U, the medoid of the observations
  ObservationMap observations;                        // keyframe -> keypoint index, by keyframe
  KeyframeId first_keyframe = -1;
  int visible = 1;  // frames that should have seen it (tracking statistics)
  int found = 1;    // frames that matched it
  double foundRatio() const { return visible > 0 ? double(found) / visible : 0.0; }
};

// A batch of results published atomically by the mapping thread.
struct MapUpdate {
  std::vector<std::pair<KeyframeId, SE3>> keyframe_poses;
  std::vector<std::pair<PointId, Eigen::Vector3d>> point_positions;
  std::vector<std::pair<PointId, KeyframeId>> erase_observations;
  std::vector<PointId> erase_points;
};

// Time the calling thread spent waiting for the Map's lock (acquisitions that found it taken).
struct MapLockWait {
  uint64_t acquisitions = 0;  // all lock acquisitions
  uint64_t contended = 0;     // acquisitions that had to wait
  double total_ms = 0;
  double max_ms = 0;  // longest single wait
};

class Map {
 public:
  explicit Map(Camera camera = {});
  Map(const Map&) = delete;
  Map& operator=(const Map&) = delete;

  // The undistorted (ideal pinhole) camera keypoints' `undistorted` positions refer to.
  const Camera& camera() const { return camera_; }

  // Inserts a keyframe (id assigned and returned). `kf.points` must have one entry per keypoint (or
  // be empty: all kNoPoint); existing points listed there get the observation. The first keyframe
  // is fixed.
  KeyframeId addKeyframe(Keyframe kf);
  // Creates a point with the given observations (keyframe -> keypoint) and computes its descriptor
  // and normal. Observations of unknown keyframes or already-associated keypoints are skipped;
  // returns kNoPoint (nothing created) when fewer than two are left.
  PointId addPoint(const Eigen::Vector3d& position, const std::map<KeyframeId, int>& observations);
  // Associates keypoint `idx` of keyframe `kf` with point `pid` (replacing nothing: false when the
  // keypoint is taken, the point already has an observation in kf, or either is unknown).
  bool addObservation(PointId pid, KeyframeId kf, int idx);
  void eraseObservation(PointId pid, KeyframeId kf);
  void erasePoint(PointId pid);
  // Removes a keyframe and its observations; points left with < 2 observations are removed.
  // With a `parent` (a keyframe that stays), the removed keyframe's pose is remembered relative to
  // it so poses of frames referenced to the removed keyframe can still be resolved (resolvePose).
  void eraseKeyframe(KeyframeId kf, KeyframeId parent = -1);
  // Current pose of keyframe `id`, following the parent chain of removed keyframes.
  std::optional<SE3> resolvePose(KeyframeId id) const;
  // Replaces `from` by `to` (observations merged, descriptors recomputed).
  void fusePoints(PointId from, PointId to);
  // Recomputes descriptor and normal of a point from its observations.
  void updatePointAppearance(PointId pid);
  void setKeyframePose(KeyframeId id, const SE3& T_world_cam);
  void applyUpdate(const MapUpdate& update);
  // Tracking statistics. Never wait: when a writer holds the lock the ids are queued and counted
  // at the next call that gets it (flushTrackingStatistics() forces that).
  void increaseVisible(const std::vector<PointId>& pids);
  void increaseFound(const std::vector<PointId>& pids);
  void flushTrackingStatistics();
  // Applies `T` (a similarity) to every pose and point, e.g. to rescale the map.
  void transform(const Sim3& T);
  void clear();
  // Saved maps (system/map_store.h). snapshot(): keyframes (by id) and points (by id) copied under one
  // lock, so their associations agree. restore(): replaces the contents with such a snapshot, ids,
  // poses, associations, descriptors, normals and statistics kept as given; new ids continue after the
  // largest restored ones. Throws an Error when the associations disagree (a point's observation
  // (kf, idx) must be named by that keyframe's slot idx and every slot's point must list it), a
  // keyframe has no frame or its slots do not match its keypoints.
  std::pair<std::vector<Keyframe>, std::vector<MapPoint>> snapshot() const;
  void restore(std::vector<Keyframe> keyframes, std::vector<MapPoint> points);

  std::optional<Keyframe> keyframe(KeyframeId id) const;
  std::optional<MapPoint> point(PointId id) const;
  std::vector<Keyframe> keyframes() const;      // ordered by id
  std::vector<KeyframeId> keyframeIds() const;  // ordered by id
  // Every keyframe's timestamp and pose, ordered by id (no features or associations copied).
  std::vector<TimedPose> keyframePoses() const;
  std::vector<MapPoint> points() const;
  std::vector<MapPoint> points(const std::vector<PointId>& ids) const;  // unknown ids skipped
  // What a dense map needs of points, without copying descriptors and observations: for each id
  // in `ids`, its position, observation count and found ratio (observations 0: the point is gone).
  struct PointSummary {
    Eigen::Vector3d position = Eigen::Vector3d::Zero();
    int observations = 0;
    double found_ratio = 0;
  };
  std::vector<PointSummary> pointSummaries(const std::vector<PointId>& ids) const;
  std::optional<KeyframeId> lastKeyframeId() const;
  size_t numKeyframes() const;
  size_t numPoints() const;
  // Keyframes sharing >= min_shared points with `id`, sorted by decreasing count.
  std::vector<std::pair<KeyframeId, int>> covisibleKeyframes(KeyframeId id, int min_shared = 1) const;
  // Points observed by the given keyframes (each once).
  std::vector<PointId> pointsSeenBy(const std::vector<KeyframeId>& kfs) const;

  // Builds `out` around `ref` (max_keyframes: ref and its best covisible keyframes; the newest
  // keyframe is added too) in one shared-lock section. With wait = false nothing is read and false
  // returned when a writer holds the lock; also false when `ref` is not in the map.
  bool localMapForTracking(KeyframeId ref, int max_keyframes, TrackingLocalMap* out, bool wait = true) const;
  // Updates the keyframe poses and point positions of `m` (the lists stay as built). false, and `m`
  // unchanged, when wait = false and a writer holds the lock.
  bool refreshLocalMap(TrackingLocalMap* m, bool wait = true) const;
  // Relocalisation's input, in one shared-lock section (the keyframes come from the keyframe
  // database, mapping/place_recognition.h). relocalizationCandidates(): the keyframes of `order` still in the map, the
  // first `max_candidates` of them in that order, each with the points it observes that have a descriptor (keypoint
  // order) and, as `neighbours`, the other points of its `neighbour_keyframes` best covisible keyframes (for the
  // relocaliser's guided search; bounded, so the cost does not grow with the map).
  std::vector<RelocalizationCandidate> relocalizationCandidates(const std::vector<KeyframeId>& order,
                                                                size_t max_candidates,
                                                                int neighbour_keyframes = 10) const;

  // Lock-wait statistics of the calling thread, over all Map instances, since the thread started or
  // the last resetThreadLockWait().
  static MapLockWait threadLockWait();
  static void resetThreadLockWait();

  // Incremented on every write.
  uint64_t version() const { return version_.load(std::memory_order_acquire); }
  // Incremented when keyframes, points or observations (or descriptors) are inserted or erased, not
  // when poses, positions or statistics change.
  uint64_t structureVersion() const { return structure_version_.load(std::memory_order_acquire); }

 private:
  void eraseObservationLocked(PointId pid, KeyframeId kf);
  std::vector<std::pair<KeyframeId, int>> covisibleLocked(KeyframeId id, int min_shared) const;
  void erasePointLocked(PointId pid);
  void updateAppearanceLocked(MapPoint& p);
  void bump() { version_.fetch_add(1, std::memory_order_acq_rel); }
  void bumpStructure() {
    structure_version_.fetch_add(1, std::memory_order_acq_rel);
    bump();
  }
  void applyStatisticsLocked(const std::vector<PointId>& visible, const std::vector<PointId>& found);
  void updateStatistics(const std::vector<PointId>& visible, const std::vector<PointId>& found, bool wait);

  Camera camera_;
  mutable std::shared_mutex mutex_;
  std::map<KeyframeId, Keyframe> keyframes_;
  std::unordered_map<PointId, MapPoint> points_;
  std::map<KeyframeId, std::pair<KeyframeId, SE3>> retired_;  // removed kf -> (parent, T_parent_kf)
  KeyframeId next_kf_ = 0;
  PointId next_point_ = 0;
  std::atomic<uint64_t> version_{0};
  std::atomic<uint64_t> structure_version_{0};
  // Statistics queued while the lock was taken (increaseVisible/Found never wait).
  std::mutex pending_mutex_;
  std::vector<PointId> pending_visible_, pending_found_;
};

}  // namespace nerfslam
