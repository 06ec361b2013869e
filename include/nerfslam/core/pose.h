#pragma once
// Rigid (SE3) and similarity (Sim3) transforms on Eigen.
// Naming convention across the project: T_a_b maps points expressed in frame b into frame a
// (p_a = T_a_b * p_b). Camera poses are T_world_cam (camera-to-world, OpenCV optical axes:
// x right, y down, z forward) unless a name says otherwise.
#include <Eigen/Core>
#include <Eigen/Geometry>

namespace nerfslam {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Vector7d = Eigen::Matrix<double, 7, 1>;

class SE3 {
 public:
  SE3();                                                       // identity
  SE3(const Eigen::Quaterniond& q, const Eigen::Vector3d& t);  // q is normalised
  SE3(const Eigen::Matrix3d& R, const Eigen::Vector3d& t);     // R is re-orthonormalised
  static SE3 fromMatrix(const Eigen::Matrix4d& T);
  static SE3 fromMatrix3x4(const Eigen::Matrix<double, 3, 4>& T);

  // Tangent vector xi = (rho, phi): rho the translational part, phi the rotation vector (rad).
  static SE3 exp(const Vector6d& xi);
  Vector6d log() const;
  static Eigen::Matrix3d hat(const Eigen::Vector3d& w);  // skew-symmetric matrix

  SE3 inverse() const;
  SE3 operator*(const SE3& o) const;
  Eigen::Vector3d operator*(const Eigen::Vector3d& p) const;

  const Eigen::Quaterniond& rotation() const { return q_; }
  Eigen::Matrix3d rotationMatrix() const { return q_.toRotationMatrix(); }
  const Eigen::Vector3d& translation() const { return t_; }
  Eigen::Matrix4d matrix() const;
  Eigen::Matrix<double, 3, 4> matrix3x4() const;

  // Geodesic interpolation a * exp(s * log(a^-1 * b)), s in [0, 1].
  static SE3 interpolate(const SE3& a, const SE3& b, double s);
  bool isApprox(const SE3& o, double tol = 1e-9) const;

 private:
  Eigen::Quaterniond q_;
  Eigen::Vector3d t_;
};

// x -> s * R * x + t
class Sim3 {
 public:
  Sim3();  // identity
  Sim3(double scale, const Eigen::Quaterniond& q, const Eigen::Vector3d& t);
  Sim3(double scale, const SE3& rigid);  // s * R, t taken from `rigid`

  // Tangent vector (rho, phi, sigma) with scale = exp(sigma).
  static Sim3 exp(const Vector7d& xi);
  Vector7d log() const;

  Sim3 inverse() const;
  Sim3 operator*(const Sim3& o) const;
  Eigen::Vector3d operator*(const Eigen::Vector3d& p) const;
  // Applies this similarity to a camera pose T_world_cam: rotation composed, centre transformed.
  SE3 transformPose(const SE3& T_world_cam) const;

  double scale() const { return s_; }
  const Eigen::Quaterniond& rotation() const { return q_; }
  const Eigen::Vector3d& translation() const { return t_; }
  Eigen::Matrix4d matrix() const;

 private:
  double s_;
  Eigen::Quaterniond q_;
  Eigen::Vector3d t_;
};

}  // namespace nerfslam
