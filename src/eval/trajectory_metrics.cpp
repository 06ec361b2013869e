#include "nerfslam/eval/trajectory_metrics.h"

#include <fmt/format.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

bool isSorted(const std::vector<double>& v) { return std::is_sorted(v.begin(), v.end()); }

// np.argmin(|stamps - s|): the first index of the smallest difference.
size_t nearestIndex(const std::vector<double>& stamps, bool sorted, double s) {
  if (!sorted) {
    size_t best = 0;
    double best_d = std::abs(stamps[0] - s);
    for (size_t i = 1; i < stamps.size(); ++i) {
      const double d = std::abs(stamps[i] - s);
      if (d < best_d) {
        best_d = d;
        best = i;
      }
    }
    return best;
  }
  // Sorted: the minimum is at the first element >= s or at the element before it; equal stamps are
  // resolved to their first occurrence, as argmin does.
  const auto it = std::lower_bound(stamps.begin(), stamps.end(), s);
  size_t best = stamps.size();
  double best_d = std::numeric_limits<double>::infinity();
  if (it != stamps.begin()) {
    const double v = *(it - 1);
    best = static_cast<size_t>(std::lower_bound(stamps.begin(), stamps.end(), v) - stamps.begin());
    best_d = std::abs(v - s);
  }
  if (it != stamps.end()) {
    const double d = std::abs(*it - s);
    if (d < best_d) best = static_cast<size_t>(it - stamps.begin());
  }
  return best;
}

double rotationAngle(const Eigen::Quaterniond& q) { return 2.0 * std::atan2(q.vec().norm(), std::abs(q.w())); }

std::vector<SE3> posesOf(const Trajectory& t, const std::vector<size_t>& idx) {
  std::vector<SE3> out;
  out.reserve(idx.size());
  for (size_t i : idx) out.push_back(t[i].pose);
  return out;
}

}  // namespace

ErrorStats computeStats(const std::vector<double>& errors) {
  if (errors.empty()) fail("cannot compute statistics of an empty error list");
  ErrorStats s;
  s.count = errors.size();
  const double n = static_cast<double>(errors.size());
  double sum = 0, sse = 0;
  s.min = errors[0];
  s.max = errors[0];
  for (double e : errors) {
    sum += e;
    sse += e * e;
    s.min = std::min(s.min, e);
    s.max = std::max(s.max, e);
  }
  s.mean = sum / n;
  s.sse = sse;
  s.rmse = std::sqrt(sse / n);
  double var = 0;
  for (double e : errors) var += (e - s.mean) * (e - s.mean);
  s.std = std::sqrt(var / n);  // numpy.std: population standard deviation
  std::vector<double> sorted = errors;
  std::sort(sorted.begin(), sorted.end());
  const size_t m = sorted.size() / 2;
  s.median = sorted.size() % 2 == 1 ? sorted[m] : 0.5 * (sorted[m - 1] + sorted[m]);
  return s;
}

Association associate(const Trajectory& ref, const Trajectory& est, double max_dt, double est_time_offset) {
  Association a;
  if (ref.empty() || est.empty()) return a;
  // evo: the longer trajectory is searched for each stamp of the shorter one; the offset is applied
  // to the searched stamps (negated when the reference is the longer one).
  const bool est_longer = est.size() > ref.size();
  const Trajectory& shorter = est_longer ? ref : est;
  const Trajectory& longer = est_longer ? est : ref;
  const double offset = est_longer ? est_time_offset : -est_time_offset;
  std::vector<double> stamps(longer.size());
  for (size_t i = 0; i < longer.size(); ++i) stamps[i] = longer[i].timestamp + offset;
  const bool sorted = isSorted(stamps);
  for (size_t i = 0; i < shorter.size(); ++i) {
    const double s = shorter[i].timestamp;
    const size_t j = nearestIndex(stamps, sorted, s);
    if (std::abs(stamps[j] - s) <= max_dt) {
      a.ref_index.push_back(est_longer ? i : j);
      a.est_index.push_back(est_longer ? j : i);
    }
  }
  return a;
}

Alignment parseAlignment(const std::string& name) {
  if (name == "none") return Alignment::kNone;
  if (name == "se3") return Alignment::kSE3;
  if (name == "sim3") return Alignment::kSim3;
  if (name == "scale") return Alignment::kScale;
  fail("unknown alignment '{}': must be one of none, se3, sim3, scale", name);
}

std::string alignmentName(Alignment a) {
  switch (a) {
    case Alignment::kNone:
      return "none";
    case Alignment::kSE3:
      return "se3";
    case Alignment::kSim3:
      return "sim3";
    case Alignment::kScale:
      return "scale";
  }
  return "unknown";
}

