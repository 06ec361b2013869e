// The NeRF mapping thread on keyframes of synthetic sequences (OSMesa, rendered at test time):
// it trains on what the keyframe bus delivers, follows pose updates made in the Map, never blocks
// the publisher, restarts after a map reset, and a box re-fit keeps what was learned (distillation).
// The end-to-end test runs the whole system (`runSlam` with the NeRF) and checks its outputs.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <thread>

#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/eval/image_metrics.h"
#include "nerfslam/io/nav_grid.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/nerf_mapping.h"
#include "nerfslam/system/runner.h"
#include "nerfslam/tracking/frame.h"
#include "test_support.h"

namespace nerfslam {
namespace {

// A map of `n` keyframes of the handheld room at 160x120 with ground-truth poses, and map points
// back-projected from the ground-truth depth of the first keyframe (so the NeRF can fit its box).
struct Fixture {
  SynthOptions so;
  std::unique_ptr<SequenceRenderer> seq;
  std::unique_ptr<Map> map;
  KeyframeBus bus;
  std::vector<KeyframeEvent> events;
  std::vector<SynthFrame> frames;

  explicit Fixture(int n, int stride = 6) {
    so.scene = "room";
    so.trajectory = "handheld";
    so.frames = n * stride + 1;
    so.width = 160;
    so.height = 120;
    so.textures = "procedural";
    seq = std::make_unique<SequenceRenderer>(so);
    map = std::make_unique<Map>(seq->camera());
    FeatureOptions fo;
    fo.max_features = 300;
    for (int i = 0; i < n; ++i) {
      SynthFrame f = seq->render(i * stride);
      auto frame = std::make_shared<Frame>(extractFrame(f.bgr, seq->camera(), fo, uint64_t(i), f.timestamp));
      Keyframe kf;
      kf.T_world_cam = f.T_world_cam;
      kf.frame = frame;
      const KeyframeId id = map->addKeyframe(kf);
      events.push_back({id, f.T_world_cam, frame});
      frames.push_back(std::move(f));
    }
    // Points: keypoints of keyframe 0 at their true depth, "observed" by keyframes 0 and 1.
    const auto kf0 = map->keyframe(0);
    const auto kf1 = map->keyframe(1);
    const size_t m = std::min(kf0->frame->size(), kf1->frame->size());
    for (size_t k = 0; k < m; ++k) {
      const cv::Point2f uv = kf0->frame->keypoints[k].pt;
      const float z = frames[0].depth.at<float>(int(uv.y), int(uv.x));
      if (!(z > 0)) continue;
      const Eigen::Vector3d p_cam = seq->camera().unproject({uv.x, uv.y}) * z;
      map->addPoint(frames[0].T_world_cam * p_cam, {{0, int(k)}, {1, int(k)}});
    }
  }

