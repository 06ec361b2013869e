// The MLP GEMM kernel: every SIMD target against the scalar reference, for the three product shapes
// the field uses (forward, backward-data against transposed weights, transposed weight gradient)
// and each epilogue.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "nerfslam/nerf/mlp.h"
#include "nerfslam/nerf/simd.h"

namespace nerfslam::nerf {
namespace {

std::vector<float> randomVector(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::vector<float> v(n);
  for (float& x : v) x = u(rng);
  return v;
}

struct Case {
  size_t M, N, K;
  bool a_transposed;  // A(m,k) = a[k*M + m] instead of a[m*K + k]
  Epilogue epilogue;
  bool accumulate;
};

void runCase(const Case& c) {
  const auto a = randomVector(c.M * c.K, 1), b = randomVector(c.K * (c.N + 16), 2), mask = randomVector(c.M * c.N, 3),
             c0 = randomVector(c.M * c.N, 4);
  GemmArgs g;
  g.M = c.M;
  g.N = c.N;
  g.K = c.K;
  g.a = a.data();
  g.a_ms = c.a_transposed ? 1 : c.K;
  g.a_ks = c.a_transposed ? c.M : 1;
  g.b = b.data() + 16;  // row stride larger than N, offset start: as the backward uses WT + 16
  g.ldb = c.N + 16;
  g.ldc = c.N;
  g.accumulate = c.accumulate;
  g.epilogue = c.epilogue;
  g.mask = mask.data();
  g.ldm = c.N;
  std::vector<float> ref(c0);
  g.c = ref.data();
  gemmScalar(g);
  // Independent double-precision check of the reference itself on a few entries.
  for (size_t m = 0; m < c.M; m += 5) {
    for (size_t n = 0; n < c.N; n += 7) {
      double acc = 0;
      for (size_t k = 0; k < c.K; ++k) acc += double(a[m * g.a_ms + k * g.a_ks]) * g.b[k * g.ldb + n];
      double expect = acc;
      if (c.accumulate) expect += c0[m * c.N + n];
      if (c.epilogue == Epilogue::kRelu) expect = std::max(acc, 0.0);
      if (c.epilogue == Epilogue::kReluMask) expect = mask[m * c.N + n] > 0 ? acc : 0.0;
      ASSERT_NEAR(ref[m * c.N + n], expect, 1e-4);
    }
  }
  forEachSimdTarget([&](const std::string& name) {
    SCOPED_TRACE(name);
    std::vector<float> out(c0);
    g.c = out.data();
    gemm(g);
    for (size_t i = 0; i < out.size(); ++i) ASSERT_NEAR(out[i], ref[i], 2e-5f * (1.f + std::abs(ref[i]))) << i;
  });
}

TEST(MlpGemm, ForwardShapesAllTargets) {
  runCase({64, 64, 32, false, Epilogue::kRelu, false});  // encoding -> hidden
  runCase({64, 16, 64, false, Epilogue::kNone, false});  // hidden -> density outputs
  runCase({37, 64, 64, false, Epilogue::kRelu, false});  // ragged tile
  runCase({5, 128, 64, false, Epilogue::kNone, false});  // wide layer, tiny batch
  // Row remainders after the 6-row (AVX-512) or 4-row blocks: 4 + 2 + 1, 2 + 1, 4.
  runCase({63, 64, 32, true, Epilogue::kRelu, false});
  runCase({11, 16, 64, false, Epilogue::kNone, false});
  runCase({10, 64, 32, false, Epilogue::kRelu, false});
}

TEST(MlpGemm, BackwardShapesAllTargets) {
  runCase({64, 64, 16, false, Epilogue::kReluMask, false});  // dX = dY W^T through a ReLU
  runCase({64, 32, 64, false, Epilogue::kNone, false});      // d encoding
  runCase({64, 64, 64, true, Epilogue::kNone, true});        // dW += X^T dY
  runCase({32, 64, 13, true, Epilogue::kNone, true});        // dW over a ragged tile
}

TEST(MlpGemm, ReportsTheDispatchedTarget) {
  std::vector<std::string> seen;
  forEachSimdTarget([&](const std::string& name) {
    EXPECT_EQ(name, activeSimdTarget());
    seen.push_back(name);
  });
  ASSERT_FALSE(seen.empty());
  // After the loop the dispatch is back to the best target.
  EXPECT_EQ(std::string(activeSimdTarget()), seen.front());
}

}  // namespace
}  // namespace nerfslam::nerf
