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

// The occupancy bits against the rule written out cell by cell: a cell of cascade m is occupied when
// its value is above the threshold or when any cell of cascade m-1 inside it is (cell (x, y, z) of
// cascade m-1 lies in (32 + x/2, 32 + y/2, 32 + z/2) of cascade m). Random sparse values, so
// both the word-wise threshold and the folded max-pool see isolated and neighbouring cells.
TEST(Occupancy, BitsAreTheThresholdedValuesMaxPooledIntoCoarserCascades) {
  constexpr int kRes = OccupancyGrid::kRes;
  const int cascades = 3;
  OccupancyGrid grid(cascades);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<float> values(size_t(cascades) * OccupancyGrid::kCells);
  for (float& v : values) v = u(rng) < 0.002f ? 0.5f + u(rng) : 0.01f * u(rng);
  const float threshold = 0.005f;
  grid.setValues(values, threshold);
  std::vector<uint8_t> expected(values.size());
  for (size_t i = 0; i < values.size(); ++i) expected[i] = values[i] > threshold;
  for (int m = 1; m < cascades; ++m)
    for (int z = 0; z < kRes; ++z)
      for (int y = 0; y < kRes; ++y)
        for (int x = 0; x < kRes; ++x)
          if (expected[size_t(m - 1) * OccupancyGrid::kCells + OccupancyGrid::cellIndex(x, y, z)])
            expected[size_t(m) * OccupancyGrid::kCells + OccupancyGrid::cellIndex(32 + x / 2, 32 + y / 2, 32 + z / 2)] =
                1;
  size_t occupied = 0, wrong = 0;
  for (int m = 0; m < cascades; ++m)
    for (int z = 0; z < kRes; ++z)
      for (int y = 0; y < kRes; ++y)
        for (int x = 0; x < kRes; ++x) {
          const bool e = expected[size_t(m) * OccupancyGrid::kCells + OccupancyGrid::cellIndex(x, y, z)] != 0;
          occupied += e;
          wrong += grid.occupiedCell(m, x, y, z) != e;
        }
  EXPECT_EQ(wrong, 0u);
  EXPECT_GT(occupied, 12000u);
  // The coarse blocks (4^3 and 16^3 cells) hold every occupied cell.
  for (int m = 0; m < cascades; ++m)
    for (int z = 0; z < kRes; ++z)
      for (int y = 0; y < kRes; ++y)
        for (int x = 0; x < kRes; ++x)
          if (grid.occupiedCell(m, x, y, z)) {
            ASSERT_TRUE(grid.occupiedBlock(m, 1, x >> 2, y >> 2, z >> 2));
            ASSERT_TRUE(grid.occupiedBlock(m, 2, x >> 4, y >> 4, z >> 4));
          }
}

// A random-pick update against the rule: the picks reach the density function in cell order, and
// each cell's new value is max(old value * decay, the largest density sampled in it * kMinStep).
// Carving: the segments' cells are emptied, the same segments again empty the same cells (cached),
// and other segments empty theirs and no longer the old ones.
TEST(Occupancy, RandomUpdateKeepsTheLargestSampleOverTheDecayedValue) {
  // One cascade: a pick's cell is then the cell its position lies in (a coarser cascade's centre
  // overlaps the finer one, where a position would not tell which was picked).
  constexpr int kRes = OccupancyGrid::kRes;
  OccupancyGrid grid(1);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<float> values(static_cast<size_t>(OccupancyGrid::kCells));
  for (float& v : values) v = u(rng) < 0.01f ? u(rng) : 0.f;
  grid.setValues(values, 0.01f);
  auto cellOf = [&](const float* p) {
    int c[3];
    for (int a = 0; a < 3; ++a) c[a] = std::clamp(int(p[a] * kRes), 0, kRes - 1);
    return OccupancyGrid::cellIndex(c[0], c[1], c[2]);
  };
  std::vector<float> sampled(values.size(), 0.f);
  uint32_t last = 0;
  bool ordered = true;
  int64_t queries = 0;
  OccupancyGrid::UpdateParams p;
  p.uniform_cells = 100000;
  p.decay = 0.9f;
  p.threshold_cap = 0.01f;
  p.seed = 17;
  grid.update(
      [&](const float* xyz, int n, float* sigma) {
        for (int i = 0; i < n; ++i) {
          // A density that differs from cell to cell: the pick's cell is recovered from its position.
          const uint32_t c = cellOf(xyz + 3 * i);
          ordered &= c >= last || queries == 0;
          last = c;
          ++queries;
          sigma[i] = 50.f * u(rng);
          sampled[c] = std::max(sampled[c], sigma[i] * kMinStep);
        }
      },
      p);
  EXPECT_TRUE(ordered) << "the picks are evaluated in cell order";
  EXPECT_EQ(queries, 100000);
  size_t wrong = 0, raised = 0;
  for (size_t i = 0; i < values.size(); ++i) {
    const float expected = std::max(values[i] * 0.9f, sampled[i]);
    wrong += grid.values()[i] != expected;
    raised += sampled[i] > values[i] * 0.9f;
  }
  EXPECT_EQ(wrong, 0u);
  EXPECT_GT(raised, 50000u);

  // Carving, cached across updates with the same segments.
  OccupancyGrid carve(1);
  carve.fill(1.f);
  OccupancyGrid::UpdateParams c;
  c.uniform_cells = 0;
  c.decay = 1.f;
  c.threshold_cap = 0.5f;
  const Eigen::Vector3f a(0.1f, 0.5f, 0.5f), b(0.9f, 0.5f, 0.5f), d(0.5f, 0.1f, 0.3f), e(0.5f, 0.9f, 0.3f);
  auto one = [](const float*, int n, float* s) { std::fill(s, s + n, 1.f); };
  auto emptyAlong = [&](const Eigen::Vector3f& from, const Eigen::Vector3f& to) {
    int empty = 0;
    for (int k = 0; k <= 100; ++k) empty += !carve.occupied(from + (float(k) / 100.f) * (to - from), 0);
    return empty;
  };
  c.keep_empty = {{a, b}};
  carve.update(one, c);
  EXPECT_EQ(emptyAlong(a, b), 101);
  const double after_first = carve.occupiedFraction();
  carve.setValues(std::vector<float>(OccupancyGrid::kCells, 1.f), 0.5f);
  carve.update(one, c);  // the same segments: the cached cells
  EXPECT_EQ(carve.occupiedFraction(), after_first);
  carve.setValues(std::vector<float>(OccupancyGrid::kCells, 1.f), 0.5f);
  c.keep_empty = {{d, e}};
  carve.update(one, c);
  EXPECT_EQ(emptyAlong(d, e), 101);
  EXPECT_EQ(emptyAlong(a, b), 0);
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