  // PSNR of the NeRF rendered at frame `i` of the sequence (any frame, keyframe or not).
  double psnrAt(const NerfMapping& nm, int i) const {
    SequenceRenderer r(so);
    const SynthFrame f = r.render(i);
    double p = 0;
    nm.withModel([&](nerf::NerfModel& model) {
      nerf::RenderOptions ro;
      ro.normals = false;
      const auto res = nerf::renderView(model, seq->camera(), f.T_world_cam, ro);
      cv::Mat rgb, gt;
      cv::cvtColor(f.bgr, rgb, cv::COLOR_BGR2RGB);
      rgb.convertTo(gt, CV_32F, 1.0 / 255.0);
      p = psnr(cv::min(cv::max(res.rgb, 0.0), 1.0), gt, 1.0);
    });
    return p;
  }
};

NerfMappingOptions testOptions() {
  NerfMappingOptions o;
  o.downscale = 1.0;
  o.train.threads = 2;
  o.nice_increment = 0;
  o.log2_hashmap_size = 16;
  o.train.samples_per_step = 1 << 13;
  o.final_samples_per_step = 0;   // trainFor keeps the small steps
  o.refit_check_steps = 1000000;  // refits only when the test asks
  o.min_view_distance = 0;        // every keyframe becomes a view
  return o;
}

template <class Pred>
bool waitFor(Pred pred, double seconds) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return pred();
}

// The ray shares of the views: the window of newest views while the sequence runs, the loss alone
// after it (final_recent_share 0), never below min_weight of the mean, nothing for lost keyframes.
TEST(NerfMapping, ViewRaySharesFollowTheWindowAndTheLoss) {
  const std::vector<double> loss = {0.02, 0.01, 0.04, 0.01, 0.01, 0.01};
  const std::vector<bool> valid(loss.size(), true);
  auto total = [](const std::vector<double>& w) {
    double t = 0;
    for (double x : w) t += x;
    return t;
  };
  // While the sequence runs: 0.4 of the rays to the 2 newest views in equal parts, the rest by loss.
  const auto live = viewRayShares(loss, valid, 2, 0.4, 0.0);
  ASSERT_EQ(live.size(), loss.size());
  EXPECT_NEAR(total(live), 1.0, 1e-12);
  EXPECT_NEAR(live[4] + live[5], 0.4 + 0.6 * 0.02 / 0.10, 1e-12);
  EXPECT_NEAR(live[2] / live[0], 2.0, 1e-12);  // by loss among the older views
  EXPECT_NEAR(live[0] / live[1], 2.0, 1e-12);
  // After the sequence (share 0): in proportion to the loss alone, the newest views no longer favoured.
  const auto fin = viewRayShares(loss, valid, 2, 0.0, 0.0);
  EXPECT_NEAR(total(fin), 1.0, 1e-12);
  for (size_t i = 0; i < loss.size(); ++i) EXPECT_NEAR(fin[i], loss[i] / 0.10, 1e-12) << i;
  // The floor: a view whose loss is far below the others' still gets min_weight of the mean.
  const auto floored = viewRayShares({1.0, 1.0, 1.0, 1e-4}, {true, true, true, true}, 1, 0.0, 0.25);
  const double mean = (3.0 + 1e-4) / 4.0;
  EXPECT_NEAR(floored[3] / floored[0], 0.25 * mean / 1.0, 1e-9);
  // A view not seen yet (loss < 0) counts as the largest loss; a lost keyframe's view gets nothing.
  const auto unseen = viewRayShares({0.01, 0.03, -1.0, 0.02}, {true, true, true, false}, 1, 0.0, 0.0);
  EXPECT_DOUBLE_EQ(unseen[2], unseen[1]);
  EXPECT_EQ(unseen[3], 0.0);
  // As many recent views as views: equal shares.
  const auto all_recent = viewRayShares({0.01, 0.05}, {true, true}, 4, 0.4, 0.0);
  EXPECT_DOUBLE_EQ(all_recent[0], 0.5);
  EXPECT_DOUBLE_EQ(all_recent[1], 0.5);
  // ... but without a window (the final training) the loss alone decides, however few the views.
  const auto few_final = viewRayShares({0.01, 0.05}, {true, true}, 4, 0.0, 0.0);
  EXPECT_NEAR(few_final[0], 1.0 / 6.0, 1e-12);
  EXPECT_NEAR(few_final[1], 5.0 / 6.0, 1e-12);
  EXPECT_THROW(viewRayShares({0.01}, {true, true}, 1, 0.0, 0.0), Error);
}

TEST(NerfMapping, TrainsInItsThreadOnPublishedKeyframes) {
  Fixture fx(8);
  NerfMapping nm(*fx.map, fx.bus, testOptions());
  nm.start();
  for (const auto& ev : fx.events) EXPECT_EQ(fx.bus.publish(ev), 1);
  ASSERT_TRUE(waitFor([&] { return nm.stats().views == 8 && nm.stats().steps >= 50; }, 120))
      << "views " << nm.stats().views << " steps " << nm.stats().steps;
  nm.stop();
  EXPECT_GT(nm.stats().samples_per_second, 0.0);
  EXPECT_GT(fx.psnrAt(nm, 3), 12.0);
}

// Each training view carries the map points its keyframe observes (sparse depth for the NeRF), at
// their positions in the map: moved by bundle adjustment, they move; erased, they stop supervising.
TEST(NerfMapping, ViewsCarryTheirMapPointsAndFollowThem) {
  Fixture fx(4);
  NerfMapping nm(*fx.map, fx.bus, testOptions());
  nm.start();
  for (const auto& ev : fx.events) EXPECT_EQ(fx.bus.publish(ev), 1);
  ASSERT_TRUE(waitFor([&] { return nm.stats().views == 4 && nm.stats().steps >= 20; }, 120));
  const std::vector<MapPoint> points = fx.map->points();
  const nerf::TrainingView v0 = nm.trainingView(0);
  ASSERT_GT(v0.points.size(), 50u);
  EXPECT_EQ(v0.points.size(), points.size());
  size_t on_surface = 0;
  for (const auto& p : v0.points) {
    // On the ground-truth surface: its depth is the rendered depth at its pixel (corners sit on depth
    // edges, where the next pixel may be another surface: most, not all).
    const Eigen::Vector3d pc = fx.frames[0].T_world_cam.inverse() * p.position.cast<double>();
    const Eigen::Vector2d uv = fx.seq->camera().project(pc);
    ASSERT_TRUE(uv.x() >= 0 && uv.y() >= 0 && uv.x() < 160 && uv.y() < 120);
    on_surface += std::abs(pc.z() - fx.frames[0].depth.at<float>(int(uv.y()), int(uv.x()))) < 0.02 * pc.z();
    EXPECT_FLOAT_EQ(p.weight, 0.5f);  // two observations of four for full trust, no reprojection error
  }
  EXPECT_GT(on_surface, v0.points.size() * 8 / 10);
  // Keyframe 1's "observations" are its keypoints of the same index, elsewhere in its image: they do
  // not reproject, so they get too little weight to supervise.
  EXPECT_LT(nm.trainingView(1).points.size(), points.size() / 4);
  EXPECT_TRUE(nm.trainingView(2).points.empty());  // keyframe 2 observes none of them
  // Bundle adjustment moves one point and erases another.
  MapUpdate u;
  const Eigen::Vector3d moved = points[0].position + Eigen::Vector3d(0.01, 0.02, 0.0);
  u.point_positions = {{points[0].id, moved}};
  u.erase_points = {points[1].id};
  fx.map->applyUpdate(u);
  ASSERT_TRUE(waitFor(
      [&] {
        const auto pts = nm.trainingView(0).points;
        return pts.size() == points.size() - 1 && pts.front().position.isApprox(moved.cast<float>(), 1e-6f);
      },
      60));
  nm.stop();
  EXPECT_GT(nm.stats().depth_rays, 0);
}

// With held-out keyframes, the thread renders them every heldout_interval_s: the running held-out
// PSNR rises as the map learns, and its history is kept.
TEST(NerfMapping, MeasuresItsHeldOutPsnrWhileItTrains) {
  Fixture fx(8);
  NerfMappingOptions o = testOptions();
  o.holdout_every = 2;
  o.heldout_interval_s = 0.5;
  o.heldout_downscale = 4.0;  // 40x30 renders
  NerfMapping nm(*fx.map, fx.bus, o);
  nm.start();
  for (const auto& ev : fx.events) EXPECT_EQ(fx.bus.publish(ev), 1);
  ASSERT_TRUE(waitFor([&] { return nm.stats().steps >= 300 && nm.stats().psnr_history.size() >= 4; }, 120))
      << "steps " << nm.stats().steps << ", PSNR measurements " << nm.stats().psnr_history.size() << ", views "
      << nm.stats().views << ", held out " << nm.stats().keyframes_held_out;
  nm.stop();
  const NerfMappingStats st = nm.stats();
  EXPECT_EQ(st.keyframes_held_out, 4u);
  EXPECT_EQ(st.views, 4);
  const auto& h = st.psnr_history;
  for (size_t i = 1; i < h.size(); ++i) {
    EXPECT_GT(h[i].seconds, h[i - 1].seconds);
    EXPECT_GE(h[i].steps, h[i - 1].steps);
  }
  std::printf("held-out PSNR %.2f dB at step %lld, %.2f dB at step %lld\n", h.front().psnr_heldout,
              static_cast<long long>(h.front().steps), h.back().psnr_heldout, static_cast<long long>(h.back().steps));
  EXPECT_GT(h.back().psnr_heldout, h.front().psnr_heldout + 1.0);
  EXPECT_GT(st.psnr_heldout, 12.0);
}

TEST(NerfMapping, DivergenceIsRolledBackAndTrainingGoesOn) {
  // A forced NaN in the running trainer's model (as a diverging step would leave it): the next step
  // detects the non-finite loss, rolls back to the last snapshot, counts it, and training goes on.
  Fixture fx(8);
  NerfMapping nm(*fx.map, fx.bus, testOptions());
  nm.start();
  for (const auto& ev : fx.events) EXPECT_EQ(fx.bus.publish(ev), 1);
  ASSERT_TRUE(waitFor([&] { return nm.stats().views == 8 && nm.stats().steps >= 150; }, 180))
      << "steps " << nm.stats().steps;
  const double before = fx.psnrAt(nm, 3);
  nm.withModel([](nerf::NerfModel& m) {
    for (auto& a : m.field->parameters())
      if (a.name == "color.w0") std::fill(a.data, a.data + a.size, std::numeric_limits<float>::quiet_NaN());
    m.field->parametersChanged();
  });
  const int64_t steps_at_nan = nm.stats().steps;
  ASSERT_TRUE(waitFor([&] { return nm.stats().rollbacks >= 1 && nm.stats().steps >= steps_at_nan + 50; }, 180))
      << "rollbacks " << nm.stats().rollbacks << ", steps " << nm.stats().steps - steps_at_nan << " after the NaN";
  nm.stop();
  EXPECT_EQ(nm.stats().rollbacks, 1);
  bool finite = true;
  nm.withModel([&](nerf::NerfModel& m) {
    for (auto& a : m.field->parameters())
      for (size_t i = 0; i < a.size; ++i) finite = finite && std::isfinite(a.data[i]);
  });
  EXPECT_TRUE(finite) << "a non-finite parameter survived the rollback";
  const double after = fx.psnrAt(nm, 3);
  std::printf("PSNR at frame 3: %.2f dB before the NaN, %.2f dB 50+ steps after the rollback\n", before, after);
  EXPECT_GT(after, before - 1.0);
}

TEST(NerfMapping, HeldOutViewsImproveWithTraining) {
  Fixture fx(8);
  NerfMapping nm(*fx.map, fx.bus, testOptions());
  for (const auto& ev : fx.events) fx.bus.publish(ev);
  nm.stop();  // takes the queued keyframes; training below runs in this thread
  ASSERT_TRUE(nm.hasModel());
  const double before = fx.psnrAt(nm, 3);  // between keyframes 0 and 1: never a training view
  EXPECT_EQ(nm.trainFor(0, 400), 400);
  const double after = fx.psnrAt(nm, 3);
  const auto st = nm.stats();
  EXPECT_EQ(st.steps, 400);
  EXPECT_GT(st.samples, 400 * 4000);
  EXPECT_GT(st.psnr_recent, 15.0);
  EXPECT_GT(after, before + 5.0) << "before " << before << " after " << after;
  EXPECT_GT(after, 18.0) << "before " << before;
  EXPECT_EQ(nm.viewKeyframes().size(), 8u);
  // The last step of the budget ran at the end of the learning rate's tail: lr_tail_factor of it.
  const nerf::TrainOptions t = testOptions().train;
  EXPECT_NEAR(st.learning_rate, t.lr * std::pow(t.lr_tail_factor, (399.0 / 400.0 - (1.0 - t.lr_tail)) / t.lr_tail),
              1e-9);
  EXPECT_LT(st.learning_rate, 0.26 * t.lr);
  // A training that follows starts at the full rate again.
  EXPECT_EQ(nm.trainFor(0, 1), 1);
  EXPECT_DOUBLE_EQ(nm.stats().learning_rate, t.lr);
}

TEST(NerfMapping, FollowsPosesThatBundleAdjustmentChanges) {
  Fixture fx(4);
  NerfMapping nm(*fx.map, fx.bus, testOptions());
  for (const auto& ev : fx.events) fx.bus.publish(ev);
  nm.stop();  // takes the queued keyframes without a thread
  ASSERT_TRUE(nm.hasModel());
  // BA moves keyframe 2; the next training picks the new pose up.
  const SE3 moved = SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.1, 0, 0)) * fx.events[2].T_world_cam;
  fx.map->setKeyframePose(2, moved);
  nm.trainFor(0, 1);
  const auto poses = nm.viewPoses();
  ASSERT_EQ(poses.size(), 4u);
  EXPECT_LT((poses[2].translation() - moved.translation()).norm(), 1e-12);
  EXPECT_LT((poses[0].translation() - fx.events[0].T_world_cam.translation()).norm(), 1e-12);
  // A keyframe culled with a parent keeps its image, with the pose resolved through the parent.
  const SE3 T_parent_kf = fx.map->keyframe(1)->T_world_cam.inverse() * fx.map->keyframe(3)->T_world_cam;
  fx.map->eraseKeyframe(3, 1);
  fx.map->setKeyframePose(
      1, SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0.2, 0)) * fx.map->keyframe(1)->T_world_cam);
  nm.trainFor(0, 1);
  const SE3 expect = fx.map->keyframe(1)->T_world_cam * T_parent_kf;
  EXPECT_LT((nm.viewPoses()[3].translation() - expect.translation()).norm(), 1e-9);
  // Worth rendering (the ROS publisher's test) only after the grid's second update.
  const int interval = testOptions().train.grid_update_interval;
  EXPECT_FALSE(nm.renderable());
  nm.trainFor(0, interval - 2);
  EXPECT_EQ(nm.stats().steps, interval);
  EXPECT_FALSE(nm.renderable());
  nm.trainFor(0, 1);
  EXPECT_TRUE(nm.renderable());
}

