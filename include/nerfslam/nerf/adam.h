#pragma once
// Adam (Kingma & Ba) as instant-ngp uses it: dense for the MLP weights (with L2 regularisation),
// sparse for the hash grid.
//
// Sparse rule (tiny-cuda-nn's): a hash entry whose gradient is zero in a step (no sample touched
// it) is left alone entirely: its parameters and moments do not change and its step counter does
// not advance. Each entry keeps its own step counter t_e, incremented when it is updated, and the
// bias correction uses t_e (not the global step), so a rarely-seen entry gets the same first
// updates as a frequently-seen one:
//   m = b1 m + (1-b1) g;  v = b2 v + (1-b2) g^2
//   p -= lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)
// The MLP weights use the same rule with g += l2 * p and the global step t.
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "nerfslam/core/options.h"

namespace nerfslam::nerf {

struct AdamOptions {
  double beta1 = 0.9;
  double beta2 = 0.99;
  double epsilon = 1e-15;
  double mlp_l2 = 1e-6;  // L2 regularisation of the MLP weights only (not the hash grid)

  template <class V>
  void visit(V& v) {
    v("beta1", beta1, "First-moment decay", check::range(0.0, 0.999999));
    v("beta2", beta2, "Second-moment decay", check::range(0.0, 0.999999));
    v("epsilon", epsilon, "Denominator epsilon", check::range(0.0, 1.0));
    v("mlp_l2", mlp_l2, "L2 regularisation of the MLP weights", check::range(0.0, 1.0));
  }
};

// One Adam update of `n` parameters with the same step t (>= 1). grad is read only; l2 is added
// as g + l2 * p. Scalar reference and dispatched SIMD version (identical arithmetic order).
void adamDense(float* param, float* m, float* v, const float* grad, size_t n, uint64_t t, float lr,
               const AdamOptions& opt, float l2);
void adamDenseScalar(float* param, float* m, float* v, const float* grad, size_t n, uint64_t t, float lr,
                     const AdamOptions& opt, float l2);

// Bias-correction table: c1[t] = 1 - b1^t, c2[t] = 1 - b2^t for t = 0..size-1, computed in double.
// Steps beyond the table use the last entry (b^t has long underflowed below fp32 resolution).
struct AdamBiasTable {
  static constexpr uint32_t kSize = 8192;
  float c1[kSize];
  float c2[kSize];
  explicit AdamBiasTable(const AdamOptions& opt);
  float correction1(uint64_t t) const { return c1[t < kSize ? t : kSize - 1]; }
  float correction2(uint64_t t) const { return c2[t < kSize ? t : kSize - 1]; }
};

// Sparse update of one hash entry (kFeatures floats) whose counter *step is incremented first.
template <int kFeatures>
inline void adamEntry(float* p, float* m, float* v, const float* g, uint32_t* step, float lr, const AdamOptions& opt,
                      const AdamBiasTable& bias) {
  const uint32_t t = ++*step;
  const float b1 = float(opt.beta1), b2 = float(opt.beta2), eps = float(opt.epsilon);
  const float c1 = bias.correction1(t), c2 = bias.correction2(t);
  for (int f = 0; f < kFeatures; ++f) {
    m[f] = b1 * m[f] + (1.f - b1) * g[f];
    v[f] = b2 * v[f] + (1.f - b2) * g[f] * g[f];
    const float mhat = m[f] / c1, vhat = v[f] / c2;
    p[f] -= lr * mhat / (std::sqrt(vhat) + eps);
  }
}

// Sparse update of a run of n entries with 2 features (one hash-grid level): every entry e whose
// bit is set in `touched` and whose summed gradient (g[2e], g[2e+1]) is not exactly zero gets
// adamEntry<2> (entries with a zero sum are skipped, as tiny-cuda-nn does). g and touched are
// cleared on the way (ready for the next step). The gradient used is g * grad_scale (the trainer
// sums unnormalised per-ray gradients and passes 1/rays here); whether an entry is skipped is decided
// on g itself. Returns the number of entries updated. Dispatched SIMD version and scalar reference;
// both give the same bits as adamEntry<2> on (g * grad_scale) entry by entry.
size_t adamSparseLevel(float* p, float* m, float* v, float* g, uint64_t* touched, uint32_t* steps, size_t n, float lr,
                       const AdamOptions& opt, const AdamBiasTable& bias, float grad_scale = 1.f);
size_t adamSparseLevelScalar(float* p, float* m, float* v, float* g, uint64_t* touched, uint32_t* steps, size_t n,
                             float lr, const AdamOptions& opt, const AdamBiasTable& bias, float grad_scale = 1.f);

}  // namespace nerfslam::nerf
