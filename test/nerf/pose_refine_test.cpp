#include "nerfslam/nerf/pose_refine.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/field.h"
#include "nerfslam/nerf/trainer.h"
#include "sphere_views.h"

namespace nerfslam::nerf {
namespace {

// The field's position gradient (through density and colour, at fixed directions) against central
// differences of the same scalar loss L = sum a_i sigma_i + b_i . rgb_i.
TEST(PoseRefine, FieldPositionGradientMatchesFiniteDifferences) {
  FieldConfig c = sphereField();
  c.hash_init_range = 0.3;  // features large enough that the field varies in space
  RadianceField field(c, 7);
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(0.1f, 0.9f), s(-1.f, 1.f);
  const size_t n = 64;
  std::vector<float> pos(3 * n), dir(3 * n), a(n), b(3 * n);
  for (size_t i = 0; i < n; ++i) {
    Eigen::Vector3f d(s(rng), s(rng), s(rng));
    d.normalize();
    for (int k = 0; k < 3; ++k) {
      pos[3 * i + k] = u(rng);
      dir[3 * i + k] = d[k];
      b[3 * i + k] = s(rng);
    }
    a[i] = 0.01f * s(rng);
  }
  // The loss of sample i alone (its own position moved): a small sum keeps float round-off out of the
  // differences.
  auto loss = [&](size_t i, const float* p) {
    float sigma, rgb[3];
    field.query(p, dir.data() + 3 * i, 1, &sigma, rgb);
    return double(a[i]) * sigma + double(b[3 * i]) * rgb[0] + double(b[3 * i + 1]) * rgb[1] +
           double(b[3 * i + 2]) * rgb[2];
  };
  auto ws = field.makeWorkspace();
  auto grads = field.makeGradients();
  std::vector<float> sigma(n), rgb(3 * n), dpos(3 * n);
  field.forward(ws, pos.data(), dir.data(), n, sigma.data(), rgb.data());
  field.backward(ws, a.data(), b.data(), grads, dpos.data());
  int checked = 0, close = 0;
  // The field is trilinear per cell: a difference whose stencil crosses a cell face of some level
  // (eps 1e-5 against cells of 1/256..1/16) averages two slopes, so nearly all, not all, agree.
  const float eps = 1e-5f;
  for (size_t i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) {
      float p[3] = {pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]};
      p[k] += eps;
      const double lp = loss(i, p);
      p[k] -= 2 * eps;
      const double fd = (lp - loss(i, p)) / (2 * eps);
      if (std::fabs(fd) < 1e-2) continue;
      ++checked;
      close += std::fabs(fd - dpos[3 * i + k]) <= 0.05 * std::fabs(fd) + 1e-2;
    }
  std::printf("position gradient: %d of %d components within 5 %% of central differences\n", close, checked);
  ASSERT_GT(checked, 60);
  EXPECT_GE(close, checked * 9 / 10);

