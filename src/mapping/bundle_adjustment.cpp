#include "nerfslam/mapping/bundle_adjustment.h"

#include <ceres/ceres.h>
#include <ceres/product_manifold.h>
#include <ceres/rotation.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <deque>
#include <limits>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

// Reprojection residual with hand-derived Jacobians. pose = (qw qx qy qz tx ty tz) of T_cam_world.
// For a unit quaternion q = (w, v): R p = (w^2 - v.v) p + 2 (v.p) v + 2 w (v x p), so
//   d(Rp)/dw = 2 (w p + v x p),  d(Rp)/dv = 2 (v p^T - p v^T + (v.p) I - w [p]x).
// The radial part of this derivative differs from that of the normalised rotation, but the
// quaternion manifold's plus-Jacobian is tangent to the unit sphere, so the projected Jacobian is exact.
class ReprojectionCost final : public ceres::SizedCostFunction<2, 7, 3> {
 public:
  ReprojectionCost(const Eigen::Vector2d& uv, double sigma, double fx, double fy, double cx, double cy)
      : u_(uv.x()), v_(uv.y()), inv_sigma_(1.0 / sigma), fx_(fx), fy_(fy), cx_(cx), cy_(cy) {}

  // An observation classified as an outlier between the two solves contributes nothing (zero
  // residual and Jacobian), so the second solve reuses the problem instead of rebuilding it.
  void disable() { disabled_ = true; }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    if (disabled_) {
      residuals[0] = residuals[1] = 0;
      if (jacobians && jacobians[0]) std::fill(jacobians[0], jacobians[0] + 14, 0.0);
      if (jacobians && jacobians[1]) std::fill(jacobians[1], jacobians[1] + 6, 0.0);
      return true;
    }
    const double* x = parameters[0];
    const Eigen::Map<const Eigen::Vector3d> pw(parameters[1]);
    const double qn = std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3]);
    const double w = x[0] / qn;
    const Eigen::Vector3d v(x[1] / qn, x[2] / qn, x[3] / qn);
    const Eigen::Vector3d vxp = v.cross(pw);
    const double vp = v.dot(pw);
    const Eigen::Vector3d P =
        (w * w - v.squaredNorm()) * pw + 2.0 * vp * v + 2.0 * w * vxp + Eigen::Vector3d(x[4], x[5], x[6]);
    const bool clamped = P.z() < 1e-9;
    const double z = clamped ? 1e-9 : P.z();
    const double iz = 1.0 / z;
    residuals[0] = (fx_ * P.x() * iz + cx_ - u_) * inv_sigma_;
    residuals[1] = (fy_ * P.y() * iz + cy_ - v_) * inv_sigma_;
    if (!jacobians || (!jacobians[0] && !jacobians[1])) return true;
    Eigen::Matrix<double, 2, 3> dr_dP;
    dr_dP << fx_ * iz, 0, clamped ? 0.0 : -fx_ * P.x() * iz * iz, 0, fy_ * iz, clamped ? 0.0 : -fy_ * P.y() * iz * iz;
    dr_dP *= inv_sigma_;
    if (jacobians[0]) {
      Eigen::Map<Eigen::Matrix<double, 2, 7, Eigen::RowMajor>> J(jacobians[0]);
      Eigen::Matrix<double, 3, 4> dP_dq;
      dP_dq.col(0) = 2.0 * (w * pw + vxp);
      Eigen::Matrix3d px;
      px << 0, -pw.z(), pw.y(), pw.z(), 0, -pw.x(), -pw.y(), pw.x(), 0;
      dP_dq.rightCols<3>() =
          2.0 * (v * pw.transpose() - pw * v.transpose() + vp * Eigen::Matrix3d::Identity() - w * px);
      J.leftCols<4>() = dr_dP * dP_dq;
      J.rightCols<3>() = dr_dP;
    }
    if (jacobians[1]) {
      Eigen::Map<Eigen::Matrix<double, 2, 3, Eigen::RowMajor>> J(jacobians[1]);
      const Eigen::Quaterniond q(w, v.x(), v.y(), v.z());
      J = dr_dP * q.toRotationMatrix();
    }
    return true;
  }

 private:
  double u_, v_, inv_sigma_, fx_, fy_, cx_, cy_;
  bool disabled_ = false;
};

