#pragma once
// Frame-to-map pose tracking. The system hands the tracker a data view of the local map
// (TrackingMapPoint, built from the mapping module's map under its lock); the tracker predicts the
// pose with a constant-velocity model, projects the points (Camera::projectInImage), matches them
// in a search window by descriptor distance + ratio test + rotation consistency, and refines the
// pose coarse-to-fine (wide window pass, optimise, narrow window pass, optimise) with the robust
// pose optimiser. It returns the pose, the inlier matches (frame feature <-> map point id) that
// the system turns into observations, and a quality good/weak/lost.
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/pose_optimizer.h"

namespace nerfslam {

// One map point as the tracker sees it.
struct TrackingMapPoint {
  uint64_t id = 0;
  Eigen::Vector3d p_world = Eigen::Vector3d::Zero();
  cv::Mat descriptor;  // 1 x 32 CV_8U (representative descriptor)
  // Optional viewing constraints (0 = unknown): distance range in which the point was observed.
  double min_distance = 0, max_distance = 0;
  // Keypoint orientation (degrees) of the observation the descriptor came from; < 0 unknown.
  // Used by the rotation-consistency check.
  double angle = -1;
};

enum class TrackingQuality { kGood, kWeak, kLost };
const char* toString(TrackingQuality q);  // "good", "weak", "lost"

struct MapMatch {
  int feature = -1;       // index into frame.keypoints / descriptors
  uint64_t point_id = 0;  // TrackingMapPoint::id
  int point_index = -1;   // index into the local map vector handed to track()
};

struct TrackerOptions {
  double coarse_radius_px = 20;       // search radius of the first pass (level-0 px, x level scale)
  double fine_radius_px = 5;          // radius of the second pass
  double wide_radius_px = 60;         // retry radius when the motion model fails
  int max_descriptor_distance = 100;  // Hamming threshold (of 256 bits), ORB-SLAM's TH_HIGH
  double ratio = 0.8;                 // best / second-best ratio (when both on the same level)
  bool check_orientation = true;      // rotation-consistency histogram
  int min_inliers_good = 50;          // good: inliers >= this and ratio >= good_ratio
  double good_inlier_ratio = 0.5;
  int min_inliers_weak = 20;  // below: lost
  PoseOptimizerOptions optimizer;
  template <class V>
  void visit(V& v) {
    v("coarse_radius_px", coarse_radius_px, "Search radius of the coarse pass (pixels)", check::positive<double>());
    v("fine_radius_px", fine_radius_px, "Search radius of the fine pass (pixels)", check::positive<double>());
    v("wide_radius_px", wide_radius_px, "Search radius when the motion model fails", check::positive<double>());
    v("max_descriptor_distance", max_descriptor_distance, "Largest Hamming distance of a match", check::range(1, 256));
    v("ratio", ratio, "Best/second-best descriptor distance ratio", check::range(0.1, 1.0));
    v("check_orientation", check_orientation, "Keep only matches with consistent keypoint rotation");
    v("min_inliers_good", min_inliers_good, "Inliers for quality 'good'", check::range(1, 100000));
    v("good_inlier_ratio", good_inlier_ratio, "Inlier ratio for quality 'good'", check::range(0.0, 1.0));
    v("min_inliers_weak", min_inliers_weak, "Inliers below which tracking is lost", check::range(1, 100000));
    v("optimizer", optimizer, "Robust pose optimiser");
  }
};

// Thread CPU time in milliseconds, as FrameTimings.
struct TrackingTimings {
  double projection_ms = 0, matching_ms = 0, optimization_ms = 0;
};

struct TrackingResult {
  TrackingQuality quality = TrackingQuality::kLost;
  SE3 T_world_cam;
  std::vector<MapMatch> matches;  // inliers only
  int num_candidates = 0;         // map points projecting into the image
  int num_matches = 0;            // before outlier rejection
  int num_inliers = 0;
  double inlier_ratio = 0;  // inliers / matches
  double rms_px = 0;
  double median_depth = 0;        // of the inlier points in this camera (for keyframe decisions)
  bool used_motion_model = true;  // false when the wide zero-velocity retry was needed
  TrackingTimings timings;
  std::string message;
};

class Tracker {
 public:
  explicit Tracker(TrackerOptions options = {});
  // Tracks `frame` against `local_map`. The prediction is the constant-velocity extrapolation of
  // the last two poses set by setPose/track (or `prior` when given). On good/weak quality the
  // result's pose becomes the new last pose; on lost the motion model is left untouched.
  TrackingResult track(const Frame& frame, const std::vector<TrackingMapPoint>& local_map, const SE3* prior = nullptr);
  // Restarts the motion model at a known pose (after initialisation, relocalisation, or a BA
  // correction of the last pose). Velocity is zeroed unless `T_world_prev` is given.
  void setPose(const SE3& T_world_cam, const SE3* T_world_prev = nullptr);
  SE3 predictedPose() const;
  // The map was scaled by `s` about the world origin (e.g. a metric scale from odometry): the last
  // pose's centre and the motion model's translation are scaled with it.
  void scaleMotion(double s);
  // The map was moved by the similarity `S` (a loop correction: x -> S x): the last pose moves with
  // it, the motion model's translation is scaled by its scale.
  void transformMotion(const Sim3& S);
  // The last pose set by setPose/track (identity before any).
  const SE3& lastPose() const { return last_; }
  bool hasPose() const { return has_pose_; }
  const TrackerOptions& options() const { return opt_; }

