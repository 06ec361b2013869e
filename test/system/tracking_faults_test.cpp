// Tracking faults injected into a synthetic sequence with ground truth (issue: hardening): black
// frames, a frozen frame repeated, a 2-second gap, and a sudden jump to another part of the
// trajectory. The system must report the loss (no pose invented for a frame it could not track),
// relocalise when the view returns, and keep the map intact: the keyframes that existed before a
// fault keep their poses through it, and the whole trajectory stays accurate against ground truth.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/slam_system.h"
#include "test_support.h"

namespace nerfslam {
namespace {

struct Fed {
  FrameRecord record;
  std::optional<SE3> truth;
};

class TrackingFaults : public ::testing::Test {
 protected:
  void render(const std::string& trajectory, int frames) {
    SynthOptions so;
    so.scene = "room";
    so.trajectory = trajectory;
    so.frames = frames;
    so.width = 640;
    so.height = 480;
    writeSynthSequence(so, dir_.path() / "seq");
    ds_ = openDataset("tum:" + (dir_.path() / "seq").string());
    SystemOptions opt;
    opt.nerf.enabled = false;
    sys_ = std::make_unique<SlamSystem>(ds_->camera(), opt);
  }
  // Feeds dataset frame i (or `image` instead of its image) with timestamp t; offline lockstep.
  const Fed& feed(size_t i, double t, const cv::Mat& image = {}) {
    const DatasetFrame f = ds_->load(i);
    Fed r;
    r.record = sys_->trackFrame(image.empty() ? f.image : image, t, next_index_++);
    r.truth = ds_->groundTruth(i);
    sys_->waitMappingIdle();
    fed_.push_back(r);
    return fed_.back();
  }
  // Keyframe poses now, by id.
  std::map<KeyframeId, SE3> keyframePoses() const {
    std::map<KeyframeId, SE3> out;
    for (const Keyframe& kf : sys_->map().keyframes()) out[kf.id] = kf.T_world_cam;
    return out;
  }
  // Sim(3) ATE of the tracked frames (poses as the system resolves them now) against ground truth,
  // in % of the path.
  double atePercent() const {
    Trajectory est = sys_->trajectory(), ref;
    for (const Fed& f : fed_)
      if (f.record.tracked && f.truth) ref.push_back({f.record.timestamp, *f.truth});
    TrajectoryEvalOptions o;
    o.align = "sim3";
    o.max_dt = 1e-6;
    return evaluateTrajectory(ref, est, o).ape_rmse_percent;
  }
  // Largest change of a keyframe present in both, relative to the map's extent (its keyframe
  // centres' bounding-box diagonal).
  static double largestMove(const std::map<KeyframeId, SE3>& before, const std::map<KeyframeId, SE3>& after) {
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e30), hi = -lo;
    double worst = 0;
    for (const auto& [id, T] : before) {
      lo = lo.cwiseMin(T.translation());
      hi = hi.cwiseMax(T.translation());
      const auto it = after.find(id);
      if (it != after.end()) worst = std::max(worst, (it->second.translation() - T.translation()).norm());
    }
    return worst / std::max((hi - lo).norm(), 1e-12);
  }