UmeyamaResult umeyamaAlignment(const std::vector<Eigen::Vector3d>& x, const std::vector<Eigen::Vector3d>& y,
                               bool with_scale) {
  if (x.size() != y.size()) fail("Umeyama alignment: {} source points but {} target points", x.size(), y.size());
  const size_t n = x.size();
  if (n < 3) fail("Umeyama alignment needs at least 3 point pairs, got {}", n);
  const double inv_n = 1.0 / static_cast<double>(n);
  Eigen::Vector3d mean_x = Eigen::Vector3d::Zero(), mean_y = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < n; ++i) {
    mean_x += x[i];
    mean_y += y[i];
  }
  mean_x *= inv_n;
  mean_y *= inv_n;
  // Variance of x (eq. 36) and covariance of y against x (eq. 38), both normalised by n.
  double sigma_x = 0;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d dx = x[i] - mean_x;
    sigma_x += dx.squaredNorm();
    cov += (y[i] - mean_y) * dx.transpose();
  }
  sigma_x *= inv_n;
  cov *= inv_n;

  Eigen::JacobiSVD<Eigen::Matrix3d> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Vector3d d = svd.singularValues();
  int rank = 0;
  for (int i = 0; i < 3; ++i) rank += d(i) > std::numeric_limits<double>::epsilon() ? 1 : 0;
  if (rank < 2) fail("degenerate covariance rank {}: Umeyama alignment is not possible (points collinear?)", rank);

  // S (eq. 43): reflection correction so that R is a proper rotation.
  Eigen::Matrix3d S = Eigen::Matrix3d::Identity();
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0.0) S(2, 2) = -1.0;

  UmeyamaResult r;
  r.R = svd.matrixU() * S * svd.matrixV().transpose();                  // eq. 40
  r.scale = with_scale ? (d.asDiagonal() * S).trace() / sigma_x : 1.0;  // eq. 42
  r.t = mean_y - r.scale * r.R * mean_x;                                // eq. 41
  return r;
}

Sim3 computeAlignment(const std::vector<SE3>& ref, const std::vector<SE3>& est, Alignment alignment) {
  if (alignment == Alignment::kNone) return Sim3();
  std::vector<Eigen::Vector3d> x, y;
  x.reserve(est.size());
  y.reserve(ref.size());
  for (const auto& p : est) x.push_back(p.translation());
  for (const auto& p : ref) y.push_back(p.translation());
  const UmeyamaResult u = umeyamaAlignment(x, y, alignment != Alignment::kSE3);
  if (alignment == Alignment::kScale) return Sim3(u.scale, Eigen::Quaterniond::Identity(), Eigen::Vector3d::Zero());
  return Sim3(u.scale, Eigen::Quaterniond(u.R), u.t);
}

std::vector<SE3> applyAlignment(const Sim3& S, const std::vector<SE3>& poses) {
  std::vector<SE3> out;
  out.reserve(poses.size());
  for (const auto& p : poses) out.push_back(S.transformPose(p));
  return out;
}

std::vector<double> apeTranslationErrors(const std::vector<SE3>& ref, const std::vector<SE3>& est) {
  if (ref.size() != est.size()) fail("APE: {} reference poses but {} estimated poses", ref.size(), est.size());
  std::vector<double> e(ref.size());
  for (size_t i = 0; i < ref.size(); ++i) e[i] = (est[i].translation() - ref[i].translation()).norm();
  return e;
}

DeltaUnit parseDeltaUnit(const std::string& name) {
  if (name == "frames" || name == "f") return DeltaUnit::kFrames;
  if (name == "m" || name == "meters") return DeltaUnit::kMeters;
  fail("unknown RPE delta unit '{}': must be frames or m", name);
}

std::string deltaUnitName(DeltaUnit u) { return u == DeltaUnit::kFrames ? "frames" : "m"; }

std::vector<std::pair<size_t, size_t>> rpePairs(const std::vector<SE3>& poses, double delta, DeltaUnit unit) {
  if (!(delta > 0) || !std::isfinite(delta)) fail("RPE delta must be a positive number, got {}", delta);
  std::vector<size_t> ids;
  if (unit == DeltaUnit::kFrames) {
    if (delta != std::floor(delta)) fail("RPE delta in frames must be an integer, got {}", delta);
    const size_t step = static_cast<size_t>(delta);
    for (size_t i = 0; i < poses.size(); i += step) ids.push_back(i);
  } else {
    // filters.filter_pairs_by_path (consecutive pairs): an index is taken whenever the path since
    // the previously taken index reaches delta.
    double path = 0.0;
    for (size_t i = 0; i < poses.size(); ++i) {
      if (i > 0) path += (poses[i].translation() - poses[i - 1].translation()).norm();
      if (path >= delta) {
        ids.push_back(i);
        path = 0.0;
      }
    }
  }
  std::vector<std::pair<size_t, size_t>> pairs;
  for (size_t k = 1; k < ids.size(); ++k) pairs.emplace_back(ids[k - 1], ids[k]);
  return pairs;
}

