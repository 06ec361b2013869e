// RadianceField: config validation, inference vs training forward, whole-field backward and
// density gradient against central finite differences, determinism, and a small fitting run.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <thread>
#include <vector>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/field.h"
#include "nerfslam/nerf/hash_grid.h"

namespace nerfslam::nerf {
namespace {

FieldConfig smallConfig() {
  FieldConfig c;
  c.n_levels = 8;
  c.log2_hashmap_size = 14;
  c.finest_resolution = 128;
  c.hidden = 32;
  return c;
}

struct Batch {
  std::vector<float> pos, dir;
};

Batch randomBatch(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::normal_distribution<float> g;
  Batch b;
  b.pos.resize(3 * n);
  b.dir.resize(3 * n);
  for (float& x : b.pos) x = 0.05f + 0.9f * u(rng);
  for (size_t s = 0; s < n; ++s) {
    float d[3] = {g(rng), g(rng), g(rng)};
    const float r = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int k = 0; k < 3; ++k) b.dir[3 * s + size_t(k)] = d[k] / r;
  }
  return b;
}

// Larger-than-init hash features so that the network is far from linear in the test.
void randomiseTable(RadianceField& field, float range, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-range, range);
  FloatArray t = field.parameters()[0];
  for (size_t i = 0; i < t.size; ++i) t.data[i] = u(rng);
  field.parametersChanged();
}

TEST(RadianceField, RejectsInvalidConfig) {
  FieldConfig c;
  c.n_levels = 12;
  EXPECT_THROW(RadianceField(c, 1), Error);
  c = FieldConfig();
  c.hidden = 40;
  EXPECT_THROW(RadianceField(c, 1), Error);
  c = FieldConfig();
  c.log2_hashmap_size = 30;
  try {
    RadianceField f(c, 1);
    FAIL() << "accepted log2_hashmap_size = 30";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("log2_hashmap_size"), std::string::npos);
  }
  c = FieldConfig();
  c.adam.beta2 = 1.5;
  EXPECT_THROW(RadianceField(c, 1), Error);
}

TEST(RadianceField, ParameterLayoutAndInit) {
  RadianceField f(FieldConfig(), 7);
  const auto params = f.parameters();
  ASSERT_EQ(params.size(), 6u);
  const auto levels = gridLevels(16, 16, 2048.0, 19);
  EXPECT_EQ(params[0].size, 2 * size_t(levels.back().offset + levels.back().size));
  EXPECT_EQ(params[1].size, 32u * 64u);
  EXPECT_EQ(params[5].size, 64u * 16u);
  float lo = 1, hi = -1;
  for (size_t i = 0; i < params[0].size; ++i) {
    lo = std::min(lo, params[0].data[i]);
    hi = std::max(hi, params[0].data[i]);
  }
  EXPECT_GE(lo, -1e-4f);
  EXPECT_LE(hi, 1e-4f);
  EXPECT_LT(lo, -0.9e-4f);
  EXPECT_GT(hi, 0.9e-4f);
  for (size_t r = 0; r < 64; ++r)
    for (size_t c = 3; c < 16; ++c) EXPECT_EQ(params[5].data[r * 16 + c], 0.f);
  size_t total = 0;
  for (const auto& p : params) total += p.size;
  EXPECT_EQ(total, f.numParameters());
}

TEST(RadianceField, TrainingForwardMatchesInference) {
  RadianceField f(smallConfig(), 3);
  randomiseTable(f, 0.5f, 1);
  const size_t n = 150;
  const Batch b = randomBatch(n, 2);
  std::vector<float> s1(n), c1(3 * n), s2(n), c2(3 * n), s3(n);
  auto ws = f.makeWorkspace();
  f.forward(ws, b.pos.data(), b.dir.data(), n, s1.data(), c1.data());
  f.query(b.pos.data(), b.dir.data(), n, s2.data(), c2.data());
  f.queryDensity(b.pos.data(), n, s3.data());
  for (size_t i = 0; i < n; ++i) {
    EXPECT_EQ(s1[i], s2[i]);
    EXPECT_EQ(s1[i], s3[i]);
    EXPECT_GT(s1[i], 0.f);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(c1[3 * i + size_t(k)], c2[3 * i + size_t(k)]);
      EXPECT_GT(c1[3 * i + size_t(k)], 0.f);
      EXPECT_LT(c1[3 * i + size_t(k)], 1.f);
    }
  }
}