// (R_i c_j + t_i - t_ij) / sigma with poses (q, t) of T_cam_world: R_i (c_j - c_i) = R_i c_j + t_i and
// c_j = -R_j^T t_j.
struct RelativeTranslationResidual {
  RelativeTranslationResidual(const Eigen::Vector3d& t_ij, double sigma) : t_ij_(t_ij), inv_sigma_(1.0 / sigma) {}
  template <typename T>
  bool operator()(const T* xi, const T* xj, T* r) const {
    const T qj_inv[4] = {xj[0], -xj[1], -xj[2], -xj[3]};
    const T tj[3] = {xj[4], xj[5], xj[6]};
    T cj[3];
    ceres::QuaternionRotatePoint(qj_inv, tj, cj);  // R_j^T t_j (normalises q)
    for (int k = 0; k < 3; ++k) cj[k] = -cj[k];
    T p[3];
    ceres::QuaternionRotatePoint(xi, cj, p);
    for (int k = 0; k < 3; ++k) r[k] = (p[k] + xi[4 + k] - T(t_ij_[k])) * T(inv_sigma_);
    return true;
  }
  Eigen::Vector3d t_ij_;
  double inv_sigma_;
};

constexpr int kDenseSchurMaxCameras = 40;

using PoseManifold = ceres::ProductManifold<ceres::QuaternionManifold, ceres::EuclideanManifold<3>>;

void toParamsImpl(const SE3& T_world_cam, double* x) {
  const SE3 T_cam_world = T_world_cam.inverse();
  const Eigen::Quaterniond& q = T_cam_world.rotation();
  x[0] = q.w();
  x[1] = q.x();
  x[2] = q.y();
  x[3] = q.z();
  x[4] = T_cam_world.translation().x();
  x[5] = T_cam_world.translation().y();
  x[6] = T_cam_world.translation().z();
}

SE3 fromParamsImpl(const double* x) {
  const Eigen::Quaterniond q(x[0], x[1], x[2], x[3]);
  return SE3(q.normalized(), Eigen::Vector3d(x[4], x[5], x[6])).inverse();
}

double obsError(const double* pose, const double* point, const BaProblem& pb, const BaProblem::Observation& o) {
  double p[3];
  ceres::QuaternionRotatePoint(pose, point, p);
  p[0] += pose[4];
  p[1] += pose[5];
  p[2] += pose[6];
  if (!(p[2] > 1e-9)) return std::numeric_limits<double>::infinity();
  const double du = pb.fx * p[0] / p[2] + pb.cx - o.uv.x();
  const double dv = pb.fy * p[1] / p[2] + pb.cy - o.uv.y();
  return std::sqrt(du * du + dv * dv);
}

}  // namespace

void poseToParams(const SE3& T_world_cam, double* x) { toParamsImpl(T_world_cam, x); }
SE3 poseFromParams(const double* x) { return fromParamsImpl(x); }
std::unique_ptr<ceres::Manifold> makePoseManifold() { return std::make_unique<PoseManifold>(); }
std::unique_ptr<ceres::CostFunction> makeReprojectionCost(const Eigen::Vector2d& uv, double sigma, double fx, double fy,
                                                          double cx, double cy) {
  return std::make_unique<ReprojectionCost>(uv, sigma, fx, fy, cx, cy);
}

std::unique_ptr<ceres::CostFunction> makeRelativeTranslationCost(const Eigen::Vector3d& t_ij, double sigma) {
  return std::make_unique<ceres::AutoDiffCostFunction<RelativeTranslationResidual, 3, 7, 7>>(
      new RelativeTranslationResidual(t_ij, sigma));
}

double reprojectionError(const BaProblem& problem, const BaProblem::Observation& obs) {
  double x[7];
  poseToParams(problem.cameras.at(obs.camera).T_world_cam, x);
  return obsError(x, problem.points.at(obs.point).position.data(), problem, obs);
}

