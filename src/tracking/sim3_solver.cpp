#include "nerfslam/tracking/sim3_solver.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <algorithm>
#include <cmath>
#include <random>

#include <Eigen/SVD>

#include "nerfslam/tracking/two_view_geometry.h"

namespace nerfslam {
namespace {

bool projectIdeal(const Camera& c, const Eigen::Vector3d& p, Eigen::Vector2d* uv) {
  if (!(p.z() > 1e-9)) return false;
  *uv = Eigen::Vector2d(c.fx * p.x() / p.z() + c.cx, c.fy * p.y() / p.z() + c.cy);
  return true;
}

// Reprojection residuals of one pair in both keyframes; parameters: quaternion (x y z w, Eigen's
// order), translation, log scale of S12.
struct PairCost {
  Sim3Match m;
  double f1[4], f2[4];
  template <typename T>
  bool operator()(const T* q, const T* t, const T* log_s, T* r) const {
    const Eigen::Quaternion<T> Q(q[3], q[0], q[1], q[2]);
    const Eigen::Matrix<T, 3, 1> tt(t[0], t[1], t[2]);
    const T s = exp(log_s[0]);
    const Eigen::Matrix<T, 3, 1> a = s * (Q * m.p2.cast<T>()) + tt;                // into keyframe 1
    const Eigen::Matrix<T, 3, 1> b = (Q.conjugate() * (m.p1.cast<T>() - tt)) / s;  // into keyframe 2
    const T za = a.z() > T(1e-6) ? a.z() : T(1e-6), zb = b.z() > T(1e-6) ? b.z() : T(1e-6);
    r[0] = (f1[0] * a.x() / za + f1[2] - m.uv1.x()) / m.sigma1;
    r[1] = (f1[1] * a.y() / za + f1[3] - m.uv1.y()) / m.sigma1;
    r[2] = (f2[0] * b.x() / zb + f2[2] - m.uv2.x()) / m.sigma2;
    r[3] = (f2[1] * b.y() / zb + f2[3] - m.uv2.y()) / m.sigma2;
    return true;
  }
};

}  // namespace

std::optional<Sim3> alignPoints(const std::vector<Eigen::Vector3d>& p1, const std::vector<Eigen::Vector3d>& p2,
                                bool fix_scale) {
  const size_t n = p1.size();
  if (n < 3 || p2.size() != n) return std::nullopt;
  Eigen::Vector3d c1 = Eigen::Vector3d::Zero(), c2 = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < n; ++i) c1 += p1[i], c2 += p2[i];
  c1 /= double(n);
  c2 /= double(n);
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();  // sum (p1 - c1)(p2 - c2)^T
  double var2 = 0;
  for (size_t i = 0; i < n; ++i) {
    H += (p1[i] - c1) * (p2[i] - c2).transpose();
    var2 += (p2[i] - c2).squaredNorm();
  }
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Vector3d sv = svd.singularValues();
  // Collinear points (or all in one spot) leave the rotation about their line undetermined.
  if (!(var2 > 1e-18) || sv(1) < 1e-9 * std::max(1e-300, sv(0))) return std::nullopt;
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1;  // no reflection
  const Eigen::Matrix3d R = svd.matrixU() * D * svd.matrixV().transpose();
  const double s = fix_scale ? 1.0 : (sv.asDiagonal() * D).trace() / var2;
  if (!(s > 0) || !std::isfinite(s)) return std::nullopt;
  const Eigen::Vector3d t = c1 - s * R * c2;
  return Sim3(s, Eigen::Quaterniond(R), t);
}

bool sim3Inlier(const Sim3Match& m, const Sim3& S12, const Camera& c1, const Camera& c2, double chi2) {
  Eigen::Vector2d uv;
  if (!projectIdeal(c1, S12 * m.p2, &uv) || (uv - m.uv1).squaredNorm() > chi2 * m.sigma1 * m.sigma1) return false;
  if (!projectIdeal(c2, S12.inverse() * m.p1, &uv) || (uv - m.uv2).squaredNorm() > chi2 * m.sigma2 * m.sigma2)
    return false;
  return true;
}