TEST(RadianceField, TwoStageTrainingForwardEqualsForwardAndBackward) {
  // forwardDensity + forwardColor on a subset: the same bits as forward() for the needed samples,
  // rgb 0 for the others, and the same parameter gradients when only needed samples carry a loss.
  RadianceField f(smallConfig(), 5);
  randomiseTable(f, 0.5f, 9);
  const size_t n = 200;  // > 3 tiles, so compacted tiles mix samples of different forward tiles
  const Batch b = randomBatch(n, 10);
  std::vector<uint8_t> needed(n);
  for (size_t i = 0; i < n; ++i) needed[i] = (i % 5 != 2 && i % 7 != 0) ? 1 : 0;
  std::vector<float> s1(n), c1(3 * n), s2(n), c2(3 * n);
  auto ws1 = f.makeWorkspace(), ws2 = f.makeWorkspace();
  f.forward(ws1, b.pos.data(), b.dir.data(), n, s1.data(), c1.data());
  f.forwardDensity(ws2, b.pos.data(), b.dir.data(), n, s2.data());
  f.forwardColor(ws2, needed.data(), c2.data());
  for (size_t i = 0; i < n; ++i) {
    ASSERT_EQ(s1[i], s2[i]) << i;
    for (size_t k = 0; k < 3; ++k) ASSERT_EQ(c2[3 * i + k], needed[i] ? c1[3 * i + k] : 0.f) << i;
  }
  std::vector<float> dls(n), dlc(3 * n);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (size_t i = 0; i < n; ++i) {
    if (!needed[i]) continue;
    dls[i] = u(rng);
    for (size_t k = 0; k < 3; ++k) dlc[3 * i + k] = u(rng);
  }
  auto g1 = f.makeGradients(), g2 = f.makeGradients();
  f.backward(ws1, dls.data(), dlc.data(), g1);
  f.backward(ws2, dls.data(), dlc.data(), g2);
  const auto a = f.gradients(g1), c = f.gradients(g2);
  ASSERT_EQ(a.size(), c.size());
  for (size_t p = 0; p < a.size(); ++p) {
    ASSERT_EQ(a[p].size, c[p].size);
    EXPECT_EQ(0, std::memcmp(a[p].data, c[p].data, a[p].size * sizeof(float))) << a[p].name;
  }
}

TEST(RadianceField, TwoStageInferenceEqualsQuery) {
  RadianceField f(smallConfig(), 4);
  randomiseTable(f, 0.5f, 7);
  const size_t n = 150;
  const Batch b = randomBatch(n, 8);
  std::vector<float> s1(n), c1(3 * n), s2(n), geo(n * kDensityOutputs), c2(3 * n);
  f.query(b.pos.data(), b.dir.data(), n, s1.data(), c1.data());
  f.queryDensityOutputs(b.pos.data(), n, s2.data(), geo.data());
  // Colour of a subset, in another order and batch size (the renderer's use).
  std::vector<size_t> pick;
  for (size_t i = n; i-- > 0;)
    if (i % 3 != 1) pick.push_back(i);
  std::vector<float> g(pick.size() * kDensityOutputs), d(3 * pick.size()), c(3 * pick.size());
  for (size_t j = 0; j < pick.size(); ++j) {
    std::copy(&geo[pick[j] * kDensityOutputs], &geo[(pick[j] + 1) * kDensityOutputs], &g[j * kDensityOutputs]);
    std::copy(&b.dir[3 * pick[j]], &b.dir[3 * pick[j] + 3], &d[3 * j]);
  }
  f.queryColor(g.data(), d.data(), pick.size(), c.data());
  for (size_t i = 0; i < n; ++i) EXPECT_EQ(s1[i], s2[i]);
  for (size_t j = 0; j < pick.size(); ++j)
    for (int k = 0; k < 3; ++k) EXPECT_EQ(c[3 * j + size_t(k)], c1[3 * pick[j] + size_t(k)]);
}

