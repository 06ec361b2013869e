#include "nerfslam/nerf/background.h"

#include <gtest/gtest.h>

#include <fstream>

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include "nerfslam/nerf/composite.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/nerf/trainer.h"
#include "sphere_views.h"
#include "test_support.h"

namespace nerfslam::nerf {
namespace {

Eigen::Matrix3f someFrame() {
  return Eigen::AngleAxisf(0.4f, Eigen::Vector3f(1, 2, 3).normalized()).toRotationMatrix();
}

Background randomBackground(unsigned seed) {
  Background bg(8, someFrame());
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-2.f, 2.f);
  for (float& x : bg.logits()) x = u(rng);
  return bg;
}

TEST(Background, LookupInterpolatesWrapsAndStartsGrey) {
  Background grey(4, Eigen::Matrix3f::Identity());
  float rgb[3];
  const float d[3] = {0.3f, -0.4f, std::sqrt(1.f - 0.25f)};
  grey.eval(d, rgb);
  for (float c : rgb) EXPECT_FLOAT_EQ(c, 0.5f);
  const Background bg = randomBackground(1);
  // Weights sum to 1, texels in range; nearby directions across the longitude seam give nearby
  // colours (the map wraps).
  std::mt19937 rng(2);
  std::normal_distribution<float> n(0.f, 1.f);
  for (int i = 0; i < 200; ++i) {
    Eigen::Vector3f v(n(rng), n(rng), n(rng));
    v.normalize();
    const Background::Sample s = bg.lookup(v.data());
    float sum = 0;
    for (int k = 0; k < 4; ++k) {
      EXPECT_GE(s.texel[k], 0);
      EXPECT_LT(s.texel[k], bg.texels());
      EXPECT_GE(s.weight[k], 0.f);
      sum += s.weight[k];
    }
    EXPECT_NEAR(sum, 1.f, 1e-5f);
  }
  const Eigen::Matrix3f F = bg.frame();
  const Eigen::Vector3f a = F * Eigen::Vector3f(1e-4f, 0.f, -1.f).normalized();
  const Eigen::Vector3f b = F * Eigen::Vector3f(-1e-4f, 0.f, -1.f).normalized();
  float ca[3], cb[3];
  bg.eval(a.data(), ca);
  bg.eval(b.data(), cb);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(ca[c], cb[c], 1e-3f);
}

// Loss of one ray composited over the learned background: Huber against a target.
double rayLoss(const Background& bg, const float dir[3], const std::vector<float>& sigma, const std::vector<float>& rgb,
               const std::vector<float>& dt, const std::vector<float>& t, const float target[3]) {
  const Background::Sample s = bg.lookup(dir);
  const CompositeResult r = compositeForward(int(sigma.size()), sigma.data(), rgb.data(), dt.data(), t.data(), s.rgb);
  float d[3];
  return huberLoss3(r.rgb, target, 1.f, d);  // delta 1: quadratic (smooth) in the range used
}

TEST(Background, GradientMatchesFiniteDifferences) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  int checked = 0;
  for (int ray = 0; ray < 6; ++ray) {
    Background bg = randomBackground(10 + ray);
    Eigen::Vector3f dir(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f);
    dir.normalize();
    const int n = 16;
    std::vector<float> sigma(n), rgb(3 * n), dt(n), t(n);
    for (int i = 0; i < n; ++i) {
      sigma[size_t(i)] = 3.f * u(rng);  // partly transparent: T_end around 0.5
      dt[size_t(i)] = 0.02f;
      t[size_t(i)] = 0.5f + 0.02f * float(i);
      for (int c = 0; c < 3; ++c) rgb[3 * size_t(i) + size_t(c)] = u(rng);
    }
    const float target[3] = {u(rng), u(rng), u(rng)};
    // Analytic: the trainer's path (composite, Huber, backgroundGradient, Background::backward).
    const Background::Sample s = bg.lookup(dir.data());
    const CompositeResult r = compositeForward(n, sigma.data(), rgb.data(), dt.data(), t.data(), s.rgb);
    ASSERT_GT(1.f - r.opacity, 0.05f);
    float d_color[3], d_bg[3];
    huberLoss3(r.rgb, target, 1.f, d_color);
    backgroundGradient(r.opacity, d_color, d_bg);
    std::vector<float> grad(bg.numParameters(), 0.f);
    bg.backward(s, d_bg, grad.data());
    // Finite differences on every logit (those the lookup does not touch must have zero gradient).
    for (size_t i = 0; i < bg.numParameters(); ++i) {
      const float h = 1e-2f, x = bg.logits()[i];
      bg.logits()[i] = x + h;
      const double lp = rayLoss(bg, dir.data(), sigma, rgb, dt, t, target);
      bg.logits()[i] = x - h;
      const double lm = rayLoss(bg, dir.data(), sigma, rgb, dt, t, target);
      bg.logits()[i] = x;
      const double fd = (lp - lm) / (2.0 * h);
      ASSERT_NEAR(grad[i], fd, 2e-4 + 2e-2 * std::fabs(fd)) << "ray " << ray << " logit " << i;
      checked += grad[i] != 0.f;
    }
    // The density gradient (compositeBackward with the learned colour as background) too.
    std::vector<float> d_sigma(n), d_rgb(3 * n);
    compositeBackward(n, sigma.data(), rgb.data(), dt.data(), t.data(), s.rgb, r, d_color, 0.f, d_sigma.data(),
                      d_rgb.data());
    for (int i = 0; i < n; ++i) {
      auto sp = sigma, sm = sigma;
      sp[size_t(i)] += 1e-2f;
      sm[size_t(i)] -= 1e-2f;
      const double fd =
          (rayLoss(bg, dir.data(), sp, rgb, dt, t, target) - rayLoss(bg, dir.data(), sm, rgb, dt, t, target)) / 2e-2;
      EXPECT_NEAR(d_sigma[size_t(i)], fd, 2e-4 + 2e-2 * std::fabs(fd)) << "ray " << ray << " sigma " << i;
    }
  }
  EXPECT_GT(checked, 6 * 3 * 2);  // the touched texels were checked, not only zeros
}

