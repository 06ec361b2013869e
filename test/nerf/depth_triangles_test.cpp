// Sparse depth densified over surfaces (nerf/depth_triangles.h): triangles between a view's surface
// points lie on the surface they sample, never bridge a depth jump or a wide stretch of image, are
// drawn by area, and follow the points when they move.
#include "nerfslam/nerf/depth_triangles.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "nerfslam/nerf/trainer.h"

namespace nerfslam::nerf {
namespace {

Camera camera() { return Camera::pinhole(320, 240, 250, 250, 159.5, 119.5); }

// A road: the plane y = 1.5 (1.5 below the camera, OpenCV axes: y down), 4..25 ahead.
std::vector<SurfacePoint> roadPoints(int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> x(-4, 4), z(4, 25);
  std::vector<SurfacePoint> p;
  for (int i = 0; i < n; ++i) p.push_back({Eigen::Vector3f(float(x(rng)), 1.5f, float(z(rng))), 0.8f});
  return p;
}

TEST(DepthTriangles, SamplesLieOnTheSurfaceAndProjectWhereTheyAreDrawn) {
  const Camera cam = camera();
  const SE3 T;  // identity: camera at the origin looking along +z
  const auto pts = roadPoints(400, 1);
  const DepthTriangles tris = triangulateSurfacePoints(pts, cam, T);
  ASSERT_GT(tris.triangles.size(), 100u);
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> u(0, 1);
  int drawn = 0;
  for (int i = 0; i < 2000; ++i) {
    const auto s = sampleDepthTriangle(tris, pts, cam, T, u(rng), u(rng), u(rng));
    if (!s) continue;
    ++drawn;
    const Eigen::Vector3d ray = cam.unproject(s->uv).normalized();
    const Eigen::Vector3d p = s->distance * ray;
    EXPECT_NEAR(p.y(), 1.5, 1e-6);  // on the road
    EXPECT_NEAR((cam.project(p) - s->uv).norm(), 0.0, 1e-6);
    EXPECT_FLOAT_EQ(s->weight, kTriangleWeight * 0.8f);
  }
  EXPECT_GT(drawn, 1900);  // only grazing rays are refused
}

TEST(DepthTriangles, NeverBridgeADepthJumpOrAWideGap) {
  const Camera cam = camera();
  const SE3 T;
  std::vector<SurfacePoint> pts;
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  // A pole 5 ahead in front of a wall 20 ahead (four times as far), and a second wall patch far to
  // the right of the first in the image, at the same depth but 40 % of the image away.
  for (int i = 0; i < 150; ++i)
    pts.push_back({Eigen::Vector3f(float(-0.1 + 0.2 * u(rng)), float(-1 + 2 * u(rng)), 5.f)});
  for (int i = 0; i < 300; ++i) pts.push_back({Eigen::Vector3f(float(-8 + 7 * u(rng)), float(-4 + 8 * u(rng)), 20.f)});
  for (int i = 0; i < 100; ++i) pts.push_back({Eigen::Vector3f(float(8 + 4 * u(rng)), float(-4 + 8 * u(rng)), 20.f)});
  const DepthTriangles tris = triangulateSurfacePoints(pts, cam, T);
  ASSERT_FALSE(tris.empty());
  size_t pole = 0, left = 0, right = 0;
  for (const DepthTriangle& t : tris.triangles) {
    int in_pole = 0, in_right = 0;
    for (const uint32_t i : t.corner) {
      in_pole += i < 150;
      in_right += i >= 450;
    }
    EXPECT_TRUE(in_pole == 0 || in_pole == 3) << "a triangle between the pole and the wall";
    EXPECT_TRUE(in_right == 0 || in_right == 3) << "a triangle across the gap between the walls";
    pole += in_pole == 3;
    right += in_right == 3;
    left += in_pole == 0 && in_right == 0;
  }
  EXPECT_GT(pole, 20u);
  EXPECT_GT(left, 50u);
  EXPECT_GT(right, 20u);
  // Drawn by area: the share of samples on the pole is its share of the triangles' area.
  double pole_area = 0, total = tris.cumulative_area.back(), prev = 0;
  for (size_t k = 0; k < tris.triangles.size(); ++k) {
    if (tris.triangles[k].corner[0] < 150) pole_area += tris.cumulative_area[k] - prev;
    prev = tris.cumulative_area[k];
  }
  int on_pole = 0, n = 0;
  for (int i = 0; i < 20000; ++i) {
    const auto s = sampleDepthTriangle(tris, pts, cam, T, u(rng), u(rng), u(rng));
    if (!s) continue;
    ++n;
    on_pole += s->distance < 10;
  }
  EXPECT_NEAR(double(on_pole) / n, pole_area / total, 0.02);
}

TEST(DepthTriangles, FollowThePointsWhenBundleAdjustmentMovesThem) {
  const Camera cam = camera();
  const SE3 T;
  auto pts = roadPoints(300, 4);
  const DepthTriangles tris = triangulateSurfacePoints(pts, cam, T);
  ASSERT_FALSE(tris.empty());
  for (auto& p : pts) p.position.y() = 1.2f;  // the road re-estimated 0.3 higher
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(0, 1);
  for (int i = 0; i < 200; ++i) {
    const auto s = sampleDepthTriangle(tris, pts, cam, T, u(rng), u(rng), u(rng));
    if (!s) continue;
    EXPECT_NEAR(s->distance * cam.unproject(s->uv).normalized().y(), 1.2, 1e-6);
  }
  // And the camera moving with its corrected pose: 1 ahead, the same road 1 closer.
  const SE3 ahead(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 1));
  for (int i = 0; i < 200; ++i) {
    const auto s = sampleDepthTriangle(tris, pts, cam, ahead, u(rng), u(rng), u(rng));
    if (!s) continue;
    const Eigen::Vector3d p = Eigen::Vector3d(0, 0, 1) + s->distance * cam.unproject(s->uv).normalized();
    EXPECT_NEAR(p.y(), 1.2, 1e-6);
  }
}

TEST(DepthTriangles, PointsOutOfViewAndTooFewGiveNone) {
  const Camera cam = camera();
  const SE3 T;
  EXPECT_TRUE(triangulateSurfacePoints({}, cam, T).empty());
  const std::vector<SurfacePoint> two = {{Eigen::Vector3f(0, 0, 5), 1.f}, {Eigen::Vector3f(0.1f, 0, 5), 1.f}};
  EXPECT_TRUE(triangulateSurfacePoints(two, cam, T).empty());
  // Behind the camera, or outside the image: left out.
  const std::vector<SurfacePoint> away = {{Eigen::Vector3f(0, 0, -5), 1.f},
                                          {Eigen::Vector3f(0.1f, 0, -5), 1.f},
                                          {Eigen::Vector3f(0, 0.1f, -5), 1.f},
                                          {Eigen::Vector3f(50, 0, 5), 1.f}};
  EXPECT_TRUE(triangulateSurfacePoints(away, cam, T).empty());
  std::mt19937_64 rng(6);
  EXPECT_FALSE(sampleDepthTriangle(DepthTriangles{}, away, cam, T, 0.5, 0.5, 0.5));
  // Corners that have gone behind the camera since: nothing drawn.
  auto pts = roadPoints(100, 7);
  const DepthTriangles tris = triangulateSurfacePoints(pts, cam, T);
  ASSERT_FALSE(tris.empty());
  const SE3 past(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 100));
  EXPECT_FALSE(sampleDepthTriangle(tris, pts, cam, past, 0.5, 0.5, 0.5));
}

}  // namespace
}  // namespace nerfslam::nerf
