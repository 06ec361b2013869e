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

// Sparse Adam over one hash-grid level (2 features per entry): groups of K = Lanes/2 consecutive
// entries are one vector; entries whose touched bit is set and whose summed gradient is non-zero
// are updated (their own step counter selects the bias correction), the others keep their values.
// Same operation order as adamEntry<2> (no FMA contraction), so every target gives its bits.
size_t AdamSparseLevelImpl(float* HWY_RESTRICT p, float* HWY_RESTRICT m, float* HWY_RESTRICT v, float* HWY_RESTRICT g,
                           uint64_t* HWY_RESTRICT touched, uint32_t* HWY_RESTRICT steps, size_t n, float lr,
                           const AdamOptions& opt, const AdamBiasTable& bias, float grad_scale) {
  const hn::ScalableTag<float> df;
  const hn::RebindToUnsigned<decltype(df)> du;
  const size_t NL = hn::Lanes(df);
  const size_t K = NL / 2;  // entries per vector
  if (K == 0) return adamSparseLevelScalar(p, m, v, g, touched, steps, n, lr, opt, bias, grad_scale);
  size_t updated = 0;
  const float b1 = float(opt.beta1), b2 = float(opt.beta2), eps = float(opt.epsilon);
  const auto vb1 = hn::Set(df, b1), vb2 = hn::Set(df, b2), va1 = hn::Set(df, 1.f - b1), va2 = hn::Set(df, 1.f - b2),
             veps = hn::Set(df, eps), vlr = hn::Set(df, lr), vscale = hn::Set(df, grad_scale);
  HWY_ALIGN float c1[HWY_MAX_BYTES / 4], c2[HWY_MAX_BYTES / 4];
  HWY_ALIGN uint32_t mk[HWY_MAX_BYTES / 4];
  const size_t words = (n + 63) / 64;
  for (size_t w = 0; w < words; ++w) {
    const uint64_t bits = touched[w];
    if (!bits) continue;
    touched[w] = 0;
    for (size_t k = 0; k < 64; k += K) {
      const uint64_t sub = (bits >> k) & ((uint64_t(2) << (K - 1)) - 1);
      if (!sub) continue;
      const size_t e0 = w * 64 + k;
      float* ge = g + 2 * e0;
      bool any = false;
      for (size_t j = 0; j < K; ++j) {
        bool act = false;
        if ((sub >> j) & 1) {
          act = ge[2 * j] != 0.f || ge[2 * j + 1] != 0.f;
          if (act) {
            const uint32_t t = ++steps[e0 + j];
            c1[2 * j] = c1[2 * j + 1] = bias.correction1(t);
            c2[2 * j] = c2[2 * j + 1] = bias.correction2(t);
          }
        }
        if (!act) c1[2 * j] = c1[2 * j + 1] = c2[2 * j] = c2[2 * j + 1] = 1.f;
        mk[2 * j] = mk[2 * j + 1] = act ? ~0u : 0u;
        any |= act;
        updated += act;
      }
      if (!any) {
        // Only entries with a zero sum: clear their gradients.
        hn::StoreU(hn::Zero(df), df, ge);
        continue;
      }
      const auto mask = hn::RebindMask(df, hn::Ne(hn::Load(du, mk), hn::Zero(du)));
      const auto gv = hn::Mul(hn::LoadU(df, ge), vscale);
      const auto p0 = hn::LoadU(df, p + 2 * e0), m0 = hn::LoadU(df, m + 2 * e0), v0 = hn::LoadU(df, v + 2 * e0);
      const auto m1 = hn::Add(hn::Mul(vb1, m0), hn::Mul(va1, gv));
      const auto v1 = hn::Add(hn::Mul(vb2, v0), hn::Mul(hn::Mul(va2, gv), gv));
      const auto mhat = hn::Div(m1, hn::Load(df, c1)), vhat = hn::Div(v1, hn::Load(df, c2));
      const auto p1 = hn::Sub(p0, hn::Div(hn::Mul(vlr, mhat), hn::Add(hn::Sqrt(vhat), veps)));
      hn::StoreU(hn::IfThenElse(mask, p1, p0), df, p + 2 * e0);
      hn::StoreU(hn::IfThenElse(mask, m1, m0), df, m + 2 * e0);
      hn::StoreU(hn::IfThenElse(mask, v1, v0), df, v + 2 * e0);
      hn::StoreU(hn::Zero(df), df, ge);
    }
  }
  return updated;
}

// NOLINTNEXTLINE(google-readability-namespace-comments)
}  // namespace nerfslam::nerf::HWY_NAMESPACE
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace nerfslam::nerf {

HWY_EXPORT(AdamDenseImpl);
HWY_EXPORT(AdamSparseLevelImpl);

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

size_t adamSparseLevelScalar(float* p, float* m, float* v, float* g, uint64_t* touched, uint32_t* steps, size_t n,
                             float lr, const AdamOptions& opt, const AdamBiasTable& bias, float grad_scale) {
  const size_t words = (n + 63) / 64;
  size_t updated = 0;
  for (size_t w = 0; w < words; ++w) {
    uint64_t bits = touched[w];
    touched[w] = 0;
    while (bits) {
      const size_t e = w * 64 + size_t(__builtin_ctzll(bits));
      bits &= bits - 1;
      float* ge = g + 2 * e;
      const bool zero = ge[0] == 0.f && ge[1] == 0.f;
      const float gs[2] = {ge[0] * grad_scale, ge[1] * grad_scale};
      ge[0] = ge[1] = 0.f;
      if (zero) continue;
      adamEntry<2>(p + 2 * e, m + 2 * e, v + 2 * e, gs, steps + e, lr, opt, bias);
      ++updated;
    }
  }
  return updated;
}

size_t adamSparseLevel(float* p, float* m, float* v, float* g, uint64_t* touched, uint32_t* steps, size_t n, float lr,
                       const AdamOptions& opt, const AdamBiasTable& bias, float grad_scale) {
  return HWY_DYNAMIC_DISPATCH(AdamSparseLevelImpl)(p, m, v, g, touched, steps, n, lr, opt, bias, grad_scale);
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
