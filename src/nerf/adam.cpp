// Dense Adam for the MLP weights (Highway) and the bias-correction table of the sparse update.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "nerf/adam.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include <cmath>

#include "nerfslam/nerf/adam.h"

HWY_BEFORE_NAMESPACE();
namespace nerfslam::nerf::HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

void AdamDenseImpl(float* HWY_RESTRICT param, float* HWY_RESTRICT m, float* HWY_RESTRICT v,
                   const float* HWY_RESTRICT grad, size_t n, float lr, float b1, float b2, float eps, float l2,
                   float c1, float c2) {
  const hn::ScalableTag<float> df;
  const size_t N = hn::Lanes(df);
  const auto vb1 = hn::Set(df, b1), vb2 = hn::Set(df, b2), va1 = hn::Set(df, 1.f - b1), va2 = hn::Set(df, 1.f - b2),
             veps = hn::Set(df, eps), vl2 = hn::Set(df, l2), vc1 = hn::Set(df, c1), vc2 = hn::Set(df, c2),
             vlr = hn::Set(df, lr);
  size_t i = 0;
  for (; i + N <= n; i += N) {
    const auto p = hn::LoadU(df, param + i);
    // Same operation order as adamDenseScalar (no FMA contraction) so all targets agree.
    const auto g = hn::Add(hn::LoadU(df, grad + i), hn::Mul(vl2, p));
    const auto mm = hn::Add(hn::Mul(vb1, hn::LoadU(df, m + i)), hn::Mul(va1, g));
    const auto vv = hn::Add(hn::Mul(vb2, hn::LoadU(df, v + i)), hn::Mul(hn::Mul(va2, g), g));
    const auto mhat = hn::Div(mm, vc1), vhat = hn::Div(vv, vc2);
    const auto upd = hn::Div(hn::Mul(vlr, mhat), hn::Add(hn::Sqrt(vhat), veps));
    hn::StoreU(mm, df, m + i);
    hn::StoreU(vv, df, v + i);
    hn::StoreU(hn::Sub(p, upd), df, param + i);
  }
  for (; i < n; ++i) {
    const float g = grad[i] + l2 * param[i];
    m[i] = b1 * m[i] + (1.f - b1) * g;
    v[i] = b2 * v[i] + (1.f - b2) * g * g;
    const float mhat = m[i] / c1, vhat = v[i] / c2;
    param[i] -= lr * mhat / (std::sqrt(vhat) + eps);
  }
}

// NOLINTNEXTLINE(google-readability-namespace-comments)
}  // namespace nerfslam::nerf::HWY_NAMESPACE
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace nerfslam::nerf {

HWY_EXPORT(AdamDenseImpl);

AdamBiasTable::AdamBiasTable(const AdamOptions& opt) {
  for (uint32_t t = 0; t < kSize; ++t) {
    c1[t] = float(1.0 - std::pow(opt.beta1, double(t)));
    c2[t] = float(1.0 - std::pow(opt.beta2, double(t)));
  }
}

namespace {
float correction(double beta, uint64_t t) { return float(1.0 - std::pow(beta, double(t))); }
}  // namespace

void adamDense(float* param, float* m, float* v, const float* grad, size_t n, uint64_t t, float lr,
               const AdamOptions& opt, float l2) {
  HWY_DYNAMIC_DISPATCH(AdamDenseImpl)
  (param, m, v, grad, n, lr, float(opt.beta1), float(opt.beta2), float(opt.epsilon), l2, correction(opt.beta1, t),
   correction(opt.beta2, t));
}

void adamDenseScalar(float* param, float* m, float* v, const float* grad, size_t n, uint64_t t, float lr,
                     const AdamOptions& opt, float l2) {
  const float b1 = float(opt.beta1), b2 = float(opt.beta2), eps = float(opt.epsilon);
  const float c1 = correction(opt.beta1, t), c2 = correction(opt.beta2, t);
  for (size_t i = 0; i < n; ++i) {
    const float g = grad[i] + l2 * param[i];
    m[i] = b1 * m[i] + (1.f - b1) * g;
    v[i] = b2 * v[i] + (1.f - b2) * g * g;
    const float mhat = m[i] / c1, vhat = v[i] / c2;
    param[i] -= lr * mhat / (std::sqrt(vhat) + eps);
  }
}

}  // namespace nerfslam::nerf
#endif  // HWY_ONCE
