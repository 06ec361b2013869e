// Adam: a hand-computed update, SIMD vs scalar on every target, and the sparse per-entry rule.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "nerfslam/nerf/adam.h"
#include "nerfslam/nerf/simd.h"

namespace nerfslam::nerf {
namespace {

TEST(Adam, FirstStepsByHand) {
  // Step 1 of Adam moves each parameter by -lr * sign(g) (m_hat = g, v_hat = g^2) up to eps.
  AdamOptions opt;
  float p[3] = {1.f, -2.f, 0.5f}, m[3] = {}, v[3] = {};
  const float g[3] = {0.3f, -4.f, 0.f};
  adamDenseScalar(p, m, v, g, 3, 1, 0.01f, opt, 0.f);
  EXPECT_NEAR(p[0], 0.99f, 1e-6);
  EXPECT_NEAR(p[1], -1.99f, 1e-6);
  EXPECT_EQ(p[2], 0.5f);
  EXPECT_NEAR(m[0], 0.03f, 1e-7);
  EXPECT_NEAR(v[1], 0.16f, 1e-6);
  // Step 2 with g = 0.1 on parameter 0: m = .9*.03 + .1*.1 = .037, v = .99*.0009 + .01*.01 = .000991
  // m_hat = .037/.19, v_hat = .000991/.0199; update = .01 * m_hat / sqrt(v_hat).
  const float g2[3] = {0.1f, 0.f, 0.f};
  adamDenseScalar(p, m, v, g2, 3, 2, 0.01f, opt, 0.f);
  const double mh = 0.037 / 0.19, vh = 0.000991 / (1 - 0.99 * 0.99);
  EXPECT_NEAR(p[0], 0.99 - 0.01 * mh / std::sqrt(vh), 1e-6);
  // L2: g_eff = g + l2 * p.
  float q = 2.f, qm = 0.f, qv = 0.f;
  const float zero = 0.f;
  adamDenseScalar(&q, &qm, &qv, &zero, 1, 1, 0.01f, opt, 0.5f);
  EXPECT_NEAR(qm, 0.1f * 1.f, 1e-7);  // (1-b1) * (0 + 0.5*2)
  EXPECT_NEAR(q, 1.99f, 1e-6);
}

TEST(Adam, SimdMatchesScalarOnEveryTarget) {
  const size_t n = 1000 + 3;
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::vector<float> p0(n), g(n);
  for (size_t i = 0; i < n; ++i) {
    p0[i] = u(rng);
    g[i] = u(rng) * 1e-2f;
  }
  AdamOptions opt;
  std::vector<float> pr(p0), mr(n, 0.f), vr(n, 0.f);
  for (uint64_t t = 1; t <= 3; ++t) adamDenseScalar(pr.data(), mr.data(), vr.data(), g.data(), n, t, 1e-2f, opt, 1e-6f);
  forEachSimdTarget([&](const std::string& name) {
    SCOPED_TRACE(name);
    std::vector<float> p(p0), m(n, 0.f), v(n, 0.f);
    for (uint64_t t = 1; t <= 3; ++t) adamDense(p.data(), m.data(), v.data(), g.data(), n, t, 1e-2f, opt, 1e-6f);
    for (size_t i = 0; i < n; ++i) {
      ASSERT_NEAR(p[i], pr[i], 1e-6f) << i;
      ASSERT_NEAR(m[i], mr[i], 1e-9f) << i;
    }
  });
}

TEST(Adam, SparseEntryUsesItsOwnStepCounter) {
  // An entry first updated at global step 100 gets a step-1 update (bias-corrected by its own t).
  AdamOptions opt;
  AdamBiasTable bias(opt);
  EXPECT_FLOAT_EQ(bias.correction1(1), 0.1f);
  EXPECT_NEAR(bias.correction2(2), 1 - 0.99 * 0.99, 1e-7);
  EXPECT_EQ(bias.correction1(1u << 30), bias.c1[AdamBiasTable::kSize - 1]);
  float p[2] = {0.f, 1.f}, m[2] = {}, v[2] = {};
  const float g[2] = {-3.f, 0.25f};
  uint32_t step = 0;
  adamEntry<2>(p, m, v, g, &step, 0.01f, opt, bias);
  EXPECT_EQ(step, 1u);
  EXPECT_NEAR(p[0], 0.01f, 1e-6);
  EXPECT_NEAR(p[1], 0.99f, 1e-6);
  // Matches the dense rule at t = 1.
  float q[2] = {0.f, 1.f}, qm[2] = {}, qv[2] = {};
  adamDenseScalar(q, qm, qv, g, 2, 1, 0.01f, opt, 0.f);
  EXPECT_FLOAT_EQ(p[0], q[0]);
  EXPECT_FLOAT_EQ(p[1], q[1]);
}

TEST(Adam, SparseLevelSimdMatchesScalarAndEntryRule) {
  // One level of 1000 entries (a multiple of 8, as every level is): random touched bits, some
  // touched entries with an exactly zero summed gradient (skipped), step counters on both sides of
  // the bias table's end.
  const size_t n = 1000;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  AdamOptions opt;
  AdamBiasTable bias(opt);
  std::vector<float> p0(2 * n), m0(2 * n), v0(2 * n), g0(2 * n, 0.f);
  std::vector<uint32_t> s0(n);
  std::vector<uint64_t> t0((n + 63) / 64, 0);
  for (size_t e = 0; e < n; ++e) {
    for (int f = 0; f < 2; ++f) {
      p0[2 * e + f] = u(rng);
      m0[2 * e + f] = 1e-2f * u(rng);
      v0[2 * e + f] = 1e-4f * std::abs(u(rng));
    }
    s0[e] = uint32_t(rng() % 3) == 0 ? uint32_t(AdamBiasTable::kSize + rng() % 100) : uint32_t(rng() % 50);
    if (rng() % 3 == 0) {
      t0[e / 64] |= uint64_t(1) << (e % 64);
      if (rng() % 5 != 0) {
        g0[2 * e] = 1e-2f * u(rng);
        g0[2 * e + 1] = rng() % 4 == 0 ? 0.f : 1e-2f * u(rng);
      }
    }
  }
  // Reference: adamEntry<2> entry by entry, on the scaled gradient (the trainer passes 1/rays).
  const float kScale = 1.f / 4093.f;
  std::vector<float> pr(p0), mr(m0), vr(v0);
  std::vector<uint32_t> sr(s0);
  for (size_t e = 0; e < n; ++e) {
    if (!((t0[e / 64] >> (e % 64)) & 1)) continue;
    if (g0[2 * e] == 0.f && g0[2 * e + 1] == 0.f) continue;
    const float gs[2] = {g0[2 * e] * kScale, g0[2 * e + 1] * kScale};
    adamEntry<2>(&pr[2 * e], &mr[2 * e], &vr[2 * e], gs, &sr[e], 1e-2f, opt, bias);
  }
  auto check = [&](bool simd) {
    std::vector<float> p(p0), m(m0), v(v0), g(g0);
    std::vector<uint32_t> st(s0);
    std::vector<uint64_t> t(t0);
    if (simd)
      adamSparseLevel(p.data(), m.data(), v.data(), g.data(), t.data(), st.data(), n, 1e-2f, opt, bias, kScale);
    else
      adamSparseLevelScalar(p.data(), m.data(), v.data(), g.data(), t.data(), st.data(), n, 1e-2f, opt, bias, kScale);
    EXPECT_EQ(st, sr);
    for (uint64_t w : t) ASSERT_EQ(w, 0u);
    for (float x : g) ASSERT_EQ(x, 0.f);
    for (size_t i = 0; i < 2 * n; ++i) {
      ASSERT_NEAR(p[i], pr[i], 1e-6f) << i;
      ASSERT_NEAR(m[i], mr[i], 1e-9f) << i;
      ASSERT_NEAR(v[i], vr[i], 1e-11f) << i;
      if (!simd) {
        ASSERT_EQ(p[i], pr[i]) << i;  // the scalar reference is adamEntry itself
      }
    }
  };
  check(false);
  forEachSimdTarget([&](const std::string& name) {
    SCOPED_TRACE(name);
    check(true);
  });
}

}  // namespace
}  // namespace nerfslam::nerf
