#include "nerfslam/nerf/composite.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace nerfslam::nerf {
namespace {

// A slab of constant density sigma between t0 and t0 + d, sampled at n midpoints.
struct Slab {
  std::vector<float> sigma, rgb, dt, t;
  Slab(int n, float s, float t0, float d, const float c[3]) {
    for (int i = 0; i < n; ++i) {
      sigma.push_back(s);
      dt.push_back(d / n);
      t.push_back(t0 + (i + 0.5f) * d / n);
      rgb.insert(rgb.end(), {c[0], c[1], c[2]});
    }
  }
};

TEST(Composite, ConstantSlabMatchesClosedForm) {
  const float c[3] = {0.9f, 0.2f, 0.4f}, bg[3] = {0.1f, 0.7f, 1.0f};
  for (float s : {0.5f, 3.f, 12.f}) {
    const float t0 = 1.f, d = 0.8f;
    const Slab slab(4000, s, t0, d, c);
    const CompositeResult r =
        compositeForward(4000, slab.sigma.data(), slab.rgb.data(), slab.dt.data(), slab.t.data(), bg, 0.f);
    const double T = std::exp(-double(s) * d);
    EXPECT_NEAR(r.opacity, 1.0 - T, 2e-4) << s;
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(r.rgb[k], c[k] * (1 - T) + bg[k] * T, 2e-4) << s;
    // E[t | terminated in the slab] for an exponential distribution truncated to [t0, t0+d].
    const double mean = t0 + 1.0 / s - d * T / (1.0 - T);
    EXPECT_NEAR(r.depth, mean, 1e-3) << s;
    // Variance of the truncated exponential: 1/s^2 - d^2 T / (1-T)^2.
    const double var = 1.0 / (double(s) * s) - d * d * T / ((1 - T) * (1 - T));
    EXPECT_NEAR(r.depth_var, var, 2e-3 * var + 1e-5) << s;
  }
}

TEST(Composite, EarlyTerminationStopsAtTransmittanceFloor) {
  const float c[3] = {1, 1, 1}, bg[3] = {0, 0, 0};
  const Slab slab(100, 50.f, 0.f, 1.f, c);  // alpha per sample 1 - e^-0.5
  const CompositeResult r =
      compositeForward(100, slab.sigma.data(), slab.rgb.data(), slab.dt.data(), slab.t.data(), bg);
  // T after k samples = e^{-0.5k} < 1e-4 first at k = 19.
  EXPECT_EQ(r.used, 19);
  EXPECT_NEAR(1.f - r.opacity, std::exp(-0.5f * 19), 1e-7);
}

TEST(Composite, UsedSamplesFromDensitiesAloneMatchTheComposite) {
  // The trainer evaluates colour only for these samples: the count must be compositeForward's.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  const float bg[3] = {0.5f, 0.5f, 0.5f};
  int terminated = 0;
  for (int ray = 0; ray < 500; ++ray) {
    const int n = 1 + int(u(rng) * 120);
    const float scale = std::pow(10.f, 4.f * u(rng) - 1.f);  // transparent to opaque rays
    const size_t count = static_cast<size_t>(n);
    std::vector<float> sigma(count), rgb(3 * count), dt(count), t(count);
    for (int i = 0; i < n; ++i) {
      sigma[size_t(i)] = scale * u(rng);
      dt[size_t(i)] = 0.001f + 0.01f * u(rng);
      t[size_t(i)] = 0.01f * float(i);
      for (int k = 0; k < 3; ++k) rgb[3 * size_t(i) + size_t(k)] = u(rng);
    }
    const CompositeResult r = compositeForward(n, sigma.data(), rgb.data(), dt.data(), t.data(), bg);
    ASSERT_EQ(compositeUsedSamples(n, sigma.data(), dt.data()), r.used) << "ray " << ray;
    terminated += r.used < n;
  }
  EXPECT_GT(terminated, 50);  // the early termination was exercised
  EXPECT_LT(terminated, 450);
}

double lossOf(const std::vector<float>& sigma, const std::vector<float>& rgb, const std::vector<float>& dt,
              const std::vector<float>& t, const float bg[3], const double a[3], double b) {
  const CompositeResult r = compositeForward(int(sigma.size()), sigma.data(), rgb.data(), dt.data(), t.data(), bg);
  return a[0] * r.rgb[0] + a[1] * r.rgb[1] + a[2] * r.rgb[2] + b * r.depth_sum;
}

void checkGradients(float sigma_scale, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  const int n = 24;
  std::vector<float> sigma(n), rgb(3 * n), dt(n), t(n);
  float tt = 0.5f;
  for (int i = 0; i < n; ++i) {
    sigma[i] = sigma_scale * u(rng);
    dt[i] = 0.01f + 0.02f * u(rng);
    t[i] = tt + 0.5f * dt[i];
    tt += dt[i];
    for (int c = 0; c < 3; ++c) rgb[3 * i + c] = u(rng);
  }
  const float bg[3] = {u(rng), u(rng), u(rng)};
  const double a[3] = {0.7, -1.3, 0.4}, b = 0.8;
  const CompositeResult fwd = compositeForward(n, sigma.data(), rgb.data(), dt.data(), t.data(), bg);
  const float d_color[3] = {float(a[0]), float(a[1]), float(a[2])};
  std::vector<float> d_sigma(n), d_rgb(3 * n);
  compositeBackward(n, sigma.data(), rgb.data(), dt.data(), t.data(), bg, fwd, d_color, float(b), d_sigma.data(),
                    d_rgb.data());
  int checked = 0;
  for (int i = 0; i < n; ++i) {
    const float h = 1e-2f * std::max(1.f, sigma[i]);
    auto sp = sigma, sm = sigma;
    sp[i] += h;
    sm[i] -= h;
    if (sm[i] < 0) continue;
    const double fd = (lossOf(sp, rgb, dt, t, bg, a, b) - lossOf(sm, rgb, dt, t, bg, a, b)) / (2.0 * h);
    EXPECT_NEAR(d_sigma[i], fd, 2e-3 + 2e-2 * std::fabs(fd)) << "sigma " << i;
    for (int c = 0; c < 3; ++c) {
      auto rp = rgb, rm = rgb;
      rp[3 * i + c] += 1e-2f;
      rm[3 * i + c] -= 1e-2f;
      const double fdc = (lossOf(sigma, rp, dt, t, bg, a, b) - lossOf(sigma, rm, dt, t, bg, a, b)) / 2e-2;
      EXPECT_NEAR(d_rgb[3 * i + c], fdc, 1e-4 + 1e-3 * std::fabs(fdc)) << "rgb " << i << "," << c;
    }
    ++checked;
  }
  EXPECT_GT(checked, n / 2);
}

TEST(Composite, BackwardMatchesFiniteDifferences) {
  for (unsigned seed = 1; seed <= 4; ++seed) checkGradients(20.f, seed);
}

TEST(Composite, BackwardMatchesFiniteDifferencesWithEarlyTermination) {
  // Dense enough that the ray terminates inside the sample list; samples past it get zero gradient.
  checkGradients(600.f, 11);
  const int n = 8;
  std::vector<float> sigma(n, 2000.f), rgb(3 * n, 0.5f), dt(n, 0.01f), t(n, 1.f), d_sigma(n), d_rgb(3 * n);
  const float bg[3] = {0, 0, 0}, dc[3] = {1, 1, 1};
  const CompositeResult fwd = compositeForward(n, sigma.data(), rgb.data(), dt.data(), t.data(), bg);
  ASSERT_LT(fwd.used, n);
  compositeBackward(n, sigma.data(), rgb.data(), dt.data(), t.data(), bg, fwd, dc, 0.f, d_sigma.data(), d_rgb.data());
  for (int i = fwd.used; i < n; ++i) EXPECT_EQ(d_sigma[i], 0.f);
}

TEST(Composite, HuberLossAndGradient) {
  const float pred[3] = {0.5f, 0.0f, 1.0f}, target[3] = {0.45f, 0.5f, 0.2f};
  float g[3];
  const float loss = huberLoss3(pred, target, 0.1f, g);
  // 0.05 is quadratic (0.5 * 0.05^2 / 0.1), 0.5 and 0.8 linear (|d| - 0.05).
  EXPECT_NEAR(loss, 0.0125f + 0.45f + 0.75f, 1e-6);
  EXPECT_NEAR(g[0], 0.5f, 1e-6);
  EXPECT_EQ(g[1], -1.f);
  EXPECT_EQ(g[2], 1.f);
}

}  // namespace
}  // namespace nerfslam::nerf
