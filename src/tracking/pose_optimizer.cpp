#include "nerfslam/tracking/pose_optimizer.h"

#include <cmath>

#include <Eigen/Cholesky>

namespace nerfslam {

PoseOptimizationResult optimizePose(const Eigen::Matrix3d& K, const std::vector<PoseObservation>& obs,
                                    const SE3& T_world_cam_init, const PoseOptimizerOptions& opt) {
  PoseOptimizationResult res;
  res.T_world_cam = T_world_cam_init;
  const size_t n = obs.size();
  res.inlier.assign(n, 1);
  if (n < 3) {
    res.inlier.assign(n, 0);
    return res;
  }
  const double fx = K(0, 0), fy = K(1, 1), cx = K(0, 2), cy = K(1, 2);
  SE3 Tcw = T_world_cam_init.inverse();
  std::vector<char> active(n, 1);

  auto whitenedError = [&](const SE3& T, size_t i, Eigen::Vector2d* e, Eigen::Vector3d* pc) -> bool {
    *pc = T * obs[i].p_world;
    if (pc->z() <= 1e-9) return false;
    const Eigen::Vector2d proj(fx * pc->x() / pc->z() + cx, fy * pc->y() / pc->z() + cy);
    *e = (obs[i].uv - proj) / obs[i].sigma;
    return true;
  };

  for (int round = 0; round < opt.rounds; ++round) {
    const bool robust = round < opt.rounds - 1 || opt.rounds == 1;
    for (int it = 0; it < opt.iterations_per_round; ++it) {
      Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
      Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
      int used = 0;
      for (size_t i = 0; i < n; ++i) {
        if (!active[i]) continue;
        Eigen::Vector2d e;
        Eigen::Vector3d pc;
        if (!whitenedError(Tcw, i, &e, &pc)) continue;
        const double iz = 1.0 / pc.z(), iz2 = iz * iz;
        Eigen::Matrix<double, 2, 3> Jp;
        Jp << fx * iz, 0, -fx * pc.x() * iz2, 0, fy * iz, -fy * pc.y() * iz2;
        Eigen::Matrix<double, 3, 6> Jx;
        Jx.leftCols<3>().setIdentity();
        Jx.rightCols<3>() = -SE3::hat(pc);
        // e = (uv - proj(p)) / sigma  ->  de/dxi = -Jp Jx / sigma
        const Eigen::Matrix<double, 2, 6> J = -(Jp * Jx) / obs[i].sigma;
        double w = 1.0;
        if (robust) {
          const double en = e.norm();
          if (en > opt.huber_delta) w = opt.huber_delta / en;
        }
        H.noalias() += w * J.transpose() * J;
        g.noalias() += w * J.transpose() * e;
        ++used;
      }
      if (used < 3) break;
      H.diagonal().array() += 1e-9;
      const Eigen::Matrix<double, 6, 1> dx = H.ldlt().solve(-g);
      if (!dx.allFinite()) break;
      Tcw = SE3::exp(dx) * Tcw;
      if (dx.squaredNorm() < 1e-14) break;
    }
    // Re-classify every observation (outliers may come back).
    int n_in = 0;
    for (size_t i = 0; i < n; ++i) {
      Eigen::Vector2d e;
      Eigen::Vector3d pc;
      const bool ok = whitenedError(Tcw, i, &e, &pc) && e.squaredNorm() <= opt.chi2_threshold;
      active[i] = ok;
      n_in += ok;
    }
    if (n_in < 6) break;
  }
  double sq = 0;
  int n_in = 0;
  for (size_t i = 0; i < n; ++i) {
    Eigen::Vector2d e;
    Eigen::Vector3d pc;
    const bool ok = whitenedError(Tcw, i, &e, &pc) && e.squaredNorm() <= opt.chi2_threshold;
    res.inlier[i] = ok;
    if (ok) {
      ++n_in;
      sq += (e * obs[i].sigma).squaredNorm();
    }
  }
  res.num_inliers = n_in;
  res.rms_px = n_in > 0 ? std::sqrt(sq / n_in) : 0;
  res.converged = n_in >= 6;
  res.T_world_cam = Tcw.inverse();
  return res;
}

}  // namespace nerfslam
