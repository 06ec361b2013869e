#pragma once
// Monocular two-view map initialisation. The first frame handed in becomes the reference; its
// FAST corners are tracked frame to frame with pyramidal KLT (forward-backward check). On every
// later frame F and H are fitted in parallel (RANSAC); the model is chosen by
// R_H = S_H / (S_H + S_F) (> 0.45: homography), the pose resolved by cheirality, the inliers
// triangulated and the map scaled so the median depth in the reference camera is 1.
// Refusals (static camera, pure rotation, too little parallax, too few inliers, ambiguous
// solution) come back with success = false and a human-readable reason, also logged at info level.
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/two_view_geometry.h"

namespace nerfslam {

struct InitializerOptions {
  int min_tracked = 100;            // KLT tracks alive, else the reference is reset
  int min_inliers = 100;            // triangulated good points required
  double min_parallax_deg = 1.0;    // median triangulation angle
  double min_median_flow_px = 5.0;  // below: static camera, not even tried
  double ransac_threshold_px = 1.0;
  int ransac_iterations = 200;     // upper bound of the adaptive count (F and H each)
  double homography_ratio = 0.45;  // R_H above this: homography model
  double fb_threshold_px = 1.0;    // forward-backward KLT error
  int klt_window = 21;
  int klt_levels = 3;
  int max_tracks = 1000;           // reference corners tracked (evenly thinned, >= min_tracked); 0: all
  double min_good_fraction = 0.9;  // good points / inliers of the model, and runner-up ratio
  template <class V>
  void visit(V& v) {
    v("min_tracked", min_tracked, "KLT tracks required to keep the reference frame", check::range(8, 100000));
    v("min_inliers", min_inliers, "Triangulated points required to initialise", check::range(8, 100000));
    v("min_parallax_deg", min_parallax_deg, "Smallest median parallax accepted", check::positive<double>());
    v("min_median_flow_px", min_median_flow_px, "Median image motion below which the camera counts as static",
      check::nonNegative<double>());
    v("ransac_threshold_px", ransac_threshold_px, "RANSAC inlier threshold (pixels)", check::positive<double>());
    v("ransac_iterations", ransac_iterations, "Most RANSAC iterations per model", check::range(10, 100000));
    v("homography_ratio", homography_ratio, "R_H = S_H/(S_H+S_F) above which the homography is used",
      check::range(0.0, 1.0));
    v("fb_threshold_px", fb_threshold_px, "KLT forward-backward consistency threshold", check::positive<double>());
    v("klt_window", klt_window, "KLT window size", check::range(5, 61));
    v("klt_levels", klt_levels, "KLT pyramid levels", check::range(0, 6));
    v("max_tracks", max_tracks, "Reference corners tracked by KLT, evenly thinned (at least min_tracked; 0: all)",
      check::range(0, 100000));
    v("min_good_fraction", min_good_fraction, "Fraction of model inliers that must triangulate well",
      check::range(0.0, 1.0));
  }
};

struct InitialPoint {
  Eigen::Vector3d p_world;  // world = reference camera, scaled to median depth 1
  int ref_feature = -1;     // index into the reference frame's keypoints/descriptors
  int cur_feature = -1;     // nearest current-frame keypoint (<= 2 px, similar level), or -1
  Eigen::Vector2d uv_ref;   // distorted pixels, reference frame
  Eigen::Vector2d uv_cur;   // distorted pixels (KLT), current frame
};

struct InitializationResult {
  bool success = false;
  std::string reason;  // why it was refused (empty on success)
  std::string model;   // "fundamental" or "homography" (when a model was fitted)
  SE3 T_world_ref;     // identity
  SE3 T_world_cur;     // current camera, translation scaled with the map
  std::vector<InitialPoint> points;
  int num_tracked = 0;
  int num_inliers = 0;
  double parallax_deg = 0;  // median triangulation parallax
  double median_flow_px = 0;
  double homography_ratio = 0;
  uint64_t ref_frame_id = 0, cur_frame_id = 0;
  // Thread CPU time of this call's stages: KLT tracking, and the model fits with reconstruction.
  double klt_cpu_ms = 0, models_cpu_ms = 0;
};

class Initializer {
 public:
  explicit Initializer(InitializerOptions options = {});
  // First call sets the reference; later calls track and attempt to initialise. The frames must
  // share one camera. The reference is kept (and its tracks) until success or reset().
  InitializationResult addFrame(const Frame& frame);
  void reset();
  bool hasReference() const { return has_ref_; }
  const Frame& reference() const { return ref_; }

 private:
  // The steps of addFrame: a new reference (its corners to track, evenly thinned); KLT of the live
  // tracks into `frame` with a forward-backward check (prev_pts_ and track_ref_index_ become the
  // tracks that survive); the two-view models, the pose and the triangulated points from the ideal
  // pixels x1 (reference) <-> x2 (frame) of those tracks, into `r` (or why not); the initial points
  // with their nearest keypoints in `frame`.
  InitializationResult setReference(const Frame& frame, InitializationResult r);
  void trackCorners(const Frame& frame);
  std::optional<std::string> reconstruct(const Frame& frame, const Points2d& x1, const Points2d& x2,
                                         InitializationResult& r) const;
  std::vector<InitialPoint> initialPoints(const Frame& frame, const Reconstruction& rec, double scale) const;

  InitializerOptions opt_;
  bool has_ref_ = false;
  Frame ref_;
  // KLT pyramid of the previous frame with its derivatives (cv::buildOpticalFlowPyramid), built once
  // per frame and used by both the forward and the backward pass.
  std::vector<cv::Mat> prev_pyr_;
  std::vector<cv::Point2f> prev_pts_;
  std::vector<int> track_ref_index_;  // reference keypoint index per live track
};

}  // namespace nerfslam