TEST(NerfMapping, NeverBlocksThePublisherAndCountsDrops) {
  Fixture fx(3);
  NerfMappingOptions o = testOptions();
  o.keyframe_queue = 2;
  NerfMapping nm(*fx.map, fx.bus, o);  // not started: nothing drains the queue
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < 1000; ++i) fx.bus.publish(fx.events[size_t(i % 3)]);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_LT(ms, 500.0);  // 1000 publishes; generous for a loaded machine (each is a queue push)
  nm.stop();
  EXPECT_EQ(nm.stats().keyframes_dropped, 998u);
  EXPECT_EQ(nm.stats().views, 2);
}

// Keyframes the queue dropped while the NeRF thread was behind are still in the map: they become
// views once the thread has caught up (one per step), or before the final training at the latest.
TEST(NerfMapping, KeyframesTheQueueDroppedBecomeViewsOnceItCatchesUp) {
  Fixture fx(6);
  NerfMappingOptions o = testOptions();
  o.keyframe_queue = 2;
  {
    NerfMapping nm(*fx.map, fx.bus, o);  // not started: the queue keeps the newest two
    for (const auto& ev : fx.events) fx.bus.publish(ev);
    nm.stop();
    EXPECT_EQ(nm.stats().keyframes_dropped, 4u);
    EXPECT_EQ(nm.stats().views, 2);
    EXPECT_EQ(nm.trainFor(0, 3), 3);  // the final training takes the dropped ones first
    EXPECT_EQ(nm.stats().views, 6);
    EXPECT_EQ(nm.stats().keyframes_recovered, 4u);
    std::vector<KeyframeId> ids = nm.viewKeyframes();
    std::sort(ids.begin(), ids.end());
    EXPECT_EQ(ids, fx.map->keyframeIds());
  }
  {
    NerfMapping nm(*fx.map, fx.bus, o);
    nm.start();
    for (const auto& ev : fx.events) fx.bus.publish(ev);  // faster than a view is made
    ASSERT_TRUE(waitFor([&] { return nm.stats().views == 6; }, 120)) << "views " << nm.stats().views;
    nm.stop();
    EXPECT_EQ(nm.stats().keyframes_recovered, nm.stats().keyframes_dropped);
  }
}

