#include "nerfslam/mapping/triangulation.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/SVD>

namespace nerfslam {

Eigen::Matrix3d fundamentalFromPoses(const SE3& T_world_cam1, const SE3& T_world_cam2, const Eigen::Matrix3d& K) {
  // X2 = R21 X1 + t21
  const SE3 T21 = T_world_cam2.inverse() * T_world_cam1;
  const Eigen::Matrix3d E = SE3::hat(T21.translation()) * T21.rotationMatrix();
  const Eigen::Matrix3d Kinv = K.inverse();
  return Kinv.transpose() * E * Kinv;
}

double epipolarDistance(const Eigen::Matrix3d& F, const Eigen::Vector2d& x1, const Eigen::Vector2d& x2) {
  const Eigen::Vector3d l = F * x1.homogeneous();
  const double n = std::hypot(l.x(), l.y());
  if (n <= 0) return std::numeric_limits<double>::infinity();
  return std::abs(l.dot(x2.homogeneous())) / n;
}

std::optional<Eigen::Vector3d> triangulateDlt(const SE3& T_world_cam1, const SE3& T_world_cam2,
                                              const Eigen::Vector2d& n1, const Eigen::Vector2d& n2) {
  const Eigen::Matrix<double, 3, 4> P1 = T_world_cam1.inverse().matrix3x4();
  const Eigen::Matrix<double, 3, 4> P2 = T_world_cam2.inverse().matrix3x4();
  Eigen::Matrix4d A;
  A.row(0) = n1.x() * P1.row(2) - P1.row(0);
  A.row(1) = n1.y() * P1.row(2) - P1.row(1);
  A.row(2) = n2.x() * P2.row(2) - P2.row(0);
  A.row(3) = n2.y() * P2.row(2) - P2.row(1);
  // Row scaling improves conditioning.
  for (int r = 0; r < 4; ++r) {
    const double n = A.row(r).norm();
    if (n > 0) A.row(r) /= n;
  }
  Eigen::JacobiSVD<Eigen::Matrix4d> svd(A, Eigen::ComputeFullV);
  const Eigen::Vector4d X = svd.matrixV().col(3);
  if (std::abs(X(3)) < 1e-12) return std::nullopt;
  const Eigen::Vector3d p = X.head<3>() / X(3);
  if (!p.allFinite()) return std::nullopt;
  return p;
}

std::optional<TriangulatedPoint> triangulateChecked(const SE3& T_world_cam1, const SE3& T_world_cam2,
                                                    const Eigen::Matrix3d& K, const Eigen::Vector2d& uv1,
                                                    const Eigen::Vector2d& uv2, double s1, double s2,
                                                    const TriangulationChecks& checks) {
  const double fx = K(0, 0), fy = K(1, 1), cx = K(0, 2), cy = K(1, 2);
  const Eigen::Vector2d n1((uv1.x() - cx) / fx, (uv1.y() - cy) / fy);
  const Eigen::Vector2d n2((uv2.x() - cx) / fx, (uv2.y() - cy) / fy);
  // Parallax of the rays (before triangulating: nearly parallel rays give unstable points).
  const Eigen::Vector3d r1 = T_world_cam1.rotation() * n1.homogeneous().normalized();
  const Eigen::Vector3d r2 = T_world_cam2.rotation() * n2.homogeneous().normalized();
  const double cos_rays = r1.dot(r2);
  const double cos_min = std::cos(checks.min_parallax_deg * M_PI / 180.0);
  if (cos_rays > cos_min || cos_rays < 0) return std::nullopt;
  const auto X = triangulateDlt(T_world_cam1, T_world_cam2, n1, n2);
  if (!X) return std::nullopt;
  TriangulatedPoint out;
  out.position = *X;
  const Eigen::Vector3d p1 = T_world_cam1.inverse() * *X;
  const Eigen::Vector3d p2 = T_world_cam2.inverse() * *X;
  if (p1.z() <= 0 || p2.z() <= 0) return std::nullopt;
  out.error1_px = std::hypot(fx * p1.x() / p1.z() + cx - uv1.x(), fy * p1.y() / p1.z() + cy - uv1.y());
  out.error2_px = std::hypot(fx * p2.x() / p2.z() + cx - uv2.x(), fy * p2.y() / p2.z() + cy - uv2.y());
  if (out.error1_px > checks.max_error_sigma * s1 || out.error2_px > checks.max_error_sigma * s2) return std::nullopt;
  const Eigen::Vector3d d1 = *X - T_world_cam1.translation();
  const Eigen::Vector3d d2 = *X - T_world_cam2.translation();
  const double c = d1.normalized().dot(d2.normalized());
  out.parallax_deg = std::acos(std::clamp(c, -1.0, 1.0)) * 180.0 / M_PI;
  if (out.parallax_deg < checks.min_parallax_deg) return std::nullopt;
  return out;
}

}  // namespace nerfslam
