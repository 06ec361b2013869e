#pragma once
// Relocalisation when tracking is lost: the frame's descriptors are matched (brute-force Hamming,
// ratio test) against the map points seen by a handful of candidate keyframes, each candidate's
// matches go through PnP-RANSAC (cv::solvePnPRansac on undistorted points), the best pose is
// refined with the robust pose optimiser and then re-tracked by projection over all candidate
// points. Keep the candidate list short (the system picks e.g. the last few / nearest keyframes).
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
};

struct RelocalizerOptions {
  int max_descriptor_distance = 80;
  double ratio = 0.8;
  int min_matches = 15;  // descriptor matches needed to try PnP on a candidate
  int min_inliers = 30;  // after refinement
  double pnp_reprojection_px = 4.0;
  int pnp_iterations = 200;
  template <class V>
  void visit(V& v) {
    v("max_descriptor_distance", max_descriptor_distance, "Largest Hamming distance of a match", check::range(1, 256));
    v("ratio", ratio, "Best/second-best distance ratio", check::range(0.1, 1.0));
    v("min_matches", min_matches, "Matches needed before PnP is tried", check::range(4, 100000));
    v("min_inliers", min_inliers, "Inliers needed to accept a relocalisation", check::range(4, 100000));
    v("pnp_reprojection_px", pnp_reprojection_px, "PnP-RANSAC reprojection threshold", check::positive<double>());
    v("pnp_iterations", pnp_iterations, "PnP-RANSAC iterations", check::range(10, 100000));
  }
};

struct RelocalizationResult {
  bool success = false;
  uint64_t keyframe_id = 0;  // candidate that gave the pose
  SE3 T_world_cam;
  std::vector<MapMatch> matches;  // inliers; point_index indexes that candidate's points
  int num_matches = 0, num_inliers = 0;
  std::string reason;
};

RelocalizationResult relocalize(const Frame& frame, const std::vector<RelocalizationCandidate>& candidates,
                                const RelocalizerOptions& options = {}, const PoseOptimizerOptions& optimizer = {});

}  // namespace nerfslam
