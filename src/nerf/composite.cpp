#include "nerfslam/nerf/composite.h"

#include <cmath>
#include <vector>

namespace nerfslam::nerf {

CompositeResult compositeForward(int n, const float* sigma, const float* rgb, const float* dt, const float* t,
                                 const float background[3], float min_transmittance) {
  CompositeResult r;
  float T = 1.f;
  float acc[3] = {0, 0, 0};
  float dsum = 0, d2sum = 0;
  int i = 0;
  for (; i < n; ++i) {
    if (T < min_transmittance) break;
    const float alpha = 1.f - std::exp(-sigma[i] * dt[i]);
    const float w = T * alpha;
    acc[0] += w * rgb[3 * i + 0];
    acc[1] += w * rgb[3 * i + 1];
    acc[2] += w * rgb[3 * i + 2];
    dsum += w * t[i];
    d2sum += w * t[i] * t[i];
    T *= 1.f - alpha;
  }
  r.used = i;
  r.opacity = 1.f - T;
  for (int c = 0; c < 3; ++c) r.rgb[c] = acc[c] + T * background[c];
  r.depth_sum = dsum;
  if (r.opacity > 1e-6f) {
    r.depth = dsum / r.opacity;
    r.depth_var = std::max(0.f, d2sum / r.opacity - r.depth * r.depth);
  }
  return r;
}

void compositeBackward(int n, const float* sigma, const float* rgb, const float* dt, const float* t,
                       const float background[3], const CompositeResult& fwd, const float d_color[3], float d_depth_sum,
                       float* d_sigma, float* d_rgb) {
  // Suffix S_{>i} = sum_{k>i} w_k c_k + T_end * bg is the final colour minus the prefix sum up to i.
  // dC/dsigma_i = dt_i (T_{i+1} c_i - S_{>i});  dC/dc_i = w_i. Same for depth with t_i, bg 0.
  const float T_end = 1.f - fwd.opacity;
  float T = 1.f;
  float prefix[3] = {0, 0, 0};
  float prefix_d = 0;
  const int used = fwd.used;
  for (int i = 0; i < used; ++i) {
    const float alpha = 1.f - std::exp(-sigma[i] * dt[i]);
    const float w = T * alpha;
    const float T_next = T * (1.f - alpha);
    float g = 0;
    for (int c = 0; c < 3; ++c) {
      const float ci = rgb[3 * i + c];
      prefix[c] += w * ci;
      const float suffix = fwd.rgb[c] - prefix[c];  // includes T_end * bg
      g += d_color[c] * (T_next * ci - suffix);
      d_rgb[3 * i + c] = d_color[c] * w;
    }
    prefix_d += w * t[i];
    g += d_depth_sum * (T_next * t[i] - (fwd.depth_sum - prefix_d));
    d_sigma[i] = g * dt[i];
    T = T_next;
  }
  (void)T_end;
  (void)background;
  for (int i = used; i < n; ++i) {
    d_sigma[i] = 0;
    d_rgb[3 * i + 0] = d_rgb[3 * i + 1] = d_rgb[3 * i + 2] = 0;
  }
}

namespace {

float lineOfSightPenalty(float t, float t_surf, float inv_two_w2) {
  const float d = t - t_surf;
  return (d < 0.f ? 2.f : 1.f) * (1.f - std::exp(-d * d * inv_two_w2));
}

}  // namespace

float lineOfSightLoss(int n, const float* sigma, const float* dt, const float* t, const CompositeResult& fwd,
                      float t_surf, float width, float scale, float* d_sigma) {
  (void)n;
  const int used = fwd.used;
  const float inv_two_w2 = 1.f / (2.f * width * width);
  const float T_end = 1.f - fwd.opacity;
  // Forward: L = sum_i w_i rho_i + T_end (rho of the transmittance left: 1).
  float loss = T_end, T = 1.f;
  for (int i = 0; i < used; ++i) {
    const float alpha = 1.f - std::exp(-sigma[i] * dt[i]);
    loss += T * alpha * lineOfSightPenalty(t[i], t_surf, inv_two_w2);
    T *= 1.f - alpha;
  }
  // Backward, as compositeBackward with a one-channel "colour" rho and background 1:
  // dL/dsigma_i = dt_i (T_{i+1} rho_i - sum_{k>i} w_k rho_k - T_end).
  T = 1.f;
  float prefix = 0.f;
  for (int i = 0; i < used; ++i) {
    const float alpha = 1.f - std::exp(-sigma[i] * dt[i]);
    const float rho = lineOfSightPenalty(t[i], t_surf, inv_two_w2);
    const float T_next = T * (1.f - alpha);
    prefix += T * alpha * rho;
    d_sigma[i] += scale * dt[i] * (T_next * rho - (loss - prefix));
    T = T_next;
  }
  return loss;
}

float distortionLoss(const float* sigma, const float* dt, const float* t, const CompositeResult& fwd, float scale,
                     float* d_sigma) {
  const int used = fwd.used;
  if (used == 0) return 0.f;
  // Weights, then g_i = dL/dw_i = 2 sum_j w_j |t_i - t_j| + 2/3 w_i dt_i from prefix sums of w and
  // w t (the t_i are increasing): sum_j w_j |t_i - t_j| = t_i W_<i - S_<i + (S_>i - t_i W_>i).
  thread_local std::vector<float> w, g;
  w.resize(size_t(used));
  g.resize(size_t(used));
  float T = 1.f, W = 0.f, S = 0.f;
  for (int i = 0; i < used; ++i) {
    const float alpha = 1.f - std::exp(-sigma[i] * dt[i]);
    w[size_t(i)] = T * alpha;
    W += w[size_t(i)];
    S += w[size_t(i)] * t[i];
    T *= 1.f - alpha;
  }
  float loss = 0.f, W_before = 0.f, S_before = 0.f;
  for (int i = 0; i < used; ++i) {
    const float wi = w[size_t(i)];
    const float W_after = W - W_before - wi, S_after = S - S_before - wi * t[i];
    const float spread = t[i] * W_before - S_before + S_after - t[i] * W_after;
    loss += wi * spread + wi * wi * dt[i] / 3.f;
    g[size_t(i)] = 2.f * spread + 2.f / 3.f * wi * dt[i];
    W_before += wi;
    S_before += wi * t[i];
  }
  // dL/dsigma_i = dt_i (T_{i+1} g_i - sum_{k>i} w_k g_k), as in lineOfSightLoss (no T_end term).
  float total = 0.f;
  for (int i = 0; i < used; ++i) total += w[size_t(i)] * g[size_t(i)];
  T = 1.f;
  float prefix = 0.f;
  for (int i = 0; i < used; ++i) {
    const float alpha = 1.f - std::exp(-sigma[i] * dt[i]);
    const float T_next = T * (1.f - alpha);
    prefix += w[size_t(i)] * g[size_t(i)];
    d_sigma[i] += scale * dt[i] * (T_next * g[size_t(i)] - (total - prefix));
    T = T_next;
  }
  return loss;
}

float huberLoss3(const float pred[3], const float target[3], float delta, float d_pred[3]) {
  float loss = 0;
  for (int c = 0; c < 3; ++c) {
    const float d = pred[c] - target[c];
    const float a = std::fabs(d);
    if (a <= delta) {
      loss += 0.5f * d * d / delta;
      d_pred[c] = d / delta;
    } else {
      loss += a - 0.5f * delta;
      d_pred[c] = d > 0 ? 1.f : -1.f;
    }
  }
  return loss;
}

}  // namespace nerfslam::nerf
