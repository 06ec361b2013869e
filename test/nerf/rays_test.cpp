#include "nerfslam/nerf/rays.h"

#include <gtest/gtest.h>

#include <random>

#include "nerfslam/core/error.h"

namespace nerfslam::nerf {
namespace {

SE3 randomPose(std::mt19937& rng) {
  std::normal_distribution<double> n(0, 1);
  Eigen::Quaterniond q(n(rng), n(rng), n(rng), n(rng));
  return SE3(q.normalized(), Eigen::Vector3d(n(rng), n(rng), n(rng)));
}

TEST(Rays, MatchCameraUnprojectAndPose) {
  std::mt19937 rng(3);
  SceneTransform scene;
  for (const bool distorted : {false, true}) {
    Camera cam = Camera::pinhole(320, 240, 300, 310, 161.5, 118.2);
    if (distorted) {
      cam.distortion_model = DistortionModel::kRadTan;
      cam.distortion = {-0.2, 0.05, 0.001, -0.002};
    }
    for (int trial = 0; trial < 20; ++trial) {
      const SE3 T = randomPose(rng);
      const RayGenerator gen(cam, T, scene);
      const double u = std::uniform_real_distribution<double>(0, 319)(rng);
      const double v = std::uniform_real_distribution<double>(0, 239)(rng);
      const Ray r = gen.ray(u, v);
      const Eigen::Vector3d expected_dir = (T.rotationMatrix() * cam.unproject({u, v})).normalized();
      EXPECT_NEAR((r.dir.cast<double>() - expected_dir).norm(), 0.0, 1e-6);
      EXPECT_NEAR((r.origin.cast<double>() - scene.toNerf(T.translation())).norm(), 0.0, 1e-6);
      // A point along the ray projects back onto the pixel.
      const Eigen::Vector3d p_nerf = r.origin.cast<double>() + 0.7 * r.dir.cast<double>();
      const Eigen::Vector2d uv = cam.project(T.inverse() * scene.toWorld(p_nerf));
      EXPECT_NEAR(uv.x(), u, 1e-3);
      EXPECT_NEAR(uv.y(), v, 1e-3);
    }
  }
}

TEST(Rays, AabbIntersection) {
  Ray r{Eigen::Vector3f(-1.f, 0.5f, 0.5f), Eigen::Vector3f(1.f, 0.f, 0.f)};
  float tn, tf;
  ASSERT_TRUE(intersectAabb(r, Eigen::Vector3f::Zero(), Eigen::Vector3f::Ones(), &tn, &tf));
  EXPECT_FLOAT_EQ(tn, 1.f);
  EXPECT_FLOAT_EQ(tf, 2.f);
  r.origin = Eigen::Vector3f(0.5f, 0.5f, 0.5f);  // inside: starts at 0
  ASSERT_TRUE(intersectAabb(r, Eigen::Vector3f::Zero(), Eigen::Vector3f::Ones(), &tn, &tf));
  EXPECT_FLOAT_EQ(tn, 0.f);
  EXPECT_FLOAT_EQ(tf, 0.5f);
  r.origin = Eigen::Vector3f(-1.f, 2.f, 0.5f);  // passes above the box
  EXPECT_FALSE(intersectAabb(r, Eigen::Vector3f::Zero(), Eigen::Vector3f::Ones(), &tn, &tf));
  r.origin = Eigen::Vector3f(2.f, 0.5f, 0.5f);  // box behind the origin
  EXPECT_FALSE(intersectAabb(r, Eigen::Vector3f::Zero(), Eigen::Vector3f::Ones(), &tn, &tf));
}

TEST(Rays, SceneTransformValidation) {
  SceneTransform s;
  EXPECT_NO_THROW(s.validate("x"));
  s.aabb_scale = 3;
  EXPECT_THROW(s.validate("x"), Error);
  s.aabb_scale = 4;
  s.scale = 0;
  EXPECT_THROW(s.validate("x"), Error);
}

}  // namespace
}  // namespace nerfslam::nerf
