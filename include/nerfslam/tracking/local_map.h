#pragma once
// The tracking thread's local map: a reference keyframe, its best covisible keyframes and the points
// they observe, as the tracker sees them. The mapping module builds it under the map's lock
// (Map::localMapForTracking, refreshLocalMap, mapping/map.h); the tracking policies
// (tracking_policy.h) read it without any lock.
#include <cstdint>
#include <optional>
#include <vector>

#include "nerfslam/core/pose.h"
#include "nerfslam/tracking/tracker.h"

namespace nerfslam {

// A keyframe's id in the map (mapping/map.h assigns them).
using KeyframeId = int64_t;

struct TrackingLocalMap {
  KeyframeId ref = -1;
  std::vector<KeyframeId> keyframes;     // ref first, then by decreasing covisibility, then the newest
  std::vector<SE3> keyframe_poses;       // T_world_cam of `keyframes`
  std::vector<TrackingMapPoint> points;  // sorted by id (TrackingMapPoint::id is the map's PointId)
  // Keyframes observing points[i]: observers[observer_begin[i] .. observer_begin[i + 1]).
  std::vector<int> observer_begin;
  std::vector<KeyframeId> observers;
  std::vector<int> keyframe_num_points;  // map points each of `keyframes` observes
  // Of those, the established ones: observed by 3 keyframes or more (2 while the map has two;
  // ORB-SLAM's nMinObs). A point just triangulated from two keyframes is not yet.
  std::vector<int> keyframe_num_established;
  uint64_t structure_version = ~0ull;
  uint64_t version = ~0ull;  // Map::version() of the last build or refresh
  bool empty() const { return keyframes.empty(); }

  // Index of the point with this id in `points` (binary search), or nothing.
  std::optional<size_t> findPoint(uint64_t point_id) const;
  // Index of this keyframe in `keyframes` (and `keyframe_poses`, ...), or nothing.
  std::optional<size_t> findKeyframe(KeyframeId id) const;
};

}  // namespace nerfslam
