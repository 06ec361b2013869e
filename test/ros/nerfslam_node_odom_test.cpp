// gtest node started by test/ros/nerfslam_node_odom.test (rostest): nerfslam_node with
// ~publish_map_to_odom, the REP-105 map -> odom correction; and by tracking_node_odom.test: the same
// checks on tracking_node (the off-board split's robot side, config/launch/offboard_mapping.launch),
// ~node_type telling which executable the invalid-parameter cases run. The test renders a synthetic room
// (`nerfslam synth`, 320x240, no data needed), plays it with image_folder_publisher (dataset stamps)
// and acts as the robot: a static base -> camera (the optical-frame rotation, pitched down 10 degrees,
// and an offset) and, for each image, odom -> base at the image's stamp from the ground truth, with
// an odom origin that is not the world's (the robot started 0.6 m away from it, turned 35 degrees:
// odometry that drifted). Odometry is withheld for the first images (the node initialises and tracks
// a few frames meanwhile), as on a robot whose odometry starts late. After the room, `lost_frames` black images (no
// features: tracking is lost on each) follow at the same rate, the robot's odometry still moving 1 cm per frame.
// Checks:
//   1. nerfslam_node publishes no map -> camera (or anything but map -> odom) on tf;
//   2. frames tracked before the odometry got no correction: counted in the diagnostics (every tracked
//      frame is published, skipped or dropped), and a warning names the missing transform;
//   3. map -> odom -> base -> camera over tf (the robot's transforms and the node's correction,
//      looked up at the stamps of ~pose) is ~pose, to rounding;
//   4. the odom origin is recovered. Monocular SLAM's map has an arbitrary scale s (map units per
//      metre) while the odometry is metric, so map -> odom cannot be constant in translation unless
//      s = 1: the node composes T_map_cam (map units) with T_cam_odom (metres), and its translation
//      moves by (s - 1) R_map_cam p_cam_odom as the camera moves. What is scale-free is asserted
//      directly, what is not after naming s:
//      - rotation: R_map_odom is the map's orientation relative to odom, independent of s; it must
//        equal R_map_world R_world_odom at every frame. R_map_world is the mean of
//        R_map_cam R_world_cam^T over ~pose (the ground truth's orientations; the evaluation's Umeyama
//        rotation, fitted to positions alone, was 29 degrees off on this short path). By construction
//        the error of R_map_odom at a frame is the error of that frame's camera orientation: the
//        SLAM's rotation drift (measured 1.1-2.8 degrees at most in four runs), so the bound is that
//        drift with a margin;
//      - translation: with s and the offset fitted to the camera centres under that rotation, the
//        point p_map_odom + (s - 1) R_map_cam p_cam_odom is where a metric-consistent correction puts
//        the odom origin; it must stay near the similarity's image of the true odom origin at every
//        frame. Its error is the SLAM's position error plus its rotation error times the camera's
//        distance to the odom origin (0.5-1 m here), given as a fraction of the path in map units, as
//        ATE is; measured 7.6-15 % at most (the camera centres themselves 7.6-12 %: scale and rotation
//        drift of monocular SLAM over 120 frames). The raw translation's spread is printed beside it:
//        260-270 % of the path, what the scale alone does to an uncorrected comparison.
//   5. while tracking is lost the node republishes its last correction, unchanged, at each image's
//      stamp (REP-105: map -> odom stays available), so that map -> odom -> base -> camera at those
//      stamps is that correction composed with the robot's odometry; every lost image gets one, and
//      the diagnostics count them.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/String.h>
#include <tf2_msgs/TFMessage.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/pose.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam_ros/conversions.h"
#include "ros_test_util.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using nerfslam::SE3;
using nerfslam::rostest_util::ChildProcess;
using nerfslam::rostest_util::DiagnosticsValues;
using nerfslam::rostest_util::RosoutLog;
using nerfslam::rostest_util::waitFor;

