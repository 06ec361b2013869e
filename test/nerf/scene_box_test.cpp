// The scene box (nerf/scene_box.h): robust bounds of a sparse map, the cube transform, the first
// fit, the points near the cameras, the outgrown test, the re-fit around the map and the old box
// and the shrunk box.
#include "nerfslam/nerf/scene_box.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace nerfslam::nerf {
namespace {

// 11^3 points on a grid over [0, 1]^3.
std::vector<Eigen::Vector3d> gridPoints() {
  std::vector<Eigen::Vector3d> p;
  for (int x = 0; x <= 10; ++x)
    for (int y = 0; y <= 10; ++y)
      for (int z = 0; z <= 10; ++z) p.emplace_back(0.1 * x, 0.1 * y, 0.1 * z);
  return p;
}

TEST(SceneBox, RobustBoundsIgnoreOutlierPointsButHoldEveryCamera) {
  std::vector<Eigen::Vector3d> pts = gridPoints();
  pts.emplace_back(100, -100, 100);  // far outliers: beyond the 2nd..98th percentile
  pts.emplace_back(-100, 100, -100);
  const Bounds b = robustBounds(pts, {});
  EXPECT_TRUE(((b.lo.array() >= 0.0) && (b.lo.array() <= 0.05)).all()) << b.lo.transpose();
  EXPECT_TRUE(((b.hi.array() >= 0.95) && (b.hi.array() <= 1.0)).all()) << b.hi.transpose();
  const Bounds c = robustBounds(pts, {Eigen::Vector3d(3, 0.5, -2)});
  EXPECT_EQ(c.hi.x(), 3.0);
  EXPECT_EQ(c.lo.z(), -2.0);
  EXPECT_EQ(c.lo.x(), b.lo.x());
  const Bounds e = robustBounds({}, {});
  EXPECT_TRUE((e.lo.array() > e.hi.array()).all());
}

TEST(SceneBox, CubeTransformMapsTheWidenedBoxOntoTheUnitCube) {
  const Bounds b{Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(2, 1, 1)};
  const SceneTransform s = cubeTransform(b, 1.5, 4.0, 0.1);  // half side 1.5 * 2 / 2 = 1.5
  EXPECT_DOUBLE_EQ(s.scale, 0.5 / 1.5);
  EXPECT_EQ(s.aabb_scale, 4.0);
  EXPECT_LT((s.toNerf(Eigen::Vector3d(1, 0.5, 0.5)) - Eigen::Vector3d::Constant(0.5)).norm(), 1e-12);
  EXPECT_NEAR(s.toNerf(Eigen::Vector3d(2.5, 0.5, 0.5)).x(), 1.0, 1e-12);
  EXPECT_NEAR(s.toNerf(Eigen::Vector3d(1, -1.0, 0.5)).y(), 0.0, 1e-12);
  // A box smaller than min_half gets min_half.
  const SceneTransform t = cubeTransform(b, 1.0, 1.0, 10.0);
  EXPECT_DOUBLE_EQ(t.scale, 0.05);
}

TEST(SceneBox, FirstFitHoldsTheMapAndIsAtLeastTheCameraBaseline) {
  const std::vector<Eigen::Vector3d> pts = gridPoints();
  const std::vector<Eigen::Vector3d> cams = {Eigen::Vector3d(0.5, 0.5, -1), Eigen::Vector3d(0.6, 0.5, -1)};
  const SceneTransform s = fitSceneBox(pts, cams, 1.2, 2.0);
  for (const auto& p : pts) {
    if ((p.array() >= 0.05).all() && (p.array() <= 0.95).all()) {
      EXPECT_TRUE(insideUnitCube(s.toNerf(p))) << p.transpose();
    }
  }
  for (const auto& c : cams) EXPECT_TRUE(insideUnitCube(s.toNerf(c)));
  EXPECT_FALSE(sceneBoxOutgrown(s, pts, cams, 0.05));
  // A flat, tiny map seen from far apart cameras: the box is as large as their distance.
  const std::vector<Eigen::Vector3d> flat(30, Eigen::Vector3d(0, 0, 0));
  const std::vector<Eigen::Vector3d> apart = {Eigen::Vector3d(-2, 0, 0), Eigen::Vector3d(1, 0, 0),
                                              Eigen::Vector3d(2, 0, 0)};
  const SceneTransform f = fitSceneBox(flat, apart, 1.0, 1.0);
  EXPECT_LE(f.scale, 0.5 / 2.0 + 1e-12);  // side >= |first - last camera| = 4
  // Two cameras 4 apart over a single point: the same.
  const SceneTransform two = fitSceneBox(flat, {Eigen::Vector3d(-2, 0, 0), Eigen::Vector3d(2, 0, 0)}, 1.0, 1.0);
  EXPECT_LE(two.scale, 0.5 / 2.0 + 1e-12);
}

// An object photographed from a ring of cameras three times its size away (the Middlebury temple
// ring): the box is the object's, not the ring's; cameras in or near the map are held.
TEST(SceneBox, ObjectCaptureBoxHoldsTheObjectNotTheCameraRing) {
  const std::vector<Eigen::Vector3d> pts = gridPoints();  // [0, 1]^3
  std::vector<Eigen::Vector3d> ring;
  for (int k = 0; k < 36; ++k) {
    const double a = 2.0 * M_PI * k / 36.0;
    ring.emplace_back(0.5 + 3.5 * std::cos(a), 0.5, 0.5 + 3.5 * std::sin(a));
  }
  EXPECT_TRUE(camerasInScene(pts, ring).empty());
  const SceneTransform s = fitSceneBox(pts, ring, 1.2, 2.0);
  EXPECT_NEAR(s.scale, 0.5 / 0.6, 0.05);  // the object's cube, half side 1.2 * 0.5 (robust bounds)
  for (const auto& c : ring) EXPECT_FALSE(insideUnitCube(s.toNerf(c)));
  EXPECT_FALSE(sceneBoxOutgrown(s, pts, ring, 0.05));
  const SceneTransform r = refitSceneBox(s, pts, ring, 1.2, 2.0);  // grows 1.5x, not to the ring
  EXPECT_NEAR(r.scale, s.scale / 1.5, 1e-9);
  // A camera inside the map and one just outside it (within one extent) are in the scene.
  const std::vector<Eigen::Vector3d> near = {Eigen::Vector3d(0.5, 0.5, 0.5), Eigen::Vector3d(0.5, 0.5, 1.9)};
  EXPECT_EQ(camerasInScene(pts, near).size(), 2u);
  EXPECT_TRUE(insideUnitCube(fitSceneBox(pts, near, 1.2, 2.0).toNerf(near[1])));
  // Without points every camera is.
  EXPECT_EQ(camerasInScene({}, ring).size(), ring.size());
}

TEST(SceneBox, OutgrownByACameraOrByMoreThanTheFractionOfPoints) {
  const std::vector<Eigen::Vector3d> pts = gridPoints();
  const SceneTransform s = fitSceneBox(pts, {Eigen::Vector3d(0.5, 0.5, 0.5), Eigen::Vector3d(0.5, 0.6, 0.5)}, 1.2, 2.0);
  EXPECT_FALSE(sceneBoxOutgrown(s, pts, {Eigen::Vector3d(0.5, 0.5, 0.5)}, 0.05));
  EXPECT_TRUE(sceneBoxOutgrown(s, pts, {Eigen::Vector3d(0.5, 0.5, 1.8)}, 0.05));
  // A camera 4 extents away looks at the map from outside the scene: not a reason to grow.
  EXPECT_FALSE(sceneBoxOutgrown(s, pts, {Eigen::Vector3d(0.5, 0.5, 5)}, 0.05));
  std::vector<Eigen::Vector3d> more = pts;
  for (int i = 0; i < 100; ++i) more.emplace_back(10 + i, 0, 0);  // 7 % of the points outside
  EXPECT_TRUE(sceneBoxOutgrown(s, more, {}, 0.05));
  EXPECT_FALSE(sceneBoxOutgrown(s, more, {}, 0.1));
  EXPECT_FALSE(sceneBoxOutgrown(s, {}, {Eigen::Vector3d(0.5, 0.5, 5)}, 0.05));  // no points: nothing to fit
}

TEST(SceneBox, RefitHoldsTheOldBoxAndTheMapAndGrowsAtLeastOneAndAHalfTimes) {
  const std::vector<Eigen::Vector3d> pts = gridPoints();
  const SceneTransform old =
      fitSceneBox(pts, {Eigen::Vector3d(0.5, 0.5, 0.5), Eigen::Vector3d(0.5, 0.6, 0.5)}, 1.2, 2.0);
  // The map moved on: new points and a camera beyond the old box.
  std::vector<Eigen::Vector3d> grown = pts;
  for (const auto& p : pts) grown.push_back(p + Eigen::Vector3d(1.5, 0, 0));
  const std::vector<Eigen::Vector3d> cams = {Eigen::Vector3d(2.8, 0.5, 0.5)};
  ASSERT_TRUE(sceneBoxOutgrown(old, grown, cams, 0.05));
  const SceneTransform s = refitSceneBox(old, grown, cams, 1.2, 2.0);
  EXPECT_LE(s.scale, old.scale / 1.5 + 1e-12);
  EXPECT_EQ(s.aabb_scale, 2.0);
  for (const double c : {0.0, 1.0}) EXPECT_TRUE(insideUnitCube(s.toNerf(old.toWorld(Eigen::Vector3d::Constant(c)))));
  EXPECT_FALSE(sceneBoxOutgrown(s, grown, cams, 0.05));
}

// A monocular map's first points spread far (a short baseline triangulates distant points badly):
// the box fitted to them is several times the box of the finished map, which is then oversized and
// fitted anew; a box fitted to the finished map is not, nor is any box with the ratio 0.
TEST(SceneBox, OversizedWhenTheFinishedMapIsMuchSmallerThanTheFirstBox) {
  const std::vector<Eigen::Vector3d> cams = {Eigen::Vector3d(0.5, 0.5, 0.0), Eigen::Vector3d(0.5, 0.5, 0.1)};
  std::vector<Eigen::Vector3d> first;
  for (const auto& p : gridPoints())
    first.push_back(Eigen::Vector3d(0.5, 0.5, 0.5) + 8.0 * (p - Eigen::Vector3d(0.5, 0.5, 0.5)));
  const SceneTransform box = fitSceneBox(first, cams, 1.2, 2.0);
  const std::vector<Eigen::Vector3d> finished = gridPoints();  // an eighth of the first extent
  EXPECT_FALSE(sceneBoxOutgrown(box, finished, cams, 0.05));
  const std::optional<SceneTransform> shrunk = shrunkSceneBox(box, finished, cams, 1.2, 0.5);
  EXPECT_FALSE(shrunkSceneBox(box, finished, cams, 1.2, 0.0));
  EXPECT_FALSE(shrunkSceneBox(box, {}, cams, 1.2, 0.5));
  const SceneTransform fitted = fitSceneBox(finished, cams, 1.2, 2.0);
  ASSERT_TRUE(shrunk);  // the box fitted to the finished map
  EXPECT_EQ(shrunk->scale, fitted.scale);
  EXPECT_EQ(shrunk->offset, fitted.offset);
  EXPECT_EQ(shrunk->aabb_scale, box.aabb_scale);
  EXPECT_FALSE(shrunkSceneBox(fitted, finished, cams, 1.2, 0.5));
  EXPECT_FALSE(sceneBoxOutgrown(fitted, finished, cams, 0.05));
  EXPECT_NEAR(fitted.scale / box.scale, 8.0, 0.5);
  // A box only a little larger than the map's own (0.6 of its side) is kept at the ratio 0.5.
  SceneTransform larger = fitted;
  larger.scale = fitted.scale * 0.6;
  EXPECT_FALSE(shrunkSceneBox(larger, finished, cams, 1.2, 0.5));
}

// A camera driving down a street: facades and trees beside the road, and a few points on buildings
// far ahead. The far points are left out of the box (which the road and its sides fill), and do
// not make it outgrown; points all around cameras in a room are all kept.
TEST(SceneBox, FarPointsAheadOfAStreetAreLeftOutOfTheBox) {
  std::vector<Eigen::Vector3d> cams, pts;
  for (int i = 0; i <= 20; ++i) cams.emplace_back(0, 0, 0.5 * i);  // 10 units down the road (z)
  for (int i = 0; i <= 200; ++i)
    for (const double x : {-1.5, -1.0, 1.0, 1.5}) pts.emplace_back(x, -0.3 * (i % 3), 0.05 * i);
  const size_t beside = pts.size();
  for (int i = 0; i < 40; ++i) pts.emplace_back(0.5 * (i % 9) - 2.0, -1.0, 40.0 + 0.5 * i);  // far ahead
  const std::vector<Eigen::Vector3d> near = pointsNearCameras(pts, cams);
  EXPECT_EQ(near.size(), beside);
  const SceneTransform s = fitSceneBox(pts, cams, 1.2, 2.0);
  // The box's side is the road's length with the margin, not the 60 units to the far points.
  EXPECT_NEAR(1.0 / s.scale, 1.2 * 10.0, 0.5);
  for (const auto& c : cams) EXPECT_TRUE(insideUnitCube(s.toNerf(c)));
  EXPECT_FALSE(insideUnitCube(s.toNerf(pts.back())));
  EXPECT_FALSE(sceneBoxOutgrown(s, pts, cams, 0.05));
  EXPECT_FALSE(shrunkSceneBox(s, pts, cams, 1.2, 0.5));
  // A room: cameras in the middle, points on every wall; all of them count.
  const std::vector<Eigen::Vector3d> room = gridPoints();
  EXPECT_EQ(pointsNearCameras(room, {Eigen::Vector3d(0.5, 0.5, 0.5), Eigen::Vector3d(0.4, 0.5, 0.5)}).size(),
            room.size());
  EXPECT_EQ(pointsNearCameras(pts, {}).size(), pts.size());
}

TEST(SceneBox, InsideUnitCubeIncludesItsFaces) {
  EXPECT_TRUE(insideUnitCube(Eigen::Vector3d(0, 1, 0.5)));
  EXPECT_FALSE(insideUnitCube(Eigen::Vector3d(0, 1.0000001, 0.5)));
  EXPECT_FALSE(insideUnitCube(Eigen::Vector3d(-1e-9, 0.5, 0.5)));
}

}  // namespace
}  // namespace nerfslam::nerf
