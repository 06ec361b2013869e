// The renderer (wavefront march in rounds of chunks, density first, colour only where it matters,
// early termination) against a plain per-ray reference: the whole march of each ray, the fused
// query() and compositeForward().
#include "nerfslam/nerf/renderer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "nerfslam/nerf/composite.h"
#include "nerfslam/nerf/raymarch.h"

namespace nerfslam::nerf {
namespace {

// A random field made dense enough that many rays terminate after a few samples and others stay
// semi-transparent: hash features of order 1 and a scaled log-density output. The occupancy grid
// keeps a ball of cells, so rays also skip empty space and some miss everything.
NerfModel denseRandomModel() {
  FieldConfig c;
  c.n_levels = 8;
  c.log2_hashmap_size = 15;
  c.finest_resolution = 256;
  c.hidden = 32;
  c.hash_init_range = 1.0;
  NerfModel model = NerfModel::create(c, SceneTransform{}, 11);
  for (FloatArray& a : model.field->parameters()) {
    if (a.name != "density.w1") continue;
    for (size_t i = 0; i < a.size; i += kDensityOutputs) a.data[i] *= 16.f;  // column 0: log-density
  }
  model.field->parametersChanged();
  std::vector<float> values(size_t(OccupancyGrid::kCells), 0.f);
  constexpr int R = OccupancyGrid::kRes;
  for (int z = 0; z < R; ++z)
    for (int y = 0; y < R; ++y)
      for (int x = 0; x < R; ++x) {
        const Eigen::Vector3f p = model.grid->cellCenter(0, x, y, z);
        if ((p - Eigen::Vector3f(0.5f, 0.5f, 0.45f)).norm() < 0.3f) values[OccupancyGrid::cellIndex(x, y, z)] = 1.f;
      }
  model.grid->setValues(std::move(values), 0.5f);
  return model;
}

TEST(Render, MatchesThePerRayReference) {
  const NerfModel model = denseRandomModel();
  // 70x45: partial 32x16 blocks at the right and bottom edges.
  const Camera cam = Camera::pinhole(70, 45, 90, 90, 34.5, 22.0);
  Eigen::Matrix3d R;  // camera looking along +y (world), image x along +x, image y along -z
  R.col(0) = Eigen::Vector3d::UnitX();
  R.col(1) = -Eigen::Vector3d::UnitZ();
  R.col(2) = Eigen::Vector3d::UnitY();
  const SE3 pose(R, Eigen::Vector3d(0.05, -4.0, 0.1));
  RenderOptions ro;
  ro.normals = false;
  ro.threads = 2;
  ro.background = {0.2, 0.5, 0.9};
  const RenderResult r = renderView(model, cam, pose, ro);

  const RayGenerator gen(cam, pose, model.scene);
  const MarchParams mp = MarchParams::forScene(model.scene, model.grid->cascades());
  const Eigen::Vector3f z_axis = pose.rotationMatrix().col(2).cast<float>();
  const float bg[3] = {0.2f, 0.5f, 0.9f};
  std::vector<float> xyz(3 * 8192), q(3 * 8192), t(8192), dt(8192), dir(3 * 8192), sigma(8192), rgb(3 * 8192);
  int64_t marched = 0, composited = 0;
  int opaque = 0, partial = 0, empty = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const Ray ray = gen.ray(x, y);
      RayMarcher m(ray, *model.grid, model.scene, mp, 0.5f);
      const int n = m.next(8192, xyz.data(), t.data(), dt.data());
      ASSERT_TRUE(m.done());
      marched += n;
      model.toFieldCoords(xyz.data(), size_t(n), q.data());
      for (int k = 0; k < n; ++k)
        for (int a = 0; a < 3; ++a) dir[3 * size_t(k) + size_t(a)] = ray.dir[a];
      model.field->query(q.data(), dir.data(), size_t(n), sigma.data(), rgb.data());
      const CompositeResult ref = compositeForward(n, sigma.data(), rgb.data(), dt.data(), t.data(), bg);
      composited += ref.used;
      const float op = r.opacity.at<float>(y, x);
      SCOPED_TRACE(testing::Message() << "pixel " << x << "," << y << " samples " << n << " used " << ref.used);
      ASSERT_NEAR(op, ref.opacity, 1e-6f);
      opaque += op > 0.999f;
      partial += op > 0.01f && op < 0.9f;
      empty += n == 0;
      // Colour: samples lighter than 1e-4 may be left out while their total stays within 1e-3.
      const cv::Vec3f c = r.rgb.at<cv::Vec3f>(y, x);
      for (int a = 0; a < 3; ++a) ASSERT_NEAR(c[a], ref.rgb[a], 1e-3f + 1e-5f);
      const float inv_scale = float(1.0 / model.scene.scale);
      if (ref.opacity >= float(ro.min_opacity)) {
        const float depth = ref.depth * inv_scale * ray.dir.dot(z_axis);
        ASSERT_NEAR(r.depth.at<float>(y, x), depth, 1e-5f * depth);
      } else {
        ASSERT_EQ(r.depth.at<float>(y, x), 0.f);
      }
      if (ref.opacity > 1e-6f) {
        ASSERT_NEAR(r.uncertainty.at<float>(y, x), std::sqrt(ref.depth_var) * inv_scale, 1e-4f);
      }
    }
  // The scene exercises what the chunked march has to get right: opaque rays that terminate early,
  // semi-transparent ones that march to the end, rays that miss every occupied cell.
  EXPECT_GT(opaque, 300);
  EXPECT_GT(partial, 30);
  EXPECT_GT(empty, 100);
  // Field queries: at least every composited sample, at most the whole marches.
  EXPECT_GE(r.samples, composited);
  EXPECT_LT(r.samples, marched);
  std::printf("render test: %d opaque, %d partial, %d empty pixels; %lld composited, %lld queried, %lld marched\n",
              opaque, partial, empty, static_cast<long long>(composited), static_cast<long long>(r.samples),
              static_cast<long long>(marched));

  // Pixels are independent: one thread gives the same image bit for bit.
  ro.threads = 1;
  const RenderResult r1 = renderView(model, cam, pose, ro);
  EXPECT_EQ(cv::norm(r1.rgb, r.rgb, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(r1.depth, r.depth, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(r1.opacity, r.opacity, cv::NORM_INF), 0.0);
}

}  // namespace
}  // namespace nerfslam::nerf
