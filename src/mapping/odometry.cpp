#include "nerfslam/mapping/odometry.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include <Eigen/Dense>

#include "nerfslam/core/error.h"

namespace nerfslam {

std::string checkRigidTransform(const std::vector<double>& m) {
  if (m.size() != 16) return fmt::format("must be 16 numbers (a 4x4 matrix, row-major), got {}", m.size());
  for (double x : m)
    if (!std::isfinite(x)) return "must be finite numbers";
  Eigen::Matrix3d R;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R(r, c) = m[4 * r + c];
  if (m[12] != 0 || m[13] != 0 || m[14] != 0 || m[15] != 1) return "is not a rigid transform: last row must be 0 0 0 1";
  const double orth = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orth > 1e-3)
    return fmt::format("is not a rigid transform: its rotation block is not orthonormal (R^T R - I up to {:.3g})",
                       orth);
  if (R.determinant() < 0) return "is not a rigid transform: its rotation block is a reflection (determinant -1)";
  return "";
}

SE3 rigidTransformFromRowMajor(const std::vector<double>& m) {
  const std::string why = checkRigidTransform(m);
  if (!why.empty()) fail("T_base_cam {}", why);
  Eigen::Matrix4d T;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) T(r, c) = m[4 * r + c];
  return SE3::fromMatrix(T);
}

OdometryTrack::OdometryTrack(Trajectory T_odom_base, const SE3& T_base_cam, std::string source,
                             const OdometryOptions& options)
    : samples_(std::move(T_odom_base)), T_base_cam_(T_base_cam), source_(std::move(source)), opt_(options) {
  if (samples_.size() < 2) fail("{}: odometry needs at least 2 samples (got {})", source_, samples_.size());
  for (size_t i = 0; i < samples_.size(); ++i) {
    const auto& s = samples_[i];
    if (!std::isfinite(s.timestamp) || !s.pose.translation().allFinite() || !s.pose.rotation().coeffs().allFinite())
      fail("{}: odometry sample {} (timestamp {}) is not finite", source_, i + 1, numberForMessage(s.timestamp));
    if (i > 0 && !(s.timestamp > samples_[i - 1].timestamp))
      fail(
          "{}: field 'timestamp' of odometry sample {}: {} does not increase (the previous sample's is {}): stamps "
          "going back",
          source_, i + 1, numberForMessage(s.timestamp, 9), numberForMessage(samples_[i - 1].timestamp, 9));
  }
}

OdometryTrack OdometryTrack::load(const std::filesystem::path& path, const OdometryOptions& options) {
  // readTumTrajectory names the file and line for NaNs, bad quaternions and columns; the constructor
  // names stamps going back by the sample's number (readTumTrajectory keeps no line numbers).
  Trajectory t = readTumTrajectory(path);
  return OdometryTrack(std::move(t), rigidTransformFromRowMajor(options.T_base_cam), path.string(), options);
}

std::optional<SE3> OdometryTrack::baseAt(double t) const {
  if (!std::isfinite(t)) return std::nullopt;
  if (t <= samples_.front().timestamp) {
    if (samples_.front().timestamp - t > opt_.max_stamp_offset_s) return std::nullopt;
    return samples_.front().pose;
  }
  if (t >= samples_.back().timestamp) {
    if (t - samples_.back().timestamp > opt_.max_stamp_offset_s) return std::nullopt;
    return samples_.back().pose;
  }
  const auto it = std::upper_bound(samples_.begin(), samples_.end(), t,
                                   [](double x, const TrajectoryEntry& e) { return x < e.timestamp; });
  const auto& b = *it;
  const auto& a = *(it - 1);
  const double dt = b.timestamp - a.timestamp;
  if (dt > opt_.max_sample_gap_s) return std::nullopt;
  return SE3::interpolate(a.pose, b.pose, (t - a.timestamp) / dt);
}

std::optional<SE3> OdometryTrack::cameraMotion(double ti, double tj) const {
  const auto a = baseAt(ti);
  const auto b = baseAt(tj);
  if (!a || !b) return std::nullopt;
  return T_base_cam_.inverse() * a->inverse() * *b * T_base_cam_;
}

namespace {

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  const size_t k = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + k, v.end());
  double m = v[k];
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), v.begin() + k));
  return m;
}

}  // namespace

ScaleEstimate estimateScale(std::vector<TimedPose> kfs, const OdometryTrack& odo, int max_pairs) {
  const OdometryOptions& o = odo.options();
  std::sort(kfs.begin(), kfs.end(), [](const TimedPose& a, const TimedPose& b) { return a.timestamp < b.timestamp; });
  struct Pair {
    double odom, map;
  };
  std::vector<Pair> pairs;
  for (size_t i = 1; i < kfs.size(); ++i) {
    if (kfs[i].timestamp - kfs[i - 1].timestamp > o.max_pair_gap_s) continue;
    const auto m = odo.cameraMotion(kfs[i - 1].timestamp, kfs[i].timestamp);
    if (!m) continue;
    const double d_odom = m->translation().norm();
    const double d_map = (kfs[i].T_world_cam.translation() - kfs[i - 1].T_world_cam.translation()).norm();
    if (d_odom < std::max(o.scale_min_pair_m, 1e-9) || !(d_map > 0)) continue;
    pairs.push_back({d_odom, d_map});
  }
  if (max_pairs > 0 && static_cast<int>(pairs.size()) > max_pairs) pairs.erase(pairs.begin(), pairs.end() - max_pairs);
  ScaleEstimate e;
  e.pairs = static_cast<int>(pairs.size());
  if (pairs.empty()) return e;
  std::vector<double> ratios;
  for (const auto& p : pairs) {
    ratios.push_back(p.odom / p.map);
    e.path_m += p.odom;
  }
  const double med = median(ratios);
  std::vector<double> dev;
  for (double r : ratios) dev.push_back(std::abs(r - med));
  const double sigma = 1.4826 * median(dev);
  e.spread = med > 0 ? sigma / med : 0;
  // Inliers within 3 robust sigmas (at least 2 % of the median, so exact data keeps every pair).
  const double tol = std::max(3.0 * sigma, 0.02 * med);
  double so = 0, sm = 0;
  for (const auto& p : pairs)
    if (std::abs(p.odom / p.map - med) <= tol) {
      so += p.odom;
      sm += p.map;
      ++e.inliers;
    }
  e.scale = sm > 0 ? so / sm : med;
  e.valid = e.pairs >= o.scale_min_pairs && e.path_m >= o.scale_min_path_m && e.inliers >= 3 && e.scale > 0 &&
            std::isfinite(e.scale);
  return e;
}

}  // namespace nerfslam
