// Register-blocked GEMM with fused ReLU epilogues for the MLP layers (see mlp.h). One Highway
// kernel serves the forward product, the backward-data product (against transposed weights) and
// the weight gradient (A read transposed through its strides).
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "nerf/mlp.cpp"
// The micro-kernel keeps its accumulators in arrays of vectors, which sizeless vector types
// (SVE, RVV) do not allow; those targets fall back to NEON / the baseline.
#ifndef HWY_DISABLED_TARGETS
#define HWY_DISABLED_TARGETS (HWY_SVE | HWY_SVE2 | HWY_SVE_256 | HWY_SVE2_128 | HWY_RVV)
#endif
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include "nerfslam/nerf/mlp.h"
#include "nerfslam/nerf/simd.h"

HWY_BEFORE_NAMESPACE();
namespace nerfslam::nerf::HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

template <size_t MR, size_t NR, class DF>
HWY_INLINE void Micro(DF df, const GemmArgs& g, size_t m0, size_t n0) {
  using VF = hn::Vec<DF>;
  const size_t NL = hn::Lanes(df);
  VF acc[MR][NR];
  for (size_t i = 0; i < MR; ++i)
    for (size_t j = 0; j < NR; ++j) acc[i][j] = hn::Zero(df);
  const float* HWY_RESTRICT a = g.a + m0 * g.a_ms;
  const float* HWY_RESTRICT b = g.b + n0;
  for (size_t k = 0; k < g.K; ++k) {
    VF bv[NR];
    for (size_t j = 0; j < NR; ++j) bv[j] = hn::LoadU(df, b + k * g.ldb + j * NL);
    const float* ak = a + k * g.a_ks;
    for (size_t i = 0; i < MR; ++i) {
      const VF av = hn::Set(df, ak[i * g.a_ms]);
      for (size_t j = 0; j < NR; ++j) acc[i][j] = hn::MulAdd(av, bv[j], acc[i][j]);
    }
  }
  for (size_t i = 0; i < MR; ++i) {
    float* c = g.c + (m0 + i) * g.ldc + n0;
    for (size_t j = 0; j < NR; ++j) {
      VF r = acc[i][j];
      switch (g.epilogue) {
        case Epilogue::kNone:
          if (g.accumulate) r = hn::Add(hn::LoadU(df, c + j * NL), r);
          break;
        case Epilogue::kRelu:
          r = hn::Max(r, hn::Zero(df));
          break;
        case Epilogue::kReluMask: {
          const VF mk = hn::LoadU(df, g.mask + (m0 + i) * g.ldm + n0 + j * NL);
          r = hn::IfThenElseZero(hn::Gt(mk, hn::Zero(df)), r);
          break;
        }
      }
      hn::StoreU(r, df, c + j * NL);
    }
  }
}

template <size_t NR, class DF>
HWY_INLINE void Columns(DF df, const GemmArgs& g, size_t n0) {
  // Rows in blocks of kMR; the remainder in blocks of 4, 2, 1 (a 64-row tile leaves 4 rows on
  // AVX-512: one row at a time they cost as much as ~10 rows in 6-row blocks, the B loads being
  // shared by fewer FMAs). Every row sums over k in the same order whatever its block.
  constexpr size_t kMR = HWY_MAX_BYTES >= 64 ? 6 : 4;
  size_t m = 0;
  for (; m + kMR <= g.M; m += kMR) Micro<kMR, NR>(df, g, m, n0);
  if constexpr (kMR > 4) {
    if (m + 4 <= g.M) {
      Micro<4, NR>(df, g, m, n0);
      m += 4;
    }
  }
  if (m + 2 <= g.M) {
    Micro<2, NR>(df, g, m, n0);
    m += 2;
  }
  if (m < g.M) Micro<1, NR>(df, g, m, n0);
}

void GemmImpl(const GemmArgs& g) {
  const hn::ScalableTag<float> df;
  const size_t NL = hn::Lanes(df);
  // 4 vectors per block on 32-register AVX-512 (6x4 accumulators), 2 elsewhere (4x2 or 6x2).
  constexpr size_t kNR = HWY_MAX_BYTES >= 64 ? 4 : 2;
  size_t n = 0;
  for (; n + kNR * NL <= g.N; n += kNR * NL) Columns<kNR>(df, g, n);
  for (; n + NL <= g.N; n += NL) Columns<1>(df, g, n);
  if (n < g.N) {
    // Only reachable when N is not a multiple of the lane count (scalar tail).
    const hn::CappedTag<float, 1> d1;
    for (; n < g.N; ++n) Columns<1>(d1, g, n);
  }
}

const char* TargetNameImpl() { return hwy::TargetName(HWY_TARGET); }

double FmaPeakImpl(uint64_t iters) {
  const hn::ScalableTag<float> df;
  using VF = hn::Vec<decltype(df)>;
  constexpr size_t kChains = 10;  // > FMA latency (4) x 2 pipes: keeps both FMA units busy
  VF acc[kChains];
  for (size_t i = 0; i < kChains; ++i) acc[i] = hn::Set(df, float(i) * 1e-3f);
  const VF a = hn::Set(df, 0.999999f), b = hn::Set(df, 1e-7f);
  for (uint64_t it = 0; it < iters; ++it) {
    for (size_t i = 0; i < kChains; ++i) acc[i] = hn::MulAdd(acc[i], a, b);
  }
  VF sum = acc[0];
  for (size_t i = 1; i < kChains; ++i) sum = hn::Add(sum, acc[i]);
  // Consume the result so the loop is not optimised away.
  volatile float sink = hn::GetLane(sum);
  (void)sink;
  return double(iters) * kChains * 2.0 * double(hn::Lanes(df));
}

// NOLINTNEXTLINE(google-readability-namespace-comments)
}  // namespace nerfslam::nerf::HWY_NAMESPACE
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace nerfslam::nerf {

HWY_EXPORT(GemmImpl);
HWY_EXPORT(TargetNameImpl);
HWY_EXPORT(FmaPeakImpl);

const char* activeSimdTarget() { return HWY_DYNAMIC_DISPATCH(TargetNameImpl)(); }
double fmaPeakLoop(uint64_t iters) { return HWY_DYNAMIC_DISPATCH(FmaPeakImpl)(iters); }

void gemm(const GemmArgs& args) { HWY_DYNAMIC_DISPATCH(GemmImpl)(args); }

void gemmScalar(const GemmArgs& g) {
  for (size_t m = 0; m < g.M; ++m) {
    for (size_t n = 0; n < g.N; ++n) {
      float acc = 0.f;
      for (size_t k = 0; k < g.K; ++k) acc += g.a[m * g.a_ms + k * g.a_ks] * g.b[k * g.ldb + n];
      float& c = g.c[m * g.ldc + n];
      switch (g.epilogue) {
        case Epilogue::kNone:
          c = g.accumulate ? c + acc : acc;
          break;
        case Epilogue::kRelu:
          c = acc > 0.f ? acc : 0.f;
          break;
        case Epilogue::kReluMask:
          c = g.mask[m * g.ldm + n] > 0.f ? acc : 0.f;
          break;
      }
    }
  }
}

}  // namespace nerfslam::nerf
#endif  // HWY_ONCE
