#pragma once
// Wheel odometry for a monocular map: metric scale and less scale drift.
//
// The odometry is the pose of the robot's base in its odom frame over time (T_odom_base, e.g. the
// TUM file `run --odometry FILE` reads) and the camera is rigidly mounted on the base
// (T_base_cam, OdometryOptions::T_base_cam). Between two keyframes at times ti and tj it predicts
// the camera's motion in metres, T_ci_cj = T_base_cam^-1 T_odom_base(ti)^-1 T_odom_base(tj) T_base_cam.
//
//   estimateScale   the map's scale from keyframe-to-keyframe translations: for every pair of
//                   consecutive keyframes whose odometry moved at least scale_min_pair_m, the ratio
//                   |t_odometry| / |t_map|; the median, then the ratios within 3 robust standard
//                   deviations (MAD) of it are pooled as sum |t_odometry| / sum |t_map| (a slipping
//                   wheel's pairs are outliers). Valid once scale_min_pairs pairs and
//                   scale_min_path_m of odometry path are seen; no rotation-only start is needed.
//   the system applies the estimate to the map once as a Sim(3) (SlamSystem, Map::transform); from
//   then on local and global bundle adjustment hold consecutive keyframes' relative translations to
//   the odometry's (BaProblem::RelativeTranslation; sigma = translation_noise x |t| + min_sigma_m,
//   Huber loss at huber_sigma), except pairs whose odometry distance differs from the map's by more
//   than gate_ratio (a slipping wheel).
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/io/trajectory.h"

namespace nerfslam {

// Checks 16 numbers as a rigid 4x4 transform (row-major): rotation block orthonormal with
// determinant +1 within 1e-3, last row 0 0 0 1, all finite. "" when valid, else the reason.
std::string checkRigidTransform(const std::vector<double>& m);
// The transform of 16 valid numbers (checkRigidTransform), its rotation re-orthonormalised.
SE3 rigidTransformFromRowMajor(const std::vector<double>& m);

struct OdometryOptions {
  // The camera's pose in the base frame (4x4 row-major; the identity: the camera is the base).
  std::vector<double> T_base_cam = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  double translation_noise = 0.02;  // odometry's relative translation error (sigma / distance)
  double min_sigma_m = 0.005;       // sigma floor of a relative translation (m)
  double huber_sigma = 2.0;         // Huber loss width of the odometry residuals (sigmas)
  double gate_ratio = 0.1;          // pairs whose odometry and map distances differ more are left out of BA
  bool constrain_ba = true;         // after the scale: relative-translation constraints in BA
  double scale_min_path_m = 1.0;    // odometry path over usable pairs before the scale is estimated
  int scale_min_pairs = 8;          // usable keyframe pairs before the scale is estimated
  double scale_min_pair_m = 0.02;   // pairs whose odometry moved less are not used for the scale
  double max_pair_gap_s = 3.0;      // keyframes further apart in time are not paired
  double max_sample_gap_s = 0.5;    // odometry samples further apart than this do not interpolate
  double max_stamp_offset_s = 0.1;  // a keyframe this far outside the odometry's time span gets none

  template <class V>
  void visit(V& v) {
    v("T_base_cam", T_base_cam,
      "The camera's pose in the odometry's base frame: a rigid 4x4 transform, 16 numbers row-major",
      Check<std::vector<double>>(checkRigidTransform));
    v("translation_noise", translation_noise,
      "Relative translation error of the odometry between keyframes (sigma / distance)", check::range(1e-4, 1.0));
    v("min_sigma_m", min_sigma_m, "Smallest sigma of an odometry relative translation (m)", check::positive<double>());
    v("huber_sigma", huber_sigma, "Huber loss width of the odometry residuals in bundle adjustment (sigmas)",
      check::positive<double>());
    v("gate_ratio", gate_ratio,
      "Keyframe pairs whose odometry distance differs from the map's by more than this fraction (at least 3 "
      "min_sigma_m) are left out of bundle adjustment (wheel slip)",
      check::range(0.0, 10.0));
    v("constrain_ba", constrain_ba,
      "Once the scale is applied: consecutive keyframes' relative translations held to the odometry's in bundle "
      "adjustment");
    v("scale_min_path_m", scale_min_path_m, "Odometry path (m) over usable keyframe pairs before the scale is set",
      check::range(0.0, 1e6));
    v("scale_min_pairs", scale_min_pairs, "Usable keyframe pairs before the scale is set", check::range(3, 100000));
    v("scale_min_pair_m", scale_min_pair_m,
      "Keyframe pairs whose odometry moved less (m) are not used to estimate the scale", check::range(0.0, 1e6));
    v("max_pair_gap_s", max_pair_gap_s, "Keyframes further apart in time (s) are not paired",
      check::positive<double>());
    v("max_sample_gap_s", max_sample_gap_s, "Odometry samples further apart in time (s) are not interpolated between",
      check::positive<double>());
    v("max_stamp_offset_s", max_stamp_offset_s,
      "A keyframe this far (s) outside the odometry's time span gets no odometry", check::nonNegative<double>());
  }
};

// The odometry of a run: T_odom_base samples (strictly increasing stamps) and the extrinsic.
class OdometryTrack {
 public:
  // Throws an Error naming `source` for fewer than 2 samples, stamps that do not increase (naming
  // the sample), or non-finite values.
  OdometryTrack(Trajectory T_odom_base, const SE3& T_base_cam, std::string source, const OdometryOptions& options);
  // Reads a TUM file (io/trajectory.h's checks: NaNs, bad quaternions) and checks it as above,
  // naming the file and line.
  static OdometryTrack load(const std::filesystem::path& path, const OdometryOptions& options);

  // T_odom_base at `t`, interpolated (SE3::interpolate); none outside the samples (beyond
  // max_stamp_offset_s: the end sample within it) or across a gap > max_sample_gap_s.
  std::optional<SE3> baseAt(double t) const;
  // The camera's motion T_ci_cj (metres) between times ti and tj; none when either has no odometry.
  std::optional<SE3> cameraMotion(double ti, double tj) const;

  double beginTime() const { return samples_.front().timestamp; }
  double endTime() const { return samples_.back().timestamp; }
  size_t size() const { return samples_.size(); }
  const std::string& source() const { return source_; }
  const SE3& T_base_cam() const { return T_base_cam_; }
  const OdometryOptions& options() const { return opt_; }

 private:
  Trajectory samples_;
  SE3 T_base_cam_;
  std::string source_;
  OdometryOptions opt_;
};

struct TimedPose {
  double timestamp = 0;
  SE3 T_world_cam;
};

struct ScaleEstimate {
  bool valid = false;  // enough pairs and path (OdometryOptions::scale_min_*)
  double scale = 1.0;  // metres per map unit
  int pairs = 0;       // usable pairs
  int inliers = 0;     // pairs pooled after the MAD test
  double path_m = 0;   // odometry path over the usable pairs
  double spread = 0;   // robust relative standard deviation of the pairs' ratios (1.4826 MAD / median)
};

// The scale from consecutive `keyframes` (sorted by time here; only the last `max_pairs` pairs
// when > 0).
ScaleEstimate estimateScale(std::vector<TimedPose> keyframes, const OdometryTrack& odometry, int max_pairs = 0);

}  // namespace nerfslam