// The known background: a colour gradient by world direction.
void trueBackground(const Eigen::Vector3d& d, float rgb[3]) {
  rgb[0] = float(0.5 + 0.4 * d.x());
  rgb[1] = float(0.5 + 0.4 * d.y());
  rgb[2] = float(0.5 - 0.4 * d.z());
}

// Opaque views (no alpha) of an empty scene: every pixel is the background. From inside the scene box
// (`outside` false) or from outside it looking away (the rays never enter the box).
TrainingView skyView(int i, int size, bool outside = false) {
  TrainingView v;
  v.camera = Camera::pinhole(size, size, 0.6 * size, 0.6 * size, (size - 1) / 2.0, (size - 1) / 2.0);
  const double yaw = 2 * M_PI * i / 8.0, pitch = 0.5 * std::sin(1.7 * i);
  const Eigen::Matrix3d R =
      (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()) * Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  v.T_world_cam = SE3(R, outside ? Eigen::Vector3d(3.0 * R.col(2)) : Eigen::Vector3d(0.05 * i, 0, 0));
  v.image = cv::Mat(size, size, CV_8UC3);
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      const Eigen::Vector3d d = (R * v.camera.unproject({double(x), double(y)})).normalized();
      float c[3];
      trueBackground(d, c);
      auto& px = v.image.at<cv::Vec3b>(y, x);
      for (int k = 0; k < 3; ++k) px[k] = cv::saturate_cast<uint8_t>(255.0 * c[k]);
    }
  return v;
}

double meanRenderError(const NerfModel& model, const TrainingView& v, const RenderOptions& ro) {
  const RenderResult r = renderView(model, v.camera, v.T_world_cam, ro);
  cv::Mat truth;
  v.image.convertTo(truth, CV_32F, 1.0 / 255.0);
  return cv::norm(r.rgb, truth, cv::NORM_L1) / double(3 * r.rgb.total());
}

TEST(Background, TrainingOnOpaqueViewsRecoversAKnownBackground) {
  // Views from inside the box (where the field could also explain the colours with view-dependent
  // fog: nothing in the loss prefers an empty box) and the same directions from outside it, where
  // only the background can.
  std::vector<TrainingView> train;
  for (int i = 0; i < 16; ++i) train.push_back(skyView(i / 2, 24, i % 2 == 1));
  const TrainingView test = skyView(3, 32);  // a direction set seen in training, another resolution
  NerfModel model = NerfModel::create(sphereField(), sphereScene(), 1);
  TrainOptions to = sphereTraining(2);
  to.background_rows = 16;
  to.learned_background = true;
  to.lr = 3e-2;
  // The background map is compared with the truth below: with per-view appearance on, its colours
  // would be those of the views' mean appearance, which this scene does not pin to identity.
  to.appearance = false;
  to.background_start_steps = 0;  // learned from the first step (the default waits)
  Trainer trainer(model, train, to);
  ASSERT_TRUE(model.background) << "opaque views create the learned background";
  EXPECT_EQ(model.background->rows(), 16);
  RenderOptions ro;
  ro.normals = false;
  const double before = meanRenderError(model, test, ro);
  constexpr int kSteps = 250;
  for (int i = 0; i < kSteps; ++i) ASSERT_FALSE(trainer.step().rolled_back) << "step " << i;
  const double after = meanRenderError(model, test, ro);
  // The background alone, as a map, against the truth over the directions the views saw.
  double bg_err = 0;
  int n = 0;
  for (const auto& v : train)
    for (int y = 0; y < 24; y += 3)
      for (int x = 0; x < 24; x += 3) {
        const Eigen::Vector3d d =
            (v.T_world_cam.rotationMatrix() * v.camera.unproject({double(x), double(y)})).normalized();
        const Eigen::Vector3f df = d.cast<float>();
        float got[3], want[3];
        model.background->eval(df.data(), got);
        trueBackground(d, want);
        for (int c = 0; c < 3; ++c) bg_err += std::fabs(got[c] - want[c]);
        n += 3;
      }
  bg_err /= n;
  RenderOptions white = ro;
  white.learned_background = false;
  const double without = meanRenderError(model, test, white);
  std::printf(
      "known background: render error %.4f before, %.4f after 250 steps (%.4f without the learned "
      "background); map error %.4f\n",
      before, after, without, bg_err);
  EXPECT_LT(after, 0.03);
  EXPECT_LT(after, 0.3 * before);
  EXPECT_LT(bg_err, 0.03);
  // The field stayed (mostly) empty: the background explains the views, not fog in the box.
  EXPECT_GT(without, 2 * after);
}

