// `run --dataset bag:FILE` end to end: a bag made from a dataset (`nerfslam bag`, io/bag.h) gives the
// same trajectory as the dataset itself, bit for bit (offline runs are lockstep, so deterministic):
// the images, the timestamps, the camera, the ground truth and the odometry come back identical.
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include "nerfslam/io/bag.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/runner.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

std::string readFile(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

RunResult runOn(const std::string& dataset, const fs::path& out, const fs::path& config,
                const std::optional<fs::path>& odometry = {}) {
  RunOptions ro;
  ro.dataset = dataset;
  ro.config = config;
  ro.odometry = odometry;
  ro.out = out;
  ro.progress = false;
  ro.nerf = false;
  ro.save_default_map = false;
  return runSlam(ro);
}

// The synthetic room (70 frames, 320x240) with its simulated odometry: the folder run with
// --odometry and the bag run with the bag's /odom topic write the same trajectory.txt, byte for byte.
TEST(BagRun, SyntheticRoomBagTracksExactlyLikeTheFolder) {
  if (!bagSupported()) GTEST_SKIP() << "built without ROS bag support (librosbag-storage-dev)";
  test::TempDir dir;
  SynthOptions so;
  so.scene = "room";
  so.frames = 70;
  so.width = 320;
  so.height = 240;
  writeSynthSequence(so, dir / "seq");
  const fs::path config = test::sourceDir() / "config" / "system" / "synthetic.yaml";
  BagWriteOptions w;
  w.encoding = "mono8";
  w.odometry = dir / "seq" / "odometry.txt";
  writeDatasetBag(*openDataset("tum:" + (dir / "seq").string()), dir / "room.bag", w);

  const RunResult rf = runOn("tum:" + (dir / "seq").string(), dir / "folder_out", config, dir / "seq" / "odometry.txt");
  const RunResult rb = runOn("bag:" + (dir / "room.bag").string(), dir / "bag_out", config);
  ASSERT_EQ(rf.exit_code, 0);
  ASSERT_EQ(rb.exit_code, 0);
  EXPECT_EQ(rb.report.at("dataset_kind").get<std::string>(), "bag");
  EXPECT_EQ(rb.report.at("frames_tracked").get<int>(), 70);
  const std::string tf = readFile(dir / "folder_out" / "trajectory.txt");
  EXPECT_GT(std::count(tf.begin(), tf.end(), '\n'), 60);
  EXPECT_EQ(readFile(dir / "bag_out" / "trajectory.txt"), tf);
  EXPECT_EQ(readFile(dir / "bag_out" / "keyframes.txt"), readFile(dir / "folder_out" / "keyframes.txt"));
  // The bag's ground truth scores the run as the folder's does (its poses went through a
  // geometry_msgs/Pose: equal to rounding).
  EXPECT_NEAR(rb.report.at("ate_rmse_m").get<double>(), rf.report.at("ate_rmse_m").get<double>(), 1e-12);
  EXPECT_EQ(rb.report.at("ate_matched").get<int>(), 70);
}

// KITTI 06 (51 frames) with odometry made from its ground truth (2 % noise): the map gets its metric
// scale from the bag's odometry exactly as from the file.
TEST(BagRun, Kitti06BagWithOdometryTracksExactlyLikeTheFolder) {
  if (!bagSupported()) GTEST_SKIP() << "built without ROS bag support (librosbag-storage-dev)";
  NERFSLAM_REQUIRE_DATA(data, "kitti06_first51");
  test::TempDir dir;
  auto r = test::runCli("synth --odometry-from kitti:" + data.string() + " --out '" + (dir / "odo").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // KITTI's options and synth's extrinsic (README, metric scale from wheel odometry).
  {
    const std::string synthetic = readFile(test::sourceDir() / "config" / "system" / "synthetic.yaml");
    test::writeText(dir / "kitti_odo.yaml", readFile(test::sourceDir() / "config" / "system" / "kitti.yaml") + "\n" +
                                                synthetic.substr(synthetic.find("\nodometry:") + 1));
  }
  const fs::path bag = dir / "k06.bag";
  r = test::runCli("bag --dataset kitti:" + data.string() + " --encoding mono8 --odometry '" +
                   (dir / "odo" / "odometry.txt").string() + "' --out '" + bag.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const RunResult rf =
      runOn("kitti:" + data.string(), dir / "folder_out", dir / "kitti_odo.yaml", dir / "odo" / "odometry.txt");
  const RunResult rb = runOn("bag:" + bag.string(), dir / "bag_out", dir / "kitti_odo.yaml");
  ASSERT_EQ(rf.exit_code, 0);
  ASSERT_EQ(rb.exit_code, 0);
  EXPECT_EQ(rb.report.at("frames_tracked").get<int>(), 51);
  EXPECT_EQ(rf.report.at("scale_source").get<std::string>(), "odometry");
  EXPECT_EQ(rb.report.at("scale_source").get<std::string>(), "odometry");
  EXPECT_EQ(readFile(dir / "bag_out" / "trajectory.txt"), readFile(dir / "folder_out" / "trajectory.txt"));
  EXPECT_EQ(rb.report.at("ate_se3_percent_of_path").get<double>(),
            rf.report.at("ate_se3_percent_of_path").get<double>());
  EXPECT_LT(rb.report.at("ate_se3_percent_of_path").get<double>(), 1.0);
}

}  // namespace
}  // namespace nerfslam
