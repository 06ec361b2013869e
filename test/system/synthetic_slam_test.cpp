// End-to-end SLAM (runSlam, defaults) on synthetic sequences rendered at test time with ground truth:
// the handheld room, the planar scene (homography initialisation) and pure rotation (must not
// initialise). Sizes keep each test within about a minute on a loaded 2-core machine; the
// full-size figures (600-frame room at 640x480, ...) are in the engineering report.
#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/runner.h"
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
  render::SynthOptions so;
  so.scene = scene;
  so.trajectory = trajectory;
  so.frames = frames;
  so.width = width;
  so.height = height;
  const std::filesystem::path seq = dir.path() / "seq";
  render::writeSynthSequence(so, seq);
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

}  // namespace
}  // namespace nerfslam
