// gtest node started by test/ros/nerfslam_node.test (rostest): image_folder_publisher plays KITTI 06
// into nerfslam_node. Checks ~path and tf against the dataset's ground truth (Sim(3)-aligned ATE,
// nerfslam::evaluateTrajectory), ~map_points, ~tracking_state and the diagnostics, and that the node survives
// images with a refused encoding, a changed size and a stamp going backwards.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <diagnostic_msgs/DiagnosticArray.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/String.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam_ros/conversions.h"
#include "ros_test_util.h"
#include "test_support.h"

namespace {

struct Observed {
  std::mutex mutex;
  nav_msgs::PathConstPtr path;
  sensor_msgs::PointCloud2ConstPtr points;
  std::vector<std::string> states;
  std::map<std::string, std::string> diag;  // last nerfslam_node status values
  int diag_count = 0;
};

uint64_t diagValue(Observed& o, const std::string& key) {
  std::lock_guard<std::mutex> lock(o.mutex);
  const auto it = o.diag.find(key);
  return it == o.diag.end() ? 0 : std::stoull(it->second);
}

using nerfslam::rostest_util::waitFor;

TEST(NerfslamNode, TracksKittiWithinTheAteThresholdAndSurvivesBadInput) {
  ros::NodeHandle nh, pnh("~");
  std::string spec, node, map_frame, camera_frame;
  int start = 0, frames = 0;
  double max_ate_percent = 0, max_tf_ate_percent = 0;
  ASSERT_TRUE(pnh.getParam("dataset", spec));
  ASSERT_TRUE(pnh.getParam("start", start));
  ASSERT_TRUE(pnh.getParam("frames", frames));
  ASSERT_TRUE(pnh.getParam("node", node));
  ASSERT_TRUE(pnh.getParam("map_frame", map_frame));
  ASSERT_TRUE(pnh.getParam("camera_frame", camera_frame));
  ASSERT_TRUE(pnh.getParam("max_ate_percent", max_ate_percent));
  ASSERT_TRUE(pnh.getParam("max_tf_ate_percent", max_tf_ate_percent));
  const std::filesystem::path root = nerfslam::parseDatasetSpec(spec).path;
  NERFSLAM_REQUIRE_PATH(root)
  nerfslam::DatasetOptions opts;
  opts.start = static_cast<size_t>(start);
  opts.max_frames = static_cast<size_t>(frames);
  const auto ds = nerfslam::openDataset(spec, opts);
  ASSERT_EQ(ds->size(), static_cast<size_t>(frames));
  ASSERT_TRUE(ds->hasGroundTruth());
  const nerfslam::Camera& cam = ds->camera();

  Observed o;
  tf2_ros::Buffer buffer(ros::Duration(600.0));
  tf2_ros::TransformListener listener(buffer, nh);
  ros::Subscriber path_sub = nh.subscribe<nav_msgs::Path>(node + "/path", 10, [&](const nav_msgs::PathConstPtr& m) {
    std::lock_guard<std::mutex> lock(o.mutex);
    o.path = m;
  });
  ros::Subscriber points_sub =
      nh.subscribe<sensor_msgs::PointCloud2>(node + "/map_points", 10, [&](const sensor_msgs::PointCloud2ConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.points = m;
      });
  ros::Subscriber state_sub =
      nh.subscribe<std_msgs::String>(node + "/tracking_state", 100, [&](const std_msgs::StringConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.states.push_back(m->data);
      });
  ros::Subscriber diag_sub = nh.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 100, [&](const diagnostic_msgs::DiagnosticArrayConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        for (const auto& st : m->status) {
          if (st.name.find("nerfslam_node") == std::string::npos) continue;
          for (const auto& kv : st.values) o.diag[kv.key] = kv.value;
          ++o.diag_count;
        }
      });
  ros::Publisher image_pub = nh.advertise<sensor_msgs::Image>("image", 10);
  ros::Publisher info_pub = nh.advertise<sensor_msgs::CameraInfo>("camera_info", 10);