TEST(RadianceField, NonFinitePositionsAreClampedNotFatal) {
  RadianceField f(smallConfig(), 3);
  const float nan = std::nanf(""), inf = INFINITY;
  const std::vector<float> pos = {nan, 0.5f, 0.5f, inf, -inf, 2.f, 0.f, 0.f, 0.f};
  const std::vector<float> dir = {0, 0, 1, 0, 0, 1, 0, 0, 1};
  std::vector<float> s(3), c(9), ref(1);
  f.query(pos.data(), dir.data(), 3, s.data(), c.data());
  for (float x : s) EXPECT_TRUE(std::isfinite(x));
  // NaN is treated as 0, +inf as 1, -inf as 0.
  const float p0[3] = {0.f, 0.5f, 0.5f};
  f.queryDensity(p0, 1, ref.data());
  EXPECT_EQ(s[0], ref[0]);
  const float p1[3] = {1.f, 0.f, 1.f};
  f.queryDensity(p1, 1, ref.data());
  EXPECT_EQ(s[1], ref[0]);
}

TEST(RadianceField, BackwardMatchesFiniteDifferences) {
  FieldConfig cfg = smallConfig();
  cfg.hidden = 16;
  RadianceField f(cfg, 11);
  randomiseTable(f, 0.5f, 2);
  const size_t n = 70;  // two tiles, the second ragged
  const Batch b = randomBatch(n, 3);
  std::mt19937 rng(4);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::vector<float> ws_(n), wc(3 * n);
  // Non-zero loss weights on 12 samples (in both tiles): fewer ReLU kinks near the FD points.
  for (size_t i = 0; i < n; ++i) {
    if (i % 6 != 0) continue;
    ws_[i] = 0.1f * u(rng);
    for (int k = 0; k < 3; ++k) wc[3 * i + size_t(k)] = u(rng);
  }
  // L = sum ws_ * sigma + sum wc * rgb  (dL/dsigma = ws_, dL/drgb = wc).
  auto loss = [&]() {
    std::vector<float> s(n), c(3 * n);
    f.query(b.pos.data(), b.dir.data(), n, s.data(), c.data());
    double l = 0;
    for (size_t i = 0; i < n; ++i) l += double(ws_[i]) * s[i];
    for (size_t i = 0; i < 3 * n; ++i) l += double(wc[i]) * c[i];
    return l;
  };
  auto ws = f.makeWorkspace();
  auto grads = f.makeGradients();
  f.forward(ws, b.pos.data(), b.dir.data(), n, nullptr, nullptr);
  f.backward(ws, ws_.data(), wc.data(), grads);
  const auto params = f.parameters();
  const auto g = f.gradients(grads);
  ASSERT_EQ(params.size(), g.size());
  for (size_t a = 0; a < params.size(); ++a) {
    SCOPED_TRACE(params[a].name);
    // Check the entries with the largest gradients (well above FD noise) plus random ones.
    std::vector<size_t> idx(params[a].size);
    for (size_t i = 0; i < idx.size(); ++i) idx[i] = i;
    std::partial_sort(idx.begin(), idx.begin() + 6, idx.end(),
                      [&](size_t x, size_t y) { return std::abs(g[a].data[x]) > std::abs(g[a].data[y]); });
    idx.resize(6);
    for (int r = 0; r < 4; ++r) idx.push_back(size_t(rng()) % params[a].size);
    double max_abs = 0;
    for (size_t i = 0; i < params[a].size; ++i) max_abs = std::max(max_abs, double(std::abs(g[a].data[i])));
    EXPECT_GT(max_abs, 1e-3);
    // The network is piecewise smooth (ReLU): central differences are only valid when no
    // pre-activation crosses zero within +-h. Two step sizes that disagree reveal a kink; such
    // indices are skipped, and most must be smooth.
    int smooth = 0;
    for (size_t i : idx) {
      float& p = params[a].data[i];
      const float p0 = p;
      auto fdAt = [&](float h) {
        p = p0 + h;
        f.parametersChanged();
        const double lp = loss();
        p = p0 - h;
        f.parametersChanged();
        const double lm = loss();
        p = p0;
        f.parametersChanged();
        return (lp - lm) / (2.0 * double(h));
      };
      const double fd1 = fdAt(1e-3f), fd2 = fdAt(5e-4f);
      if (std::abs(fd1 - fd2) > 1e-3 + 0.005 * std::abs(fd1)) continue;
      ++smooth;
      EXPECT_NEAR(g[a].data[i], fd2, 2e-3 + 0.02 * std::abs(fd2)) << "index " << i;
    }
    EXPECT_GE(smooth, int(idx.size()) * 6 / 10);
  }
}

