// End-to-end SLAM (runSlam, defaults) on synthetic sequences rendered at test time with ground truth:
// the handheld room, the planar scene (homography initialisation) and pure rotation (must not
// initialise). Sizes keep each test within about a minute on a loaded 2-core machine; the
// full-size figures (600-frame room at 640x480, ...) are in the engineering report.
#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "nerfslam/io/dataset.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/nerf_mapping.h"
#include "nerfslam/system/runner.h"
#include "nerfslam/system/slam_system.h"
#include "test_support.h"

namespace nerfslam {
namespace {

struct SynthRun {
  nlohmann::json report;
  bool initialized = false;
  std::filesystem::path out;
};

// Renders `frames` frames of scene/trajectory into `dir`/seq and runs the SLAM over them (all frames,
// default options, offline lockstep) into `dir`/out.
SynthRun renderAndRun(const test::TempDir& dir, const std::string& scene, const std::string& trajectory, int frames,
                      int width, int height, std::size_t max_frames = 0) {
  SynthOptions so;
  so.scene = scene;
  so.trajectory = trajectory;
  so.frames = frames;
  so.width = width;
  so.height = height;
  const std::filesystem::path seq = dir.path() / "seq";
  writeSynthSequence(so, seq);
  RunOptions ro;
  ro.dataset = "tum:" + seq.string();
  ro.out = dir.path() / "out";
  ro.progress = false;
  ro.max_frames = max_frames;
  ro.nerf = false;  // sparse SLAM only here; nerf_mapping_test covers the NeRF thread end to end
  const RunResult r = runSlam(ro);
  EXPECT_EQ(r.exit_code, 0);
  return {r.report, r.initialized, ro.out};
}

int posesInFile(const std::filesystem::path& file) {
  std::ifstream in(file);
  EXPECT_TRUE(in.good()) << file;
  std::string line;
  int poses = 0;
  while (std::getline(in, line)) poses += !line.empty() && line[0] != '#';
  return poses;
}

TEST(SyntheticSlam, HandheldRoomTracksEveryFrameAccurately) {
  test::TempDir dir;
  const SynthRun r = renderAndRun(dir, "room", "handheld", 80, 640, 480);
  ASSERT_TRUE(r.initialized) << r.report.dump(2);
  EXPECT_EQ(r.report.at("frames").get<int>(), 80);
  // Every frame tracked (the frames up to the initialisation pair are tracked retroactively).
  EXPECT_EQ(r.report.at("frames_tracked").get<int>(), 80) << r.report.dump(2);
  EXPECT_EQ(r.report.at("first_tracked_frame").get<int>(), 0);
  EXPECT_EQ(r.report.at("frames_lost_after_init").get<int>(), 0);
  EXPECT_EQ(r.report.at("initializations").get<int>(), 1);
  EXPECT_EQ(r.report.at("ate_matched").get<int>(), 80);
  // Measured 0.461 % on these 80 frames (0.466 % on 100, 0.403 % on 200); the 0.5 % target applies to the full
  // 600-frame room (figure in the report).
  EXPECT_LT(r.report.at("ate_percent_of_path").get<double>(), 0.6) << r.report.dump(2);
  EXPECT_EQ(posesInFile(r.out / "trajectory.txt"), 80);
}

TEST(SyntheticSlam, HandheldRoomInitialisesWithinThirtyFrames) {
  // The handheld trajectory translates from its first frame: the map must exist by frame 30.
  test::TempDir dir;
  const SynthRun r = renderAndRun(dir, "room", "handheld", 30, 640, 480);
  ASSERT_TRUE(r.initialized) << r.report.dump(2);
  EXPECT_EQ(r.report.at("frames_tracked").get<int>(), 30) << r.report.dump(2);
}

TEST(SyntheticSlam, PlanarSceneInitialisesFromHomography) {
  test::TempDir dir;
  const SynthRun r = renderAndRun(dir, "plane", "handheld", 60, 640, 480);
  ASSERT_TRUE(r.initialized) << r.report.dump(2);
  EXPECT_EQ(r.report.at("initialization_model").get<std::string>(), "homography");
  EXPECT_EQ(r.report.at("frames_tracked").get<int>(), 60) << r.report.dump(2);
  EXPECT_EQ(r.report.at("frames_lost_after_init").get<int>(), 0);
  // Measured 1.42 % on these 60 frames (short 0.2 m path: small absolute error, 2.9 mm RMSE).
  EXPECT_LT(r.report.at("ate_percent_of_path").get<double>(), 2.0) << r.report.dump(2);
}

TEST(SyntheticSlam, PureRotationNeverInitialises) {
  test::TempDir dir;
  const SynthRun r = renderAndRun(dir, "room", "rotation", 90, 320, 240);
  EXPECT_FALSE(r.initialized);
  EXPECT_FALSE(r.report.at("initialized").get<bool>());
  EXPECT_EQ(r.report.at("frames_tracked").get<int>(), 0);
  EXPECT_EQ(r.report.at("keyframes").get<int>(), 0);
  EXPECT_NE(r.report.at("failure").get<std::string>().find("rotation"), std::string::npos) << r.report.dump(2);
  // No invented trajectory: the trajectory file exists and holds no pose.
  EXPECT_EQ(posesInFile(r.out / "trajectory.txt"), 0);
}

// The handheld walk in the synthetic room, rendered into `dir`/seq and opened as a dataset.
std::unique_ptr<Dataset> renderHandheldRoom(const test::TempDir& dir, int frames, int width, int height) {
  SynthOptions so;
  so.scene = "room";
  so.trajectory = "handheld";
  so.frames = frames;
  so.width = width;
  so.height = height;
  writeSynthSequence(so, dir.path() / "seq");
  return openDataset("tum:" + (dir.path() / "seq").string());
}

TEST(SyntheticSlam, LocalizationOnlySwitchStopsAndResumesMapping) {
  // Mapping for 50 frames, localisation only for 40 (tracked, the map frozen: no keyframe, no point,
  // no change of a keyframe pose after mapping went idle), then mapping again for 30.
  test::TempDir dir;
  const auto ds = renderHandheldRoom(dir, 120, 640, 480);
  SystemOptions opt;
  opt.nerf.enabled = false;
  SlamSystem sys(ds->camera(), opt);
  auto track = [&](size_t i) {
    const DatasetFrame f = ds->load(i);
    const FrameRecord r = sys.trackFrame(f.image, f.timestamp, i);
    sys.waitMappingIdle();  // offline lockstep, as the runner does
    return r;
  };
  for (size_t i = 0; i < 50; ++i) track(i);
  ASSERT_TRUE(sys.initialized());
  EXPECT_FALSE(sys.localizationOnly());
  sys.setLocalizationOnly(true);
  const auto kf_before = sys.map().keyframeIds();
  const size_t points_before = sys.map().numPoints();
  const Trajectory kf_poses_before = sys.keyframeTrajectory();
  int tracked = 0;
  for (size_t i = 50; i < 90; ++i) {
    const FrameRecord r = track(i);
    tracked += r.tracked;
    EXPECT_FALSE(r.keyframe) << "frame " << i;
  }
  EXPECT_EQ(tracked, 40);
  EXPECT_EQ(sys.map().keyframeIds(), kf_before);
  EXPECT_EQ(sys.map().numPoints(), points_before);
  const Trajectory kf_poses_after = sys.keyframeTrajectory();
  ASSERT_EQ(kf_poses_after.size(), kf_poses_before.size());
  for (size_t k = 0; k < kf_poses_after.size(); ++k)
    EXPECT_LT((kf_poses_after[k].pose.translation() - kf_poses_before[k].pose.translation()).norm(), 1e-12);
  sys.setLocalizationOnly(false);
  int keyframes = 0;
  for (size_t i = 90; i < 120; ++i) {
    const FrameRecord r = track(i);
    EXPECT_TRUE(r.tracked) << "frame " << i;
    keyframes += r.keyframe;
  }
  EXPECT_GT(keyframes, 0);
  EXPECT_GT(sys.map().numKeyframes(), kf_before.size());
  sys.finish();
}

TEST(SyntheticSlam, TrackingMappingAndNerfThreadsRunTogether) {
  // Every thread of the system at once, without the offline lock-step: tracking feeds frames as fast
  // as it can while the mapping thread triangulates and bundle-adjusts and the NeRF thread trains on
  // the keyframes with the poses BA keeps changing. Small (320x240, 60 frames) so that it also runs
  // under ThreadSanitizer in CI (scripts/sanitize.sh thread), which is what it is for; the checks are
  // that nothing was lost on the way: frames tracked, the NeRF trained on the mapped keyframes with
  // their final poses.
  test::TempDir dir;
  const auto ds = renderHandheldRoom(dir, 60, 320, 240);
  SystemOptions opt;
  opt.nerf.enabled = true;
  opt.nerf.train.threads = 2;
  opt.nerf.nice_increment = 0;  // train while tracking runs, not only when the machine is idle
  opt.nerf.final_train_seconds = 0;
  SlamSystem sys(ds->camera(), opt);
  std::string states;
  const auto t0 = std::chrono::steady_clock::now();
  for (size_t i = 0; i < ds->size(); ++i) {
    const DatasetFrame f = ds->load(i);
    // A camera at 30 Hz: the frame is handed over at its time (or at once when tracking is behind).
    std::this_thread::sleep_until(t0 + std::chrono::milliseconds(33 * i));
    const FrameRecord r = sys.trackFrame(f.image, f.timestamp, i);
    states += r.tracked ? 'T' : '.';
  }
  ASSERT_TRUE(sys.initialized());
  ASSERT_NE(sys.nerf(), nullptr);
  // Let the NeRF thread train for a while against a mapping thread that is still busy.
  for (int k = 0; k < 600 && sys.nerf()->stats().steps < 10; ++k)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  sys.finish();
  // Initialised within 30 frames (at 320x240 the 1 degree of parallax takes ~25), every frame tracked from then on.
  const size_t first = states.find('T');
  EXPECT_LT(first, 30u) << states;
  EXPECT_EQ(states.find('.', first), std::string::npos) << states;
  const NerfMappingStats st = sys.nerf()->stats();
  // Every keyframe still in the map reached the NeRF thread: a view, or skipped as too close to one
  // (or dropped by the bounded queue, counted). Under AddressSanitizer tracking is slow enough that
  // the map may hold only three keyframes, so the count of views alone is not the check.
  EXPECT_GE(st.views, 2);
  EXPECT_GE(uint64_t(st.views) + st.keyframes_skipped + st.keyframes_dropped, sys.map().numKeyframes())
      << st.views << " views, " << st.keyframes_skipped << " skipped, " << st.keyframes_dropped << " dropped";
  EXPECT_GT(st.steps, 0);
  // After finish() the NeRF views carry the map's final (globally adjusted) keyframe poses.
  const auto kfs = sys.nerf()->viewKeyframes();
  const auto poses = sys.nerf()->viewPoses();
  ASSERT_EQ(kfs.size(), poses.size());
  for (size_t i = 0; i < kfs.size(); ++i) {
    const auto p = sys.map().resolvePose(kfs[i]);
    ASSERT_TRUE(p.has_value()) << "keyframe " << kfs[i];
    EXPECT_LT((p->translation() - poses[i].translation()).norm(), 1e-9) << "view " << i;
  }
}

}  // namespace
}  // namespace nerfslam