  auto publishPair = [&](const std::string& encoding, int width, int height, int step_bytes, double stamp) {
    sensor_msgs::Image img;
    img.header.stamp = ros::Time(stamp);
    img.header.frame_id = "camera";
    img.encoding = encoding;
    img.width = width;
    img.height = height;
    img.step = width * step_bytes;
    img.data.assign(static_cast<size_t>(img.step) * height, 128);
    nerfslam::Camera c = cam;
    c.width = width;
    c.height = height;
    c.cx = width / 2.0;
    c.cy = height / 2.0;
    image_pub.publish(img);
    info_pub.publish(nerfslam::rosbridge::toCameraInfo(c, img.header));
  };

  // 1. Before the dataset starts (the publisher is launched 4 s late): an image with an encoding
  //    the conversions policy refuses is counted and named, and does not fix the image size.
  ASSERT_TRUE(waitFor(30.0, [&] { return image_pub.getNumSubscribers() > 0 && info_pub.getNumSubscribers() > 0; }))
      << "nerfslam_node did not subscribe to image and camera_info";
  ASSERT_TRUE(waitFor(20.0, [&] {
    if (diagValue(o, "frames refused (encoding)") >= 1) return true;
    publishPair("bayer_rggb8", cam.width, cam.height, 1, 1e-3);
    ros::WallDuration(0.2).sleep();
    return false;
  })) << "the bayer_rggb8 image was not counted as refused";

  // 2. The dataset: every frame processed (the node keeps them all: queue_size 100).
  const bool done = waitFor(150.0, [&] {
    return diagValue(o, "frames processed") + diagValue(o, "frames dropped (queue full)") >=
           static_cast<uint64_t>(frames);
  });
  ros::WallDuration(1.5).sleep();  // the last path, map points and diagnostics
  ASSERT_TRUE(done) << "processed " << diagValue(o, "frames processed") << " of " << frames;
  const uint64_t dropped = diagValue(o, "frames dropped (queue full)");
  std::printf("nerfslam_node: %lu frames processed, %lu tracked, %lu dropped, mean tracking %s ms\n",
              static_cast<unsigned long>(diagValue(o, "frames processed")),
              static_cast<unsigned long>(diagValue(o, "frames tracked")), static_cast<unsigned long>(dropped),
              o.diag["tracking ms (mean)"].c_str());

  nav_msgs::PathConstPtr path;
  sensor_msgs::PointCloud2ConstPtr points;
  std::vector<std::string> states;
  {
    std::lock_guard<std::mutex> lock(o.mutex);
    path = o.path;
    points = o.points;
    states = o.states;
  }
  // 3. ~path against the ground truth after Sim(3) alignment.
  ASSERT_TRUE(path) << "no ~path received";
  EXPECT_EQ(path->header.frame_id, map_frame);
  nerfslam::Trajectory ref, est, est_tf;
  for (size_t i = 0; i < ds->size(); ++i) ref.push_back({ds->timestamp(i), *ds->groundTruth(i)});
  for (const auto& ps : path->poses) {
    est.push_back({ps.header.stamp.toSec(), nerfslam::rosbridge::fromPose(ps.pose)});
    try {
      const auto ts = buffer.lookupTransform(map_frame, camera_frame, ps.header.stamp);
      est_tf.push_back({ps.header.stamp.toSec(), nerfslam::rosbridge::fromTransform(ts.transform)});
    } catch (const tf2::TransformException&) {
    }
  }
  ASSERT_GE(est.size(), static_cast<size_t>(0.9 * frames)) << "tracked frames on ~path";
  nerfslam::TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-3;
  const auto rep = nerfslam::evaluateTrajectory(ref, est, eo);
  std::printf("~path: %zu poses, %zu matched, ATE RMSE %.4f m = %.4f %% of %.2f m (sim3 scale %.4f)\n", est.size(),
              rep.matched, rep.ape.rmse, rep.ape_rmse_percent, rep.ref_path_length, rep.scale);
  EXPECT_GE(rep.matched, static_cast<size_t>(0.9 * frames));
  EXPECT_LT(rep.ape_rmse_percent, max_ate_percent);
  EXPECT_GT(rep.ref_path_length, 10.0);