Sim3 refineSim3(const std::vector<Sim3Match>& matches, const std::vector<bool>& inlier, const Sim3& S12,
                const Camera& c1, const Camera& c2, double chi2, bool fix_scale) {
  const Eigen::Quaterniond q0 = S12.rotation().normalized();
  double q[4] = {q0.x(), q0.y(), q0.z(), q0.w()};
  double t[3] = {S12.translation().x(), S12.translation().y(), S12.translation().z()};
  double log_s = std::log(S12.scale());
  ceres::Problem problem;
  int used = 0;
  for (size_t i = 0; i < matches.size(); ++i) {
    if (!inlier[i]) continue;
    auto* cost = new PairCost{matches[i], {c1.fx, c1.fy, c1.cx, c1.cy}, {c2.fx, c2.fy, c2.cx, c2.cy}};
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<PairCost, 4, 4, 3, 1>(cost),
                             new ceres::HuberLoss(std::sqrt(chi2)), q, t, &log_s);
    ++used;
  }
  if (used < 3) return S12;
  problem.SetManifold(q, new ceres::EigenQuaternionManifold);
  if (fix_scale) problem.SetParameterBlockConstant(&log_s);
  ceres::Solver::Options opts;
  opts.linear_solver_type = ceres::DENSE_QR;
  opts.max_num_iterations = 20;
  opts.num_threads = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(opts, &problem, &summary);
  return Sim3(std::exp(log_s), Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized(),
              Eigen::Vector3d(t[0], t[1], t[2]));
}

Sim3Result solveSim3(const std::vector<Sim3Match>& matches, const Camera& c1, const Camera& c2,
                     const Sim3SolverOptions& o) {
  Sim3Result res;
  const size_t n = matches.size();
  res.inlier.assign(n, false);
  if (n < 3 || n < size_t(std::max(3, o.min_inliers))) return res;
  std::mt19937_64 rng(o.seed);
  std::vector<bool> in(n);
  int max_iterations = o.max_iterations;
  for (int it = 0; it < max_iterations; ++it) {
    ++res.iterations;
    size_t idx[3];
    for (int k = 0; k < 3; ++k) {
      bool repeat;
      do {
        idx[k] = size_t(rng() % n);
        repeat = false;
        for (int j = 0; j < k; ++j) repeat |= idx[j] == idx[k];
      } while (repeat);
    }
    const auto S = alignPoints({matches[idx[0]].p1, matches[idx[1]].p1, matches[idx[2]].p1},
                               {matches[idx[0]].p2, matches[idx[1]].p2, matches[idx[2]].p2}, o.fix_scale);
    if (!S) continue;
    int count = 0;
    for (size_t i = 0; i < n; ++i) count += (in[i] = sim3Inlier(matches[i], *S, c1, c2, o.chi2)) ? 1 : 0;
    if (count > res.ransac_inliers) {
      res.ransac_inliers = count;
      res.S12 = *S;
      res.inlier = in;
      // Samples needed for `probability` at this inlier ratio.
      const double w = double(count) / double(n);
      if (w >= 1.0) break;
      max_iterations = ransacIterations(w, 3, o.probability, o.max_iterations);
    }
  }
  if (res.ransac_inliers < o.min_inliers) return res;
  if (o.refine) {
    // Two rounds as ORB-SLAM: refine on the RANSAC inliers, reclassify every pair, refine again.
    for (int round = 0; round < 2; ++round) {
      const Sim3 S = refineSim3(matches, res.inlier, res.S12, c1, c2, o.chi2, o.fix_scale);
      std::vector<bool> in2(n);
      int count = 0;
      for (size_t i = 0; i < n; ++i) count += (in2[i] = sim3Inlier(matches[i], S, c1, c2, o.chi2)) ? 1 : 0;
      if (count < o.min_inliers) break;  // keep the previous estimate
      res.S12 = S;
      res.inlier = std::move(in2);
    }
  }
  res.inliers = int(std::count(res.inlier.begin(), res.inlier.end(), true));
  res.ok = res.inliers >= o.min_inliers;
  return res;
}

}  // namespace nerfslam