SE3 rotZ(double deg, const Eigen::Vector3d& t) {
  return SE3(Eigen::Quaterniond(Eigen::AngleAxisd(deg * M_PI / 180, Eigen::Vector3d::UnitZ())), t);
}
double angleDeg(const Eigen::Quaterniond& a, const Eigen::Quaterniond& b) { return a.angularDistance(b) * 180 / M_PI; }

struct Observed {
  std::mutex mutex;
  std::vector<std::string> states;   // ~tracking_state, in order
  std::map<double, SE3> poses;       // ~pose by stamp
  std::map<double, SE3> map_odom;    // the node's map -> odom by stamp
  std::vector<std::string> foreign;  // anything else the node put on tf
  size_t map_camera = 0;             // map -> camera on tf, from anyone
};

TEST(NerfslamNodeOdom, PublishesTheMapToOdomCorrection) {
  ros::NodeHandle nh, pnh("~");
  std::string node, map_frame, odom_frame, base_frame, camera_frame;
  int frames = 0, withhold_images = 0, lost_frames = 0;
  double rate = 0, max_chain_error = 0, max_rotation_deg = 0, max_origin_percent = 0;
  ASSERT_TRUE(pnh.getParam("node", node));
  ASSERT_TRUE(pnh.getParam("map_frame", map_frame));
  ASSERT_TRUE(pnh.getParam("odom_frame", odom_frame));
  ASSERT_TRUE(pnh.getParam("base_frame", base_frame));
  ASSERT_TRUE(pnh.getParam("camera_frame", camera_frame));
  ASSERT_TRUE(pnh.getParam("frames", frames));
  ASSERT_TRUE(pnh.getParam("rate", rate));
  ASSERT_TRUE(pnh.getParam("withhold_odom_images", withhold_images));
  ASSERT_TRUE(pnh.getParam("lost_frames", lost_frames));
  ASSERT_TRUE(pnh.getParam("max_chain_error", max_chain_error));
  ASSERT_TRUE(pnh.getParam("max_rotation_deg", max_rotation_deg));
  ASSERT_TRUE(pnh.getParam("max_origin_percent", max_origin_percent));

  // The sequence (its frame 0 is at t = 0, a "no stamp" stamp: played from frame 1).
  nerfslam::test::TempDir tmp;
  const auto room = nerfslam::rostest_util::renderSyntheticRoom(tmp.path(), frames);
  ASSERT_TRUE(room.dataset);
  const fs::path& seq = room.dir;
  const auto& ds = room.dataset;
  ASSERT_EQ(ds->size(), size_t(frames));
  const nerfslam::Trajectory& gt = room.ground_truth;
  // The camera's true pose at a stamp of `traj` (null when it has none).
  auto poseAt = [](const nerfslam::Trajectory& traj, double t) -> const SE3* {
    const auto it = std::lower_bound(traj.begin(), traj.end(), t - 1e-6,
                                     [](const nerfslam::TrajectoryEntry& e, double x) { return e.timestamp < x; });
    return it != traj.end() && std::abs(it->timestamp - t) < 1e-6 ? &it->pose : nullptr;
  };
  auto gtAt = [&](double t) { return poseAt(gt, t); };

  // After the room: black images (a folder dataset with the room's camera), stamped on at the room's
  // rate. The robot's camera meanwhile moves on 1 cm per frame along its optical axis (`robot`: the
  // ground truth, then those poses, what its odometry follows).
  const fs::path dark = tmp.path() / "dark";
  fs::create_directories(dark);
  fs::copy_file(seq / "camera.yaml", dark / "camera.yaml");
  nerfslam::Trajectory robot = gt;
  std::vector<double> lost_stamps;
  {
    const double dt = gt[1].timestamp - gt[0].timestamp;
    std::FILE* times = std::fopen((dark / "times.txt").c_str(), "w");
    ASSERT_NE(times, nullptr);
    for (int k = 1; k <= lost_frames; ++k) {
      const double t = gt.back().timestamp + k * dt;
      lost_stamps.push_back(t);
      robot.push_back({t, gt.back().pose * SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, 0.01 * k))});
      std::fprintf(times, "%.9f\n", t);
      char name[32];
      std::snprintf(name, sizeof name, "dark%03d.png", k);
      ASSERT_TRUE(
          cv::imwrite((dark / name).string(), cv::Mat::zeros(ds->camera().height, ds->camera().width, CV_8UC1)));
    }
    std::fclose(times);
  }

  // The robot (world z up). The camera on the base: optical axes (z forward = base x, x right =
  // -base y, y down = -base z), pitched down 10 degrees, 12 cm ahead, 4 cm right, 25 cm up.
  Eigen::Matrix3d R_optical;
  R_optical << 0, 0, 1, -1, 0, 0, 0, -1, 0;
  const SE3 T_base_cam(Eigen::AngleAxisd(10 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix() * R_optical,
                       Eigen::Vector3d(0.12, -0.04, 0.25));
  // The odom origin: 0.6 m from where the robot started, turned 35 degrees about the vertical.
  const SE3 T_world_base0 = gt.front().pose * T_base_cam.inverse();
  const SE3 T_world_odom = T_world_base0 * rotZ(35, Eigen::Vector3d(0.5, -0.3, 0.1));
  const SE3 T_odom_world = T_world_odom.inverse();

  Observed o;
  DiagnosticsValues diag(nh, node.substr(node.rfind('/') + 1));
  const RosoutLog rosout(nh, node);
  tf2_ros::Buffer buffer(ros::Duration(600.0));
  tf2_ros::TransformListener listener(buffer, nh);
  tf2_ros::StaticTransformBroadcaster static_tf;
  tf2_ros::TransformBroadcaster odom_tf;
  static_tf.sendTransform(nerfslam::rosbridge::toTransformStamped(T_base_cam, base_frame, camera_frame, ros::Time(0)));
  std::atomic<size_t> images_seen{0}, odom_sent{0}, odom_withheld{0};
  ros::Subscriber pose_sub =
      nh.subscribe<geometry_msgs::PoseStamped>(node + "/pose", 1000, [&](const geometry_msgs::PoseStampedConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.poses[m->header.stamp.toSec()] = nerfslam::rosbridge::fromPose(m->pose);
      });
  ros::Subscriber state_sub =
      nh.subscribe<std_msgs::String>(node + "/tracking_state", 100, [&](const std_msgs::StringConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.states.push_back(m->data);
      });
  // The robot's odometry at each image's stamp, after the first `withhold_images` images (counted as
  // they arrive, not by the node's progress: which images have odometry does not depend on how far
  // behind the camera the node is; it initialises within them and tracks some without odometry).
  ros::Subscriber image_sub = nh.subscribe<sensor_msgs::Image>("image", 1000, [&](const sensor_msgs::ImageConstPtr& m) {
    const SE3* T_world_cam = poseAt(robot, m->header.stamp.toSec());
    if (!T_world_cam) return;
    if (images_seen++ < size_t(withhold_images)) {
      ++odom_withheld;
      return;
    }
    const SE3 T_odom_base = T_odom_world * *T_world_cam * T_base_cam.inverse();
    odom_tf.sendTransform(
        nerfslam::rosbridge::toTransformStamped(T_odom_base, odom_frame, base_frame, m->header.stamp));
    ++odom_sent;
  });
  ros::Subscriber tf_sub = nh.subscribe<tf2_msgs::TFMessage>(
      "/tf", 1000,
      boost::function<void(const ros::MessageEvent<tf2_msgs::TFMessage const>&)>(
          [&](const ros::MessageEvent<tf2_msgs::TFMessage const>& e) {
            std::lock_guard<std::mutex> lock(o.mutex);
            for (const auto& t : e.getMessage()->transforms) {
              if (t.header.frame_id == map_frame && t.child_frame_id == camera_frame) ++o.map_camera;
              if (e.getPublisherName() != node) continue;
              if (t.header.frame_id == map_frame && t.child_frame_id == odom_frame)
                o.map_odom[t.header.stamp.toSec()] = nerfslam::rosbridge::fromTransform(t.transform);
              else
                o.foreign.push_back(t.header.frame_id + " -> " + t.child_frame_id);
            }
          }));
  ASSERT_TRUE(waitFor(30.0, [&] { return diag.count() > 0; })) << "no diagnostics from " << node;

  // The camera: every frame, dataset stamps, once the node and this test subscribe.
  const char* log_dir = std::getenv("ROS_LOG_DIR");
  const std::string log = (log_dir ? fs::path(log_dir) : tmp.path()) / "nerfslam_odom_publisher.log";
  ChildProcess publisher({NERFSLAM_PUBLISHER_PATH, "__name:=odom_test_camera", "_dataset:=" + seq.string(), "_start:=1",
                          "_use_dataset_stamps:=true", "_rate:=" + std::to_string(rate), "_frame_id:=" + camera_frame,
                          "_wait_for_subscribers:=true", "_min_subscribers:=2", "_exit_when_done:=true"},
                         log);
  ASSERT_TRUE(waitFor(120.0, [&] { return !publisher.running(); })) << nerfslam::rostest_util::readText(log);
  ASSERT_TRUE(waitFor(
      60.0, [&] { return diag.num("frames received") >= frames && diag.accounted() == diag.num("frames received"); }))
      << "received " << diag.num("frames received") << ", accounted for " << diag.accounted();
  // Every tracked frame: its correction published, skipped (named transform missing) or dropped.
  const std::string k_published = "map -> odom published",
                    k_no_odom = "map -> odom skipped (no " + odom_frame + " -> " + base_frame + ")",
                    k_no_mount = "map -> odom skipped (no " + base_frame + " -> " + camera_frame + ")",
                    k_behind = "map -> odom skipped (lookups behind)";
  auto handled = [&] {
    return diag.num(k_published) + diag.num(k_no_odom) + diag.num(k_no_mount) + diag.num(k_behind);
  };
  EXPECT_TRUE(waitFor(20.0, [&] { return handled() == diag.num("frames tracked"); }))
      << handled() << " corrections handled for " << diag.num("frames tracked") << " tracked frames";
  const double room_tracked = diag.num("frames tracked");

  // The black images: tracking lost on each.
  const std::string k_repeated = "map -> odom repeated (tracking lost)",
                    k_not_repeated = "map -> odom not repeated (lost, none for this map)";
  if (lost_frames > 0) {
    const double received_before = diag.num("frames received");
    const double repeats_before = diag.num(k_repeated) + diag.num(k_not_repeated);
    ChildProcess dark_publisher(
        {NERFSLAM_PUBLISHER_PATH, "__name:=odom_test_dark_camera", "_dataset:=folder:" + dark.string(),
         "_use_dataset_stamps:=true", "_rate:=" + std::to_string(rate), "_frame_id:=" + camera_frame,
         "_wait_for_subscribers:=true", "_min_subscribers:=2", "_exit_when_done:=true"},
        log);
    ASSERT_TRUE(waitFor(60.0, [&] { return !dark_publisher.running(); })) << nerfslam::rostest_util::readText(log);
    EXPECT_TRUE(waitFor(60.0,
                        [&] {
                          return diag.num("frames received") >= received_before + lost_frames &&
                                 diag.accounted() == diag.num("frames received") &&
                                 diag.num(k_repeated) + diag.num(k_not_repeated) >= repeats_before + lost_frames;
                        }))
        << "received " << diag.num("frames received") << " (" << received_before
        << " before the black images), accounted for " << diag.accounted() << ", lost images handled "
        << diag.num(k_repeated) + diag.num(k_not_repeated);
    EXPECT_EQ(diag.num("frames tracked"), room_tracked) << "a black image was tracked";
  }
  ros::WallDuration(1.0).sleep();  // the last tf and ~pose messages

  Observed snap;
  {
    std::lock_guard<std::mutex> lock(o.mutex);
    snap.poses = o.poses;
    snap.map_odom = o.map_odom;
    snap.foreign = o.foreign;
    snap.map_camera = o.map_camera;
    snap.states = o.states;
  }
  // The node's corrections at tracked images (with a ~pose), and the others (repeated while lost).
  std::map<double, SE3> corrections, repeats;
  for (const auto& [t, T] : snap.map_odom) (snap.poses.count(t) ? corrections : repeats)[t] = T;
  std::printf(
      "frames: %g received, %g tracked; odometry withheld for %zu images, sent for %zu; map -> odom: %g published "
      "(%zu seen on tf), %g without odometry, %g without the camera mount, %g dropped, %g repeated while lost (%zu "
      "seen on tf), %g lost images without a correction to repeat; ~pose %zu\n",
      diag.num("frames received"), diag.num("frames tracked"), size_t(odom_withheld), size_t(odom_sent),
      diag.num(k_published), corrections.size(), diag.num(k_no_odom), diag.num(k_no_mount), diag.num(k_behind),
      diag.num(k_repeated), repeats.size(), diag.num(k_not_repeated), snap.poses.size());

  // 1. No map -> camera: the camera's parent is the robot's base.
  EXPECT_EQ(snap.map_camera, 0u) << map_frame << " -> " << camera_frame << " was published";
  EXPECT_TRUE(snap.foreign.empty()) << "the node published " << snap.foreign.front();

  // 2. Frames tracked before the odometry: no correction, counted and named.
  EXPECT_GE(diag.num(k_no_odom), 1.0);
  EXPECT_EQ(diag.num(k_no_mount), 0.0);
  const std::string warning = rosout.find({"map -> odom not published", odom_frame + " -> " + base_frame});
  EXPECT_FALSE(warning.empty()) << "no warning naming " << odom_frame << " -> " << base_frame;
  std::printf("node said: %s\n", warning.c_str());
  EXPECT_EQ(double(corrections.size()), diag.num(k_published));
  EXPECT_GE(double(corrections.size()), 0.5 * frames);
  EXPECT_GE(double(snap.poses.size()), 0.8 * frames);

  // 3. map -> odom -> base -> camera over tf is ~pose.
  double max_chain_pos = 0, max_chain_rot = 0;
  size_t chained = 0;
  for (const auto& [t, T_map_odom] : corrections) {
    const auto pose = snap.poses.find(t);
    SE3 T_chain;
    try {
      T_chain =
          nerfslam::rosbridge::fromTransform(buffer.lookupTransform(map_frame, camera_frame, ros::Time(t)).transform);
    } catch (const tf2::TransformException& e) {
      ADD_FAILURE() << "tf " << map_frame << " -> " << camera_frame << " at " << t << ": " << e.what();
      continue;
    }
    ++chained;
    max_chain_pos = std::max(max_chain_pos, (T_chain.translation() - pose->second.translation()).norm());
    max_chain_rot = std::max(max_chain_rot, angleDeg(T_chain.rotation(), pose->second.rotation()));
  }
  std::printf(
      "tf chain %s -> %s -> %s -> %s against ~pose at %zu stamps: largest difference %.3g map units, %.3g deg\n",
      map_frame.c_str(), odom_frame.c_str(), base_frame.c_str(), camera_frame.c_str(), chained, max_chain_pos,
      max_chain_rot);
  EXPECT_EQ(chained, corrections.size());
  EXPECT_LE(max_chain_pos, max_chain_error);
  EXPECT_LE(max_chain_rot, max_chain_error * 180 / M_PI);

  // 4. The odom origin. The similarity map <- world: its rotation from the orientations (the mean of
  // R_map_cam R_world_cam^T: positions alone leave it ill-conditioned on this short, nearly straight
  // path), then scale and offset from the positions (least squares with that rotation).
  nerfslam::Trajectory est;
  for (const auto& [t, T] : snap.poses) est.push_back({t, T});
  nerfslam::TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-4;
  const auto ate = nerfslam::evaluateTrajectory(gt, est, eo);
  Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
  Eigen::Vector3d c_map = Eigen::Vector3d::Zero(), c_world = Eigen::Vector3d::Zero();
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> pairs;  // (map, world) camera centres
  for (const auto& [t, T_map_cam] : snap.poses) {
    const SE3* T_world_cam = gtAt(t);
    if (!T_world_cam) continue;
    sum += T_map_cam.rotationMatrix() * T_world_cam->rotationMatrix().transpose();
    pairs.emplace_back(T_map_cam.translation(), T_world_cam->translation());
    c_map += T_map_cam.translation();
    c_world += T_world_cam->translation();
  }
  ASSERT_GE(pairs.size(), 3u);
  c_map /= double(pairs.size());
  c_world /= double(pairs.size());
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(sum, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d R_map_world = svd.matrixU() * svd.matrixV().transpose();
  if (R_map_world.determinant() < 0)
    R_map_world = svd.matrixU() * Eigen::Vector3d(1, 1, -1).asDiagonal() * svd.matrixV().transpose();
  double num = 0, den = 0;
  for (const auto& [m, w] : pairs) {
    num += (m - c_map).dot(R_map_world * (w - c_world));
    den += (w - c_world).squaredNorm();
  }
  const double s = num / den;  // map units per metre
  const Eigen::Vector3d t_map_world = c_map - s * R_map_world * c_world;
  double max_cam = 0;  // the camera centres' largest error under this alignment (map units)
  for (const auto& [m, w] : pairs) max_cam = std::max(max_cam, (m - s * R_map_world * w - t_map_world).norm());
  const Eigen::Quaterniond q_map_odom_true(R_map_world * T_world_odom.rotationMatrix());
  const Eigen::Vector3d origin_true = s * R_map_world * T_world_odom.translation() + t_map_world;
  const double path_map = ate.ref_path_length * s;
  double max_rot = 0, max_origin = 0, spread_raw = 0;
  const Eigen::Vector3d raw0 = corrections.begin()->second.translation();
  for (const auto& [t, T_map_odom] : corrections) {
    const SE3 T_cam_odom = gtAt(t)->inverse() * T_world_odom;  // metric, what the robot's tf says
    const SE3& T_map_cam = snap.poses.at(t);
    const Eigen::Vector3d origin =
        T_map_odom.translation() + (s - 1) * (T_map_cam.rotation() * T_cam_odom.translation());
    max_rot = std::max(max_rot, angleDeg(T_map_odom.rotation(), q_map_odom_true));
    max_origin = std::max(max_origin, (origin - origin_true).norm());
    spread_raw = std::max(spread_raw, (T_map_odom.translation() - raw0).norm());
  }
  const double origin_percent = 100 * max_origin / path_map;
  std::printf(
      "~pose ATE (Sim(3)) %.3f %% of the %.3f m path (evaluation scale %.4f); map scale %.4f map units per metre "
      "(orientation-based alignment, camera centres within %.3f %% of the path); map -> odom rotation "
      "differs from the true one by at most %.3f deg; odom origin (scale-corrected) off by at most %.4g map units = "
      "%.3f %% of the path; uncorrected map -> odom translation moves by up to %.4g map units = %.2f %% of the path\n",
      ate.ape_rmse_percent, ate.ref_path_length, 1 / ate.scale, s, 100 * max_cam / path_map, max_rot, max_origin,
      origin_percent, spread_raw, 100 * spread_raw / path_map);
  EXPECT_LE(max_rot, max_rotation_deg);
  EXPECT_LE(origin_percent, max_origin_percent);

  // 5. While lost: the last correction again at each image's stamp, and through it and the robot's
  // odometry the camera on tf (the lookups at those stamps succeed).
  EXPECT_NE(std::find(snap.states.begin(), snap.states.end(), "lost"), snap.states.end())
      << "~tracking_state never said lost";
  EXPECT_EQ(double(repeats.size()), diag.num(k_repeated));
  size_t dark_repeated = 0;
  for (double t : lost_stamps) {  // the stamps as published: to the nanosecond
    const auto it = repeats.lower_bound(t - 1e-6);
    if (it != repeats.end() && std::abs(it->first - t) < 1e-6) ++dark_repeated;
  }
  EXPECT_EQ(dark_repeated, size_t(lost_frames)) << "black images with map -> odom at their stamp";
  double max_repeat_diff = 0, max_lost_chain = 0;
  size_t lost_chained = 0;
  for (const auto& [t, T_map_odom] : repeats) {
    auto before = snap.map_odom.find(t);
    ASSERT_NE(before, snap.map_odom.begin()) << "map -> odom repeated at " << t << " before any correction";
    --before;  // the correction (or repeat) before it
    // The same doubles (one SE3 sent again): compared exactly.
    max_repeat_diff =
        std::max({max_repeat_diff, (before->second.translation() - T_map_odom.translation()).cwiseAbs().maxCoeff(),
                  (before->second.rotation().coeffs() - T_map_odom.rotation().coeffs()).cwiseAbs().maxCoeff()});
    const SE3* T_world_cam = poseAt(robot, t);
    ASSERT_NE(T_world_cam, nullptr) << "map -> odom repeated at " << t << ", not an image's stamp";
    const SE3 T_map_cam_expected = T_map_odom * (T_odom_world * *T_world_cam * T_base_cam.inverse()) * T_base_cam;
    try {
      const SE3 T_chain =
          nerfslam::rosbridge::fromTransform(buffer.lookupTransform(map_frame, camera_frame, ros::Time(t)).transform);
      max_lost_chain = std::max({max_lost_chain, (T_chain.translation() - T_map_cam_expected.translation()).norm(),
                                 T_chain.rotation().angularDistance(T_map_cam_expected.rotation())});
      ++lost_chained;
    } catch (const tf2::TransformException& e) {
      ADD_FAILURE() << "tf " << map_frame << " -> " << camera_frame << " at " << t << " (tracking lost): " << e.what();
    }
  }
  std::printf(
      "tracking lost: %zu of %d black images got map -> odom; repeated corrections differ from the one before by at "
      "most %.3g; tf chain at %zu lost stamps against the last correction and the odometry: largest difference %.3g\n",
      dark_repeated, lost_frames, max_repeat_diff, lost_chained, max_lost_chain);
  EXPECT_EQ(max_repeat_diff, 0.0) << "a repeated correction is not the last one";
  EXPECT_EQ(lost_chained, repeats.size());
  EXPECT_LE(max_lost_chain, max_chain_error);
}

// Runs the node binary (~node_type: nerfslam_node or tracking_node) against this test's master.
nerfslam::test::CommandResult runNode(const std::string& args) {
  std::string type;
  ros::NodeHandle("~").param<std::string>("node_type", type, "nerfslam_node");
  EXPECT_TRUE(type == "nerfslam_node" || type == "tracking_node") << "~node_type " << type;
  const std::string path = type == "tracking_node" ? NERFSLAM_TRACKING_NODE_PATH : NERFSLAM_NODE_PATH;
  return nerfslam::test::runCommand("timeout 60 '" + path + "' _publish_map_to_odom:=true " + args);
}

TEST(NerfslamNodeOdom, InvalidFramesExitNonZeroNamingTheParameter) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"__name:=odom_bad1 _odom_frame:=", "~odom_frame must not be empty"},
      {"__name:=odom_bad2 _map_frame:=world _odom_frame:=world", "~odom_frame must differ from ~map_frame"},
      {"__name:=odom_bad3 _base_frame:=camera_optical_frame", "~base_frame must differ from ~camera_frame"},
      {"__name:=odom_bad4 _base_frame:=odom", "~odom_frame and ~base_frame must differ"},
      {"__name:=odom_bad5 _tf_timeout:=-1.0", "~tf_timeout: field 'tf_timeout': must be in [0, 10] (got -1)"},
  };
  for (const auto& [args, message] : cases) {
    const auto r = runNode(args);
    EXPECT_EQ(r.exit_code, 1) << args << ": " << r.output;
    EXPECT_NE(r.output.find(message), std::string::npos) << args << ": " << r.output;
  }
}

}  // namespace

int main(int argc, char** argv) { return nerfslam::rostest_util::runRosGtest(argc, argv, "nerfslam_node_odom_test"); }
