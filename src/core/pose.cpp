#include "nerfslam/core/pose.h"

#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>

namespace nerfslam {
namespace {

// Below this angle (rad) the closed-form SO(3)/SE(3) coefficients lose digits to cancellation and
// their Taylor series (truncated after the theta^6 term, error < theta^8 / 9! ~ 3e-22) are used.
constexpr double kSmallAngle = 1e-2;

Eigen::Quaterniond normalisedWithPositiveW(const Eigen::Quaterniond& q) {
  Eigen::Quaterniond r = q.normalized();
  if (r.w() < 0) r.coeffs() = -r.coeffs();
  return r;
}

// Rotation vector -> unit quaternion. sin(theta/2)/theta via its series near 0.
Eigen::Quaterniond soExp(const Eigen::Vector3d& phi) {
  const double theta2 = phi.squaredNorm();
  const double theta = std::sqrt(theta2);
  double k;  // sin(theta/2) / theta
  if (theta < kSmallAngle) {
    k = 0.5 - theta2 / 48.0 + theta2 * theta2 / 3840.0;
  } else {
    k = std::sin(0.5 * theta) / theta;
  }
  Eigen::Quaterniond q(std::cos(0.5 * theta), k * phi.x(), k * phi.y(), k * phi.z());
  return q.normalized();
}

// Unit quaternion -> rotation vector with angle in [0, pi]. atan2 keeps it accurate near 0 and
// near pi (where acos/asin based formulas lose half of the digits).
Eigen::Vector3d soLog(const Eigen::Quaterniond& q_in) {
  const Eigen::Quaterniond q = normalisedWithPositiveW(q_in);
  const Eigen::Vector3d v = q.vec();
  const double n = v.norm();
  const double w = q.w();
  double k;  // theta / n, with theta = 2 atan2(n, w)
  if (n < 1e-8 * w) {
    // atan(x)/x = 1 - x^2/3 + ..., x = n/w; w ~ 1 here.
    const double x2 = (n / w) * (n / w);
    k = 2.0 / w * (1.0 - x2 / 3.0);
  } else {
    k = 2.0 * std::atan2(n, w) / n;
  }
  return k * v;
}

// Coefficients of V = I + A K + B K^2 (K = hat(phi)), the left Jacobian of SO(3).
void soVCoefficients(double theta, double& A, double& B) {
  const double t2 = theta * theta;
  if (theta < kSmallAngle) {
    A = 0.5 - t2 / 24.0 + t2 * t2 / 720.0 - t2 * t2 * t2 / 40320.0;
    B = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2 * t2 * t2 / 362880.0;
  } else {
    const double s = std::sin(0.5 * theta);
    A = 2.0 * s * s / t2;  // (1 - cos theta) / theta^2 without cancellation
    B = (theta - std::sin(theta)) / (t2 * theta);
  }
}

// V^-1 = I - 1/2 K + C K^2 with C = (1 - (theta/2) cot(theta/2)) / theta^2.
double soVInverseCoefficient(double theta) {
  const double t2 = theta * theta;
  if (theta < kSmallAngle) {
    return 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0 + t2 * t2 * t2 / 1209600.0;
  }
  const double h = 0.5 * theta;
  return (1.0 - h * std::cos(h) / std::sin(h)) / t2;
}

// Gauss-Legendre nodes and weights on [0, 1] (computed once by Newton iteration on P_n).
struct GaussLegendre {
  static constexpr int kN = 12;
  std::array<double, kN> x{}, w{};
  GaussLegendre() {
    const int n = kN;
    for (int i = 0; i < n; ++i) {
      double z = std::cos(M_PI * (i + 0.75) / (n + 0.5));
      double dp = 1.0;
      for (int it = 0; it < 100; ++it) {
        double p0 = 1.0, p1 = 0.0;
        for (int j = 0; j < n; ++j) {
          const double p2 = p1;
          p1 = p0;
          p0 = ((2.0 * j + 1.0) * z * p1 - j * p2) / (j + 1.0);
        }
        dp = n * (z * p0 - p1) / (z * z - 1.0);
        const double dz = p0 / dp;
        z -= dz;
        if (std::abs(dz) < 1e-16) break;
      }
      x[i] = 0.5 * (1.0 - z);
      w[i] = 1.0 / ((1.0 - z * z) * dp * dp);  // 2 / ((1-z^2) P'^2), halved for [0, 1]
    }
  }
};

// Sim(3) translation Jacobian W = C I + A K + B K^2 with K = hat(phi), theta = |phi|:
//   W = integral_0^1 exp(sigma tau) exp(tau K) dtau, so
//   C = (e^sigma - 1) / sigma,
//   A = integral e^{sigma tau} sin(tau theta) / theta,
//   B = integral e^{sigma tau} (1 - cos(tau theta)) / theta^2.
// For theta >= 0.5 the standard closed forms (Strasdat 2012, as in Sophus) are used; they are well
// conditioned there. Below, where the closed forms cancel catastrophically as sigma and theta go to
// 0 (B divides by theta^2 and theta^2 + sigma^2), the integrals of the same smooth integrands
// (sin(x)/x and 2 sin^2(x/2)/x^2 evaluated without cancellation) are taken by composite
// Gauss-Legendre quadrature with panels narrow enough that the rule is exact to rounding.
void simWCoefficients(double sigma, double theta, double& A, double& B, double& C) {
  C = std::abs(sigma) < 1e-12 ? 1.0 + 0.5 * sigma : std::expm1(sigma) / sigma;
  if (theta >= 0.5) {
    const double t2 = theta * theta;
    if (std::abs(sigma) < 1e-12) {
      double a, b;
      soVCoefficients(theta, a, b);
      A = a;
      B = b;
      return;
    }
    const double s = std::exp(sigma);
    const double a = s * std::sin(theta);
    const double b = s * std::cos(theta);
    const double c = t2 + sigma * sigma;
    A = (a * sigma + (1.0 - b) * theta) / (theta * c);
    B = (C - ((b - 1.0) * sigma + a * theta) / c) / t2;
    return;
  }
  static const GaussLegendre gl;
  const int panels = std::max(1, static_cast<int>(std::ceil(std::abs(sigma) + theta)));
  const double h = 1.0 / panels;
  A = 0.0;
  B = 0.0;
  for (int p = 0; p < panels; ++p) {
    for (int i = 0; i < GaussLegendre::kN; ++i) {
      const double tau = (p + gl.x[i]) * h;
      const double e = std::exp(sigma * tau);
      const double x = tau * theta;
      const double sinc = x < 1e-4 ? 1.0 - x * x / 6.0 : std::sin(x) / x;
      const double hx = 0.5 * x;
      const double sinc_half = hx < 1e-4 ? 1.0 - hx * hx / 6.0 : std::sin(hx) / hx;
      A += gl.w[i] * h * e * tau * sinc;                               // e sin(x)/theta
      B += gl.w[i] * h * e * 0.5 * tau * tau * sinc_half * sinc_half;  // e (1-cos x)/theta^2
    }
  }
}

Eigen::Matrix3d simW(double sigma, const Eigen::Vector3d& phi) {
  double A, B, C;
  simWCoefficients(sigma, phi.norm(), A, B, C);
  const Eigen::Matrix3d K = SE3::hat(phi);
  return C * Eigen::Matrix3d::Identity() + A * K + B * K * K;
}

Eigen::Quaterniond projectToRotation(const Eigen::Matrix3d& M) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1.0;
  const Eigen::Matrix3d R = svd.matrixU() * D * svd.matrixV().transpose();
  return Eigen::Quaterniond(R).normalized();
}

}  // namespace