RpeErrors computeRpe(const std::vector<SE3>& ref, const std::vector<SE3>& est, double delta, DeltaUnit unit,
                     bool pairs_from_reference) {
  if (ref.size() != est.size()) fail("RPE: {} reference poses but {} estimated poses", ref.size(), est.size());
  RpeErrors r;
  r.pairs = rpePairs(pairs_from_reference ? ref : est, delta, unit);
  if (r.pairs.empty())
    fail("RPE delta = {} ({}) produced no pose pairs among {} poses: use a smaller delta", delta, deltaUnitName(unit),
         ref.size());
  r.translation.reserve(r.pairs.size());
  r.rotation_deg.reserve(r.pairs.size());
  for (const auto& [i, j] : r.pairs) {
    const SE3 Q = ref[i].inverse() * ref[j];
    const SE3 P = est[i].inverse() * est[j];
    const SE3 E = Q.inverse() * P;
    r.translation.push_back(E.translation().norm());
    r.rotation_deg.push_back(rotationAngle(E.rotation()) * 180.0 / M_PI);
  }
  return r;
}

double pathLength(const std::vector<SE3>& poses) {
  double len = 0;
  for (size_t i = 1; i < poses.size(); ++i) len += (poses[i].translation() - poses[i - 1].translation()).norm();
  return len;
}

TrajectoryReport evaluateTrajectory(const Trajectory& ref, const Trajectory& est, const TrajectoryEvalOptions& o) {
  if (ref.empty()) fail("the reference trajectory has no poses");
  if (est.empty()) fail("the estimated trajectory has no poses");
  const Alignment align = parseAlignment(o.align);
  const DeltaUnit unit = parseDeltaUnit(o.rpe_delta_unit);
  if (!(o.max_dt >= 0)) fail("max_dt must be >= 0, got {}", o.max_dt);

  TrajectoryReport rep;
  rep.ref_poses = ref.size();
  rep.est_poses = est.size();
  auto range = [](const Trajectory& t, double& lo, double& hi) {
    lo = hi = t.front().timestamp;
    for (const auto& e : t) {
      lo = std::min(lo, e.timestamp);
      hi = std::max(hi, e.timestamp);
    }
  };
  range(ref, rep.ref_t_begin, rep.ref_t_end);
  range(est, rep.est_t_begin, rep.est_t_end);

  const Association a = associate(ref, est, o.max_dt, o.est_time_offset);
  rep.matched = a.size();
  if (a.size() == 0)
    fail(
        "no estimated pose is within {} s of a reference pose: reference timestamps span [{:.6f}, {:.6f}] "
        "({} poses), estimate timestamps span [{:.6f}, {:.6f}] ({} poses){}",
        o.max_dt, rep.ref_t_begin, rep.ref_t_end, rep.ref_poses, rep.est_t_begin, rep.est_t_end, rep.est_poses,
        o.est_time_offset != 0 ? fmt::format(" before the estimate offset of {} s", o.est_time_offset) : "");
  if (align != Alignment::kNone && a.size() < 3)
    fail("{} alignment needs at least 3 associated pose pairs, found {} (max_dt {} s)", alignmentName(align), a.size(),
         o.max_dt);

  const std::vector<SE3> ref_p = posesOf(ref, a.ref_index);
  const std::vector<SE3> est_raw = posesOf(est, a.est_index);
  rep.align = alignmentName(align);
  rep.alignment = computeAlignment(ref_p, est_raw, align);
  rep.scale = rep.alignment.scale();
  const std::vector<SE3> est_p = applyAlignment(rep.alignment, est_raw);

  rep.ape = computeStats(apeTranslationErrors(ref_p, est_p));
  rep.rpe_delta = o.rpe_delta;
  rep.rpe_delta_unit = deltaUnitName(unit);
  const auto pairs = rpePairs(o.rpe_pairs_from_reference ? ref_p : est_p, o.rpe_delta, unit);
  if (!pairs.empty()) {
    const RpeErrors r = computeRpe(ref_p, est_p, o.rpe_delta, unit, o.rpe_pairs_from_reference);
    rep.rpe_translation = computeStats(r.translation);
    rep.rpe_rotation_deg = computeStats(r.rotation_deg);
    rep.has_rpe = true;
  }
  rep.ref_path_length = pathLength(ref_p);
  // Undefined (NaN; null in JSON) for a reference that does not move.
  rep.ape_rmse_percent =
      rep.ref_path_length > 0 ? 100.0 * rep.ape.rmse / rep.ref_path_length : std::numeric_limits<double>::quiet_NaN();
  return rep;
}