  test::TempDir dir_;
  std::unique_ptr<Dataset> ds_;
  std::unique_ptr<SlamSystem> sys_;
  std::vector<Fed> fed_;
  uint64_t next_index_ = 0;
};

TEST_F(TrackingFaults, BlackFramesFrozenFrameAndGapAreReportedAndRecovered) {
  render("handheld", 150);
  const double dt = 1.0 / 30.0;
  for (size_t i = 0; i < 50; ++i) feed(i, double(i) * dt);
  ASSERT_TRUE(sys_->initialized());
  ASSERT_EQ(sys_->state(), TrackingState::kTracking);

  // 1. Five black frames: each reported lost, no pose, no keyframe; the map does not move.
  const auto kf_before_black = keyframePoses();
  const cv::Mat black = cv::Mat::zeros(480, 640, CV_8UC3);
  double t = 50 * dt;
  for (int k = 0; k < 5; ++k, t += dt) {
    const Fed& f = feed(49, t, black);
    EXPECT_FALSE(f.record.tracked) << "black frame " << k << " got a pose";
    EXPECT_FALSE(f.record.keyframe);
    EXPECT_EQ(f.record.state, TrackingState::kLost);
  }
  EXPECT_EQ(keyframePoses().size(), kf_before_black.size());
  EXPECT_LT(largestMove(kf_before_black, keyframePoses()), 1e-9);

  // 2. The view returns (frames 50..69, the camera moved on meanwhile): tracked again within 2 frames
  // (from the last pose, or by relocalisation).
  int first_back = -1;
  for (size_t i = 50; i < 70; ++i, t += dt) {
    const Fed& f = feed(i, t);
    if (f.record.tracked && first_back < 0) first_back = int(i);
  }
  EXPECT_GE(first_back, 50);
  EXPECT_LE(first_back, 51) << "not tracking again after the black frames";
  EXPECT_EQ(sys_->state(), TrackingState::kTracking);

  // 3. A frozen frame repeated 15 times: tracked (a static camera), at one pose, no new keyframe (the
  // camera stands where one is: KeyframePolicyOptions::stopped_distance_ratio).
  const size_t kfs_before_frozen = sys_->map().numKeyframes();
  std::vector<SE3> frozen;
  for (int k = 0; k < 15; ++k, t += dt) {
    const Fed& f = feed(69, t);
    EXPECT_TRUE(f.record.tracked);
    EXPECT_FALSE(f.record.keyframe) << "a frozen frame became a keyframe (" << f.record.message << ")";
    if (f.record.tracked) frozen.push_back(f.record.T_world_cam);
  }
  ASSERT_FALSE(frozen.empty());
  for (const SE3& T : frozen) EXPECT_LT((T.translation() - frozen.front().translation()).norm(), 1e-3);
  EXPECT_EQ(sys_->map().numKeyframes(), kfs_before_frozen);

  // 4. A 2-second gap (frames 70..129 never arrive; the camera is elsewhere, possibly in an unmapped
  // view): frames 130..139 are either lost or tracked correctly (the final ATE checks the latter),
  // then the camera comes back to a mapped view (frames 60..69 again): relocalised within 2 frames.
  const auto kf_before_gap = keyframePoses();
  t += 2.0;
  for (size_t i = 130; i < 140; ++i, t += dt) feed(i, t);
  first_back = -1;
  for (size_t i = 60; i < 70; ++i, t += dt) {
    const Fed& f = feed(i, t);
    if (f.record.tracked && first_back < 0) first_back = int(i);
  }
  EXPECT_GE(first_back, 60);
  EXPECT_LE(first_back, 61) << "not tracking again when the mapped view returned";
  // Bundle adjustment may refine old keyframes a little when new ones join, but the map is not
  // wrecked: no keyframe moved by more than 2 % of the map's extent.
  EXPECT_LT(largestMove(kf_before_gap, keyframePoses()), 0.02);

  sys_->finish();
  // Every pose the system gave (none for the black frames) agrees with ground truth.
  const double ate = atePercent();
  // Measured: 95 of 110 fed frames tracked, 0.42 %.
  std::printf("tracked %zu of %zu fed frames, %d relocalisations, ATE %.3f %% of path\n", sys_->trajectory().size(),
              fed_.size(), sys_->relocalizations(), ate);
  EXPECT_LT(ate, 1.0);
}

TEST_F(TrackingFaults, SuddenJumpIsLostThenRelocalisedWhenTheViewReturns) {
  // Orbit around the room's centre: frames 0..59 map a part of it; the camera then jumps ~90 degrees
  // along the orbit (frames 110..124, an unmapped view), and comes back (frames 60..89).
  render("orbit", 200);
  const double dt = 1.0 / 30.0;
  double t = 0;
  for (size_t i = 0; i < 60; ++i, t += dt) feed(i, t);
  ASSERT_TRUE(sys_->initialized());
  const auto kf_before = keyframePoses();
  // Poses given in the unmapped view (the room's far wall may be in sight) count in the final ATE.
  int lost = 0;
  for (size_t i = 110; i < 125; ++i, t += dt) lost += !feed(i, t).record.tracked;
  EXPECT_GT(lost, 0) << "the jump to an unmapped view was never reported lost";
  EXPECT_LT(largestMove(kf_before, keyframePoses()), 0.02);
  int first_back = -1;
  for (size_t i = 60; i < 90; ++i, t += dt) {
    const Fed& f = feed(i, t);
    if (f.record.tracked && first_back < 0) first_back = int(i);
  }
  EXPECT_GE(first_back, 60);
  EXPECT_LE(first_back, 62) << "not relocalised when the mapped view returned";
  sys_->finish();
  const double ate = atePercent();
  // The same frames 0..89 without the jump, in a fresh system: the jump must not cost accuracy.
  // (A short 1.1 m arc seen from a 0.4 m circle, initialised from a homography: the reference
  // itself measured 1.57 % with ORB descriptors and 2.21 % with ours.)
  fed_.clear();
  next_index_ = 0;
  SystemOptions opt;
  opt.nerf.enabled = false;
  sys_ = std::make_unique<SlamSystem>(ds_->camera(), opt);
  t = 0;
  for (size_t i = 0; i < 90; ++i, t += dt) feed(i, t);
  sys_->finish();
  const double ate_reference = atePercent();
  std::printf("jump: %d of 15 unmapped frames lost, back at frame %d, ATE %.3f %% of path (%.3f %% without the jump)\n",
              lost, first_back, ate, ate_reference);
  EXPECT_LT(ate_reference, 3.0);
  EXPECT_LT(ate, ate_reference + 0.5);
}

}  // namespace
}  // namespace nerfslam