// ---------------------------------------------------------------------------------------------- SE3

SE3::SE3() : q_(Eigen::Quaterniond::Identity()), t_(Eigen::Vector3d::Zero()) {}

SE3::SE3(const Eigen::Quaterniond& q, const Eigen::Vector3d& t) : q_(q.normalized()), t_(t) {}

SE3::SE3(const Eigen::Matrix3d& R, const Eigen::Vector3d& t) : q_(projectToRotation(R)), t_(t) {}

SE3 SE3::fromMatrix(const Eigen::Matrix4d& T) {
  return SE3(Eigen::Matrix3d(T.block<3, 3>(0, 0)), Eigen::Vector3d(T.block<3, 1>(0, 3)));
}

SE3 SE3::fromMatrix3x4(const Eigen::Matrix<double, 3, 4>& T) {
  return SE3(Eigen::Matrix3d(T.block<3, 3>(0, 0)), Eigen::Vector3d(T.col(3)));
}

Eigen::Matrix3d SE3::hat(const Eigen::Vector3d& w) {
  Eigen::Matrix3d K;
  K << 0.0, -w.z(), w.y(),  //
      w.z(), 0.0, -w.x(),   //
      -w.y(), w.x(), 0.0;
  return K;
}

SE3 SE3::exp(const Vector6d& xi) {
  const Eigen::Vector3d rho = xi.head<3>();
  const Eigen::Vector3d phi = xi.tail<3>();
  double A, B;
  soVCoefficients(phi.norm(), A, B);
  const Eigen::Matrix3d K = hat(phi);
  const Eigen::Matrix3d V = Eigen::Matrix3d::Identity() + A * K + B * K * K;
  return SE3(soExp(phi), V * rho);
}