  // 4. tf at the path's stamps (the poses at tracking time, before later bundle adjustment).
  ASSERT_GE(est_tf.size(), static_cast<size_t>(0.9 * frames)) << "tf map -> camera at the path's stamps";
  const auto rep_tf = nerfslam::evaluateTrajectory(ref, est_tf, eo);
  std::printf("tf: %zu poses, ATE RMSE %.4f m = %.4f %% of path\n", est_tf.size(), rep_tf.ape.rmse,
              rep_tf.ape_rmse_percent);
  EXPECT_LT(rep_tf.ape_rmse_percent, max_tf_ate_percent);

  // 5. ~map_points: in the map frame, with points and x y z fields.
  ASSERT_TRUE(points) << "no ~map_points received";
  EXPECT_EQ(points->header.frame_id, map_frame);
  EXPECT_GT(static_cast<size_t>(points->width) * points->height, 100u);
  std::vector<std::string> fields;
  for (const auto& f : points->fields) fields.push_back(f.name);
  EXPECT_EQ(fields, (std::vector<std::string>{"x", "y", "z", "intensity"}));

  // 6. ~tracking_state went initializing -> good/weak, and never lost on this easy sequence.
  ASSERT_FALSE(states.empty());
  EXPECT_EQ(states.front(), "initializing");
  EXPECT_TRUE(states.back() == "good" || states.back() == "weak") << states.back();
  for (const auto& s : states) EXPECT_NE(s, "lost");

  // 7. After the run: a changed image size and a stamp going backwards are refused and counted,
  //    and the node keeps running (its diagnostics keep coming and count them).
  const double last_stamp = ds->timestamp(ds->size() - 1);
  ASSERT_TRUE(waitFor(20.0, [&] {
    if (diagValue(o, "frames refused (size)") >= 1) return true;
    publishPair("mono8", cam.width / 2, cam.height / 2, 1, last_stamp + 1.0);
    ros::WallDuration(0.2).sleep();
    return false;
  })) << "a half-size image was not refused";
  ASSERT_TRUE(waitFor(20.0, [&] {
    if (diagValue(o, "frames refused (timestamp)") >= 1) return true;
    publishPair("mono8", cam.width, cam.height, 1, 0.5 * ds->timestamp(0));
    ros::WallDuration(0.2).sleep();
    return false;
  })) << "an image stamped before the last frame was not refused";
  int diag_before = 0;
  {
    std::lock_guard<std::mutex> lock(o.mutex);
    diag_before = o.diag_count;
  }
  EXPECT_TRUE(waitFor(5.0, [&] {
    std::lock_guard<std::mutex> lock(o.mutex);
    return o.diag_count > diag_before + 1;
  })) << "nerfslam_node stopped publishing diagnostics";
  EXPECT_EQ(diagValue(o, "tracking errors"), 0u);
}

// Runs the node binary against this test's master with the given arguments.
nerfslam::test::CommandResult runNode(const std::string& args) {
  return nerfslam::test::runCommand("timeout 60 '" NERFSLAM_NODE_PATH "' " + args);
}

