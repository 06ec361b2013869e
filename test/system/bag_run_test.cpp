// `run --dataset bag:FILE` end to end: a bag made from a dataset (`nerfslam bag`, io/bag.h) gives the
// same trajectory as the dataset itself, bit for bit (offline runs are lockstep, so deterministic):
// the images, the timestamps, the camera, the ground truth and the odometry come back identical.
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include "nerfslam/core/input_file.h"
#include "nerfslam/io/bag.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/runner.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

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

// The synthetic room of `frames` frames at width x height (with its simulated odometry) in `out`.
void writeRoom(const fs::path& out, int frames, int width, int height) {
  SynthOptions so;
  so.scene = "room";
  so.frames = frames;
  so.width = width;
  so.height = height;
  writeSynthSequence(so, out);
}

// The synthetic room (70 frames, 320x240) with its simulated odometry: the folder run with
// --odometry, the bag run with the bag's /odom topic and the run on the same bag with the odometry as
// tf instead write the same trajectory.txt, byte for byte, with the same metric scale.
TEST(BagRun, SyntheticRoomBagTracksExactlyLikeTheFolder) {
  if (!bagSupported()) GTEST_SKIP() << "built without ROS bag support (librosbag-storage-dev)";
  test::TempDir dir;
  writeRoom(dir / "seq", 70, 320, 240);
  const fs::path config = test::sourceDir() / "config" / "system" / "synthetic.yaml";
  BagWriteOptions w;
  w.encoding = "mono8";
  w.odometry = dir / "seq" / "odometry.txt";
  writeDatasetBag(*openDataset("tum:" + (dir / "seq").string()), dir / "room.bag", w);

  // The same bag with the odometry as tf (/tf, odom -> base_link) instead of the /odom topic.
  w.odometry_as = "tf";
  writeDatasetBag(*openDataset("tum:" + (dir / "seq").string()), dir / "room_tf.bag", w);

  const RunResult rf = runOn("tum:" + (dir / "seq").string(), dir / "folder_out", config, dir / "seq" / "odometry.txt");
  const RunResult rb = runOn("bag:" + (dir / "room.bag").string(), dir / "bag_out", config);
  const RunResult rt = runOn("bag:" + (dir / "room_tf.bag").string(), dir / "tf_out", config);
  ASSERT_EQ(rf.exit_code, 0);
  ASSERT_EQ(rb.exit_code, 0);
  ASSERT_EQ(rt.exit_code, 0);
  // Where the odometry came from, and the same metric scale set at the same frame from all three.
  EXPECT_EQ(rf.report.at("odometry").at("from").get<std::string>(), "file");
  EXPECT_EQ(rb.report.at("odometry").at("from").get<std::string>(), "topic");
  EXPECT_EQ(rt.report.at("odometry").at("from").get<std::string>(), "tf");
  EXPECT_EQ(rt.report.at("odometry").at("file").get<std::string>(),
            (dir / "room_tf.bag").string() + ":tf odom -> base_link");
  // (70 frames are too short a path for the scale to be set: KITTI's test below sets it.)
  EXPECT_EQ(rt.report.at("scale_source"), rb.report.at("scale_source"));
  for (const char* field : {"applied_scale", "scale_applied_at_frame"})
    EXPECT_EQ(rt.report.at("odometry").at(field), rb.report.at("odometry").at(field)) << field;
  EXPECT_EQ(rt.report.at("ate_se3_rmse_m").get<double>(), rb.report.at("ate_se3_rmse_m").get<double>());
  EXPECT_EQ(readInputFile(dir / "tf_out" / "trajectory.txt"), readInputFile(dir / "bag_out" / "trajectory.txt"));
  EXPECT_EQ(rb.report.at("dataset_kind").get<std::string>(), "bag");
  EXPECT_EQ(rb.report.at("frames_tracked").get<int>(), 70);
  const std::string tf = readInputFile(dir / "folder_out" / "trajectory.txt");
  EXPECT_GT(std::count(tf.begin(), tf.end(), '\n'), 60);
  EXPECT_EQ(readInputFile(dir / "bag_out" / "trajectory.txt"), tf);
  EXPECT_EQ(readInputFile(dir / "bag_out" / "keyframes.txt"), readInputFile(dir / "folder_out" / "keyframes.txt"));
  // The bag's ground truth scores the run as the folder's does (its poses went through a
  // geometry_msgs/Pose: equal to rounding).
  EXPECT_NEAR(rb.report.at("ate_rmse_m").get<double>(), rf.report.at("ate_rmse_m").get<double>(), 1e-12);
  EXPECT_EQ(rb.report.at("ate_matched").get<int>(), 70);
}