Vector6d SE3::log() const {
  const Eigen::Vector3d phi = soLog(q_);
  const Eigen::Matrix3d K = hat(phi);
  const Eigen::Matrix3d Vinv = Eigen::Matrix3d::Identity() - 0.5 * K + soVInverseCoefficient(phi.norm()) * K * K;
  Vector6d xi;
  xi.head<3>() = Vinv * t_;
  xi.tail<3>() = phi;
  return xi;
}

SE3 SE3::inverse() const {
  const Eigen::Quaterniond qi = q_.conjugate();
  return SE3(qi, -(qi * t_));
}

SE3 SE3::operator*(const SE3& o) const { return SE3(q_ * o.q_, q_ * o.t_ + t_); }

Eigen::Vector3d SE3::operator*(const Eigen::Vector3d& p) const { return q_ * p + t_; }

Eigen::Matrix4d SE3::matrix() const {
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.block<3, 3>(0, 0) = rotationMatrix();
  T.block<3, 1>(0, 3) = t_;
  return T;
}

Eigen::Matrix<double, 3, 4> SE3::matrix3x4() const {
  Eigen::Matrix<double, 3, 4> T;
  T.block<3, 3>(0, 0) = rotationMatrix();
  T.col(3) = t_;
  return T;
}

SE3 SE3::interpolate(const SE3& a, const SE3& b, double s) {
  const Vector6d xi = (a.inverse() * b).log();
  return a * exp(s * xi);
}

bool SE3::isApprox(const SE3& o, double tol) const {
  // Rotation: angle of q^-1 q_o (sign-invariant); translation: relative to the larger magnitude,
  // absolute below 1.
  const double angle = soLog(q_.conjugate() * o.q_).norm();
  const double scale = std::max({1.0, t_.norm(), o.t_.norm()});
  return angle <= tol && (t_ - o.t_).norm() <= tol * scale;
}

// --------------------------------------------------------------------------------------------- Sim3

Sim3::Sim3() : s_(1.0), q_(Eigen::Quaterniond::Identity()), t_(Eigen::Vector3d::Zero()) {}

Sim3::Sim3(double scale, const Eigen::Quaterniond& q, const Eigen::Vector3d& t)
    : s_(scale), q_(q.normalized()), t_(t) {}

Sim3::Sim3(double scale, const SE3& rigid) : s_(scale), q_(rigid.rotation()), t_(rigid.translation()) {}

Sim3 Sim3::exp(const Vector7d& xi) {
  const Eigen::Vector3d rho = xi.head<3>();
  const Eigen::Vector3d phi = xi.segment<3>(3);
  const double sigma = xi(6);
  return Sim3(std::exp(sigma), soExp(phi), simW(sigma, phi) * rho);
}

Vector7d Sim3::log() const {
  const double sigma = std::log(s_);
  const Eigen::Vector3d phi = soLog(q_);
  Vector7d xi;
  xi.head<3>() = simW(sigma, phi).partialPivLu().solve(t_);
  xi.segment<3>(3) = phi;
  xi(6) = sigma;
  return xi;
}

Sim3 Sim3::inverse() const {
  const Eigen::Quaterniond qi = q_.conjugate();
  const double si = 1.0 / s_;
  return Sim3(si, qi, -si * (qi * t_));
}

Sim3 Sim3::operator*(const Sim3& o) const { return Sim3(s_ * o.s_, q_ * o.q_, s_ * (q_ * o.t_) + t_); }

Eigen::Vector3d Sim3::operator*(const Eigen::Vector3d& p) const { return s_ * (q_ * p) + t_; }

SE3 Sim3::transformPose(const SE3& T_world_cam) const {
  return SE3(q_ * T_world_cam.rotation(), (*this) * T_world_cam.translation());
}

Eigen::Matrix4d Sim3::matrix() const {
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.block<3, 3>(0, 0) = s_ * q_.toRotationMatrix();
  T.block<3, 1>(0, 3) = t_;
  return T;
}

}  // namespace nerfslam