TEST(NerfslamNode, InvalidParametersExitNonZeroNamingTheParameter) {
  const nerfslam::test::CommandResult queue = runNode("__name:=bad_queue_node _queue_size:=0");
  EXPECT_EQ(queue.exit_code, 1) << queue.output;
  EXPECT_NE(queue.output.find("~queue_size: field 'queue_size': must be > 0 (got 0)"), std::string::npos)
      << queue.output;

  const nerfslam::test::CommandResult frames = runNode("__name:=bad_frames_node _map_frame:=same _camera_frame:=same");
  EXPECT_EQ(frames.exit_code, 1) << frames.output;
  EXPECT_NE(frames.output.find("~map_frame and ~camera_frame must differ"), std::string::npos) << frames.output;

  const nerfslam::test::CommandResult period = runNode("__name:=bad_period_node _map_points_period:=-1.0");
  EXPECT_EQ(period.exit_code, 1) << period.output;
  EXPECT_NE(period.output.find("~map_points_period: field 'map_points_period': must be >= 0 (got -1)"),
            std::string::npos)
      << period.output;

  const nerfslam::test::CommandResult yaml =
      runNode("__name:=bad_yaml_node _camera_yaml:=/nonexistent/nerfslam_no_camera.yaml");
  EXPECT_EQ(yaml.exit_code, 1) << yaml.output;
  EXPECT_NE(yaml.output.find("/nonexistent/nerfslam_no_camera.yaml"), std::string::npos) << yaml.output;

  // A library option by its path, and a bad value in the ~config file: named with where it came from.
  const nerfslam::test::CommandResult path = runNode("__name:=bad_path_node _tracking/features/max_features:=10");
  EXPECT_EQ(path.exit_code, 1) << path.output;
  EXPECT_NE(path.output.find("~tracking/features/max_features: field 'tracking.features.max_features': must be in "
                             "[50, 20000] (got 10)"),
            std::string::npos)
      << path.output;
  nerfslam::test::TempDir dir;
  const std::string config = (dir / "bad.yaml").string();
  nerfslam::test::writeText(config, "nerf:\n  train:\n    threads: 0\n");
  const nerfslam::test::CommandResult file = runNode("__name:=bad_config_node _config:=" + config);
  EXPECT_EQ(file.exit_code, 1) << file.output;
  EXPECT_NE(file.output.find(config + ": field 'nerf.train.threads': must be in [1, 256] (got 0)"), std::string::npos)
      << file.output;
  nerfslam::test::writeText(config, "trackng: {}\n");
  const nerfslam::test::CommandResult typo = runNode("__name:=typo_config_node _config:=" + config);
  EXPECT_EQ(typo.exit_code, 1) << typo.output;
  EXPECT_NE(typo.output.find("field 'trackng': unknown option (did you mean 'tracking'?)"), std::string::npos)
      << typo.output;
}

// ~config read with the library's loader, overridden by a parameter by path and by an alias: the
// effective options the node prints at start-up (it is stopped with SIGINT after 10 s).
TEST(NerfslamNode, ConfigFileThenParametersSetTheOptions) {
  nerfslam::test::TempDir dir;
  const std::string config = (dir / "system.yaml").string();
  nerfslam::test::writeText(config,
                            "local_map_keyframes: 7\n"
                            "tracking:\n  features:\n    max_features: 1500\n"
                            "nerf:\n  enabled: false\n  train:\n    threads: 3\n");
  const nerfslam::test::CommandResult r =
      nerfslam::test::runCommand("timeout -s INT 10 '" NERFSLAM_NODE_PATH "' __name:=config_node _config:=" + config +
                                 " _max_features:=1800 _nerf/train/threads:=2 image:=/config_node_test/image");
  EXPECT_NE(r.output.find("local_map_keyframes = 7  #"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("local_map_keyframes (from " + config + ")"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("tracking.features.max_features = 1800  #"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("tracking.features.max_features (from ~max_features)"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("nerf.train.threads = 2  #"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("nerf.train.threads (from ~nerf/train/threads)"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("nerf.enabled = false  #"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("FATAL"), std::string::npos) << r.output;
}

}  // namespace

int main(int argc, char** argv) { return nerfslam::rostest_util::runRosGtest(argc, argv, "nerfslam_node_test"); }