  // Level weights: all zero gives no gradient; the forward pass is unchanged by them.
  std::vector<float> zeros(size_t(c.n_levels), 0.f), dpos0(3 * n, 1.f);
  field.forward(ws, pos.data(), dir.data(), n, sigma.data(), rgb.data());
  field.backward(ws, a.data(), b.data(), grads, dpos0.data(), zeros.data());
  for (float x : dpos0) ASSERT_EQ(x, 0.f);
}

// accumulatePoseGradient against central differences of a linear loss of the samples' NeRF-space
// positions under PoseCorrection::apply (the samples ride with the camera).
TEST(PoseRefine, PoseGradientMatchesFiniteDifferences) {
  const SE3 T = lookAt(Eigen::Vector3d(2.0, -1.0, 1.5));
  SceneTransform scene;
  scene.scale = 0.3;
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<Eigen::Vector3d> q;  // camera-frame sample positions
  std::vector<Eigen::Vector3d> g;  // dL/d(NeRF-space position)
  for (int k = 0; k < 40; ++k) {
    q.emplace_back(0.3 * u(rng), 0.3 * u(rng), 1.0 + 2.0 * std::fabs(u(rng)));
    g.emplace_back(u(rng), u(rng), u(rng));
  }
  auto loss = [&](const PoseCorrection& c) {
    const SE3 Tr = c.apply(T);
    double l = 0;
    for (size_t k = 0; k < q.size(); ++k) l += g[k].dot(scene.toNerf(Tr * q[k]));
    return l;
  };
  std::vector<float> pos, dpos;
  for (size_t k = 0; k < q.size(); ++k) {
    const Eigen::Vector3d p = scene.toNerf(T * q[k]);
    for (int d = 0; d < 3; ++d) {
      pos.push_back(float(p[d]));
      dpos.push_back(float(g[k][d]));
    }
  }
  double grad[6] = {};
  accumulatePoseGradient(scene.toNerf(T.translation()).cast<float>(), pos.data(), dpos.data(), int(q.size()),
                         scene.scale, grad);
  const double eps = 1e-6;
  for (int i = 0; i < 6; ++i) {
    PoseCorrection plus, minus;
    (i < 3 ? plus.rotation[i] : plus.translation[i - 3]) = eps;
    (i < 3 ? minus.rotation[i] : minus.translation[i - 3]) = -eps;
    const double fd = (loss(plus) - loss(minus)) / (2 * eps);
    EXPECT_NEAR(grad[i], fd, 1e-4 * std::max(1.0, std::fabs(fd))) << "parameter " << i;
  }
}

TEST(PoseRefine, BarfWindowOpensCoarseToFine) {
  std::vector<float> w(8);
  barfLevelWeights(8, 0.0, w.data());
  EXPECT_EQ(w[0], 1.f);
  for (int l = 1; l < 8; ++l) EXPECT_EQ(w[size_t(l)], 0.f);
  barfLevelWeights(8, 0.5, w.data());
  for (int l = 1; l < 8; ++l) EXPECT_LE(w[size_t(l)], w[size_t(l - 1)]);
  EXPECT_GT(w[3], 0.f);
  EXPECT_EQ(w[7], 0.f);
  barfLevelWeights(8, 1.0, w.data());
  for (float x : w) EXPECT_EQ(x, 1.f);
}

double rotationErrorDeg(const SE3& a, const SE3& b) {
  return Eigen::AngleAxisd(a.rotation().inverse() * b.rotation()).angle() * 180.0 / M_PI;
}

// One view of the sphere given a pose 2 degrees and 0.08 units off: the refinement brings it back
// while the views given exactly stay put.
TEST(PoseRefine, PerturbedViewConvergesBackOnTheSphere) {
  std::vector<TrainingView> views;
  for (int i = 0; i < 20; ++i) views.push_back(syntheticView(i, 20, 48));
  const size_t bad = 5;
  const SE3 truth = views[bad].T_world_cam;
  PoseCorrection perturb;
  perturb.rotation = Eigen::Vector3d(0.6, -1.0, 0.8).normalized() * (2.0 * M_PI / 180.0);
  perturb.translation = Eigen::Vector3d(0.05, 0.05, -0.04);
  views[bad].T_world_cam = perturb.apply(truth);
  for (int i = 0; i < 20; ++i)  // surface points for the shift statistics: the sphere's front
    for (int k = 0; k < 30; ++k) {
      const Eigen::Vector3d dir = (views[size_t(i)].T_world_cam.translation().normalized() +
                                   0.4 * Eigen::Vector3d(std::sin(k * 1.3), std::cos(k * 2.1), std::sin(k * 0.7)))
                                      .normalized();
      views[size_t(i)].points.push_back({(kSphereRadius * dir).cast<float>(), 1.f});
    }
  NerfModel model = NerfModel::create(sphereField(), sphereScene(), 1);
  TrainOptions o = sphereTraining(2);
  o.depth_weight = 0;  // the points are only for the statistics
  o.pose_refinement = true;
  o.pose_refine_start = 150;
  o.pose_refine_interval = 1;
  o.pose_c2f_steps = 150;
  o.pose_lr = 2e-3;
  Trainer trainer(model, views, o);
  const double rot0 = rotationErrorDeg(trainer.refinedViewPose(bad), truth);
  const double t0 = (trainer.refinedViewPose(bad).translation() - truth.translation()).norm();
  for (int i = 0; i < 450; ++i) ASSERT_FALSE(trainer.step().rolled_back);
  const SE3 refined = trainer.refinedViewPose(bad);
  const double rot1 = rotationErrorDeg(refined, truth);
  const double t1 = (refined.translation() - truth.translation()).norm();
  double others_rot = 0, others_t = 0;  // printed
  for (size_t v = 0; v < views.size(); ++v) {
    if (v == bad) continue;
    others_rot = std::max(others_rot, rotationErrorDeg(trainer.refinedViewPose(v), views[v].T_world_cam));
    others_t =
        std::max(others_t, (trainer.refinedViewPose(v).translation() - views[v].T_world_cam.translation()).norm());
  }
  const auto st = trainer.poseRefinementStats();
  std::printf(
      "perturbed view: rotation error %.2f -> %.2f deg, position error %.3f -> %.3f; the other views moved at most "
      "%.2f deg, %.3f; shifts: median %.2f px, max %.2f px over %d views; %lld refinement steps, %lld resets\n",
      rot0, rot1, t0, t1, others_rot, others_t, st.median_shift_px, st.max_shift_px, st.views,
      static_cast<long long>(st.steps), static_cast<long long>(st.resets));
  EXPECT_LT(rot1, 0.5 * rot0);
  EXPECT_LT(t1, 0.5 * t0);
  // The views given exactly stay within a pixel (48-pixel images: a degree is 0.9 px) while the
  // perturbed one moves by its error.
  std::vector<Eigen::Vector3f> pts;
  for (const auto& p : views[bad].points) pts.push_back(p.position);
  const double bad_shift = medianReprojectionShiftPx(views[bad].camera, views[bad].T_world_cam, refined, pts);
  EXPECT_EQ(st.views, 20);
  EXPECT_LT(st.median_shift_px, 1.0);
  EXPECT_GT(bad_shift, 2.0);
  EXPECT_GT(bad_shift, 2.5 * st.median_shift_px);
  EXPECT_EQ(st.resets, 0);
  EXPECT_EQ(st.steps, 300);
}

// A refinement that runs away (bounds far below what the perturbation needs) is reset and counted,
// and training goes on with the given poses.
TEST(PoseRefine, DivergedCorrectionIsResetAndCounted) {
  std::vector<TrainingView> views;
  for (int i = 0; i < 12; ++i) views.push_back(syntheticView(i, 12, 32));
  PoseCorrection perturb;
  perturb.rotation = Eigen::Vector3d(0, 0, 3.0 * M_PI / 180.0);
  views[2].T_world_cam = perturb.apply(views[2].T_world_cam);
  NerfModel model = NerfModel::create(sphereField(), sphereScene(), 1);
  TrainOptions o = sphereTraining(1);
  o.pose_refinement = true;
  o.pose_refine_start = 20;
  o.pose_refine_interval = 1;
  o.pose_lr = 0.05;
  o.pose_max_rotation_deg = 0.05;
  Trainer trainer(model, views, o);
  for (int i = 0; i < 80; ++i) ASSERT_FALSE(trainer.step().rolled_back);
  const auto st = trainer.poseRefinementStats();
  EXPECT_GT(st.resets, 0);
  for (size_t v = 0; v < views.size(); ++v)
    EXPECT_LE(trainer.viewPoseCorrection(v).rotation.norm(), 2 * 0.05 * M_PI / 180.0) << v;
  EXPECT_THROW(trainer.setViewPoseCorrection(0, PoseCorrection{Eigen::Vector3d::Constant(NAN), {}}), Error);
}

}  // namespace
}  // namespace nerfslam::nerf