TEST(NerfMapping, StartsAgainWhenTheSparseMapIsReset) {
  Fixture fx(4);
  NerfMapping nm(*fx.map, fx.bus, testOptions());
  for (const auto& ev : fx.events) fx.bus.publish(ev);
  nm.stop();
  nm.trainFor(0, 2);
  ASSERT_TRUE(nm.hasModel());
  fx.map->clear();  // tracking re-initialised: every keyframe is gone
  nm.trainFor(0, 1);
  EXPECT_FALSE(nm.hasModel());
  EXPECT_EQ(nm.stats().views, 0);
}

TEST(NerfMapping, RefitKeepsWhatWasLearned) {
  Fixture fx(8);
  // The field's distillation alone: with the learned background (carried over unchanged) a field
  // one step old already renders its grey (16.1 dB here), and the gain measured is smaller by it;
  // the distilled field loses the same ~4 dB of the trained one's either way (26.0 -> 22.0).
  NerfMappingOptions o = testOptions();
  o.train.learned_background = false;
  NerfMapping nm(*fx.map, fx.bus, o);
  for (const auto& ev : fx.events) fx.bus.publish(ev);
  nm.stop();
  nm.trainFor(0, 1);
  const double fresh = fx.psnrAt(nm, 6);  // keyframe 1's view, from a field one step old
  nm.trainFor(0, 299);
  const double trained = fx.psnrAt(nm, 6);
  double scale_before = 0, scale_after = 0;
  nm.withModel([&](nerf::NerfModel& m) { scale_before = m.scene.scale; });
  ASSERT_TRUE(nm.refitNow());
  nm.withModel([&](nerf::NerfModel& m) { scale_after = m.scene.scale; });
  EXPECT_LT(scale_after, scale_before / 1.4);  // the box grew
  const double distilled = fx.psnrAt(nm, 6);
  // A fresh model renders ~grey (< 10 dB here); the distilled one keeps most of what was gained over
  // it. (Measured: 9.3 dB fresh, 25.2 trained, 21.3 distilled. The field distils to ~22 dB whatever
  // the march it trained with; the march of cone angle 1/64 trains it to 25.9 where 1/256 gave 23.1,
  // so the earlier rule, within 4 dB of the trained PSNR, no longer measured the distillation.)
  EXPECT_LT(fresh, 12.0);
  EXPECT_GT(distilled - fresh, 0.7 * (trained - fresh))
      << "fresh " << fresh << " trained " << trained << " distilled " << distilled;
  std::printf("refit: PSNR %.2f dB fresh, %.2f dB trained, %.2f dB after re-fit + distillation\n", fresh, trained,
              distilled);
  EXPECT_EQ(nm.stats().refits, 1);
}

