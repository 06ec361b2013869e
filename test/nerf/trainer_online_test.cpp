// The trainer's online API (used by the SLAM NeRF thread): views added and re-posed between
// steps, per-view sampling weights and losses, views read back, and the thread count changed
// mid-training.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/trainer.h"

namespace nerfslam::nerf {
namespace {

TrainingView view(int i) {
  TrainingView v;
  v.camera = Camera::pinhole(32, 24, 30, 30, 15.5, 11.5);
  const Eigen::Vector3d eye(0.3 * std::cos(i), 0.3 * std::sin(i), -1.2);
  v.T_world_cam = SE3(Eigen::Quaterniond::Identity(), eye);
  v.image = cv::Mat(24, 32, CV_8UC3);
  cv::RNG rng(uint64_t(100 + i));  // the same image for the same i
  rng.fill(v.image, cv::RNG::UNIFORM, cv::Scalar::all(0), cv::Scalar::all(256));
  v.image.at<cv::Vec3b>(0, 0) = cv::Vec3b(uint8_t(i), 1, 2);
  return v;
}

FieldConfig tinyField() {
  FieldConfig c;
  c.n_levels = 8;
  c.log2_hashmap_size = 14;
  c.finest_resolution = 64;
  c.hidden = 16;
  return c;
}

TrainOptions tinyTraining(int threads) {
  TrainOptions o;
  o.samples_per_step = 1 << 11;
  o.threads = threads;
  o.seed = 5;
  o.max_samples_per_ray = 64;
  return o;
}

std::vector<float> allParameters(NerfModel& m) {
  std::vector<float> out;
  for (const auto& a : m.field->parameters()) out.insert(out.end(), a.data, a.data + a.size);
  return out;
}

TEST(TrainerOnline, AddsViewsAndReadsThemBack) {
  NerfModel m = NerfModel::create(tinyField(), SceneTransform{}, 1);
  Trainer t(m, {view(0)}, tinyTraining(1));
  EXPECT_EQ(t.addView(view(1)), 1u);
  EXPECT_EQ(t.numViews(), 2u);
  const TrainingView back = t.view(1);
  ASSERT_EQ(back.image.type(), CV_8UC4);
  const TrainingView orig = view(1);
  // BGR input order is kept as given (TrainingView images are RGB by contract); alpha is opaque.
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 32; ++x)
      for (int c = 0; c < 3; ++c) ASSERT_EQ(back.image.at<cv::Vec4b>(y, x)[c], orig.image.at<cv::Vec3b>(y, x)[c]);
  EXPECT_EQ(back.image.at<cv::Vec4b>(5, 5)[3], 255);
  EXPECT_TRUE(back.T_world_cam.matrix().isApprox(orig.T_world_cam.matrix()));
  // A view of the wrong size is refused, naming the view.
  TrainingView bad = view(2);
  bad.image = cv::Mat(10, 10, CV_8UC3, cv::Scalar::all(0));
  try {
    t.addView(bad);
    FAIL() << "accepted a mismatched image";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("training view 2"), std::string::npos) << e.what();
  }
  EXPECT_EQ(t.numViews(), 2u);
}

