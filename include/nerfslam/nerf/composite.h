#pragma once
// Volume compositing along one ray (emission-absorption, NeRF quadrature) and its exact backward.
//
// Samples i = 0..n-1 in ray order with density sigma_i >= 0, colour c_i, segment length dt_i and
// segment midpoint t_i:
//   alpha_i = 1 - exp(-sigma_i dt_i),   T_i = prod_{j<i} (1 - alpha_j),   w_i = T_i alpha_i
//   colour  = sum_i w_i c_i + T_end * background
//   opacity = 1 - T_end = sum_i w_i
//   depth_sum = sum_i w_i t_i            (expected depth, un-normalised: depth = depth_sum / opacity)
//   depth_var = sum_i w_i (t_i - depth)^2 / opacity    (the uncertainty channel)
// Compositing stops early once T drops below `min_transmittance` (1e-4 as instant-ngp); samples
// after that point get weight 0 and T_end is the transmittance where it stopped. The backward pass
// differentiates exactly this truncated sum, so it matches finite differences.
#include <cmath>
#include <cstdint>

namespace nerfslam::nerf {

struct CompositeResult {
  float rgb[3] = {0, 0, 0};  // including the background term
  float opacity = 0;         // 1 - T_end
  float depth_sum = 0;       // sum w_i t_i
  float depth = 0;           // depth_sum / opacity (0 when opacity ~ 0)
  float depth_var = 0;       // weighted variance of t around depth
  int used = 0;              // samples composited before early termination
};

constexpr float kMinTransmittance = 1e-4f;

// rgb is n x 3 interleaved.
CompositeResult compositeForward(int n, const float* sigma, const float* rgb, const float* dt, const float* t,
                                 const float background[3], float min_transmittance = kMinTransmittance);

// The samples compositeForward would use (its `used`), from the densities alone: the transmittance
// does not depend on colour. Same arithmetic as compositeForward, so the count is the same.
inline int compositeUsedSamples(int n, const float* sigma, const float* dt,
                                float min_transmittance = kMinTransmittance) {
  float T = 1.f;
  int i = 0;
  for (; i < n; ++i) {
    if (T < min_transmittance) break;
    const float alpha = 1.f - std::exp(-sigma[i] * dt[i]);
    T *= 1.f - alpha;
  }
  return i;
}

// Gradient of L with respect to sigma and rgb given dL/d(colour) and dL/d(depth_sum) (set d_depth_sum = 0
// for a colour-only loss). `fwd` must be the forward result for the same inputs. Writes d_sigma[0..n)
// and d_rgb[0..3n) (zeros past fwd.used).
void compositeBackward(int n, const float* sigma, const float* rgb, const float* dt, const float* t,
                       const float background[3], const CompositeResult& fwd, const float d_color[3], float d_depth_sum,
                       float* d_sigma, float* d_rgb);

// Sparse depth supervision of one ray whose surface is known at t_surf (a map point the view
// observes), as depth-supervised NeRF and urban radiance fields' line-of-sight prior do: the
// expected penalty of where the ray terminates under the compositing weights,
//   L = sum_i w_i rho(t_i) + T_end,
//   rho(t) = k (1 - exp(-(t - t_surf)^2 / (2 width^2))),  k = 2 in front of the surface, 1 behind it,
// so weight on the surface costs nothing, density in front of it (hiding it: free space that is not
// free) costs most, and a ray that does not stop (T_end) or stops behind the surface costs 1.
// Bounded, so a wrong map point costs a bounded loss. Adds scale * dL/dsigma_i to d_sigma[0..fwd.used)
// (samples past fwd.used have no weight) and returns L. `fwd` is compositeForward's result for the
// same densities.
float lineOfSightLoss(int n, const float* sigma, const float* dt, const float* t, const CompositeResult& fwd,
                      float t_surf, float width, float scale, float* d_sigma);

// Distortion loss of one ray (mip-NeRF 360): with the compositing weights w_i at the segment
// midpoints t_i of lengths dt_i,
//   L = sum_i sum_j w_i w_j |t_i - t_j| + 1/3 sum_i w_i^2 dt_i,
// small when the weight is one compact peak and large when it is spread along the ray (fog, floaters
// in front of the surface). O(n) with prefix sums (the t_i are sorted). Adds scale * dL/dsigma_i to
// d_sigma[0..fwd.used) and returns L. `fwd` is compositeForward's result for the same densities.
float distortionLoss(const float* sigma, const float* dt, const float* t, const CompositeResult& fwd, float scale,
                     float* d_sigma);
// Huber loss (delta) of prediction minus target summed over 3 channels; writes dL/dpred.
float huberLoss3(const float pred[3], const float target[3], float delta, float d_pred[3]);

}  // namespace nerfslam::nerf
