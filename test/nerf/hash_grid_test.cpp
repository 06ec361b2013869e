// Hash encoding: instant-ngp's level geometry and hash, interpolation properties, SIMD vs scalar on
// every compiled target, and the backward pass against finite differences.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "nerfslam/nerf/hash_grid.h"
#include "nerfslam/nerf/simd.h"

namespace nerfslam::nerf {
namespace {

TEST(HashGrid, LevelGeometryMatchesInstantNgp) {
  // L=16, N_min=16, N_max=2048, T=2^19: b = 128^(1/15); scale_l = 16 b^l - 1; res = ceil+1.
  const auto levels = gridLevels(16, 16, 2048.0, 19);
  ASSERT_EQ(levels.size(), 16u);
  EXPECT_FLOAT_EQ(levels[0].scale, 15.f);
  EXPECT_EQ(levels[0].resolution, 16u);
  EXPECT_NEAR(levels[1].scale, 21.1106061f, 1e-4);
  EXPECT_EQ(levels[1].resolution, 23u);
  EXPECT_EQ(levels[4].resolution, 59u);
  EXPECT_EQ(levels[5].resolution, 81u);
  EXPECT_NEAR(levels[5].scale, 79.6349472f, 1e-3);
  EXPECT_FLOAT_EQ(levels[15].scale, 2047.f);
  EXPECT_EQ(levels[15].resolution, 2048u);
  // Dense while res^3 <= T (59^3 = 205379 <= 524288 < 81^3); sizes padded to multiples of 8.
  for (int l = 0; l < 5; ++l) EXPECT_TRUE(levels[size_t(l)].dense) << l;
  for (int l = 5; l < 16; ++l) EXPECT_FALSE(levels[size_t(l)].dense) << l;
  EXPECT_EQ(levels[0].size, 4096u);
  EXPECT_EQ(levels[1].size, 12168u);  // 23^3 = 12167 -> 12168
  EXPECT_EQ(levels[2].size, 29792u);  // 31^3 = 29791
  EXPECT_EQ(levels[5].size, 524288u);
  EXPECT_EQ(levels[1].offset, 4096u);
  EXPECT_EQ(levels[2].offset, 4096u + 12168u);
  uint64_t total = 0;
  for (const auto& L : levels) total += L.size;
  EXPECT_EQ(levels.back().offset + levels.back().size, total);
}

TEST(HashGrid, HashAndDenseIndices) {
  // 1 ^ (2*2654435761 mod 2^32) ^ (3*805459861 mod 2^32) = 2892625372 (computed by hand/Python).
  EXPECT_EQ(gridHash(1, 2, 3), 2892625372u);
  const auto levels = gridLevels(16, 16, 2048.0, 19);
  EXPECT_EQ(gridIndex(levels[10], 1, 2, 3), 2892625372u % 524288u);
  EXPECT_EQ(gridIndex(levels[10], 1, 2, 3), 128476u);
  EXPECT_EQ(gridIndex(levels[10], 5, 7, 11), 364725u);
  // Dense: x + y*res + z*res^2, level 1 has res 23.
  EXPECT_EQ(gridIndex(levels[1], 3, 4, 5), 3u + 4u * 23u + 5u * 529u);
  // The x = res corner wraps modulo the level size (tiny-cuda-nn behaviour).
  EXPECT_EQ(gridIndex(levels[0], 16, 15, 15), (16u + 15u * 16u + 15u * 256u) % 4096u);
}

// Small grid with random features for the property tests.
struct TestGrid {
  std::vector<GridLevel> levels;
  std::vector<float> table;
  explicit TestGrid(int n_levels = 8, int log2_t = 14, double finest = 256.0, uint32_t seed = 1) {
    levels = gridLevels(n_levels, 16, finest, log2_t);
    const size_t entries = levels.back().offset + size_t(levels.back().size);
    table.resize(2 * entries);
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(-1.f, 1.f);
    for (float& x : table) x = u(rng);
  }
  HashGridView view() const { return {levels.data(), int(levels.size()), table.data()}; }
  size_t features() const { return 2 * levels.size(); }
};

std::vector<float> randomPositions(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<float> p(3 * n);
  for (float& x : p) x = u(rng);
  return p;
}

TEST(HashGrid, DenseAndHashedLevelsWithSmallTable) {
  // T = 2^14: 16^3 = 4096 dense; 23^3 = 12167 dense; 31^3 = 29791 > 16384 hashed.
  TestGrid g(8, 14);
  EXPECT_TRUE(g.levels[0].dense);
  EXPECT_TRUE(g.levels[1].dense);
  EXPECT_FALSE(g.levels[2].dense);
  EXPECT_EQ(g.levels[2].size, 16384u);
}

TEST(HashGrid, ConstantTableInterpolatesToConstant) {
  // Weights sum to 1: a table filled with (a, b) encodes every point to (a, b) on every level.
  TestGrid g;
  for (size_t e = 0; e < g.table.size() / 2; ++e) {
    g.table[2 * e] = 0.75f;
    g.table[2 * e + 1] = -2.5f;
  }
  const size_t n = 257;
  const auto pos = randomPositions(n, 3);
  std::vector<float> enc(g.features() * n);
  hashEncodeScalar(g.view(), pos.data(), n, enc.data(), n);
  for (size_t k = 0; k < g.features(); ++k)
    for (size_t s = 0; s < n; ++s) ASSERT_NEAR(enc[k * n + s], (k % 2 == 0) ? 0.75f : -2.5f, 1e-5f);
}

TEST(HashGrid, GridVertexReturnsItsEntryAndEncodingIsContinuous) {
  TestGrid g;
  const GridLevel& L = g.levels[3];
  // A point exactly on grid vertex (i,j,k) of level 3: x*scale + 0.5 = i + 0.5 -> frac 0.5 in
  // the cell of vertex i... instead pick x with x*scale + 0.5 = i exactly: frac 0, weight 1.
  const uint32_t i = 7, j = 9, k = 4;
  const float pos[3] = {(float(i) - 0.5f) / L.scale, (float(j) - 0.5f) / L.scale, (float(k) - 0.5f) / L.scale};
  std::vector<float> enc(g.features());
  hashEncodeScalar(g.view(), pos, 1, enc.data(), 1);
  const uint32_t e = L.offset + gridIndex(L, i, j, k);
  EXPECT_NEAR(enc[6], g.table[2 * e], 1e-4f);
  EXPECT_NEAR(enc[7], g.table[2 * e + 1], 1e-4f);

  // Continuity: crossing a cell boundary on the finest level changes the encoding by O(eps).
  const GridLevel& F = g.levels.back();
  const float xb = (40.f - 0.5f) / F.scale;  // boundary between cells 39 and 40
  for (float eps : {1e-3f, 1e-4f}) {
    const float a[3] = {xb - eps / F.scale, 0.37f, 0.61f}, b[3] = {xb + eps / F.scale, 0.37f, 0.61f};
    std::vector<float> ea(g.features()), eb(g.features());
    hashEncodeScalar(g.view(), a, 1, ea.data(), 1);
    hashEncodeScalar(g.view(), b, 1, eb.data(), 1);
    for (size_t f = 0; f < g.features(); ++f) EXPECT_NEAR(ea[f], eb[f], 20 * eps) << f;
  }
}

TEST(HashGrid, SimdMatchesScalarOnEveryTarget) {
  TestGrid g(16, 15, 2048.0);
  const size_t n = 203;  // not a multiple of any lane count: exercises the tail
  auto pos = randomPositions(n, 5);
  pos[0] = 0.f;
  pos[1] = 1.f;
  pos[2] = 1.f;    // corners of the cube
  pos[3] = -0.5f;  // clamped
  std::vector<float> ref(g.features() * n);
  hashEncodeScalar(g.view(), pos.data(), n, ref.data(), n);
  std::vector<float> d_enc(g.features() * n);
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (float& x : d_enc) x = u(rng);
  for (size_t s = 0; s < n; s += 7) d_enc[s * g.features() + 3] = 0.f;
  const size_t entries = g.table.size() / 2;
  std::vector<float> gref(g.table.size(), 0.f);
  std::vector<uint64_t> tref((entries + 63) / 64, 0);
  hashEncodeBackwardScalar(g.view(), pos.data(), n, d_enc.data(), gref.data(), tref.data());
  // Targets without hardware FMA (SSE4, SSSE3, scalar) round x*scale+0.5 twice: on the finest
  // level (scale 2047) the fraction can then differ by one ulp of 2048 (1.2e-4), moving a feature
  // by at most 1.2e-4 * |table difference| (< 2.4e-4 here). A wrong corner or weight is O(0.1).
  const float tol = 3e-4f;
  int targets = 0;
  forEachSimdTarget([&](const std::string& name) {
    SCOPED_TRACE(name);
    EXPECT_EQ(name, activeSimdTarget());
    ++targets;
    std::vector<float> enc(g.features() * n, -9.f);
    hashEncode(g.view(), pos.data(), n, enc.data(), n);
    for (size_t i = 0; i < enc.size(); ++i) ASSERT_NEAR(enc[i], ref[i], tol) << i;
    std::vector<float> grad(g.table.size(), 0.f);
    std::vector<uint64_t> touched(tref.size(), 0);
    hashEncodeBackward(g.view(), pos.data(), n, d_enc.data(), grad.data(), touched.data());
    EXPECT_EQ(touched, tref);
    for (size_t i = 0; i < grad.size(); ++i) ASSERT_NEAR(grad[i], gref[i], tol) << i;
  });
  EXPECT_GE(targets, 1);
}

TEST(HashGrid, PerLevelBackwardMatchesFullBackwardOnEveryTarget) {
  // The optimiser's level-by-level scatter (d_enc level-major) must add what the full-table
  // backward adds, level by level, and mark the same entries. 203 samples: several blocks and a
  // ragged tail; some samples with a zero gradient on some levels.
  TestGrid g(16, 15, 2048.0);
  const size_t n = 203, nf = g.features();
  auto pos = randomPositions(n, 21);
  pos[3] = 1.f;
  pos[4] = -0.25f;  // clamped
  std::vector<float> d_enc(nf * n);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (float& x : d_enc) x = u(rng);
  for (size_t s = 0; s < n; s += 5) d_enc[s * nf + 6] = d_enc[s * nf + 7] = 0.f;
  const size_t entries = g.table.size() / 2;
  std::vector<float> gref(g.table.size(), 0.f);
  std::vector<uint64_t> tref((entries + 63) / 64, 0);
  hashEncodeBackwardScalar(g.view(), pos.data(), n, d_enc.data(), gref.data(), tref.data());
  auto run = [&](bool simd) {
    for (int l = 0; l < int(g.levels.size()); ++l) {
      SCOPED_TRACE(l);
      const GridLevel& L = g.levels[size_t(l)];
      std::vector<float> dl(2 * n), grad(2 * size_t(L.size), 0.f);
      for (size_t s = 0; s < n; ++s) {
        dl[2 * s] = d_enc[s * nf + 2 * size_t(l)];
        dl[2 * s + 1] = d_enc[s * nf + 2 * size_t(l) + 1];
      }
      std::vector<uint64_t> touched((L.size + 63) / 64, 0);
      if (simd)
        hashEncodeBackwardLevel(g.view(), l, pos.data(), n, dl.data(), grad.data(), touched.data());
      else
        hashEncodeBackwardLevelScalar(g.view(), l, pos.data(), n, dl.data(), grad.data(), touched.data());
      for (uint32_t e = 0; e < L.size; ++e) {
        const uint32_t a = L.offset + e;
        ASSERT_EQ((touched[e / 64] >> (e % 64)) & 1, (tref[a / 64] >> (a % 64)) & 1) << e;
        ASSERT_NEAR(grad[2 * e], gref[2 * size_t(a)], 3e-4f) << e;
        ASSERT_NEAR(grad[2 * e + 1], gref[2 * size_t(a) + 1], 3e-4f) << e;
      }
    }
  };
  run(false);
  forEachSimdTarget([&](const std::string& name) {
    SCOPED_TRACE(name);
    run(true);
  });
}

TEST(HashGrid, BackwardMatchesFiniteDifferences) {
  // The encoding is linear in the table: d(sum_k c_k enc_k)/d table[e] must equal the scattered
  // gradient; check a few touched entries by central differences in double-checked fp32.
  TestGrid g(8, 14, 256.0);
  const size_t n = 16, nf = g.features();
  const auto pos = randomPositions(n, 11);
  std::vector<float> c(nf * n);
  std::mt19937 rng(2);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (float& x : c) x = u(rng);
  auto loss = [&]() {
    std::vector<float> enc(nf * n);
    hashEncodeScalar(g.view(), pos.data(), n, enc.data(), n);
    double l = 0;
    for (size_t s = 0; s < n; ++s)
      for (size_t k = 0; k < nf; ++k) l += double(c[s * nf + k]) * enc[k * n + s];
    return l;
  };
  std::vector<float> grad(g.table.size(), 0.f);
  std::vector<uint64_t> touched((g.table.size() / 2 + 63) / 64, 0);
  hashEncodeBackward(g.view(), pos.data(), n, c.data(), grad.data(), touched.data());
  int checked = 0;
  for (size_t e = 0; e < g.table.size() / 2 && checked < 40; e += 37) {
    const bool t = (touched[e / 64] >> (e % 64)) & 1;
    for (int f = 0; f < 2; ++f) {
      float& p = g.table[2 * e + size_t(f)];
      const float p0 = p, h = 1e-2f;
      p = p0 + h;
      const double lp = loss();
      p = p0 - h;
      const double lm = loss();
      p = p0;
      const double fd = (lp - lm) / (2 * h);
      EXPECT_NEAR(grad[2 * e + size_t(f)], fd, 2e-4 + 1e-3 * std::abs(fd)) << e;
      if (!t) {
        EXPECT_EQ(grad[2 * e + size_t(f)], 0.f);
      }
    }
    if (t) ++checked;
  }
  EXPECT_GT(checked, 5);
}

TEST(HashGrid, PositionGradientMatchesFiniteDifferences) {
  TestGrid g(8, 14, 256.0);
  const size_t nf = g.features();
  const auto pos = randomPositions(8, 13);
  std::vector<float> c(nf);
  std::mt19937 rng(4);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (float& x : c) x = u(rng);
  for (size_t s = 0; s < 8; ++s) {
    std::vector<float> dcs(c);
    float grad[3];
    hashEncodePositionGradient(g.view(), &pos[3 * s], 1, dcs.data(), grad);
    for (int d = 0; d < 3; ++d) {
      // Within one cell of the finest level the encoding is smooth (trilinear).
      const double h = 1e-3 / g.levels.back().scale;
      float p[3] = {pos[3 * s], pos[3 * s + 1], pos[3 * s + 2]};
      auto f = [&](double x) {
        float q[3] = {p[0], p[1], p[2]};
        q[d] = float(x);
        std::vector<float> enc(nf);
        hashEncodeScalar(g.view(), q, 1, enc.data(), 1);
        double l = 0;
        for (size_t k = 0; k < nf; ++k) l += double(c[k]) * enc[k];
        return l;
      };
      const double fd = (f(p[d] + h) - f(p[d] - h)) / (2 * h);
      EXPECT_NEAR(grad[d], fd, 0.02 * std::abs(fd) + 0.5) << s << " " << d;
    }
  }
}

}  // namespace
}  // namespace nerfslam::nerf