namespace {

void validateObservations(const BaProblem& pb) {
  const int nc = static_cast<int>(pb.cameras.size());
  const int np = static_cast<int>(pb.points.size());
  for (const auto& o : pb.observations) {
    if (o.camera < 0 || o.camera >= nc || o.point < 0 || o.point >= np)
      fail("bundle adjustment: observation refers to camera {} / point {} of {} / {}", o.camera, o.point, nc, np);
    if (!(o.sigma > 0) || !o.uv.allFinite()) fail("bundle adjustment: invalid observation (sigma {})", o.sigma);
  }
  for (const auto& r : pb.relative_translations) {
    if (r.camera_i < 0 || r.camera_i >= nc || r.camera_j < 0 || r.camera_j >= nc || r.camera_i == r.camera_j)
      fail("bundle adjustment: relative translation between cameras {} and {} of {}", r.camera_i, r.camera_j, nc);
    if (!(r.sigma > 0) || !(r.huber > 0) || !r.t_ij.allFinite())
      fail("bundle adjustment: invalid relative translation (sigma {}, huber {})", r.sigma, r.huber);
  }
}

// One Ceres problem for both solves. The cost functions live in `costs_` (one allocation per chunk,
// not owned by Ceres: no per-block new/delete and ownership bookkeeping); outliers found after the
// first solve are disabled in place. Inputs are validated before (validateObservations), so Ceres'
// own per-block safety checks are skipped.
ceres::Problem::Options problemOptions() {
  ceres::Problem::Options popt;
  popt.manifold_ownership = ceres::TAKE_OWNERSHIP;
  popt.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  popt.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  popt.disable_all_safety_checks = true;
  return popt;
}

ceres::Solver::Options solverOptions(const BundleAdjustmentOptions& opt, int iterations, int free_cams) {
  ceres::Solver::Options so;
  // A local window has few cameras: the reduced camera system (6 x free cameras squared) is small
  // and dense, where DENSE_SCHUR beats SPARSE_SCHUR (bench_mapping_ba: 226 vs 284 ms CPU at 2000
  // points, 10 free cameras; ITERATIVE_SCHUR with SCHUR_JACOBI was slower still).
  so.linear_solver_type = free_cams <= kDenseSchurMaxCameras ? ceres::DENSE_SCHUR : ceres::SPARSE_SCHUR;
  so.max_num_iterations = iterations;
  // Ceres' default function tolerance (1e-6) spends half of a local BA's iterations on cost changes
  // far below the pixel noise: the default 1e-3 takes bench_mapping_ba (2000 points) from 12 to 5
  // iterations, free-camera error 1.11 -> 1.13 mm, final RMSE 1.233 -> 1.232 px.
  so.function_tolerance = opt.function_tolerance;
  so.num_threads = opt.num_threads;
  so.max_solver_time_in_seconds = opt.max_solver_time_s;
  so.minimizer_progress_to_stdout = false;
  so.logging_type = ceres::SILENT;
  return so;
}

// Ends a solve after the iteration in which should_stop() became true (USER_SUCCESS: Ceres keeps
// the parameters of the last successful step).
class StopCallback : public ceres::IterationCallback {
 public:
  explicit StopCallback(const std::function<bool()>& should_stop) : should_stop_(should_stop) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary&) override {
    return should_stop_ && should_stop_() ? ceres::SOLVER_TERMINATE_SUCCESSFULLY : ceres::SOLVER_CONTINUE;
  }

 private:
  const std::function<bool()>& should_stop_;
};

// The steps of bundleAdjust on one validated problem: its parameters (poses as in poseToParams,
// points), the Ceres problem over the inlier observations and the classification in res_.inlier.
class BundleAdjuster {
 public:
  BundleAdjuster(BaProblem& pb, const BundleAdjustmentOptions& opt)
      : pb_(pb),
        opt_(opt),
        nc_(static_cast<int>(pb.cameras.size())),
        np_(static_cast<int>(pb.points.size())),
        poses_(nc_),
        pts_(np_),
        huber_(opt.huber_px),
        problem_(problemOptions()),
        cost_of_(pb.observations.size(), nullptr),
        cam_used_(nc_, false),
        pt_used_(np_, false) {
    res_.inlier.assign(pb_.observations.size(), true);
    for (int i = 0; i < nc_; ++i) poseToParams(pb_.cameras[i].T_world_cam, poses_[i].data());
    for (int i = 0; i < np_; ++i) pts_[i] = pb_.points[i].position;
  }

