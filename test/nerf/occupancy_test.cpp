#include "nerfslam/nerf/occupancy.h"

#include <gtest/gtest.h>

#include <random>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/raymarch.h"

namespace nerfslam::nerf {
namespace {

const Eigen::Vector3f kCentre(0.5f, 0.45f, 0.55f);
constexpr float kRadius = 0.2f;

void sphereDensity(const float* xyz, int n, float* sigma) {
  for (int i = 0; i < n; ++i)
    sigma[i] = (Eigen::Vector3f(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]) - kCentre).norm() < kRadius ? 100.f : 0.f;
}

TEST(Occupancy, MarksAnalyticSphereCells) {
  OccupancyGrid grid(1);
  OccupancyGrid::UpdateParams p;  // every cell once
  grid.update(sphereDensity, p);
  const float h = OccupancyGrid::cellSize(0) * 0.5f * std::sqrt(3.f);
  int inside = 0, outside = 0;
  for (int z = 0; z < OccupancyGrid::kRes; ++z)
    for (int y = 0; y < OccupancyGrid::kRes; ++y)
      for (int x = 0; x < OccupancyGrid::kRes; ++x) {
        const float d = (grid.cellCenter(0, x, y, z) - kCentre).norm();
        if (d < kRadius - h) {  // the whole cell is inside
          EXPECT_TRUE(grid.occupiedCell(0, x, y, z)) << x << " " << y << " " << z;
          ++inside;
        } else if (d > kRadius + h) {  // the whole cell is outside
          EXPECT_FALSE(grid.occupiedCell(0, x, y, z)) << x << " " << y << " " << z;
          ++outside;
        }
      }
  EXPECT_GT(inside, 50000);
  EXPECT_GT(outside, 1500000);
  // Values in instant-ngp's units: sigma * sqrt(3)/1024.
  EXPECT_NEAR(*std::max_element(grid.values().begin(), grid.values().end()), 100.f * kMinStep, 1e-6);
  EXPECT_LE(grid.threshold(), 0.01f);

  // Without new density the values decay by 0.95 per update and the threshold follows the mean.
  const float before = grid.values()[OccupancyGrid::cellIndex(64, 58, 70)];
  OccupancyGrid::UpdateParams none;
  none.uniform_cells = 0;
  grid.update([](const float*, int n, float* s) { std::fill(s, s + n, 0.f); }, none);
  EXPECT_FLOAT_EQ(grid.values()[OccupancyGrid::cellIndex(64, 58, 70)], before * 0.95f);
}

// A block sweep (a fresh field's first update) asks for one density per block of cells and gives
// every cell of the block that value: 1/64 of the queries for blocks of 4, the sphere's interior still
// occupied and the far outside still empty; a block that is not a power of two is refused.
TEST(Occupancy, BlockSweepSharesOneSamplePerBlock) {
  OccupancyGrid grid(2);
  OccupancyGrid::UpdateParams p;
  p.sweep_block = 4;
  int64_t queries = 0;
  grid.update(
      [&](const float* xyz, int n, float* s) {
        queries += n;
        sphereDensity(xyz, n, s);
      },
      p);
  EXPECT_EQ(queries, 2 * OccupancyGrid::kCells / 64);
  for (int bz = 0; bz < OccupancyGrid::kRes; bz += 4)
    for (int by = 0; by < OccupancyGrid::kRes; by += 4)
      for (int bx = 0; bx < OccupancyGrid::kRes; bx += 4) {
        const float v = grid.values()[OccupancyGrid::cellIndex(bx, by, bz)];
        for (int k = 1; k < 64; ++k)
          ASSERT_EQ(grid.values()[OccupancyGrid::cellIndex(bx + k % 4, by + k / 4 % 4, bz + k / 16)], v)
              << bx << " " << by << " " << bz;
      }
  // Blocks wholly inside the sphere (their centre more than a block's half-diagonal inside) are
  // occupied; blocks wholly outside are not.
  const float h = 4 * OccupancyGrid::cellSize(0) * 0.5f * std::sqrt(3.f);
  int inside = 0, outside = 0;
  for (int z = 2; z < OccupancyGrid::kRes; z += 4)
    for (int y = 2; y < OccupancyGrid::kRes; y += 4)
      for (int x = 2; x < OccupancyGrid::kRes; x += 4) {
        const Eigen::Vector3f c =
            grid.cellCenter(0, x, y, z) - Eigen::Vector3f::Constant(0.5f * OccupancyGrid::cellSize(0));
        const float d = (c - kCentre).norm();
        if (d < kRadius - h) inside += !grid.occupiedCell(0, x, y, z) ? 1000000 : 1;
        if (d > kRadius + h) outside += grid.occupiedCell(0, x, y, z) ? 1000000 : 1;
      }
  EXPECT_GT(inside, 500);
  EXPECT_LT(inside, 1000000) << "a block inside the sphere is empty";
  EXPECT_GT(outside, 20000);
  EXPECT_LT(outside, 1000000) << "a block outside the sphere is occupied";
  p.sweep_block = 3;
  EXPECT_THROW(grid.update(sphereDensity, p), Error);
}

TEST(Occupancy, CoarseCascadesIncludeFineOccupancy) {
  OccupancyGrid grid(3);
  grid.update(sphereDensity, {});
  // Every occupied cell of cascade 0 is also occupied at cascades 1 and 2 at the same point.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  int checked = 0;
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector3f p(u(rng), u(rng), u(rng));
    if (!grid.occupied(p, 0)) continue;
    EXPECT_TRUE(grid.occupied(p, 1));
    EXPECT_TRUE(grid.occupied(p, 2));
    ++checked;
  }
  EXPECT_GT(checked, 100);
}