// The learning rate's tail: full rate until the last lr_tail of the reported budget, then down
// exponentially to lr_tail_factor of it at the end; a training that reports no progress keeps it.
TEST(TrainerOnline, LearningRateFallsOverTheBudgetsTail) {
  NerfModel m = NerfModel::create(tinyField(), SceneTransform{}, 1);
  TrainOptions o = tinyTraining(1);
  o.lr = 0.01;
  o.lr_tail = 0.3;
  o.lr_tail_factor = 0.25;
  Trainer t(m, {view(0)}, o);
  EXPECT_DOUBLE_EQ(t.learningRate(), 0.01);  // no progress reported
  t.setBudgetProgress(0.7);
  EXPECT_DOUBLE_EQ(t.learningRate(), 0.01);
  t.setBudgetProgress(0.85);
  EXPECT_NEAR(t.learningRate(), 0.01 * 0.5, 1e-12);  // halfway through the tail: sqrt(0.25)
  t.setBudgetProgress(1.0);
  EXPECT_NEAR(t.learningRate(), 0.01 * 0.25, 1e-12);
  t.setBudgetProgress(7.0);  // clamped
  EXPECT_NEAR(t.learningRate(), 0.01 * 0.25, 1e-12);
  t.setBudgetProgress(std::nan(""));
  EXPECT_DOUBLE_EQ(t.learningRate(), 0.01);
  o.lr_tail = 0;  // off
  Trainer off(m, {view(0)}, o);
  off.setBudgetProgress(1.0);
  EXPECT_DOUBLE_EQ(off.learningRate(), 0.01);
  // The budget used: whichever limit is nearer its end; a limit not set (0) does not count.
  EXPECT_DOUBLE_EQ(budgetProgress(50, 100, 0.0, 0.0), 0.5);
  EXPECT_DOUBLE_EQ(budgetProgress(0, 0, 15.0, 60.0), 0.25);
  EXPECT_DOUBLE_EQ(budgetProgress(50, 100, 45.0, 60.0), 0.75);
  EXPECT_DOUBLE_EQ(budgetProgress(90, 100, 6.0, 60.0), 0.9);
  EXPECT_DOUBLE_EQ(budgetProgress(10, 0, 10.0, 0.0), 0.0);
}

TEST(TrainerOnline, PosesAndWeightsAreValidated) {
  NerfModel m = NerfModel::create(tinyField(), SceneTransform{}, 1);
  Trainer t(m, {view(0), view(1)}, tinyTraining(1));
  const SE3 p(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.1, 0.2, -1));
  t.setViewPose(1, p);
  EXPECT_TRUE(t.viewPose(1).matrix().isApprox(p.matrix()));
  EXPECT_THROW(t.setViewPose(2, p), Error);
  const SE3 nan(Eigen::Quaterniond::Identity(), Eigen::Vector3d(std::numeric_limits<double>::quiet_NaN(), 0, 0));
  EXPECT_THROW(t.setViewPose(0, nan), Error);
  EXPECT_THROW(t.setViewWeights({1.0}), Error);        // one per view
  EXPECT_THROW(t.setViewWeights({0.0, 0.0}), Error);   // not all zero
  EXPECT_THROW(t.setViewWeights({-1.0, 2.0}), Error);  // non-negative
  EXPECT_THROW(t.setViewWeights({std::nan(""), 1.0}), Error);
  EXPECT_NO_THROW(t.setViewWeights({}));  // uniform
}

TEST(TrainerOnline, RaysFollowTheWeightsAndLossesArePerView) {
  NerfModel m = NerfModel::create(tinyField(), SceneTransform{}, 1);
  Trainer t(m, {view(0), view(1), view(2)}, tinyTraining(1));
  t.setViewWeights({1.0, 0.0, 1.0});
  for (int i = 0; i < 5; ++i) t.step();
  ASSERT_EQ(t.viewLoss().size(), 3u);
  EXPECT_GT(t.viewLoss()[0], 0.0);
  EXPECT_EQ(t.viewLoss()[1], -1.0);  // never drawn
  EXPECT_GT(t.viewLoss()[2], 0.0);
  // A view added after the weights were set gets weight 1 and is drawn.
  t.addView(view(3));
  for (int i = 0; i < 5; ++i) t.step();
  EXPECT_GT(t.viewLoss()[3], 0.0);
  EXPECT_EQ(t.viewLoss()[1], -1.0);
}

TEST(TrainerOnline, ChangingThreadsMidTrainingIsDeterministic) {
  auto run = [] {
    NerfModel m = NerfModel::create(tinyField(), SceneTransform{}, 1);
    Trainer t(m, {view(0), view(1)}, tinyTraining(1));
    for (int i = 0; i < 3; ++i) t.step();
    t.setThreads(2);
    t.addView(view(2));
    for (int i = 0; i < 3; ++i) t.step();
    t.setThreads(1);
    t.step();
    EXPECT_EQ(t.steps(), 7);
    return allParameters(m);
  };
  const auto a = run(), b = run();
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(float)), 0);
  NerfModel m = NerfModel::create(tinyField(), SceneTransform{}, 1);
  Trainer t(m, {view(0)}, tinyTraining(1));
  EXPECT_THROW(t.setThreads(0), Error);
}

}  // namespace
}  // namespace nerfslam::nerf