TEST(Background, ViewsWithAlphaKeepTheRandomBackground) {
  std::vector<TrainingView> views;
  for (int i = 0; i < 4; ++i) views.push_back(syntheticView(i, 4, 16));  // RGBA, transparent around the sphere
  NerfModel model = NerfModel::create(sphereField(), sphereScene(), 1);
  TrainOptions on = sphereTraining(1);
  on.learned_background = true;
  Trainer trainer(model, views, on);
  EXPECT_FALSE(model.background);
  // An RGBA image whose alpha is 255 everywhere is opaque.
  TrainingView opaque = skyView(0, 16);
  cv::cvtColor(opaque.image, opaque.image, cv::COLOR_RGB2RGBA);
  trainer.addView(opaque);
  EXPECT_TRUE(model.background);
  // learned_background false: never created.
  NerfModel plain = NerfModel::create(sphereField(), sphereScene(), 1);
  TrainOptions off = sphereTraining(1);
  off.learned_background = false;
  Trainer t2(plain, {skyView(0, 16)}, off);
  EXPECT_FALSE(plain.background);
}

TEST(Background, ModelFileRoundTripKeepsTheBackground) {
  test::TempDir dir;
  NerfModel a = NerfModel::create(sphereField(), sphereScene(), 7);
  saveModel(a, dir / "plain.nerf");
  {
    // Without a background the file stays a version-1 file, which loads without one.
    std::ifstream in(dir / "plain.nerf", std::ios::binary);
    char head[12];
    in.read(head, 12);
    uint32_t version;
    std::memcpy(&version, head + 8, 4);
    EXPECT_EQ(version, 1u);
    EXPECT_FALSE(loadModel(dir / "plain.nerf").background);
  }
  // An empty occupancy grid: every ray leaves the box untouched and ends on the background.
  a.grid->setValues(std::vector<float>(a.grid->values().size(), 0.f), 0.01f);
  a.background = std::make_unique<Background>(randomBackground(3));
  for (size_t i = 0; i < a.background->adamM().size(); ++i) a.background->adamM()[i] = 0.001f * float(i);
  a.background->adamSteps()[5] = 9;
  saveModel(a, dir / "bg.nerf");
  NerfModel b = loadModel(dir / "bg.nerf");
  ASSERT_TRUE(b.background);
  EXPECT_EQ(b.background->rows(), a.background->rows());
  EXPECT_TRUE(b.background->frame().isApprox(a.background->frame(), 0.f));
  EXPECT_EQ(b.background->logits(), a.background->logits());
  EXPECT_EQ(b.background->adamSteps()[5], 0u);  // optimizer state only with include_optimizer
  // Renders agree (the rays that leave the box end on the background).
  const TrainingView v = skyView(2, 16);
  const RenderResult ra = renderView(a, v.camera, v.T_world_cam), rb = renderView(b, v.camera, v.T_world_cam);
  EXPECT_EQ(cv::norm(ra.rgb, rb.rgb, cv::NORM_INF), 0.0);
  const RenderResult rw = renderView(NerfModel::create(sphereField(), sphereScene(), 7), v.camera, v.T_world_cam);
  EXPECT_GT(cv::norm(ra.rgb, rw.rgb, cv::NORM_INF), 0.05);  // and differ from the white background
  SaveOptions so;
  so.include_optimizer = true;
  saveModel(a, dir / "opt.nerf");
  saveModel(a, dir / "opt.nerf", so);
  NerfModel c = loadModel(dir / "opt.nerf");
  EXPECT_EQ(c.background->adamM(), a.background->adamM());
  EXPECT_EQ(c.background->adamSteps(), a.background->adamSteps());
}

}  // namespace
}  // namespace nerfslam::nerf