TEST(RadianceField, DensityGradientMatchesFiniteDifferences) {
  RadianceField f(smallConfig(), 5);
  randomiseTable(f, 0.5f, 3);
  const size_t n = 20;
  const Batch b = randomBatch(n, 6);
  std::vector<float> grad(3 * n);
  f.densityGradient(b.pos.data(), n, grad.data());
  const double h = 1e-3 / 128.0;  // a thousandth of the finest cell
  int close = 0;
  for (size_t s = 0; s < n; ++s) {
    for (int d = 0; d < 3; ++d) {
      float q[3] = {b.pos[3 * s], b.pos[3 * s + 1], b.pos[3 * s + 2]};
      float sp, sm;
      q[d] = float(b.pos[3 * s + size_t(d)] + h);
      f.queryDensity(q, 1, &sp);
      q[d] = float(b.pos[3 * s + size_t(d)] - h);
      f.queryDensity(q, 1, &sm);
      const double fd = (double(sp) - sm) / (2 * h);
      // A ReLU kink inside +-h is possible but rare: require 90% of the components to agree.
      if (std::abs(grad[3 * s + size_t(d)] - fd) <= 0.02 * std::abs(fd) + 0.05 * (1 + std::abs(sp))) ++close;
    }
  }
  EXPECT_GE(close, int(0.9 * 3 * n));
}

// Two threads, each forward/backward on its half of the batch, then step; returns all params.
std::vector<float> trainFewSteps(uint64_t seed, int step_threads) {
  RadianceField f(smallConfig(), seed);
  const size_t n = 512;
  std::vector<RadianceField::Workspace> ws;
  std::vector<RadianceField::Gradients> gs;
  for (int t = 0; t < 2; ++t) {
    ws.push_back(f.makeWorkspace());
    gs.push_back(f.makeGradients());
  }
  for (int it = 0; it < 4; ++it) {
    const Batch b = randomBatch(n, uint32_t(100 + it));
    std::vector<float> target(3 * n, 0.3f);
    auto work = [&](int t) {
      const size_t s0 = size_t(t) * n / 2, m = n / 2;
      std::vector<float> sigma(m), rgb(3 * m), dl_ds(m), dl_dc(3 * m);
      f.forward(ws[size_t(t)], &b.pos[3 * s0], &b.dir[3 * s0], m, sigma.data(), rgb.data());
      for (size_t i = 0; i < m; ++i) {
        dl_ds[i] = 0.01f * (sigma[i] - 2.f);
        for (int k = 0; k < 3; ++k) dl_dc[3 * i + size_t(k)] = rgb[3 * i + size_t(k)] - target[3 * (s0 + i)];
      }
      f.backward(ws[size_t(t)], dl_ds.data(), dl_dc.data(), gs[size_t(t)]);
    };
    std::thread t1(work, 1);
    work(0);
    t1.join();
    f.step({&gs[0], &gs[1]}, 1e-2f, step_threads);
  }
  EXPECT_EQ(f.stepCount(), 4u);
  std::vector<float> all;
  for (const auto& p : f.parameters()) all.insert(all.end(), p.data, p.data + p.size);
  for (const auto& p : f.optimizerMoments()) all.insert(all.end(), p.data, p.data + p.size);
  return all;
}

TEST(RadianceField, DeterministicAcrossRunsAndStepThreads) {
  const auto a = trainFewSteps(42, 1);
  const auto b = trainFewSteps(42, 1);
  const auto c = trainFewSteps(42, 2);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(float)));
  EXPECT_EQ(0, std::memcmp(a.data(), c.data(), a.size() * sizeof(float)));
  const auto d = trainFewSteps(43, 1);
  EXPECT_NE(0, std::memcmp(a.data(), d.data(), a.size() * sizeof(float)));
}

