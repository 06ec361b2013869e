#include "nerfslam/mapping/pose_graph.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <array>
#include <cmath>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

// A vertex's parameter blocks: quaternion (x y z w, Eigen's order), translation, log scale.
struct Vertex {
  std::array<double, 4> q;
  std::array<double, 3> t;
  double log_s;
};

template <typename T>
struct SimT {
  T s;
  Eigen::Quaternion<T> q;
  Eigen::Matrix<T, 3, 1> t;
  SimT inverse() const {
    const Eigen::Quaternion<T> qi = q.conjugate();
    return {T(1) / s, qi, -(qi * t) / s};
  }
  SimT operator*(const SimT& o) const { return {s * o.s, q * o.q, s * (q * o.t) + t}; }
};

struct EdgeCost {
  SimT<double> inv_meas;  // S_ij^-1
  double sqrt_w;
  template <typename T>
  bool operator()(const T* qi, const T* ti, const T* li, const T* qj, const T* tj, const T* lj, T* r) const {
    const SimT<T> Si{exp(li[0]), Eigen::Quaternion<T>(qi[3], qi[0], qi[1], qi[2]),
                     Eigen::Matrix<T, 3, 1>(ti[0], ti[1], ti[2])};
    const SimT<T> Sj{exp(lj[0]), Eigen::Quaternion<T>(qj[3], qj[0], qj[1], qj[2]),
                     Eigen::Matrix<T, 3, 1>(tj[0], tj[1], tj[2])};
    const SimT<T> M{T(inv_meas.s), inv_meas.q.cast<T>(), inv_meas.t.cast<T>()};
    const SimT<T> E = M * (Si.inverse() * Sj);
    const T qe[4] = {E.q.w(), E.q.x(), E.q.y(), E.q.z()};
    T aa[3];
    ceres::QuaternionToAngleAxis(qe, aa);
    for (int k = 0; k < 3; ++k) r[k] = T(sqrt_w) * E.t[k];
    for (int k = 0; k < 3; ++k) r[3 + k] = T(sqrt_w) * aa[k];
    r[6] = T(sqrt_w) * log(E.s);
    return true;
  }
};

}  // namespace

PoseGraphEdge measuredEdge(uint64_t i, uint64_t j, const Sim3& S_world_i, const Sim3& S_world_j, double weight,
                           PoseGraphEdgeKind kind) {
  return {i, j, S_world_i.inverse() * S_world_j, weight, kind};
}

PoseGraphResult optimizeEssentialGraph(const std::map<uint64_t, Sim3>& S_world_kf,
                                       const std::vector<PoseGraphEdge>& edges, uint64_t fixed,
                                       const PoseGraphOptions& o) {
  if (!S_world_kf.count(fixed)) fail("pose graph: the fixed vertex {} is not a vertex", fixed);
  std::map<uint64_t, Vertex> v;
  for (const auto& [id, S] : S_world_kf) {
    const Eigen::Quaterniond q = S.rotation().normalized();
    v[id] = {{q.x(), q.y(), q.z(), q.w()},
             {S.translation().x(), S.translation().y(), S.translation().z()},
             std::log(S.scale())};
  }
  ceres::Problem::Options po;
  po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  ceres::EigenQuaternionManifold quaternion;
  for (size_t e = 0; e < edges.size(); ++e) {
    const PoseGraphEdge& g = edges[e];
    const auto a = v.find(g.i), b = v.find(g.j);
    if (a == v.end() || b == v.end())
      fail("pose graph: edge {} joins {} and {}, and {} is not a vertex", e, g.i, g.j, a == v.end() ? g.i : g.j);
    if (g.i == g.j) fail("pose graph: edge {} joins vertex {} to itself", e, g.i);
    if (!(g.weight > 0) || !std::isfinite(g.weight)) fail("pose graph: edge {} has weight {}", e, g.weight);
    const Sim3 inv = g.S_ij.inverse();
    auto* cost = new EdgeCost{{inv.scale(), inv.rotation().normalized(), inv.translation()}, std::sqrt(g.weight)};
    Vertex& x = a->second;
    Vertex& y = b->second;
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<EdgeCost, 7, 4, 3, 1, 4, 3, 1>(cost), nullptr, x.q.data(),
                             x.t.data(), &x.log_s, y.q.data(), y.t.data(), &y.log_s);
  }
  for (auto& [id, x] : v) {
    if (!problem.HasParameterBlock(x.q.data())) continue;  // a vertex without edges stays as it is
    problem.SetManifold(x.q.data(), &quaternion);
    if (id == fixed) {
      problem.SetParameterBlockConstant(x.q.data());
      problem.SetParameterBlockConstant(x.t.data());
    }
    if (id == fixed || o.fix_scale) problem.SetParameterBlockConstant(&x.log_s);
  }
  PoseGraphResult res;
  if (problem.NumResidualBlocks() > 0) {
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    so.max_num_iterations = o.max_iterations;
    so.num_threads = o.threads;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    res.initial_cost = summary.initial_cost;
    res.final_cost = summary.final_cost;
    res.iterations = int(summary.iterations.size());
    res.usable = summary.IsSolutionUsable();
  } else {
    res.usable = true;
  }
  for (const auto& [id, x] : v) {
    if (!res.usable) {
      res.S_world_kf[id] = S_world_kf.at(id);
      continue;
    }
    res.S_world_kf[id] = Sim3(std::exp(x.log_s), Eigen::Quaterniond(x.q[3], x.q[0], x.q[1], x.q[2]).normalized(),
                              Eigen::Vector3d(x.t[0], x.t[1], x.t[2]));
  }
  return res;
}

SE3 correctedPose(const Sim3& S_world_kf) { return SE3(S_world_kf.rotation(), S_world_kf.translation()); }

Eigen::Vector3d correctPoint(const Eigen::Vector3d& p_world, const Sim3& before, const Sim3& after) {
  return after * (before.inverse() * p_world);
}

}  // namespace nerfslam
