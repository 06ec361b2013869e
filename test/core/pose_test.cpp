#include "nerfslam/core/pose.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <unsupported/Eigen/MatrixFunctions>
#include <vector>

namespace nerfslam {
namespace {

using Eigen::Matrix3d;
using Eigen::Matrix4d;
using Eigen::Quaterniond;
using Eigen::Vector3d;

// 4x4 generator of se(3) for xi = (rho, phi).
Matrix4d hat4(const Vector6d& xi) {
  Matrix4d X = Matrix4d::Zero();
  X.block<3, 3>(0, 0) = SE3::hat(xi.tail<3>());
  X.block<3, 1>(0, 3) = xi.head<3>();
  return X;
}

Vector6d vee4(const Matrix4d& X) {
  Vector6d xi;
  xi << X(0, 3), X(1, 3), X(2, 3), X(2, 1), X(0, 2), X(1, 0);
  return xi;
}

// 4x4 generator of sim(3) for xi = (rho, phi, sigma).
Matrix4d hatSim(const Vector7d& xi) {
  Matrix4d X = Matrix4d::Zero();
  X.block<3, 3>(0, 0) = SE3::hat(xi.segment<3>(3)) + xi(6) * Matrix3d::Identity();
  X.block<3, 1>(0, 3) = xi.head<3>();
  return X;
}

Vector3d unitVector(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  return Vector3d(n(rng), n(rng), n(rng)).normalized();
}

// Tangent vectors with rotation angles spread over the delicate regions: 0, tiny, around the
// Taylor switch, generic, and just below pi.
std::vector<Vector6d> testTangents() {
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  const std::vector<double> angles = {0.0, 1e-12, 1e-9, 1e-6, 1e-4,        0.0099999,   0.0100001,
                                      0.3, 1.0,   2.0,  3.0,  M_PI - 1e-3, M_PI - 1e-6, M_PI - 1e-9};
  std::vector<Vector6d> out;
  for (double a : angles) {
    for (int k = 0; k < 3; ++k) {
      Vector6d xi;
      xi.head<3>() = Vector3d(u(rng), u(rng), u(rng));
      xi.tail<3>() = a * unitVector(rng);
      out.push_back(xi);
    }
  }
  return out;
}

TEST(SE3, RotationAboutZBy90Degrees) {
  Vector6d xi = Vector6d::Zero();
  xi(5) = M_PI / 2;
  const SE3 T = SE3::exp(xi);
  Matrix3d Rz;
  Rz << 0, -1, 0, 1, 0, 0, 0, 0, 1;
  EXPECT_TRUE(T.rotationMatrix().isApprox(Rz, 1e-15));
  EXPECT_TRUE((T * Vector3d(1, 0, 0)).isApprox(Vector3d(0, 1, 0), 1e-15));
  EXPECT_NEAR(T.translation().norm(), 0.0, 1e-15);

  // With rho = e_x the translation is the screw-motion integral (sin t / t, (1 - cos t) / t, 0)
  // at t = pi/2, i.e. (2/pi, 2/pi, 0).
  xi(0) = 1.0;
  const SE3 S = SE3::exp(xi);
  EXPECT_NEAR(S.translation().x(), 2.0 / M_PI, 1e-15);
  EXPECT_NEAR(S.translation().y(), 2.0 / M_PI, 1e-15);
  EXPECT_NEAR(S.translation().z(), 0.0, 1e-15);
  const Vector6d back = S.log();
  EXPECT_LT((back - xi).norm(), 1e-14);
}

TEST(SE3, ExpMatchesMatrixExponential) {
  for (const Vector6d& xi : testTangents()) {
    const Matrix4d ref = hat4(xi).exp();
    const Matrix4d got = SE3::exp(xi).matrix();
    EXPECT_LT((ref - got).cwiseAbs().maxCoeff(), 1e-13) << xi.transpose();
  }
}

TEST(SE3, ExpLogRoundTrip) {
  for (const Vector6d& xi : testTangents()) {
    const SE3 T = SE3::exp(xi);
    const Vector6d back = T.log();
    // Angles up to pi - 1e-9: log(exp(xi)) == xi, and the pose round trip holds.
    EXPECT_TRUE(SE3::exp(back).isApprox(T, 1e-12)) << xi.transpose();
    EXPECT_TRUE(SE3::exp(back).matrix().isApprox(T.matrix(), 1e-12)) << xi.transpose();
    const double tol = 1e-12;
    EXPECT_LT((back - xi).norm(), tol * std::max(1.0, xi.norm())) << xi.transpose();
  }
}

TEST(SE3, LogExactlyAtPi) {
  // Rotation by pi about a tilted axis: the quaternion has w = 0.
  const Vector3d axis = Vector3d(1, 2, -2).normalized();
  const SE3 T(Quaterniond(Eigen::AngleAxisd(M_PI, axis)), Vector3d(0.3, -1.0, 2.0));
  const Vector6d xi = T.log();
  EXPECT_NEAR(xi.tail<3>().norm(), M_PI, 1e-12);
  EXPECT_NEAR(std::abs(xi.tail<3>().normalized().dot(axis)), 1.0, 1e-12);
  EXPECT_TRUE(SE3::exp(xi).isApprox(T, 1e-12));
}

TEST(SE3, LogTinyRotationHasNoCancellation) {
  // A rotation of 1e-9 rad: the rotation vector must come back with full relative precision.
  const Vector3d phi(1e-9, -2e-9, 0.5e-9);
  Vector6d xi;
  xi << 1.0, 2.0, 3.0, phi;
  const Vector6d back = SE3::exp(xi).log();
  EXPECT_LT((back.tail<3>() - phi).norm(), 1e-15 * phi.norm() * 10);
  EXPECT_LT((back.head<3>() - xi.head<3>()).norm(), 1e-14);
}

TEST(SE3, CompositionInverseAndAction) {
  std::mt19937 rng(7);
  for (const Vector6d& xa : testTangents()) {
    Vector6d xb;
    std::uniform_real_distribution<double> u(-2.0, 2.0);
    for (int i = 0; i < 6; ++i) xb(i) = u(rng);
    const SE3 a = SE3::exp(xa), b = SE3::exp(xb);
    EXPECT_TRUE((a * b).matrix().isApprox(a.matrix() * b.matrix(), 1e-13));
    EXPECT_TRUE((a * a.inverse()).isApprox(SE3(), 1e-13));
    EXPECT_TRUE(a.inverse().matrix().isApprox(a.matrix().inverse(), 1e-12));
    const Vector3d p(u(rng), u(rng), u(rng));
    const Eigen::Vector4d ph = a.matrix() * p.homogeneous();
    EXPECT_TRUE((a * p).isApprox(ph.head<3>(), 1e-13));
  }
}

TEST(SE3, MatrixConstructorsReorthonormalise) {
  const SE3 T = SE3::exp((Vector6d() << 0.5, -1, 2, 0.3, -0.2, 1.1).finished());
  EXPECT_TRUE(SE3::fromMatrix(T.matrix()).isApprox(T, 1e-14));
  EXPECT_TRUE(SE3::fromMatrix3x4(T.matrix3x4()).isApprox(T, 1e-14));
  // A slightly perturbed (non-orthonormal) rotation matrix is projected to the closest rotation.
  Matrix3d R = T.rotationMatrix();
  R(0, 1) += 1e-6;
  const SE3 P(R, T.translation());
  const Matrix3d Rp = P.rotationMatrix();
  EXPECT_LT((Rp.transpose() * Rp - Matrix3d::Identity()).norm(), 1e-14);
  EXPECT_NEAR(Rp.determinant(), 1.0, 1e-14);
  EXPECT_TRUE(P.isApprox(T, 1e-6));
  EXPECT_FALSE(P.isApprox(T, 1e-9));
}

TEST(SE3, BakerCampbellHausdorffToFirstOrder) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Vector6d a0, b0;
  for (int i = 0; i < 6; ++i) {
    a0(i) = u(rng);
    b0(i) = u(rng);
  }
  for (double eps : {1e-2, 1e-3}) {
    const Vector6d a = eps * a0, b = eps * b0;
    const Vector6d c = (SE3::exp(a) * SE3::exp(b)).log();
    // log(exp(a) exp(b)) = a + b + 1/2 [a, b] + O(eps^3).
    const Vector6d bracket = vee4(hat4(a) * hat4(b) - hat4(b) * hat4(a));
    const Vector6d bch = a + b + 0.5 * bracket;
    EXPECT_LT((c - (a + b)).norm(), 2.0 * eps * eps * 10);
    EXPECT_LT((c - bch).norm(), 10.0 * eps * eps * eps);
    EXPECT_GT((c - (a + b)).norm(), 10.0 * (c - bch).norm());  // the bracket term is what's left
  }
}

TEST(SE3, DerivativeOfExpAtZeroIsHat) {
  const Vector6d xi = (Vector6d() << 0.4, -0.7, 1.3, -0.9, 0.25, 0.6).finished();
  const double h = 1e-6;
  const Matrix4d fd = (SE3::exp(h * xi).matrix() - SE3::exp(-h * xi).matrix()) / (2 * h);
  EXPECT_LT((fd - hat4(xi)).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(SE3, InterpolationMidpoint) {
  // Identity to a screw motion (90 deg about z, 2 m along z): the midpoint is 45 deg and 1 m.
  const SE3 b(Quaterniond(Eigen::AngleAxisd(M_PI / 2, Vector3d::UnitZ())), Vector3d(0, 0, 2));
  const SE3 mid = SE3::interpolate(SE3(), b, 0.5);
  const SE3 expected(Quaterniond(Eigen::AngleAxisd(M_PI / 4, Vector3d::UnitZ())), Vector3d(0, 0, 1));
  EXPECT_TRUE(mid.isApprox(expected, 1e-14));
  // Left-invariance: interpolating a*I .. a*b gives a * mid; the end points are reproduced.
  const SE3 a = SE3::exp((Vector6d() << 1, 2, 3, 0.3, -0.4, 0.5).finished());
  EXPECT_TRUE(SE3::interpolate(a, a * b, 0.5).isApprox(a * expected, 1e-13));
  EXPECT_TRUE(SE3::interpolate(a, a * b, 0.0).isApprox(a, 1e-13));
  EXPECT_TRUE(SE3::interpolate(a, a * b, 1.0).isApprox(a * b, 1e-13));
  // Interpolating half-way to the midpoint gives the quarter point.
  const SE3 q = SE3::interpolate(a, a * b, 0.25);
  EXPECT_TRUE(SE3::interpolate(a, SE3::interpolate(a, a * b, 0.5), 0.5).isApprox(q, 1e-13));
}

TEST(SE3, IsApprox) {
  const SE3 a(Quaterniond(Eigen::AngleAxisd(0.5, Vector3d::UnitX())), Vector3d(1, 2, 3));
  const SE3 b(Quaterniond(-a.rotation().coeffs()), a.translation());  // same rotation, q -> -q
  EXPECT_TRUE(a.isApprox(b));
  EXPECT_FALSE(a.isApprox(SE3(a.rotation(), Vector3d(1, 2, 3.001)), 1e-6));
  EXPECT_FALSE(a.isApprox(SE3(Quaterniond(Eigen::AngleAxisd(0.5001, Vector3d::UnitX())), a.translation()), 1e-6));
}

// ---------------------------------------------------------------------------------------------- Sim3

std::vector<Vector7d> simTangents() {
  std::vector<Vector7d> out;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  const std::vector<double> sigmas = {0.0, 1e-13, 1e-9, 1e-5, 0.01, -0.3, 0.7, 2.0, -3.0};
  const std::vector<double> angles = {0.0, 1e-12, 1e-7, 1e-3, 0.2, 0.49999, 0.50001, 1.5, 3.0, M_PI - 1e-7};
  for (double s : sigmas) {
    for (double a : angles) {
      Vector7d xi;
      xi.head<3>() = Vector3d(u(rng), u(rng), u(rng));
      xi.segment<3>(3) = a * unitVector(rng);
      xi(6) = s;
      out.push_back(xi);
    }
  }
  return out;
}

TEST(Sim3, ExpMatchesMatrixExponential) {
  for (const Vector7d& xi : simTangents()) {
    const Matrix4d ref = hatSim(xi).exp();
    const Matrix4d got = Sim3::exp(xi).matrix();
    EXPECT_LT((ref - got).cwiseAbs().maxCoeff(), 1e-12 * std::max(1.0, ref.cwiseAbs().maxCoeff())) << xi.transpose();
  }
}

TEST(Sim3, ExpLogRoundTrip) {
  for (const Vector7d& xi : simTangents()) {
    const Sim3 S = Sim3::exp(xi);
    const Vector7d back = S.log();
    EXPECT_TRUE(Sim3::exp(back).matrix().isApprox(S.matrix(), 1e-12)) << xi.transpose();
    const double tol = 1e-12;
    EXPECT_LT((back - xi).norm(), tol * std::max(1.0, xi.norm())) << xi.transpose();
  }
}

TEST(Sim3, ZeroScaleLogReducesToSE3) {
  const Vector6d xi6 = (Vector6d() << 0.5, -0.2, 1.0, 0.1, 0.7, -0.3).finished();
  Vector7d xi7;
  xi7 << xi6, 0.0;
  EXPECT_TRUE(Sim3::exp(xi7).matrix().isApprox(SE3::exp(xi6).matrix(), 1e-14));
  // Pure scale: exp((rho, 0, sigma)) translates by (e^sigma - 1)/sigma * rho.
  Vector7d xs;
  xs << 1.0, 2.0, 3.0, 0, 0, 0, std::log(2.0);
  const Sim3 S = Sim3::exp(xs);
  EXPECT_NEAR(S.scale(), 2.0, 1e-15);
  EXPECT_TRUE(S.translation().isApprox(Vector3d(1, 2, 3) / std::log(2.0), 1e-14));
}

TEST(Sim3, CompositionInverseTransformPose) {
  const Sim3 a = Sim3::exp((Vector7d() << 0.3, -1, 2, 0.4, 0.1, -0.8, 0.5).finished());
  const Sim3 b = Sim3::exp((Vector7d() << -2, 0.5, 1, -1.2, 0.3, 0.2, -0.9).finished());
  EXPECT_TRUE((a * b).matrix().isApprox(a.matrix() * b.matrix(), 1e-13));
  EXPECT_TRUE(a.inverse().matrix().isApprox(a.matrix().inverse(), 1e-13));
  const Vector3d p(0.7, -0.1, 3.0);
  EXPECT_TRUE((a * p).isApprox((a.matrix() * p.homogeneous()).head<3>(), 1e-14));

  const SE3 T = SE3::exp((Vector6d() << 1, 2, 3, 0.2, -0.5, 0.9).finished());
  const SE3 U = a.transformPose(T);
  EXPECT_TRUE(U.translation().isApprox(a * T.translation(), 1e-14));
  EXPECT_TRUE(U.rotationMatrix().isApprox(a.rotation().toRotationMatrix() * T.rotationMatrix(), 1e-14));
  // A camera's points map consistently: a * (T * x) == U * (x * scale) (the similarity scales depth).
  const Vector3d x(0.1, 0.2, 1.5);
  EXPECT_TRUE((a * (T * x)).isApprox(U * (a.scale() * x), 1e-13));
  // Built from an SE3 with scale 1 it acts like the SE3.
  EXPECT_TRUE(Sim3(1.0, T).transformPose(T).isApprox(T * T, 1e-13));
}

}  // namespace
}  // namespace nerfslam