  BaResult run() {
    res_.initial_rmse_px = rmse(false);
    rejectBehindCamera();
    build();
    bool ok = solve(opt_.max_iterations);
    if (opt_.refine_iterations > 0 && rejectOutliers() > 0) {
      disableOutliers();
      ok = solve(opt_.refine_iterations) && ok;
    }
    classify();
    res_.final_rmse_px = rmse(true);
    res_.converged = ok;
    writeBack();
    return std::move(res_);
  }

 private:
  // Reprojection error (pixels) of observation k at the current parameters; infinite behind the camera.
  double error(std::size_t k) const {
    const auto& o = pb_.observations[k];
    return obsError(poses_[o.camera].data(), pts_[o.point].data(), pb_, o);
  }

  double rmse(bool inliers_only) const {
    double s = 0;
    int n = 0;
    for (std::size_t k = 0; k < pb_.observations.size(); ++k) {
      if (inliers_only && !res_.inlier[k]) continue;
      const double e = error(k);
      if (!std::isfinite(e)) continue;
      s += e * e;
      ++n;
    }
    return n ? std::sqrt(s / n) : 0.0;
  }

  // Observations already behind the camera cannot be optimised meaningfully.
  void rejectBehindCamera() {
    for (std::size_t k = 0; k < pb_.observations.size(); ++k)
      if (!std::isfinite(error(k))) res_.inlier[k] = false;
  }

  // A residual block per inlier observation; the used poses on the pose manifold, the fixed cameras
  // and points constant.
  void build() {
    for (std::size_t k = 0; k < pb_.observations.size(); ++k) {
      if (!res_.inlier[k]) continue;
      const auto& o = pb_.observations[k];
      ReprojectionCost* cost = &costs_.emplace_back(o.uv, o.sigma, pb_.fx, pb_.fy, pb_.cx, pb_.cy);
      cost_of_[k] = cost;
      problem_.AddResidualBlock(cost, &huber_, poses_[o.camera].data(), pts_[o.point].data());
      cam_used_[o.camera] = true;
      pt_used_[o.point] = true;
    }
    for (const auto& r : pb_.relative_translations) {
      rel_costs_.push_back(makeRelativeTranslationCost(r.t_ij, r.sigma));
      rel_losses_.push_back(std::make_unique<ceres::HuberLoss>(r.huber));
      problem_.AddResidualBlock(rel_costs_.back().get(), rel_losses_.back().get(), poses_[r.camera_i].data(),
                                poses_[r.camera_j].data());
      cam_used_[r.camera_i] = cam_used_[r.camera_j] = true;
    }
    for (int i = 0; i < nc_; ++i) {
      if (!cam_used_[i]) continue;
      problem_.SetManifold(poses_[i].data(), new PoseManifold());
      if (pb_.cameras[i].fixed) problem_.SetParameterBlockConstant(poses_[i].data());
    }
    for (int i = 0; i < np_; ++i)
      if (pt_used_[i] && pb_.points[i].fixed) problem_.SetParameterBlockConstant(pts_[i].data());
  }

  // After the first solve: inliers whose error exceeds outlier_px x sigma are no longer. Returns how many.
  int rejectOutliers() {
    int removed = 0;
    for (std::size_t k = 0; k < pb_.observations.size(); ++k) {
      if (!res_.inlier[k]) continue;
      if (!(error(k) <= opt_.outlier_px * pb_.observations[k].sigma)) {
        res_.inlier[k] = false;
        ++removed;
      }
    }
    return removed;
  }

