#include "nerfslam/nerf/background.h"

#include <algorithm>
#include <cmath>

#include "nerfslam/core/error.h"

namespace nerfslam::nerf {

Background::Background(int rows, const Eigen::Matrix3f& frame) : rows_(rows), frame_(frame) {
  if (rows < 2 || rows > 4096) fail("NeRF background: rows must be in [2, 4096] (got {})", rows);
  if (!frame.allFinite()) fail("NeRF background: the frame is not finite");
  const size_t n = size_t(texels()) * 3;
  logits_.assign(n, 0.f);
  m_.assign(n, 0.f);
  v_.assign(n, 0.f);
  steps_.assign(size_t(texels()), 0u);
}

Background::Sample Background::lookup(const float dir[3]) const {
  const Eigen::Vector3f d = frame_.transpose() * Eigen::Vector3f(dir[0], dir[1], dir[2]);
  const float lon = std::atan2(d.x(), d.z());                 // (-pi, pi]
  const float lat = std::asin(std::clamp(d.y(), -1.f, 1.f));  // [-pi/2, pi/2]
  const int W = cols(), H = rows_;
  // Texel centres at (i + 0.5) / W of the longitude range and (j + 0.5) / H of the latitude range.
  const float u = (lon + float(M_PI)) * (float(W) / float(2 * M_PI)) - 0.5f;
  const float v = (lat + float(M_PI / 2)) * (float(H) / float(M_PI)) - 0.5f;
  const float u0f = std::floor(u), v0f = std::floor(v);
  const float fu = u - u0f, fv = v - v0f;
  int u0 = int(u0f) % W;
  if (u0 < 0) u0 += W;
  const int u1 = u0 + 1 == W ? 0 : u0 + 1;
  const int v0 = std::clamp(int(v0f), 0, H - 1), v1 = std::clamp(int(v0f) + 1, 0, H - 1);
  Sample s;
  s.texel[0] = v0 * W + u0;
  s.texel[1] = v0 * W + u1;
  s.texel[2] = v1 * W + u0;
  s.texel[3] = v1 * W + u1;
  s.weight[0] = (1.f - fu) * (1.f - fv);
  s.weight[1] = fu * (1.f - fv);
  s.weight[2] = (1.f - fu) * fv;
  s.weight[3] = fu * fv;
  for (int c = 0; c < 3; ++c) {
    float x = 0;
    for (int k = 0; k < 4; ++k) x += s.weight[k] * logits_[3 * size_t(s.texel[k]) + size_t(c)];
    s.rgb[c] = 1.f / (1.f + std::exp(-x));
  }
  return s;
}

void Background::backward(const Sample& s, const float d_bg[3], float* grad) const {
  for (int c = 0; c < 3; ++c) {
    const float d_logit = d_bg[c] * s.rgb[c] * (1.f - s.rgb[c]);  // sigmoid'
    for (int k = 0; k < 4; ++k) grad[3 * size_t(s.texel[k]) + size_t(c)] += s.weight[k] * d_logit;
  }
}

void Background::step(float* grad, float lr, const AdamOptions& opt, float grad_scale) {
  const float b1 = float(opt.beta1), b2 = float(opt.beta2), eps = float(opt.epsilon);
  for (size_t e = 0; e < size_t(texels()); ++e) {
    float* g = grad + 3 * e;
    if (g[0] == 0.f && g[1] == 0.f && g[2] == 0.f) continue;
    const uint32_t t = ++steps_[e];
    const float c1 = float(1.0 - std::pow(opt.beta1, double(t))), c2 = float(1.0 - std::pow(opt.beta2, double(t)));
    for (int c = 0; c < 3; ++c) {
      const size_t i = 3 * e + size_t(c);
      const float gi = g[c] * grad_scale;
      m_[i] = b1 * m_[i] + (1.f - b1) * gi;
      v_[i] = b2 * v_[i] + (1.f - b2) * gi * gi;
      logits_[i] -= lr * (m_[i] / c1) / (std::sqrt(v_[i] / c2) + eps);
      g[c] = 0.f;
    }
  }
}

void Background::resetOptimizer() {
  std::fill(m_.begin(), m_.end(), 0.f);
  std::fill(v_.begin(), v_.end(), 0.f);
  std::fill(steps_.begin(), steps_.end(), 0u);
}

}  // namespace nerfslam::nerf
