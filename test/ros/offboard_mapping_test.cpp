// gtest node started by test/ros/offboard_mapping.test (rostest): the off-board mapping split,
// tracking_node + nerf_mapping_node (config/launch/offboard_mapping.launch), beside a single
// nerfslam_node (~nerf false) fed the same frames. The test renders a short synthetic room sequence
// (`nerfslam synth`, 320x240: no data needed) and plays it in colour, at the dataset's stamps, with
// image_folder_publisher into both SLAM nodes. Checks:
//   (a) tracking_node's ~path equals nerfslam_node's (same stamps, positions within a tolerance of
//       the path length) and both meet the same Sim(3) ATE target against the ground truth;
//   (b) nerf_mapping_node received every keyframe tracking_node sent (counted on ~keyframes_out by
//       this test, in both nodes' diagnostics), applied the last pose update, and its replica's
//       keyframes (saved with ~save_map) are the tracking map's (also saved with ~save_map): the same
//       ids, poses equal within 1e-6; the last update carries the tracking map's points;
//   (c) nerf_mapping_node's ~nerf_view improves: its correlation with the input image of its stamp
//       (grey levels) rises from the first render to a threshold.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <cv_bridge/cv_bridge.h>
#include <diagnostic_msgs/DiagnosticArray.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/Trigger.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/KeyframePoses.h"
#include "nerfslam/MapKeyframe.h"
#include "nerfslam/core/camera.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/nerf_mapping.h"
#include "nerfslam_ros/conversions.h"
#include "ros_test_util.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;

struct Observed {
  std::mutex mutex;
  nav_msgs::PathConstPtr tracking_path, reference_path;
  std::vector<uint64_t> keyframe_ids;  // on ~keyframes_out, in arrival order
  nerfslam::KeyframePosesConstPtr last_poses;
  std::vector<std::pair<double, sensor_msgs::ImageConstPtr>> views;  // (s since the start, view)
  std::map<std::string, std::map<std::string, std::string>> diag;    // node -> key -> value
};

std::string diagString(Observed& o, const std::string& node, const std::string& key) {
  std::lock_guard<std::mutex> lock(o.mutex);
  const auto n = o.diag.find(node);
  if (n == o.diag.end()) return "";
  const auto it = n->second.find(key);
  return it == n->second.end() ? "" : it->second;
}
double diagValue(Observed& o, const std::string& node, const std::string& key) {
  const std::string v = diagString(o, node, key);
  return v.empty() ? 0.0 : std::stod(v);
}

using nerfslam::rostest_util::correlation;
using nerfslam::rostest_util::Joiner;
using nerfslam::rostest_util::waitFor;

nerfslam::Trajectory fromPath(const nav_msgs::Path& path) {
  nerfslam::Trajectory t;
  for (const auto& ps : path.poses) t.push_back({ps.header.stamp.toSec(), nerfslam::rosbridge::fromPose(ps.pose)});
  return t;
}

// Calls `<node>/save_map` into `dir`; the loaded map folder.
nerfslam::LoadedMap saveAndLoad(const std::string& node, const fs::path& dir, const nerfslam::Camera& cam,
                                double* seconds) {
  ros::param::set(node + "/map_dir", dir.string());
  std_srvs::Trigger srv;
  const ros::WallTime t0 = ros::WallTime::now();
  EXPECT_TRUE(ros::service::call(node + "/save_map", srv)) << node << "/save_map";
  *seconds = (ros::WallTime::now() - t0).toSec();
  EXPECT_TRUE(srv.response.success) << node << ": " << srv.response.message;
  return nerfslam::loadMapFolder(dir, cam);
}