namespace {

std::string alignTitle(const std::string& align) {
  if (align == "se3") return "(with SE(3) Umeyama alignment)";
  if (align == "sim3") return "(with Sim(3) Umeyama alignment)";
  if (align == "scale") return "(scale corrected)";
  return "(not aligned)";
}

std::string statsBlock(const ErrorStats& s) {
  // evo_ape prints the statistics sorted by name, right-aligned names and 6 decimals.
  return fmt::format(
      "{:>10}\t{:.6f}\n{:>10}\t{:.6f}\n{:>10}\t{:.6f}\n{:>10}\t{:.6f}\n{:>10}\t{:.6f}\n{:>10}\t{:.6f}\n{:>10}\t{:.6f}"
      "\n",
      "max", s.max, "mean", s.mean, "median", s.median, "min", s.min, "rmse", s.rmse, "sse", s.sse, "std", s.std);
}

nlohmann::json statsJson(const ErrorStats& s) {
  return {{"count", s.count}, {"rmse", s.rmse}, {"mean", s.mean}, {"median", s.median},
          {"std", s.std},     {"min", s.min},   {"max", s.max},   {"sse", s.sse}};
}

}  // namespace

std::string formatReport(const TrajectoryReport& r) {
  std::string out;
  out += fmt::format("Associated {} of {} reference / {} estimated poses\n", r.matched, r.ref_poses, r.est_poses);
  if (r.align == "sim3" || r.align == "scale") out += fmt::format("Scale correction: {:.6f}\n", r.scale);
  out += "\nAPE w.r.t. translation part (m)\n" + alignTitle(r.align) + "\n\n" + statsBlock(r.ape);
  if (r.ref_path_length > 0)
    out += fmt::format("\nreference path length {:.6f} m, APE rmse {:.4f} % of it\n", r.ref_path_length,
                       r.ape_rmse_percent);
  else
    out += "\nreference path length 0 m: APE as a percentage of it is undefined\n";
  if (r.has_rpe) {
    out += fmt::format("\nRPE w.r.t. translation part (m)\nfor delta = {} ({}) using consecutive pairs\n{}\n\n",
                       r.rpe_delta, r.rpe_delta_unit, alignTitle(r.align));
    out += statsBlock(r.rpe_translation);
    out += fmt::format("\nRPE w.r.t. rotation angle (deg)\nfor delta = {} ({}) using consecutive pairs\n{}\n\n",
                       r.rpe_delta, r.rpe_delta_unit, alignTitle(r.align));
    out += statsBlock(r.rpe_rotation_deg);
  } else {
    out += fmt::format("\nRPE: delta = {} ({}) gives no pose pairs; not computed\n", r.rpe_delta, r.rpe_delta_unit);
  }
  return out;
}

std::string reportToJson(const TrajectoryReport& r) {
  nlohmann::json j;
  j["ref_poses"] = r.ref_poses;
  j["est_poses"] = r.est_poses;
  j["matched"] = r.matched;
  j["ref_time_range"] = {r.ref_t_begin, r.ref_t_end};
  j["est_time_range"] = {r.est_t_begin, r.est_t_end};
  j["align"] = r.align;
  const Eigen::Matrix4d M = r.alignment.matrix();
  nlohmann::json rows = nlohmann::json::array();
  for (int i = 0; i < 4; ++i) rows.push_back({M(i, 0), M(i, 1), M(i, 2), M(i, 3)});
  j["alignment_matrix"] = rows;
  j["scale"] = r.scale;
  j["ape_translation_m"] = statsJson(r.ape);
  j["ref_path_length_m"] = r.ref_path_length;
  j["ape_rmse_percent_of_path"] = r.ref_path_length > 0 ? nlohmann::json(r.ape_rmse_percent) : nlohmann::json(nullptr);
  j["rpe_delta"] = r.rpe_delta;
  j["rpe_delta_unit"] = r.rpe_delta_unit;
  if (r.has_rpe) {
    j["rpe_translation_m"] = statsJson(r.rpe_translation);
    j["rpe_rotation_deg"] = statsJson(r.rpe_rotation_deg);
  } else {
    j["rpe_translation_m"] = nullptr;
    j["rpe_rotation_deg"] = nullptr;
  }
  return j.dump(2) + "\n";
}

}  // namespace nerfslam
