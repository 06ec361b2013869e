#pragma once
// Per-view appearance: a real camera changes exposure and white balance from frame to frame, and a
// radiance field that must explain every view with one colour per point turns those changes into
// fog and flicker. Each training view without alpha gets an affine colour transform per channel,
//   out_c = exp(log_gain_c) * c + bias_c,
// applied to the composited ray colour (background included), learned with the field by its own
// Adam and regularised towards identity. After every step the mean transform over the views is
// taken out, which fixes the gauge: the field's colours are those of the views' mean appearance.
//
// Renders at novel poses use identity (the mean appearance); the held-out evaluation
// of `nerfslam run` and `nerfslam train` renders each held-out frame with the appearance of the
// training view nearest to it (camera centres), the same rule in every figure.
#include <array>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/core/pose.h"
#include "nerfslam/nerf/adam.h"

namespace nerfslam::nerf {

struct Appearance {
  std::array<float, 3> log_gain = {0.f, 0.f, 0.f};
  std::array<float, 3> bias = {0.f, 0.f, 0.f};
  static constexpr int kParams = 6;  // log_gain then bias

  bool isIdentity() const;
  bool finite() const;
  void apply(const float in[3], float out[3]) const;
  // An RGB image (CV_32FC3, values 0..1) transformed (not clamped).
  cv::Mat apply(const cv::Mat& rgb) const;
  // Gradient of the loss with respect to the parameters (added to grad[0..6)) and to the input
  // colour (written to d_in), given dL/d(out) and the input colour.
  void backward(const float in[3], const float d_out[3], float* grad, float d_in[3]) const;
};

// Adam over the appearances of the views (one step counter per view, so views that join later get
// the same first updates), with L2 towards identity.
class AppearanceOptimizer {
 public:
  explicit AppearanceOptimizer(const AdamOptions& adam) : adam_(adam), bias_(adam) {}
  // One update of `app` from the gradient grad[0..6) (already scaled) plus reg * 2 * params.
  void step(size_t view, Appearance& app, const float* grad, float lr, float reg);
  void reset(size_t view);

 private:
  struct State {
    std::array<float, Appearance::kParams> m{}, v{};
    uint32_t t = 0;
  };
  AdamOptions adam_;
  AdamBiasTable bias_;
  std::vector<State> state_;
};

// The index of the pose in `poses` whose camera centre is nearest to `pose`'s (0 when empty).
size_t nearestView(const std::vector<SE3>& poses, const SE3& pose);
// The rule for a frame no view was trained on (every held-out figure uses it): the appearance of the
// view (poses[i], appearances[i]) whose camera centre is nearest; identity without views.
Appearance appearanceNear(const std::vector<SE3>& poses, const std::vector<Appearance>& appearances, const SE3& pose);

}  // namespace nerfslam::nerf
