#pragma once
// Trajectory accuracy metrics that reproduce the evo package (github.com/MichaelGrupp/evo, the tool
// robotics papers report ATE/RPE with) number for number:
//   associate()        = evo.core.sync.associate_trajectories
//   umeyamaAlignment() = evo.core.geometry.umeyama_alignment
//   alignTrajectory()  = PosePath3D.align (applied to the estimate)
//   computeApe()       = metrics.APE, translation part
//   rpePairs() / computeRpe() = filters.id_pairs_from_delta + metrics.RPE (translation part and
//                        rotation angle in degrees), consecutive pairs (evo's all_pairs=false)
//   computeStats()     = PE.get_all_statistics (numpy semantics: population std, median of an even
//                        count is the mean of the two middle values)
#include <Eigen/Core>
#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/io/trajectory.h"

namespace nerfslam {

struct ErrorStats {
  size_t count = 0;
  double rmse = 0, mean = 0, median = 0, std = 0, min = 0, max = 0, sse = 0;
};
// Throws an Error when `errors` is empty.
ErrorStats computeStats(const std::vector<double>& errors);

// Index pairs (ref_index[k], est_index[k]) of associated poses.
struct Association {
  std::vector<size_t> ref_index;
  std::vector<size_t> est_index;
  size_t size() const { return ref_index.size(); }
};
// evo's association: for every stamp of the trajectory with fewer poses (ref on ties) the nearest
// stamp of the other (first on ties), kept when |difference| <= max_dt. `est_time_offset` is added
// to the estimate's stamps (evo's --t_offset). Returns an empty association when nothing matches.
Association associate(const Trajectory& ref, const Trajectory& est, double max_dt, double est_time_offset = 0.0);

enum class Alignment { kNone, kSE3, kSim3, kScale };
// "none", "se3", "sim3", "scale"; throws an Error otherwise.
Alignment parseAlignment(const std::string& name);
std::string alignmentName(Alignment a);

// Least-squares y_i ~ c R x_i + t (Umeyama 1991), exactly as evo: variance normalised by n,
// covariance of y against x, reflection fixed through the sign of det(U) det(V), c = 1 unless
// `with_scale`. Throws an Error for different sizes, fewer than 3 points or a degenerate
// covariance (rank < 2).
struct UmeyamaResult {
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  double scale = 1.0;
};
UmeyamaResult umeyamaAlignment(const std::vector<Eigen::Vector3d>& x, const std::vector<Eigen::Vector3d>& y,
                               bool with_scale);

// The similarity taking the estimate onto the reference (positions of equal-length pose lists, as
// evo's align): kSE3 rotation and translation, kSim3 also scale, kScale only evo's scale factor
// (rotation and translation identity), kNone identity.
Sim3 computeAlignment(const std::vector<SE3>& ref, const std::vector<SE3>& est, Alignment alignment);
// Applies `S` to every pose: rotation composed, position s R p + t (evo's scale() + transform()).
std::vector<SE3> applyAlignment(const Sim3& S, const std::vector<SE3>& poses);

// Translation part of the APE: per pose |p_est - p_ref| (the estimate already aligned).
std::vector<double> apeTranslationErrors(const std::vector<SE3>& ref, const std::vector<SE3>& est);

enum class DeltaUnit { kFrames, kMeters };
DeltaUnit parseDeltaUnit(const std::string& name);  // "frames"/"f" or "m"/"meters"
std::string deltaUnitName(DeltaUnit u);

// evo's consecutive pairs. Frames: (0, d), (d, 2d), ... . Meters (filters.filter_pairs_by_path,
// all_pairs=false): the path is accumulated from pose 0; each index at which the path since the
// previously taken index (or since pose 0 for the first) reaches `delta` is taken, and the taken
// indices are paired consecutively — so pose 0 itself starts no pair, exactly as in evo.
std::vector<std::pair<size_t, size_t>> rpePairs(const std::vector<SE3>& poses, double delta, DeltaUnit unit);

struct RpeErrors {
  std::vector<std::pair<size_t, size_t>> pairs;
  std::vector<double> translation;   // |t(E_ij)| (m)
  std::vector<double> rotation_deg;  // angle(E_ij) (degrees)
};
// E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j), Q reference, P estimate. Pairs are chosen on the
// estimate's poses (evo's default; its stored KITTI RPE results match this) or, with
// `pairs_from_reference`, on the reference's.
// Throws an Error when no pair is found (delta too large).
RpeErrors computeRpe(const std::vector<SE3>& ref, const std::vector<SE3>& est, double delta, DeltaUnit unit,
                     bool pairs_from_reference = false);

// Sum of distances between consecutive positions (evo's path_length).
double pathLength(const std::vector<SE3>& poses);

struct TrajectoryEvalOptions {
  double max_dt = 0.02;                   // s; association tolerance
  double est_time_offset = 0.0;           // s; added to the estimate's stamps
  std::string align = "se3";              // none | se3 | sim3 | scale
  double rpe_delta = 1.0;                 // RPE step
  std::string rpe_delta_unit = "frames";  // frames | m
  bool rpe_pairs_from_reference = false;
  template <class V>
  void visit(V& v) {
    v("max_dt", max_dt, "Largest timestamp difference (s) for associating estimate and reference poses",
      check::nonNegative<double>());
    v("est_time_offset", est_time_offset, "Time offset (s) added to the estimate's timestamps",
      check::range(-1e9, 1e9));
    v("align", align, "Alignment of the estimate before computing errors",
      check::oneOf({"none", "se3", "sim3", "scale"}));
    v("rpe_delta", rpe_delta, "RPE step between pose pairs, in rpe_delta_unit", check::positive<double>());
    v("rpe_delta_unit", rpe_delta_unit, "Unit of rpe_delta: frames or m (path length)", check::oneOf({"frames", "m"}));
    v("rpe_pairs_from_reference", rpe_pairs_from_reference,
      "Choose RPE pairs on the reference instead of the estimate (evo --pairs_from_reference)");
  }
};

struct TrajectoryReport {
  size_t ref_poses = 0, est_poses = 0, matched = 0;
  double ref_t_begin = 0, ref_t_end = 0, est_t_begin = 0, est_t_end = 0;
  std::string align;
  Sim3 alignment;               // estimate -> reference
  double scale = 1.0;           // alignment.scale()
  ErrorStats ape;               // translation part (m), after alignment
  ErrorStats rpe_translation;   // m
  ErrorStats rpe_rotation_deg;  // degrees
  bool has_rpe = false;         // false when the delta admitted no pair
  double rpe_delta = 1.0;
  std::string rpe_delta_unit;
  double ref_path_length = 0;   // of the associated reference poses (m)
  double ape_rmse_percent = 0;  // ape.rmse / ref_path_length * 100 (NaN when the path length is 0)
};

// Associates, aligns (the estimate, onto the reference), and computes APE and RPE. Throws an Error
// when no poses associate (naming both timestamp ranges) or alignment has fewer than 3 pairs.
TrajectoryReport evaluateTrajectory(const Trajectory& ref, const Trajectory& est,
                                    const TrajectoryEvalOptions& options = {});

// evo_ape-style text block (and JSON) of a report.
std::string formatReport(const TrajectoryReport& report);
std::string reportToJson(const TrajectoryReport& report);

}  // namespace nerfslam
