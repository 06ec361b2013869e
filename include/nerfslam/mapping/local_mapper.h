#pragma once
// The mapping back end, run on every new keyframe (ORB-SLAM's local mapping, with Ceres BA):
//   1. cull recently created points that tracking rarely finds or that too few keyframes observe;
//   2. create points by epipolar-guided matching against the covisible neighbours (Hamming distance
//      within the epipolar band of the pose-derived fundamental matrix, mutual best, rotation
//      consistency) and checked triangulation (parallax, positive depth, reprojection);
//   3. fuse duplicates between the keyframe and its neighbours by projection;
//   4. local bundle adjustment over the keyframe's covisible window (keyframes that observe the
//      window's points but are outside it stay fixed, as does the first keyframe), outlier
//      observations removed;
//   5. cull redundant keyframes (90% of their points seen by >= 3 other keyframes).
// Works on copies of the map and publishes each step with one Map call.
#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "nerfslam/core/options.h"
#include "nerfslam/mapping/bundle_adjustment.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/mapping/odometry.h"
#include "nerfslam/mapping/triangulation.h"

namespace nerfslam {

struct MappingOptions {
  int matching_neighbours = 10;      // covisible keyframes searched for new points
  int max_descriptor_distance = 50;  // Hamming threshold for new-point matches (ORB-SLAM TH_LOW)
  double epipolar_chi2 = 3.84;       // squared epipolar distance / sigma^2 (1 dof, 95%)
  double min_parallax_deg = 1.0;     // triangulation parallax
  double max_error_sigma = 2.45;     // triangulation reprojection check (x sigma)
  double min_baseline_ratio = 0.01;  // baseline / median depth of the neighbour to try it
  double fuse_radius_px = 3.0;       // projection search radius for fusion (x level scale)
  int fuse_descriptor_distance = 50;
  int local_window = 10;         // keyframes optimised by local BA (the new one + covisibles)
  int max_fixed_keyframes = 20;  // fixed keyframes added to anchor the window
  double point_min_found_ratio = 0.25;
  int point_probation_keyframes = 3;  // a new point must be seen by >= 3 keyframes after this many
  bool cull_keyframes = true;
  double redundant_ratio = 0.9;
  int global_ba_iterations = 20;
  BundleAdjustmentOptions ba;

  template <class V>
  void visit(V& v) {
    v("matching_neighbours", matching_neighbours, "Covisible keyframes searched for new points", check::range(1, 100));
    v("max_descriptor_distance", max_descriptor_distance, "Hamming threshold for new-point matches",
      check::range(1, 256));
    v("epipolar_chi2", epipolar_chi2, "Epipolar band: squared distance / sigma^2", check::positive<double>());
    v("min_parallax_deg", min_parallax_deg, "Smallest triangulation parallax of a new point",
      check::positive<double>());
    v("max_error_sigma", max_error_sigma, "Reprojection check of new points (x keypoint sigma)",
      check::positive<double>());
    v("min_baseline_ratio", min_baseline_ratio, "Baseline / median depth below which a neighbour is skipped",
      check::nonNegative<double>());
    v("fuse_radius_px", fuse_radius_px, "Projection radius for fusing duplicates (x level scale)",
      check::positive<double>());
    v("fuse_descriptor_distance", fuse_descriptor_distance, "Hamming threshold for fusion", check::range(1, 256));
    v("local_window", local_window, "Keyframes optimised by local BA", check::range(1, 1000));
    v("max_fixed_keyframes", max_fixed_keyframes, "Fixed keyframes anchoring local BA", check::range(0, 1000));
    v("point_min_found_ratio", point_min_found_ratio, "Found/visible ratio below which a new point is culled",
      check::range(0.0, 1.0));
    v("point_probation_keyframes", point_probation_keyframes,
      "Keyframes after which a new point must have >= 3 observations", check::range(1, 100));
    v("cull_keyframes", cull_keyframes, "Remove redundant keyframes");
    v("redundant_ratio", redundant_ratio, "Fraction of a keyframe's points seen elsewhere that makes it redundant",
      check::range(0.0, 1.0));
    v("global_ba_iterations", global_ba_iterations, "Iterations of the final global BA (0: none)",
      check::range(0, 1000));
    v("ba", ba, "Bundle adjustment");
  }
};

struct MappingStats {
  int culled_points = 0;
  int new_points = 0;
  int fused_points = 0;
  int culled_keyframes = 0;
  int ba_keyframes = 0, ba_points = 0, ba_outliers = 0;
  double ba_rmse_px = 0;
  double ba_ms = 0, total_ms = 0;
};

class LocalMapper {
 public:
  LocalMapper(Map& map, MappingOptions options);
  // Runs steps 1-5 for keyframe `id` (already in the map).
  MappingStats processKeyframe(KeyframeId id);
  // Steps of processKeyframe, usable alone.
  int cullRecentPoints(KeyframeId current);
  int createNewPoints(KeyframeId id);
  int fuseWithNeighbours(KeyframeId id);
  BaResult localBundleAdjustment(KeyframeId id, int* n_keyframes = nullptr, int* n_points = nullptr);
  int cullRedundantKeyframes(KeyframeId id);
  // All keyframes and points, the first keyframe fixed.
  // should_stop: checked after every iteration; true ends the BA there (a run stopped twice).
  BaResult globalBundleAdjustment(int iterations, const std::function<bool()>& should_stop = {});
  // The same global BA, its result not written (the loop closer's background global BA writes it
  // itself): `solution` gets the free keyframes' poses, every point's position and the outlier
  // observations. Only reads the map, and records no statistics: safe beside the mapping thread.
  BaResult solveGlobalBundleAdjustment(int iterations, const std::function<bool()>& should_stop, MapUpdate* solution);
  // Points the system created outside the mapper (initialisation) enter probation too.
  void addRecentPoints(const std::vector<PointId>& ids, KeyframeId created_at);

  const MappingOptions& options() const { return opt_; }

  // Wheel odometry (mapping/odometry.h). While active (the map has the odometry's metric scale, set
  // by the system) and OdometryOptions::constrain_ba, every bundle adjustment holds the relative
  // translations of keyframes consecutive in time (at most max_pair_gap_s apart, at least one of
  // them free) to the odometry's. Set before the thread starts; activate from any thread while the
  // mapping thread is held.
  void setOdometry(std::shared_ptr<const OdometryTrack> odometry) { odometry_ = std::move(odometry); }
  void setOdometryActive(bool on) { odometry_active_.store(on, std::memory_order_release); }
  bool odometryActive() const { return odometry_active_.load(std::memory_order_acquire); }
  // Odometry residuals in the last bundle adjustment.
  int lastOdometryConstraints() const { return last_odometry_constraints_; }
  // Pairs left out of bundle adjustments so far by OdometryOptions::gate_ratio (mapping thread only).
  int64_t odometryGated() const { return odometry_gated_; }

 private:
  BaResult runBa(const std::vector<KeyframeId>& free_kfs, const std::vector<KeyframeId>& fixed_kfs,
                 const std::vector<PointId>& points, const BundleAdjustmentOptions& ba, MapUpdate* solution = nullptr);

  Map& map_;
  MappingOptions opt_;
  std::deque<std::pair<PointId, KeyframeId>> recent_;  // (point, keyframe it was created at)
  std::shared_ptr<const OdometryTrack> odometry_;
  std::atomic<bool> odometry_active_{false};
  int last_odometry_constraints_ = 0;
  int64_t odometry_gated_ = 0;
};

}  // namespace nerfslam