// KITTI 06 (51 frames) with odometry made from its ground truth (2 % noise): the map gets its metric
// scale from the bag's odometry exactly as from the file, whether the bag has it as a
// nav_msgs/Odometry topic or as tf.
TEST(BagRun, Kitti06BagWithOdometryTracksExactlyLikeTheFolder) {
  if (!bagSupported()) GTEST_SKIP() << "built without ROS bag support (librosbag-storage-dev)";
  NERFSLAM_REQUIRE_DATA(data, "kitti06_first51");
  test::TempDir dir;
  auto r = test::runCli("synth --odometry-from kitti:" + data.string() + " --out '" + (dir / "odo").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // KITTI's options and synth's extrinsic (README, metric scale from wheel odometry).
  {
    const std::string synthetic = readInputFile(test::sourceDir() / "config" / "system" / "synthetic.yaml");
    test::writeText(dir / "kitti_odo.yaml", readInputFile(test::sourceDir() / "config" / "system" / "kitti.yaml") +
                                                "\n" + synthetic.substr(synthetic.find("\nodometry:") + 1));
  }
  const fs::path bag = dir / "k06.bag";
  r = test::runCli("bag --dataset kitti:" + data.string() + " --encoding mono8 --odometry '" +
                   (dir / "odo" / "odometry.txt").string() + "' --out '" + bag.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // The same with the odometry as tf (`--odometry-as tf`).
  const fs::path tf_bag = dir / "k06_tf.bag";
  r = test::runCli("bag --dataset kitti:" + data.string() + " --encoding mono8 --odometry '" +
                   (dir / "odo" / "odometry.txt").string() + "' --odometry-as tf --out '" + tf_bag.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const RunResult rf =
      runOn("kitti:" + data.string(), dir / "folder_out", dir / "kitti_odo.yaml", dir / "odo" / "odometry.txt");
  const RunResult rb = runOn("bag:" + bag.string(), dir / "bag_out", dir / "kitti_odo.yaml");
  const RunResult rt = runOn("bag:" + tf_bag.string(), dir / "tf_out", dir / "kitti_odo.yaml");
  ASSERT_EQ(rf.exit_code, 0);
  ASSERT_EQ(rb.exit_code, 0);
  ASSERT_EQ(rt.exit_code, 0);
  EXPECT_EQ(rt.report.at("scale_source").get<std::string>(), "odometry");
  EXPECT_EQ(rt.report.at("odometry").at("from").get<std::string>(), "tf");
  EXPECT_EQ(rt.report.at("odometry").at("applied_scale").get<double>(),
            rb.report.at("odometry").at("applied_scale").get<double>());
  EXPECT_EQ(rt.report.at("odometry").at("scale_applied_at_frame"),
            rb.report.at("odometry").at("scale_applied_at_frame"));
  EXPECT_EQ(readInputFile(dir / "tf_out" / "trajectory.txt"), readInputFile(dir / "bag_out" / "trajectory.txt"));
  EXPECT_EQ(rt.report.at("ate_se3_percent_of_path").get<double>(),
            rb.report.at("ate_se3_percent_of_path").get<double>());
  EXPECT_EQ(rb.report.at("frames_tracked").get<int>(), 51);
  EXPECT_EQ(rf.report.at("scale_source").get<std::string>(), "odometry");
  EXPECT_EQ(rb.report.at("scale_source").get<std::string>(), "odometry");
  EXPECT_EQ(readInputFile(dir / "bag_out" / "trajectory.txt"), readInputFile(dir / "folder_out" / "trajectory.txt"));
  EXPECT_EQ(rb.report.at("ate_se3_percent_of_path").get<double>(),
            rf.report.at("ate_se3_percent_of_path").get<double>());
  EXPECT_LT(rb.report.at("ate_se3_percent_of_path").get<double>(), 1.0);
}

// The CLI on bags whose tf cannot give the odometry asked for: exit status 1 and a message naming the
// bag and the frames; --odometry-frames with one frame is a usage error.
TEST(BagRun, OdometryFramesRefusedClearly) {
  if (!bagSupported()) GTEST_SKIP() << "built without ROS bag support (librosbag-storage-dev)";
  test::TempDir dir;
  writeRoom(dir / "seq", 5, 160, 120);
  BagWriteOptions w;
  w.encoding = "mono8";
  w.odometry = dir / "seq" / "odometry.txt";
  w.odometry_as = "tf";
  const fs::path bag = dir / "tf.bag";
  writeDatasetBag(*openDataset("tum:" + (dir / "seq").string()), bag, w);
  const std::string run = "run --no-nerf --dataset bag:'" + bag.string() + "' --out '" + (dir / "out").string() + "' ";
  auto r = test::runCli(run + "--odometry-frames odom,base_nope");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find(bag.string() + ": odometry 'odom' -> 'base_nope' (--odometry-frames): the bag's tf (/tf) "
                                         "has no frame 'base_nope'; its frames: base_link, odom"),
            std::string::npos)
      << r.output;
  EXPECT_FALSE(fs::exists(dir / "out"));
  r = test::runCli(run + "--odometry-frames odom,base_link --odometry-topic /odom");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("--odometry-topic '/odom' and --odometry-frames both given"), std::string::npos) << r.output;
  r = test::runCli(run + "--odometry-frames odom");
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("--odometry-frames"), std::string::npos) << r.output;
  r = test::runCli(run + "--groundtruth-frames odom,camera");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("ground truth 'odom' -> 'camera' (--groundtruth-frames)"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "out"));
}

}  // namespace
}  // namespace nerfslam
