#pragma once
// Relocalisation when tracking is lost, verified as ORB-SLAM's Tracking::Relocalization does: for
// each candidate keyframe, the frame's descriptors are matched (brute-force Hamming, ratio test)
// against the map points the keyframe sees, the matches go through PnP-RANSAC (cv::solvePnPRansac on
// undistorted points) and the robust pose optimiser; when that leaves fewer than
// guided_search_below inliers, the points of the keyframe and of its covisible neighbours
// (`neighbours`) are projected with that pose to add matches (a wide window, then a narrow one) and
// the pose is optimised again. A candidate is accepted with min_inliers inliers or more, and of the
// accepted ones the one with the most inliers wins (not the first). Keep the candidate list short:
// the cost is per candidate and does not grow with the map.
#include <cstdint>
#include <string>
#include <vector>

#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/tracker.h"

namespace nerfslam {

struct RelocalizationCandidate {
  uint64_t keyframe_id = 0;
  SE3 T_world_cam;                       // the keyframe pose (for logging and ordering only)
  std::vector<TrackingMapPoint> points;  // map points the keyframe observes, with descriptors
  // Points of its best covisible keyframes that it does not observe itself (guided search only).
  std::vector<TrackingMapPoint> neighbours;
};

struct RelocalizerOptions {
  int max_descriptor_distance = 80;
  double ratio = 0.8;
  int min_matches = 15;  // descriptor matches needed to try PnP on a candidate
  int min_inliers = 50;  // after refinement (ORB-SLAM's 50)
  double pnp_reprojection_px = 4.0;
  int pnp_iterations = 200;
  int guided_search_below = 50;        // fewer inliers after PnP: search by projection for more
  double guided_radius_px = 10.0;      // its first window (level-0 px, x level scale)
  double guided_fine_radius_px = 3.0;  // the second, when the first left 30..guided_search_below
  int guided_max_descriptor_distance = 100;
  template <class V>
  void visit(V& v) {
    v("max_descriptor_distance", max_descriptor_distance, "Largest Hamming distance of a match", check::range(1, 256));
    v("ratio", ratio, "Best/second-best distance ratio", check::range(0.1, 1.0));
    v("min_matches", min_matches, "Matches needed before PnP is tried", check::range(4, 100000));
    v("min_inliers", min_inliers, "Inliers needed to accept a relocalisation", check::range(4, 100000));
    v("pnp_reprojection_px", pnp_reprojection_px, "PnP-RANSAC reprojection threshold", check::positive<double>());
    v("pnp_iterations", pnp_iterations, "PnP-RANSAC iterations", check::range(10, 100000));
    v("guided_search_below", guided_search_below,
      "Fewer inliers than this after PnP: project the candidate's and its covisible keyframes' points for more",
      check::range(0, 100000));
    v("guided_radius_px", guided_radius_px, "Window of the first guided search by projection (pixels)",
      check::positive<double>());
    v("guided_fine_radius_px", guided_fine_radius_px, "Window of the second, narrower guided search (pixels)",
      check::positive<double>());
    v("guided_max_descriptor_distance", guided_max_descriptor_distance,
      "Largest Hamming distance of a match found by the guided search", check::range(1, 256));
  }
};

struct RelocalizationResult {
  bool success = false;
  uint64_t keyframe_id = 0;  // candidate that gave the pose
  SE3 T_world_cam;
  // Inliers; point_index indexes that candidate's points followed by its neighbours.
  std::vector<MapMatch> matches;
  int num_matches = 0, num_inliers = 0;
  std::string reason;
};

RelocalizationResult relocalize(const Frame& frame, const std::vector<RelocalizationCandidate>& candidates,
                                const RelocalizerOptions& options = {}, const PoseOptimizerOptions& optimizer = {});

}  // namespace nerfslam