  // Disables the observations no longer counted as inliers; cameras and points left without an
  // inlier observation are held constant (their rows are all zero).
  void disableOutliers() {
    std::vector<int> cam_inliers(nc_, 0), pt_inliers(np_, 0);
    for (std::size_t k = 0; k < pb_.observations.size(); ++k) {
      if (!cost_of_[k]) continue;
      if (!res_.inlier[k]) {
        cost_of_[k]->disable();
        continue;
      }
      ++cam_inliers[pb_.observations[k].camera];
      ++pt_inliers[pb_.observations[k].point];
    }
    for (int i = 0; i < nc_; ++i)
      if (cam_used_[i] && cam_inliers[i] == 0) {
        problem_.SetParameterBlockConstant(poses_[i].data());
        cam_used_[i] = false;
      }
    for (int i = 0; i < np_; ++i)
      if (pt_used_[i] && pt_inliers[i] == 0) {
        problem_.SetParameterBlockConstant(pts_[i].data());
        pt_used_[i] = false;
      }
  }

  // One Levenberg-Marquardt solve (nothing to do without a free parameter block or a residual).
  // Returns false when Ceres failed.
  bool solve(int iterations) {
    bool any_free = false;
    int free_cams = 0;
    for (int i = 0; i < nc_; ++i)
      if (cam_used_[i] && !pb_.cameras[i].fixed) {
        any_free = true;
        ++free_cams;
      }
    for (int i = 0; i < np_; ++i) any_free = any_free || (pt_used_[i] && !pb_.points[i].fixed);
    if (!any_free || problem_.NumResidualBlocks() == 0) return true;
    ceres::Solver::Options so = solverOptions(opt_, iterations, free_cams);
    // Schur ordering: points first.
    auto* ordering = new ceres::ParameterBlockOrdering;
    for (int i = 0; i < np_; ++i)
      if (problem_.HasParameterBlock(pts_[i].data())) ordering->AddElementToGroup(pts_[i].data(), 0);
    for (int i = 0; i < nc_; ++i)
      if (problem_.HasParameterBlock(poses_[i].data())) ordering->AddElementToGroup(poses_[i].data(), 1);
    so.linear_solver_ordering.reset(ordering);
    StopCallback stop(opt_.should_stop);
    if (opt_.should_stop) so.callbacks.push_back(&stop);
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem_, &summary);
    res_.iterations += static_cast<int>(summary.iterations.size());
    return summary.termination_type == ceres::CONVERGENCE || summary.termination_type == ceres::NO_CONVERGENCE ||
           summary.termination_type == ceres::USER_SUCCESS;
  }

  // Final classification of every observation (also those left out of the solves).
  void classify() {
    res_.outliers = 0;
    for (std::size_t k = 0; k < pb_.observations.size(); ++k) {
      res_.inlier[k] = error(k) <= opt_.outlier_px * pb_.observations[k].sigma;
      if (!res_.inlier[k]) ++res_.outliers;
    }
  }

  // The adjusted cameras and points (the fixed ones as they were) back into the problem.
  void writeBack() {
    for (int i = 0; i < nc_; ++i)
      if (!pb_.cameras[i].fixed) pb_.cameras[i].T_world_cam = poseFromParams(poses_[i].data());
    for (int i = 0; i < np_; ++i)
      if (!pb_.points[i].fixed) pb_.points[i].position = pts_[i];
  }

  BaProblem& pb_;
  const BundleAdjustmentOptions& opt_;
  const int nc_, np_;
  BaResult res_;
  std::vector<std::array<double, 7>> poses_;
  std::vector<Eigen::Vector3d> pts_;
  // Declared before problem_, which refers to them: destroyed after it.
  std::deque<ReprojectionCost> costs_;
  std::vector<std::unique_ptr<ceres::CostFunction>> rel_costs_;
  std::vector<std::unique_ptr<ceres::HuberLoss>> rel_losses_;
  ceres::HuberLoss huber_;
  ceres::Problem problem_;
  std::vector<ReprojectionCost*> cost_of_;
  std::vector<bool> cam_used_, pt_used_;
};

}  // namespace

BaResult bundleAdjust(BaProblem& pb, const BundleAdjustmentOptions& opt) {
  const auto t0 = std::chrono::steady_clock::now();
  validateObservations(pb);
  BaResult res = BundleAdjuster(pb, opt).run();
  res.time_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace nerfslam