 private:
  TrackerOptions opt_;
  bool has_pose_ = false, has_velocity_ = false;
  SE3 last_, velocity_;  // velocity_ = T_prev_last (last relative motion)
};

// Projection-based matching alone (used by the tracker and the relocaliser): for every map point
// projecting into the image at T_world_cam, the best keypoint within radius * level scale.
std::vector<MapMatch> matchByProjection(const Frame& frame, const std::vector<TrackingMapPoint>& local_map,
                                        const SE3& T_world_cam, double radius_px, const TrackerOptions& options,
                                        int* num_candidates = nullptr);

// ---- Keyframe decision (PTAM criteria + ORB-SLAM tracked-points ratio) ----
struct KeyframePolicyOptions {
  int min_frames_between = 5;       // never sooner (unless tracking is weak and mapping idle)
  int max_frames_between = 30;      // always by then (if tracking is not lost)
  double min_distance_ratio = 0.1;  // distance to nearest keyframe / median scene depth
  // Inliers (all of the frame's) / the reference keyframe's established points (observed by 3
  // keyframes or more) below this, as ORB-SLAM decides. The ratio of only the inliers the reference
  // keyframe also observes to all its points sat at 0.6-0.75 one frame after a keyframe, which made
  // every frame of an offline run a keyframe (130 of 200 kept on the turntable orbit).
  double max_tracked_ratio = 0.9;
  int min_inliers = 50;  // enough inliers for the new keyframe to be useful
  // A view is "covered" when an older keyframe of the local map (not one of the newest two, which
  // exploration extends from) lies within min_distance_ratio x depth of the camera and looks the same
  // way (optical axes within this angle). While tracking is good, a covered view makes no keyframe:
  // a camera revisiting mapped space does not grow the map as fast (0 = off, the default: on the
  // synthetic room it made 20-28 % fewer keyframes and points, but the ATE of short runs worse,
  // docs/reliability.md "Standalone soak"; for long runs in one place, 8 is a good start).
  double covered_view_angle_deg = 0.0;
  double covered_min_tracked_ratio = 0.5;  // ... and tracking finds this much of the reference keyframe
  // A stopped camera: a keyframe (any, the newest included) lies within this fraction of the depth
  // and looks within stopped_view_angle_deg the same way. It then makes no keyframe, whatever the
  // other criteria say: a second keyframe at the same place adds nothing to triangulate from (a
  // camera standing still, or a driver repeating a frozen frame). 0 = off.
  double stopped_distance_ratio = 0.001;
  double stopped_view_angle_deg = 2.0;
  template <class V>
  void visit(V& v) {
    v("min_frames_between", min_frames_between, "Frames before another keyframe may be made", check::range(0, 10000));
    v("max_frames_between", max_frames_between, "Frames after which a keyframe is always made",
      check::range(1, 100000));
    v("min_distance_ratio", min_distance_ratio, "Baseline to nearest keyframe / median depth (PTAM)",
      check::nonNegative<double>());
    v("max_tracked_ratio", max_tracked_ratio,
      "Inliers / the reference keyframe's points seen by 3+ keyframes, below which a keyframe is made (ORB-SLAM)",
      check::range(0.0, 1.0));
    v("min_inliers", min_inliers, "Inliers a keyframe needs", check::range(1, 100000));
    v("covered_view_angle_deg", covered_view_angle_deg,
      "No keyframe while tracking is good and an older keyframe (not the newest two) looking within this "
      "angle is within the baseline: revisits grow the map less (0 = off; 8 for long runs in one place)",
      check::range(0.0, 180.0));
    v("covered_min_tracked_ratio", covered_min_tracked_ratio,
      "A view is covered only while tracking finds at least this fraction of the reference keyframe's points",
      check::range(0.0, 1.0));
    v("stopped_distance_ratio", stopped_distance_ratio,
      "No keyframe within this distance / median depth of a keyframe looking the same way (a stopped camera; 0 = off)",
      check::range(0.0, 1.0));
    v("stopped_view_angle_deg", stopped_view_angle_deg,
      "Optical axes within this angle count as the same way for stopped_distance_ratio", check::range(0.0, 180.0));
  }
};

struct KeyframeDecisionInput {
  TrackingQuality quality = TrackingQuality::kLost;
  int num_inliers = 0;
  int frames_since_last_keyframe = 0;
  double distance_to_nearest_keyframe = 0;  // camera centre distance, map units
  // Camera centre distance to the nearest older keyframe (not the newest two) whose optical axis is
  // within covered_view_angle_deg of the camera's (infinity when there is none).
  double distance_to_similar_view = std::numeric_limits<double>::infinity();
  // Camera centre distance to the nearest keyframe of the local map (the newest included) whose
  // optical axis is within stopped_view_angle_deg of the camera's (infinity when there is none).
  double distance_to_same_view = std::numeric_limits<double>::infinity();
  double median_scene_depth = 1;  // TrackingResult::median_depth
  // Inliers that the reference keyframe also observes (counted only for the covered-view gate).
  int tracked_reference_points = 0;
  int reference_keyframe_points = 0;  // map points the reference keyframe observes
  // Those of them observed by 3 keyframes or more (2 while the map has two): ORB-SLAM's nRefMatches,
  // which all of the frame's inliers are compared with (max_tracked_ratio).
  int reference_keyframe_established_points = 0;
  bool mapping_idle = true;  // keyframe queue empty
};

struct KeyframeDecision {
  bool insert = false;
  std::string reason;  // e.g. "baseline 0.14 > 0.10 x depth", "lost", "too soon (2 < 5 frames)"
};

KeyframeDecision decideKeyframe(const KeyframeDecisionInput& in, const KeyframePolicyOptions& options);

}  // namespace nerfslam