TEST(RadianceField, StepTouchesOnlyUsedEntriesAndClearsGradients) {
  RadianceField f(smallConfig(), 9);
  const auto before = std::vector<float>(f.parameters()[0].data, f.parameters()[0].data + f.parameters()[0].size);
  const Batch b = randomBatch(1, 1);
  auto ws = f.makeWorkspace();
  auto gs = f.makeGradients();
  float sigma, rgb[3];
  f.forward(ws, b.pos.data(), b.dir.data(), 1, &sigma, rgb);
  const float dls = 1.f, dlc[3] = {1.f, -1.f, 0.5f};
  f.backward(ws, &dls, dlc, gs);
  f.step({&gs}, 1e-2f);
  const FloatArray t = f.parameters()[0];
  size_t changed = 0;
  for (size_t i = 0; i < t.size; ++i) changed += t.data[i] != before[i];
  // One sample touches at most 8 corners x 2 features per level.
  EXPECT_GT(changed, 0u);
  EXPECT_LE(changed, 8u * 2u * 8u);
  const U32Array steps = f.optimizerCounters()[0];
  size_t stepped = 0;
  for (size_t i = 0; i < steps.size; ++i) stepped += steps.data[i];
  EXPECT_EQ(stepped * 2, changed);
  for (const auto& g : f.gradients(gs))
    for (size_t i = 0; i < g.size; ++i) ASSERT_EQ(g.data[i], 0.f) << g.name;
}

TEST(RadianceField, FitsAnAnalyticFieldTenfold) {
  FieldConfig cfg = smallConfig();
  cfg.log2_hashmap_size = 16;
  cfg.hidden = 64;
  RadianceField f(cfg, 1);
  auto logd = [](const float* p) { return 2.f * std::sin(6.f * p[0]) * std::cos(5.f * p[1]) + 1.5f * p[2]; };
  auto color = [](const float* p, const float* d, int k) {
    return 0.5f + 0.35f * std::sin(4.f * p[k] + 3.f * p[(k + 1) % 3]) + 0.1f * d[k];
  };
  const Batch test = randomBatch(2000, 999);
  auto evalLoss = [&]() {
    std::vector<float> s(2000), c(6000);
    f.query(test.pos.data(), test.dir.data(), 2000, s.data(), c.data());
    double l = 0;
    for (size_t i = 0; i < 2000; ++i) {
      const double e = std::log(double(s[i])) - logd(&test.pos[3 * i]);
      l += e * e;
      for (int k = 0; k < 3; ++k) {
        const double ec = c[3 * i + size_t(k)] - color(&test.pos[3 * i], &test.dir[3 * i], k);
        l += 10 * ec * ec;
      }
    }
    return l / 2000;
  };
  const double l0 = evalLoss();
  auto ws = f.makeWorkspace();
  auto gs = f.makeGradients();
  const size_t n = 2048;
  for (int it = 0; it < 120; ++it) {
    const Batch b = randomBatch(n, uint32_t(it));
    std::vector<float> s(n), c(3 * n), ds(n), dc(3 * n);
    f.forward(ws, b.pos.data(), b.dir.data(), n, s.data(), c.data());
    for (size_t i = 0; i < n; ++i) {
      ds[i] = 2.f * (std::log(s[i]) - logd(&b.pos[3 * i])) / s[i] / float(n);
      for (int k = 0; k < 3; ++k)
        dc[3 * i + size_t(k)] = 20.f * (c[3 * i + size_t(k)] - color(&b.pos[3 * i], &b.dir[3 * i], k)) / float(n);
    }
    f.backward(ws, ds.data(), dc.data(), gs);
    f.step({&gs}, 1e-2f);
  }
  const double l1 = evalLoss();
  EXPECT_LT(l1, l0 / 10) << "initial " << l0 << " final " << l1;
  RecordProperty("loss_ratio", std::to_string(l0 / l1));
  std::printf("fit: initial loss %.4f, final %.4f\n", l0, l1);
}

}  // namespace
}  // namespace nerfslam::nerf