// The samples of a skipping march must be exactly the lattice points of an unskipped march that fall
// in occupied cells: skipping never drops an occupied cell's sample and never adds an empty one.
void checkSkipping(double aabb_scale, unsigned seed) {
  SceneTransform scene;
  scene.aabb_scale = aabb_scale;
  const int cascades = OccupancyGrid::cascadesForAabbScale(aabb_scale);
  OccupancyGrid grid(cascades);
  grid.update(sphereDensity, {});
  const MarchParams mp = MarchParams::forScene(scene, cascades);
  std::mt19937 rng(seed);
  std::normal_distribution<float> n(0.f, 1.f);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  int hits = 0;
  for (int trial = 0; trial < 300; ++trial) {
    Ray ray;
    ray.dir = Eigen::Vector3f(n(rng), n(rng), n(rng)).normalized();
    const Eigen::Vector3f target = kCentre + 0.08f * Eigen::Vector3f(n(rng), n(rng), n(rng));
    ray.origin = target - 1.5f * float(aabb_scale) * ray.dir;
    const float jitter = u(rng);
    RayMarcher marcher(ray, grid, scene, mp, jitter);
    std::vector<float> xyz(3 * 8192), t(8192), dt(8192);
    const int count = marcher.next(8192, xyz.data(), t.data(), dt.data());
    ASSERT_TRUE(marcher.done());
    // Reference: the unskipped lattice.
    std::vector<float> ref;
    float tn, tf;
    if (intersectAabb(ray, scene.aabbMin(), scene.aabbMax(), &tn, &tf)) {
      const float t0 = tn + mp.dt(tn) * jitter;
      float tt = t0;
      for (int64_t k = 0; tt < tf; ++k) {
        const Eigen::Vector3f p = ray.origin + tt * ray.dir;
        const float step = mp.dt(tt);
        if (grid.occupied(p, grid.mipFromDt(step, p))) ref.push_back(tt);
        tt = mp.cone_angle == 0.f ? t0 + float(k + 1) * kMinStep : tt + step;
      }
    }
    ASSERT_EQ(size_t(count), ref.size()) << "trial " << trial;
    for (int i = 0; i < count; ++i) ASSERT_EQ(t[i], ref[i]) << "trial " << trial << " sample " << i;
    hits += count > 0;
  }
  EXPECT_GT(hits, 200);
}

TEST(Raymarch, SkippingNeverSkipsOccupiedCells) { checkSkipping(1.0, 1); }
TEST(Raymarch, SkippingNeverSkipsOccupiedCellsWithConeSteps) { checkSkipping(4.0, 2); }

TEST(Raymarch, ResumableMarchGivesTheSameSamples) {
  OccupancyGrid grid(1);
  grid.update(sphereDensity, {});
  SceneTransform scene;
  const MarchParams mp = MarchParams::forScene(scene, 1);
  const Ray ray{Eigen::Vector3f(-0.5f, 0.4f, 0.6f), Eigen::Vector3f(1.f, 0.05f, -0.02f).normalized()};
  RayMarcher a(ray, grid, scene, mp, 0.3f), b(ray, grid, scene, mp, 0.3f);
  std::vector<float> xa(3 * 4096), ta(4096), da(4096), xb(3 * 4096), tb(4096), db(4096);
  const int na = a.next(4096, xa.data(), ta.data(), da.data());
  int nb = 0;
  while (!b.done()) nb += b.next(7, xb.data() + 3 * nb, tb.data() + nb, db.data() + nb);
  ASSERT_GT(na, 50);
  ASSERT_EQ(na, nb);
  for (int i = 0; i < na; ++i) EXPECT_EQ(ta[i], tb[i]);
}

}  // namespace
}  // namespace nerfslam::nerf
