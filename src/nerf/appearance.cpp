#include "nerfslam/nerf/appearance.h"

#include <cmath>

namespace nerfslam::nerf {

bool Appearance::isIdentity() const {
  for (int c = 0; c < 3; ++c)
    if (log_gain[size_t(c)] != 0.f || bias[size_t(c)] != 0.f) return false;
  return true;
}

bool Appearance::finite() const {
  for (int c = 0; c < 3; ++c)
    if (!std::isfinite(log_gain[size_t(c)]) || !std::isfinite(bias[size_t(c)])) return false;
  return true;
}

void Appearance::apply(const float in[3], float out[3]) const {
  for (int c = 0; c < 3; ++c) out[c] = std::exp(log_gain[size_t(c)]) * in[c] + bias[size_t(c)];
}

cv::Mat Appearance::apply(const cv::Mat& rgb) const {
  CV_Assert(rgb.type() == CV_32FC3);
  if (isIdentity()) return rgb.clone();
  cv::Mat out(rgb.size(), CV_32FC3);
  for (int y = 0; y < rgb.rows; ++y) {
    const auto* s = rgb.ptr<cv::Vec3f>(y);
    auto* d = out.ptr<cv::Vec3f>(y);
    for (int x = 0; x < rgb.cols; ++x) apply(&s[x][0], &d[x][0]);
  }
  return out;
}

void Appearance::backward(const float in[3], const float d_out[3], float* grad, float d_in[3]) const {
  for (int c = 0; c < 3; ++c) {
    const float gain = std::exp(log_gain[size_t(c)]);
    grad[c] += d_out[c] * gain * in[c];
    grad[3 + c] += d_out[c];
    d_in[c] = d_out[c] * gain;
  }
}

void AppearanceOptimizer::step(size_t view, Appearance& app, const float* grad, float lr, float reg) {
  if (view >= state_.size()) state_.resize(view + 1);
  float p[Appearance::kParams], g[Appearance::kParams];
  for (int c = 0; c < 3; ++c) {
    p[c] = app.log_gain[size_t(c)];
    p[3 + c] = app.bias[size_t(c)];
  }
  for (int k = 0; k < Appearance::kParams; ++k) g[k] = grad[k] + 2.f * reg * p[k];
  State& s = state_[view];
  adamEntry<Appearance::kParams>(p, s.m.data(), s.v.data(), g, &s.t, lr, adam_, bias_);
  for (int c = 0; c < 3; ++c) {
    app.log_gain[size_t(c)] = p[c];
    app.bias[size_t(c)] = p[3 + c];
  }
}

void AppearanceOptimizer::reset(size_t view) {
  if (view < state_.size()) state_[view] = State{};
}

size_t nearestView(const std::vector<SE3>& poses, const SE3& pose) {
  size_t best = 0;
  double best_d = INFINITY;
  for (size_t i = 0; i < poses.size(); ++i) {
    const double d = (poses[i].translation() - pose.translation()).squaredNorm();
    if (d < best_d) {
      best_d = d;
      best = i;
    }
  }
  return best;
}

Appearance appearanceNear(const std::vector<SE3>& poses, const std::vector<Appearance>& appearances, const SE3& pose) {
  const size_t k = nearestView(poses, pose);
  return k < appearances.size() && k < poses.size() ? appearances[k] : Appearance{};
}

}  // namespace nerfslam::nerf