TEST(OffboardMapping, SplitNodesMatchTheSingleNodeAndTrainTheNerf) {
  ros::NodeHandle nh, pnh("~");
  std::string tracking, mapping, reference;
  int frames = 0;
  double rate = 0, min_correlation = 0, max_ate_percent = 0, max_difference_percent = 0;
  ASSERT_TRUE(pnh.getParam("tracking_node", tracking));
  ASSERT_TRUE(pnh.getParam("mapping_node", mapping));
  ASSERT_TRUE(pnh.getParam("reference_node", reference));
  ASSERT_TRUE(pnh.getParam("frames", frames));
  ASSERT_TRUE(pnh.getParam("rate", rate));
  ASSERT_TRUE(pnh.getParam("min_correlation", min_correlation));
  ASSERT_TRUE(pnh.getParam("max_ate_percent", max_ate_percent));
  ASSERT_TRUE(pnh.getParam("max_difference_percent", max_difference_percent));
  const ros::WallTime t_start = ros::WallTime::now();
  const std::string tname = tracking.substr(1), mname = mapping.substr(1), rname = reference.substr(1);

  // 1. The sequence (its frame 0 is at t = 0, a "no stamp" stamp: played from frame 1).
  nerfslam::test::TempDir tmp;
  const auto room = nerfslam::rostest_util::renderSyntheticRoom(tmp.path(), frames);
  ASSERT_TRUE(room.dataset);
  const fs::path& seq = room.dir;
  const auto& ds = room.dataset;
  ASSERT_EQ(ds->size(), size_t(frames));
  const nerfslam::Camera cam = ds->camera();
  const nerfslam::Trajectory& gt = room.ground_truth;
  const cv::Size train = nerfslam::rostest_util::nerfTrainingSize(cam);
  const int train_w = train.width, train_h = train.height;

  Observed o;
  const nerfslam::rostest_util::InputImages input(nh, "image");
  ros::Subscriber tpath_sub =
      nh.subscribe<nav_msgs::Path>(tracking + "/path", 10, [&](const nav_msgs::PathConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.tracking_path = m;
      });
  ros::Subscriber rpath_sub =
      nh.subscribe<nav_msgs::Path>(reference + "/path", 10, [&](const nav_msgs::PathConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.reference_path = m;
      });
  ros::Subscriber kf_sub = nh.subscribe<nerfslam::MapKeyframe>(tracking + "/keyframes_out", 200,
                                                               [&](const nerfslam::MapKeyframeConstPtr& m) {
                                                                 std::lock_guard<std::mutex> lock(o.mutex);
                                                                 o.keyframe_ids.push_back(m->id);
                                                               });
  ros::Subscriber poses_sub = nh.subscribe<nerfslam::KeyframePoses>(tracking + "/keyframe_poses", 50,
                                                                    [&](const nerfslam::KeyframePosesConstPtr& m) {
                                                                      std::lock_guard<std::mutex> lock(o.mutex);
                                                                      if (!o.last_poses || m->seq > o.last_poses->seq)
                                                                        o.last_poses = m;
                                                                    });
  ros::Subscriber view_sub =
      nh.subscribe<sensor_msgs::Image>(mapping + "/nerf_view", 10, [&](const sensor_msgs::ImageConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.views.emplace_back((ros::WallTime::now() - t_start).toSec(), m);
      });
  ros::Subscriber diag_sub = nh.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 100, [&](const diagnostic_msgs::DiagnosticArrayConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        for (const auto& st : m->status) {
          const std::string node = st.name.substr(0, st.name.find(':'));
          for (const auto& kv : st.values) o.diag[node][kv.key] = kv.value;
        }
      });

  // 2. nerf_mapping_node connected to tracking_node before the first frame (keyframes are not resent).
  ASSERT_TRUE(waitFor(30.0, [&] { return diagString(o, mname, "tracking node connected") == "yes"; }))
      << mapping << " is not connected to " << tracking << "'s ~keyframes_out and ~keyframe_poses";

  // 3. The publisher (colour, dataset stamps): it starts once both SLAM nodes and this test subscribe.
  nerfslam::test::CommandResult publisher;
  std::atomic<bool> publisher_done{false};
  std::thread publisher_thread([&] {
    publisher = nerfslam::test::runCommand(
        "timeout 120 '" NERFSLAM_PUBLISHER_PATH "' __name:=offboard_test_publisher _dataset:='" + seq.string() +
        "' _start:=1 _color:=true _use_dataset_stamps:=true _rate:=" + std::to_string(rate) +
        " _wait_for_subscribers:=true _min_subscribers:=3 _exit_when_done:=true");
    publisher_done = true;
  });
  const Joiner joiner{publisher_thread};

  // 4. Both SLAM nodes process every frame they receive (~wait_for_mapping, deep queues).
  const bool processed = waitFor(100.0, [&] {
    if (!publisher_done) return false;
    const double tr = diagValue(o, tname, "frames received"), rr = diagValue(o, rname, "frames received");
    return tr >= frames - 2 && rr >= frames - 2 && diagValue(o, tname, "frames processed") >= tr &&
           diagValue(o, rname, "frames processed") >= rr;
  });
  ASSERT_TRUE(processed) << "tracking_node processed " << diagValue(o, tname, "frames processed") << " of "
                         << diagValue(o, tname, "frames received") << ", nerfslam_node "
                         << diagValue(o, rname, "frames processed") << " of " << diagValue(o, rname, "frames received")
                         << "; publisher: " << publisher.output;
  const double t_processed = (ros::WallTime::now() - t_start).toSec();
  EXPECT_EQ(publisher.exit_code, 0) << publisher.output;

  // 5. The last pose update (mapping is idle after the last frame: the map no longer changes) has
  // reached nerf_mapping_node: its newest applied seq is the newest sent, for 3 pose periods.
  uint64_t last_seq = 0;
  double stable_since = -1;
  const bool settled = waitFor(30.0, [&] {
    uint64_t seq = 0;
    {
      std::lock_guard<std::mutex> lock(o.mutex);
      seq = o.last_poses ? o.last_poses->seq : 0;
    }
    const bool applied = seq > 0 && uint64_t(diagValue(o, mname, "last pose update seq")) == seq;
    const double now = (ros::WallTime::now() - t_start).toSec();
    if (!applied || seq != last_seq) {
      last_seq = seq;
      stable_since = applied ? now : -1;
      return false;
    }
    return now - stable_since >= 1.5;
  });
  ASSERT_TRUE(settled) << "nerf_mapping_node applied pose update " << diagValue(o, mname, "last pose update seq")
                       << ", the newest sent is " << last_seq;

  // (b) Every keyframe sent was received; the replica's keyframes are the tracking map's.
  std::vector<uint64_t> sent_ids;
  nerfslam::KeyframePosesConstPtr last_poses;
  {
    std::lock_guard<std::mutex> lock(o.mutex);
    sent_ids = o.keyframe_ids;
    last_poses = o.last_poses;
  }
  const double sent = diagValue(o, tname, "keyframes sent");
  std::printf(
      "keyframes: %zu seen on ~keyframes_out, %g sent by tracking_node (%g dropped), %g received by "
      "nerf_mapping_node (%g refused, %g stale messages), %g pose updates sent, %g applied; last update "
      "seq %lu: %zu keyframes placed (%zu culled, %zu removed), %zu map points\n",
      sent_ids.size(), sent, diagValue(o, tname, "keyframes dropped (sender behind)"),
      diagValue(o, mname, "keyframes received"), diagValue(o, mname, "keyframes refused"),
      diagValue(o, mname, "stale messages"), diagValue(o, tname, "keyframe pose updates sent"),
      diagValue(o, mname, "pose updates applied"), static_cast<unsigned long>(last_poses->seq), last_poses->ids.size(),
      last_poses->culled_ids.size(), last_poses->removed_ids.size(), last_poses->points.size());
  EXPECT_GT(sent, 2.0);
  EXPECT_EQ(double(sent_ids.size()), sent);
  EXPECT_EQ(diagValue(o, mname, "keyframes received"), sent);
  EXPECT_EQ(diagValue(o, mname, "keyframes refused"), 0.0);
  EXPECT_EQ(diagValue(o, tname, "keyframes dropped (sender behind)"), 0.0);
  EXPECT_EQ(std::set<uint64_t>(sent_ids.begin(), sent_ids.end()).size(), sent_ids.size()) << "a keyframe sent twice";
  {
    std::set<uint64_t> placed(last_poses->ids.begin(), last_poses->ids.end());
    placed.insert(last_poses->removed_ids.begin(), last_poses->removed_ids.end());
    EXPECT_EQ(placed, std::set<uint64_t>(sent_ids.begin(), sent_ids.end()))
        << "the last pose update does not cover every keyframe sent";
  }

  double save_t = 0, save_m = 0;
  const nerfslam::LoadedMap tmap = saveAndLoad(tracking, tmp / "tracking_map", cam, &save_t);
  const nerfslam::LoadedMap rmap = saveAndLoad(mapping, tmp / "replica_map", cam, &save_m);
  ASSERT_TRUE(tmap.map && rmap.map);
  const auto tkfs = tmap.map->keyframes(), rkfs = rmap.map->keyframes();
  std::vector<int64_t> tids, rids;
  for (const auto& k : tkfs) tids.push_back(k.id);
  for (const auto& k : rkfs) rids.push_back(k.id);
  EXPECT_EQ(rids, tids) << "the replica's keyframes are not the tracking map's";
  double max_dt = 0, max_drot = 0;
  for (const auto& k : tkfs) {
    const auto r = rmap.map->keyframe(k.id);
    if (!r) continue;
    max_dt = std::max(max_dt, (r->T_world_cam.translation() - k.T_world_cam.translation()).norm());
    max_drot = std::max(max_drot, r->T_world_cam.rotation().angularDistance(k.T_world_cam.rotation()));
  }
  std::printf(
      "saved maps: tracking %zu keyframes, %zu points (%.2f s); replica %zu keyframes, %zu points, NeRF "
      "model %s (%.2f s); keyframe poses differ by at most %.3g (translation, map units), %.3g rad\n",
      tkfs.size(), tmap.map->numPoints(), save_t, rkfs.size(), rmap.map->numPoints(),
      rmap.nerf_model ? "saved" : "missing", save_m, max_dt, max_drot);
  EXPECT_LE(max_dt, 1e-6);
  EXPECT_LE(max_drot, 1e-6);
  EXPECT_EQ(last_poses->points.size(), tmap.map->numPoints()) << "the map points of the last pose update";
  EXPECT_EQ(diagValue(o, mname, "map points"), double(tmap.map->numPoints())) << "the replica's map points";
  EXPECT_TRUE(rmap.nerf_model.has_value()) << "nerf_mapping_node saved no NeRF model";

  // (a) The split's trajectory is the single node's, and both meet the ATE target.
  nav_msgs::PathConstPtr tpath, rpath;
  {
    std::lock_guard<std::mutex> lock(o.mutex);
    tpath = o.tracking_path;
    rpath = o.reference_path;
  }
  ASSERT_TRUE(tpath && rpath) << "no ~path from tracking_node or nerfslam_node";
  const nerfslam::Trajectory test = fromPath(*tpath), ref = fromPath(*rpath);
  nerfslam::TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-4;
  const auto ate_t = nerfslam::evaluateTrajectory(gt, test, eo);
  const auto ate_r = nerfslam::evaluateTrajectory(gt, ref, eo);
  // Directly, in the map frame both start from (no alignment): the largest position difference.
  std::map<double, Eigen::Vector3d> ref_at;
  for (const auto& e : ref) ref_at[e.timestamp] = e.pose.translation();
  size_t common = 0;
  double max_diff = 0, length = 0;
  for (size_t i = 0; i < test.size(); ++i) {
    if (i > 0) length += (test[i].pose.translation() - test[i - 1].pose.translation()).norm();
    const auto it = ref_at.find(test[i].timestamp);
    if (it == ref_at.end()) continue;
    ++common;
    max_diff = std::max(max_diff, (test[i].pose.translation() - it->second).norm());
  }
  const double diff_percent = length > 0 ? 100.0 * max_diff / length : 100.0;
  std::printf(
      "trajectories: tracking_node %zu poses, nerfslam_node %zu, %zu at common stamps; largest position "
      "difference %.3g map units = %.4f %% of the %.3f-unit path; ATE (Sim(3)) against the ground truth: "
      "tracking_node %.4f %%, nerfslam_node %.4f %% of the %.3f m path\n",
      test.size(), ref.size(), common, max_diff, diff_percent, length, ate_t.ape_rmse_percent, ate_r.ape_rmse_percent,
      ate_t.ref_path_length);
  EXPECT_EQ(test.size(), ref.size()) << "frames received: tracking_node " << diagValue(o, tname, "frames received")
                                     << ", nerfslam_node " << diagValue(o, rname, "frames received")
                                     << "; lost before the node (seq gaps): tracking_node "
                                     << diagValue(o, tname, "frames lost before the node (seq gaps)")
                                     << ", nerfslam_node "
                                     << diagValue(o, rname, "frames lost before the node (seq gaps)");
  EXPECT_GE(common, size_t(0.9 * std::min(test.size(), ref.size())));
  EXPECT_GE(test.size(), size_t(0.5 * frames));
  EXPECT_LE(diff_percent, max_difference_percent);
  EXPECT_LT(ate_t.ape_rmse_percent, max_ate_percent);
  EXPECT_LT(ate_r.ape_rmse_percent, max_ate_percent);

  // (c) nerf_mapping_node's ~nerf_view improves: correlation with the input image of its stamp.
  double first_corr = -2, best_corr = -2;
  std::string series;
  size_t checked = 0, matched = 0;
  auto checkViews = [&] {
    std::vector<std::pair<double, sensor_msgs::ImageConstPtr>> views;
    {
      std::lock_guard<std::mutex> lock(o.mutex);
      views.assign(o.views.begin() + long(checked), o.views.end());
      checked = o.views.size();
    }
    const std::map<double, cv::Mat> images = input.snapshot();  // after the views: their frames came first
    for (const auto& [t, v] : views) {
      EXPECT_EQ(v->encoding, "rgb8");
      EXPECT_EQ(int(v->width), train_w);
      EXPECT_EQ(int(v->height), train_h);
      const auto it = images.find(v->header.stamp.toSec());
      if (it == images.end() || int(v->width) != train_w || int(v->height) != train_h || v->encoding != "rgb8")
        continue;
      ++matched;
      cv::Mat real;
      cv::resize(it->second, real, cv::Size(train_w, train_h), 0, 0, cv::INTER_AREA);
      const double c = correlation(cv_bridge::toCvCopy(v, "rgb8")->image, real);
      if (first_corr < -1) first_corr = c;
      best_corr = std::max(best_corr, c);
      series += std::to_string(int(t)) + "s:" + std::to_string(c).substr(0, 5) + " ";
    }
    // Improved: a later view beats the first (which may already pass the threshold).
    return best_corr >= min_correlation && matched >= 2 && best_corr > first_corr;
  };
  const bool good_view = waitFor(std::max(5.0, 150.0 - (ros::WallTime::now() - t_start).toSec()), checkViews);
  std::printf(
      "~nerf_view of nerf_mapping_node: %zu received (%zu matched an input image), correlation with the "
      "input first %.3f, best %.3f; NeRF steps %g, views %g, PSNR recent %s dB, renders %g (mean %s ms); "
      "frames processed after %.1f s, %.1f s in all\n",
      checked, matched, first_corr, best_corr, diagValue(o, mname, "nerf steps"), diagValue(o, mname, "nerf views"),
      diagString(o, mname, "nerf psnr recent (dB)").c_str(), diagValue(o, mname, "nerf renders"),
      diagString(o, mname, "nerf render ms (mean)").c_str(), t_processed, (ros::WallTime::now() - t_start).toSec());
  std::printf("~nerf_view correlation over time: %s\n", series.c_str());
  EXPECT_TRUE(good_view) << "~nerf_view never reached a correlation of " << min_correlation << " with the input";
  EXPECT_GT(best_corr, first_corr) << "~nerf_view did not improve";
}

}  // namespace

int main(int argc, char** argv) { return nerfslam::rostest_util::runRosGtest(argc, argv, "offboard_mapping_test"); }
