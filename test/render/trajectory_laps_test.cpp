// Laps of the loop trajectory (makeTrajectory's `laps`, `nerfslam synth --laps`).
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "nerfslam/render/scene.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/render/trajectory.h"
#include "test_support.h"

namespace nerfslam {
namespace {

Scene proceduralScene(const std::string& name) {
  SynthSceneOptions so;
  so.name = name;
  so.textures = "procedural";
  so.texture_size = 32;
  return makeScene(so);
}

TEST(TrajectoryLaps, EveryLapIsTheSame) {
  for (const std::string& scene : sceneNames()) {
    const Scene sc = proceduralScene(scene);
    for (const std::string name : {"loop"}) {
      const CameraTrajectory t = makeTrajectory(sc, name, 12.0, 3, 3);
      for (double s = 0; s <= 8.0; s += 0.37) {
        EXPECT_TRUE(t.pose(s).isApprox(t.pose(s + 4.0), 1e-9)) << scene << "/" << name << " t=" << s;
      }
      EXPECT_TRUE(t.pose(0).isApprox(t.pose(12.0), 1e-9)) << scene << "/" << name;
      // The path is really travelled within a lap.
      EXPECT_GT((t.pose(0).translation() - t.pose(2.0).translation()).norm(), 0.1) << scene << "/" << name;
      // One lap is the trajectory of before, bit for bit.
      const CameraTrajectory one = makeTrajectory(sc, name, 12.0, 3, 1), old = makeTrajectory(sc, name, 12.0, 3);
      for (double s = -1.0; s <= 13.0; s += 0.61) EXPECT_TRUE(one.pose(s).isApprox(old.pose(s), 0));
    }
  }
}

TEST(TrajectoryLaps, ALapOfMoreLapsIsTheSinglePathFaster) {
  const Scene sc = proceduralScene("corridor");
  const CameraTrajectory three = makeTrajectory(sc, "loop", 9.0, 4, 3), one = makeTrajectory(sc, "loop", 3.0, 4, 1);
  for (double s = 0; s <= 3.0; s += 0.25) EXPECT_TRUE(three.pose(s).isApprox(one.pose(s), 1e-9)) << s;
}

TEST(TrajectoryLaps, RefusesLapsWhereThereAreNone) {
  const Scene sc = proceduralScene("room");
  EXPECT_NE(test::errorOf([&] { makeTrajectory(sc, "handheld", 10.0, 1, 2); }).find("has no laps"), std::string::npos);
  // The orbit's height wanders without closing: its laps would jump at every lap boundary.
  EXPECT_NE(test::errorOf([&] { makeTrajectory(sc, "orbit", 10.0, 1, 2); }).find("has no laps"), std::string::npos);
  EXPECT_NE(test::errorOf([&] { makeTrajectory(sc, "loop", 10.0, 1, 0); }).find("laps must be"), std::string::npos);
  SynthOptions o;
  o.scene = "corridor";
  o.frames = 300;
  o.laps = 3;
  EXPECT_NE(test::errorOf([&] { o.validate(); }).find("e.g. 298"), std::string::npos);
  o.frames = 301;
  EXPECT_EQ(test::errorOf([&] { o.validate(); }), "");
  o.trajectory = "forward";
  EXPECT_NE(test::errorOf([&] { o.validate(); }).find("has no laps"), std::string::npos);
}

// The written ground truth: frame i and frame i + (frames - 1) / laps have the same pose.
TEST(TrajectoryLaps, SynthWritesIdenticalLaps) {
  test::TempDir dir;
  const auto r = test::runCli(
      "synth --scene corridor --trajectory loop --frames 31 --laps 3 --size 64x48 "
      "--textures procedural --out " +
      (dir / "seq").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream in(dir / "seq/groundtruth.txt");
  std::vector<std::vector<double>> poses;
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    std::vector<double> v(8);
    for (double& x : v) s >> x;
    poses.push_back({v.begin() + 1, v.end()});  // without the timestamp
  }
  ASSERT_EQ(poses.size(), 31u);
  for (size_t i = 0; i + 10 < poses.size(); ++i)
    for (size_t k = 0; k < 7; ++k) EXPECT_NEAR(poses[i][k], poses[i + 10][k], 1e-6) << "frame " << i << " field " << k;
  double moved = 0;
  for (size_t k = 0; k < 3; ++k) moved += std::abs(poses[0][k] - poses[5][k]);
  EXPECT_GT(moved, 0.1);
}

}  // namespace
}  // namespace nerfslam
