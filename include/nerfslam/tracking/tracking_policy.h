#pragma once
// The tracking thread's decisions between the tracker and the map (SlamSystem::trackFrame calls them
// in this order): which frames are worth relocalising although tracked, which keyframes
// relocalisation tries, which pose wins, when a weak pose is refused, which keyframe a frame is
// referenced to, which local-map points count as visible, and the geometry the keyframe decision
// (decideKeyframe, tracker.h) is made from. Pure functions of tracking data: no map, no lock.
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/tracking/local_map.h"
#include "nerfslam/tracking/tracker.h"

namespace nerfslam {

// The rules for frames tracked with few inliers (SystemOptions::relocalize_when_weak and
// relocalize_inlier_drop, TrackerOptions::min_inliers_good).
struct WeakTrackingPolicy {
  bool relocalize_when_weak = true;
  double inlier_drop = 0.25;
  int min_inliers_good = 50;
};

// Relocalisation is also tried for a frame tracked (not lost) with fewer than min_inliers_good
// inliers, or fewer than inlier_drop x the previous frame's (`last_inliers`, 0 when that one was not
// tracked): a wide baseline or a sudden motion the motion model missed. Never without
// relocalize_when_weak.
bool relocalizeWeakTracking(const TrackingResult& tracked, int last_inliers, const WeakTrackingPolicy& policy);

// The camera may be anywhere in the map (a loaded map, localisation only, or tracking lost, not just
// weak): relocalisation then also tries the keyframe database's candidates (mapping/place_recognition.h).
bool relocalizeAnywhere(bool loaded_map, bool localization_only, TrackingQuality quality);

// The keyframes relocalisation tries, in order, and how many.
struct RelocalizationChoice {
  // The voted keyframes (best first), then every other keyframe, newest first.
  std::vector<KeyframeId> keyframes;
  // The first this many of them that are still in the map: every voted one and `recent` more.
  size_t max_candidates = 0;
};
// `keyframe_ids`: the map's keyframes (any order); `voted`: the keyframe database's candidates, best
// first (PlaceRecognition::relocalizationCandidates, or empty).
RelocalizationChoice chooseRelocalizationKeyframes(const std::vector<KeyframeId>& keyframe_ids,
                                                   const std::vector<KeyframeId>& voted, int recent);

// After a successful relocalisation the frame is tracked again from its pose (`retracked`). For a
// frame that was lost that pose wins; for a weak one (`weak_retry`) only with more inliers than it
// was tracked with (`tracked`), else the weak pose stands.
bool relocalizedPoseWins(bool weak_retry, const TrackingResult& tracked, const TrackingResult& retracked);

// Weak evidence is not enough where the motion model cannot be trusted: right after a loss
// (`after_loss`), or when the inliers collapsed (fewer than inlier_drop x `last_inliers`, with
// relocalize_when_weak) and relocalisation found nothing better (`relocalized` false). Such a pose
// is most likely wrong and, once in a keyframe, would corrupt the map: the frame is to be lost
// instead, and the tracker to go back to its pose before the frame. Returns the frame's message
// then ("lost: ..."), nothing when the pose stands (every good pose, and a weak one otherwise).
std::optional<std::string> refuseWeakPose(const TrackingResult& result, bool relocalized, bool after_loss,
                                          int last_inliers, const WeakTrackingPolicy& policy);

// The keyframe of `local` observing the most of the matched points (ties: the newer), or -1 when
// none of them is in `local`.
KeyframeId chooseReferenceKeyframe(const std::vector<MapMatch>& matches, const TrackingLocalMap& local);

// Ids of the points of `local` that project into the image at T_world_cam (point-culling
// statistics: "visible"; the inlier matches are "found"), in the order of `local.points`.
std::vector<uint64_t> visiblePoints(const TrackingLocalMap& local, const Camera& camera, const SE3& T_world_cam);

// The keyframe decision's input for a tracked frame: its quality, inliers and median depth
// (`tracked`), the camera centre's distance to the nearest keyframe of `local`, to the nearest one
// looking the same way (stopped_view_angle_deg; `last_keyframe_pose`, the last keyframe made and
// perhaps not yet in `local`, counts too) and to the nearest older one (not the newest two) looking a
// similar way (covered_view_angle_deg), and the points of the `reference` keyframe (tracked ones
// counted only when covered_view_angle_deg > 0).
KeyframeDecisionInput keyframeDecisionInput(const TrackingResult& tracked, const TrackingLocalMap& local,
                                            KeyframeId reference, const std::optional<SE3>& last_keyframe_pose,
                                            int frames_since_keyframe, bool mapping_idle,
                                            const KeyframePolicyOptions& options);

}  // namespace nerfslam