TEST(NerfMapping, ResumesFromASavedModelFrozenOrTraining) {
  Fixture fx(6);
  test::TempDir dir;
  const auto file = dir.path() / "model.nerf";
  double saved_psnr = 0;
  {
    NerfMapping nm(*fx.map, fx.bus, testOptions());
    for (const auto& ev : fx.events) fx.bus.publish(ev);
    nm.stop();
    nm.trainFor(0, 200);
    saved_psnr = fx.psnrAt(nm, 3);
    nm.withModel([&](nerf::NerfModel& m) { nerf::saveModel(m, file); });
  }
  KeyframeBus bus2;
  {
    // Localisation in a saved map: the model renders as saved and never trains.
    NerfMapping frozen(*fx.map, bus2, testOptions());
    frozen.resume(file, false);
    EXPECT_TRUE(frozen.frozen());
    EXPECT_EQ(frozen.viewKeyframes().size(), 6u);
    frozen.start();
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    frozen.stop();
    EXPECT_EQ(frozen.trainFor(0, 10), 0);
    EXPECT_NEAR(fx.psnrAt(frozen, 3), saved_psnr, 1e-6);
    EXPECT_EQ(frozen.stats().steps, 200);
  }
  {
    // Extending a saved map: training continues from the saved field, not from scratch.
    NerfMapping extend(*fx.map, bus2, testOptions());
    extend.resume(file, true);
    extend.stop();
    EXPECT_EQ(extend.trainFor(0, 20), 20);
    EXPECT_GT(fx.psnrAt(extend, 3), saved_psnr - 1.0);
    EXPECT_EQ(extend.stats().steps, 220);
  }
  EXPECT_THROW(NerfMapping(*fx.map, bus2, testOptions()).resume(dir.path() / "missing.nerf"), Error);
}

