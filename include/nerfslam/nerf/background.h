#pragma once
// A learned background (environment map) for views without alpha (real cameras).
//
// Sky and far scenery lie outside the scene box; with a random (or any fixed) background colour the
// field can only explain them by density inside the box, i.e. fog in front of the cameras. Instead
// a ray that leaves the box with transmittance T_end gets
//   colour = sum_i w_i c_i + T_end * bg(dir)
// where bg is a function of the ray direction alone, learned together with the field (its own
// sparse Adam, see adam.h): dL/dbg = T_end * dL/dcolour; dL/dT_end flows through compositeBackward,
// which reads the background through the forward colour.
//
// bg is a lat-long texture of logits, rows x 2*rows texels x RGB, in a frame fixed at creation
// (Trainer: the first opaque view's camera frame, so longitude 0 is its optical axis, the seam is
// behind it and the poles are along its image y axis, i.e. up and down for an upright camera):
//   d = frame^T dir;  longitude = atan2(d.x, d.z);  latitude = asin(d.y)
// bilinear in the logits (wrapping in longitude, clamped at the poles), colour = sigmoid(logit).
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "nerfslam/nerf/adam.h"

namespace nerfslam::nerf {

class Background {
 public:
  // A lookup: the four texels, their bilinear weights and the colour.
  struct Sample {
    int texel[4];
    float weight[4];
    float rgb[3];
  };

  // rows >= 2; frame: rotation from the background's frame to NeRF space (= world directions).
  // Logits start at 0 (grey 0.5).
  Background(int rows, const Eigen::Matrix3f& frame);

  int rows() const { return rows_; }
  int cols() const { return 2 * rows_; }
  int texels() const { return rows_ * cols(); }
  const Eigen::Matrix3f& frame() const { return frame_; }

  // dir: unit vector in NeRF space. Thread-safe.
  Sample lookup(const float dir[3]) const;
  void eval(const float dir[3], float rgb[3]) const {
    const Sample s = lookup(dir);
    for (int c = 0; c < 3; ++c) rgb[c] = s.rgb[c];
  }
  // Adds dL/dlogits to grad (numParameters() floats) given dL/dbg of a lookup.
  void backward(const Sample& s, const float d_bg[3], float* grad) const;

  // One Adam step on grad * grad_scale (texels whose gradient is exactly zero are left alone, as the
  // hash grid's sparse rule); clears grad.
  void step(float* grad, float lr, const AdamOptions& opt, float grad_scale = 1.f);
  // Adam's moments and per-texel step counters back to zero (after a rollback).
  void resetOptimizer();

  size_t numParameters() const { return logits_.size(); }
  // Row-major [row][col][rgb]; row 0 is latitude -90 deg (direction -y of the frame).
  std::vector<float>& logits() { return logits_; }
  const std::vector<float>& logits() const { return logits_; }
  std::vector<float>& adamM() { return m_; }
  std::vector<float>& adamV() { return v_; }
  std::vector<uint32_t>& adamSteps() { return steps_; }

 private:
  int rows_;
  Eigen::Matrix3f frame_;
  std::vector<float> logits_, m_, v_;
  std::vector<uint32_t> steps_;
};

// dL/dbg of a ray composited over bg with transmittance T_end = 1 - opacity: T_end * dL/dcolour.
inline void backgroundGradient(float opacity, const float d_color[3], float d_bg[3]) {
  const float T_end = 1.f - opacity;
  for (int c = 0; c < 3; ++c) d_bg[c] = T_end * d_color[c];
}

}  // namespace nerfslam::nerf