TEST(NerfMapping, WholeSystemWritesTheDenseMapAndReport) {
  test::TempDir dir;
  SynthOptions so;
  so.scene = "room";
  so.trajectory = "handheld";
  so.frames = 90;
  so.width = 320;
  so.height = 240;
  writeSynthSequence(so, dir.path() / "seq");
  RunOptions ro;
  ro.dataset = "tum:" + (dir.path() / "seq").string();
  ro.out = dir.path() / "out";
  ro.progress = false;
  SystemOptions sys;
  // A fixed number of final steps, not seconds: with a time budget a loaded machine made 45 (CI
  // rehearsal beside it) where the floors below assume more than 50.
  sys.nerf.final_train_steps = 100;
  sys.nerf.downscale = 2;
  ro.system = sys;
  const RunResult r = runSlam(ro);
  ASSERT_EQ(r.exit_code, 0);
  ASSERT_TRUE(r.initialized);
  const auto& rep = r.report;
  for (const char* f : {"nerf_steps", "nerf_psnr_keyframes", "nerf_psnr_heldout", "tracking_ms_median_with_nerf",
                        "nerf_depth_median_abs_rel"})
    EXPECT_TRUE(rep.contains(f)) << f << " missing in " << rep.dump(2);
  EXPECT_GE(rep.value("nerf_steps", 0), 100);
  EXPECT_EQ(rep.value("nerf_final_train_steps", 0), 100);
  EXPECT_GT(rep.value("nerf_psnr_heldout", 0.0), 14.0) << rep.dump(2);
  EXPECT_GT(rep.value("nerf_psnr_heldout_frames", 0), 3);
  EXPECT_GT(rep.value("nerf_psnr_keyframes", 0.0), 14.0);
  EXPECT_FALSE(std::filesystem::is_empty(ro.out / "nerf" / "keyframes"));
  for (const char* f : {"nerf/model.nerf", "nerf_cloud.ply", "nerf_cloud.pcd", "mesh.ply", "map_preview.png",
                        "trajectory.png", "report.json"})
    EXPECT_TRUE(std::filesystem::exists(ro.out / f)) << f;
  EXPECT_FALSE(std::filesystem::is_empty(ro.out / "nerf" / "heldout"));
  // The report lists what was written, in the order written.
  const auto outputs = rep.at("outputs").get<std::vector<std::string>>();
  for (const char* f : {"nerf/heldout/", "nerf/keyframes/", "nerf/model.nerf", "nerf_cloud.ply", "nerf_cloud.pcd",
                        "mesh.ply", "occupancy.bt", "occupancy.ot", "occupancy.meta.yaml", "map.yaml", "map.pgm",
                        "map.meta.yaml", "map_preview.png", "trajectory.png", "map/", "report.json"})
    EXPECT_NE(std::find(outputs.begin(), outputs.end(), f), outputs.end()) << f << " not in " << rep.at("outputs");
  // The maps a robot plans in (issue 25): metric through the ground truth's scale, 5 cm voxels.
  ASSERT_TRUE(rep.contains("occupancy")) << rep.value("occupancy_error", std::string("no occupancy_error either"));
  const auto& occ = rep.at("occupancy");
  EXPECT_GT(occ.at("occupied").get<double>(), 100);
  EXPECT_GT(occ.at("free").get<double>(), 1000);
  EXPECT_NEAR(occ.at("resolution").get<double>() * occ.at("metres_per_unit").get<double>(), 0.05, 1e-9);
  EXPECT_GT(occ.at("grid").at("occupied").get<double>(), 10);
  EXPECT_GT(occ.at("grid").at("free").get<double>(), 10);
  const NavGrid grid = loadMapServer(ro.out / "map.yaml");
  EXPECT_EQ(grid.width, occ.at("grid").at("width").get<int>());
  std::printf("occupancy: %s\n", occ.dump().c_str());
  // The saved model loads and renders.
  const nerf::NerfModel m = nerf::loadModel(ro.out / "nerf" / "model.nerf");
  EXPECT_GT(m.training_steps, 0u);
}

}  // namespace
}  // namespace nerfslam
