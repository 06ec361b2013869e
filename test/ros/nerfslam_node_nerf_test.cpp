// gtest node started by test/ros/nerfslam_node_nerf.test (rostest): nerfslam_node with the NeRF on.
// The test renders a short synthetic room sequence (`nerfslam synth`, 320x240) and plays it in colour
// with image_folder_publisher into the node. Checks:
//   - nothing is rendered while nobody subscribes to the NeRF topics, even with a trained model;
//   - ~nerf_view (rgb8) and ~nerf_depth (32FC1) at the NeRF's training resolution, in ~camera_frame,
//     stamped like an input image; the view becomes non-trivial: its correlation with the input image
//     of the same stamp (grey levels, Pearson) reaches a threshold (PSNR printed alongside);
//   - ~nerf_cloud in ~map_frame with x y z rgb and points;
//   - ~occupancy (latched, ~map_frame, cells 0 / 100 / -1) and ~occupied_voxels; ~save_occupancy;
//   - the NeRF fields in the diagnostics;
//   - ~save_map: refused with a message before there is a map and with an unwritable ~map_dir (the
//     node keeps running), and a map folder that map_store's loadMapFolder loads back, with the NeRF
//     model, after ~map_dir is changed at run time;
//   - invalid NeRF parameters exit with status 1 naming the parameter.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <cv_bridge/cv_bridge.h>
#include <diagnostic_msgs/DiagnosticArray.h>
#include <nav_msgs/OccupancyGrid.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/io/nav_grid.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/nerf_mapping.h"
#include "ros_test_util.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;

struct Observed {
  std::mutex mutex;
  std::vector<sensor_msgs::ImageConstPtr> views, depths;
  sensor_msgs::PointCloud2ConstPtr cloud;
  std::map<std::string, std::string> diag;
  int diag_count = 0;
};

std::string diagString(Observed& o, const std::string& key) {
  std::lock_guard<std::mutex> lock(o.mutex);
  const auto it = o.diag.find(key);
  return it == o.diag.end() ? "" : it->second;
}
double diagValue(Observed& o, const std::string& key) {
  const std::string v = diagString(o, key);
  return v.empty() ? 0.0 : std::stod(v);
}

using nerfslam::rostest_util::correlation;
using nerfslam::rostest_util::Joiner;
using nerfslam::rostest_util::waitFor;

double psnr(const cv::Mat& a, const cv::Mat& b) {
  const double mse = cv::norm(a, b, cv::NORM_L2SQR) / double(a.total() * a.channels());
  return mse <= 0 ? 99.0 : 10.0 * std::log10(255.0 * 255.0 / mse);
}

// Calls ~save_map; returns false when the call itself fails.
bool callSaveMap(const std::string& node, std_srvs::Trigger::Response* res) {
  std_srvs::Trigger srv;
  if (!ros::service::call(node + "/save_map", srv)) return false;
  *res = srv.response;
  return true;
}

TEST(NerfslamNodeNerf, PublishesNerfTopicsAndSavesMaps) {
  ros::NodeHandle nh, pnh("~");
  std::string node, map_frame, camera_frame;
  int frames = 0;
  double rate = 0, min_correlation = 0;
  ASSERT_TRUE(pnh.getParam("node", node));
  ASSERT_TRUE(pnh.getParam("map_frame", map_frame));
  ASSERT_TRUE(pnh.getParam("camera_frame", camera_frame));
  ASSERT_TRUE(pnh.getParam("frames", frames));
  ASSERT_TRUE(pnh.getParam("rate", rate));
  ASSERT_TRUE(pnh.getParam("min_correlation", min_correlation));
  const ros::WallTime t_start = ros::WallTime::now();

  // 1. The sequence.
  nerfslam::test::TempDir tmp;
  const fs::path seq = tmp / "room";
  const auto synth = nerfslam::test::runCli("synth --scene room --frames " + std::to_string(frames) +
                                            " --size 320x240 --textures procedural --out '" + seq.string() + "'");
  ASSERT_EQ(synth.exit_code, 0) << synth.output;
  const nerfslam::Camera cam = nerfslam::loadCameraYaml(seq / "camera.yaml");
  const cv::Size train = nerfslam::rostest_util::nerfTrainingSize(cam);
  const int train_w = train.width, train_h = train.height;

  Observed o;
  const nerfslam::rostest_util::InputImages input(nh, "image");
  ros::Subscriber diag_sub = nh.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 100, [&](const diagnostic_msgs::DiagnosticArrayConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        for (const auto& st : m->status) {
          if (st.name.find("nerfslam_node") == std::string::npos) continue;
          for (const auto& kv : st.values) o.diag[kv.key] = kv.value;
          ++o.diag_count;
        }
      });

  // 2. ~save_map before any image: refused with a message.
  ASSERT_TRUE(ros::service::waitForService(node + "/save_map", 30000)) << "no ~save_map service";
  std_srvs::Trigger::Response res;
  ASSERT_TRUE(callSaveMap(node, &res));
  EXPECT_FALSE(res.success);
  EXPECT_NE(res.message.find("no map to save"), std::string::npos) << res.message;

  // 3. The publisher (colour, live stamps), started against this test's master.
  std::atomic<bool> publisher_done{false};
  nerfslam::test::CommandResult publisher;
  std::thread publisher_thread([&] {
    publisher = nerfslam::test::runCommand(
        "timeout 120 '" NERFSLAM_PUBLISHER_PATH "' __name:=nerf_test_publisher _dataset:='" + seq.string() +
        "' _color:=true _rate:=" + std::to_string(rate) + " _wait_for_subscribers:=true _exit_when_done:=true");
    publisher_done = true;
  });
  const Joiner joiner{publisher_thread};

  // 4. A trained model, and still nothing rendered: nobody subscribes to the NeRF topics.
  ASSERT_TRUE(waitFor(60.0, [&] { return diagString(o, "nerf model") == "yes" && diagValue(o, "nerf steps") > 0; }))
      << "no NeRF model after 60 s (steps " << diagValue(o, "nerf steps") << ", keyframes " << diagValue(o, "keyframes")
      << ", frames tracked " << diagValue(o, "frames tracked") << ")";
  {
    std::lock_guard<std::mutex> lock(o.mutex);
    ASSERT_EQ(o.diag["nerf"], "on");
  }
  const int diag_now = o.diag_count;
  ros::WallDuration(2.5).sleep();  // > 2 render periods
  EXPECT_TRUE(waitFor(5.0, [&] {
    std::lock_guard<std::mutex> lock(o.mutex);
    return o.diag_count > diag_now;
  }));
  EXPECT_EQ(diagValue(o, "nerf renders"), 0.0) << "rendered with nobody subscribed";
  EXPECT_EQ(diagValue(o, "nerf clouds"), 0.0) << "exported a cloud with nobody subscribed";

  // 5. Subscribe: views, depths, clouds.
  const ros::WallTime t_subscribed = ros::WallTime::now();
  ros::Subscriber view_sub =
      nh.subscribe<sensor_msgs::Image>(node + "/nerf_view", 10, [&](const sensor_msgs::ImageConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.views.push_back(m);
      });
  ros::Subscriber depth_sub =
      nh.subscribe<sensor_msgs::Image>(node + "/nerf_depth", 10, [&](const sensor_msgs::ImageConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.depths.push_back(m);
      });
  ros::Subscriber cloud_sub =
      nh.subscribe<sensor_msgs::PointCloud2>(node + "/nerf_cloud", 2, [&](const sensor_msgs::PointCloud2ConstPtr& m) {
        std::lock_guard<std::mutex> lock(o.mutex);
        o.cloud = m;
      });

  // The view becomes non-trivial: it correlates with the input frame of its stamp.
  double best_corr = -1, best_psnr = 0, best_baseline = 0, best_std = 0, first_corr = -2;
  std::string series;  // correlation over time since subscribing
  size_t checked = 0, matched = 0;
  auto checkViews = [&] {
    std::vector<sensor_msgs::ImageConstPtr> views;
    {
      std::lock_guard<std::mutex> lock(o.mutex);
      views.assign(o.views.begin() + long(checked), o.views.end());
      checked = o.views.size();
    }
    const std::map<double, cv::Mat> images = input.snapshot();  // after the views: their frames came first
    for (const auto& v : views) {
      EXPECT_EQ(v->encoding, "rgb8");
      EXPECT_EQ(int(v->width), train_w);
      EXPECT_EQ(int(v->height), train_h);
      EXPECT_EQ(v->header.frame_id, camera_frame);
      const auto it = images.find(v->header.stamp.toSec());
      if (it == images.end() || int(v->width) != train_w || int(v->height) != train_h || v->encoding != "rgb8")
        continue;
      ++matched;
      cv::Mat real;
      cv::resize(it->second, real, cv::Size(train_w, train_h), 0, 0, cv::INTER_AREA);
      const cv::Mat render = cv_bridge::toCvCopy(v, "rgb8")->image;
      const cv::Mat mean_img(real.size(), real.type(), cv::mean(real));
      const double c = correlation(render, real);
      if (first_corr < -1) first_corr = c;
      series += std::to_string(int((ros::WallTime::now() - t_subscribed).toSec())) +
                "s:" + std::to_string(c).substr(0, 5) + " ";
      cv::Scalar mu, sd;
      cv::meanStdDev(render, mu, sd);
      if (c > best_corr) {
        best_corr = c;
        best_psnr = psnr(render, real);
        best_baseline = psnr(mean_img, real);
        best_std = (sd[0] + sd[1] + sd[2]) / 3;
      }
    }
    return best_corr >= min_correlation;
  };
  const bool good_view = waitFor(60.0, checkViews);
  std::printf(
      "~nerf_view: %zu checked (%zu matched an input image), correlation with the input first %.3f, best "
      "%.3f (PSNR %.2f dB; the frame's mean colour %.2f dB), pixel std %.1f; %.1f s after subscribing; "
      "renders %g, render ms (mean) %s, model lock wait ms (last) %s, copy ms (last) %s; "
      "NeRF steps %g, views %g, PSNR recent %s dB, samples/s %s\n",
      checked, matched, first_corr, best_corr, best_psnr, best_baseline, best_std,
      (ros::WallTime::now() - t_subscribed).toSec(), diagValue(o, "nerf renders"),
      diagString(o, "nerf render ms (mean)").c_str(), diagString(o, "nerf model lock wait ms (last)").c_str(),
      diagString(o, "nerf model copy ms (last)").c_str(), diagValue(o, "nerf steps"), diagValue(o, "nerf views"),
      diagString(o, "nerf psnr recent (dB)").c_str(), diagString(o, "nerf samples/s").c_str());
  std::printf("~nerf_view correlation over time: %s\n", series.c_str());
  EXPECT_TRUE(good_view) << "~nerf_view never reached a correlation of " << min_correlation << " with the input";
  EXPECT_GT(matched, 0u) << "no ~nerf_view stamped like an input image";
  EXPECT_GT(best_std, 5.0) << "~nerf_view is flat";

  // ~nerf_depth: 32FC1, same size and frame, finite positive depths where the NeRF is opaque.
  ASSERT_TRUE(waitFor(10.0, [&] {
    std::lock_guard<std::mutex> lock(o.mutex);
    return !o.depths.empty();
  })) << "no ~nerf_depth";
  sensor_msgs::ImageConstPtr depth;
  {
    std::lock_guard<std::mutex> lock(o.mutex);
    depth = o.depths.back();
  }
  EXPECT_EQ(depth->encoding, "32FC1");
  EXPECT_EQ(int(depth->width), train_w);
  EXPECT_EQ(int(depth->height), train_h);
  EXPECT_EQ(depth->header.frame_id, camera_frame);
  {
    const cv::Mat d = cv_bridge::toCvCopy(depth, "32FC1")->image;
    int valid = 0, negative = 0;
    for (int y = 0; y < d.rows; ++y)
      for (int x = 0; x < d.cols; ++x) {
        const float z = d.at<float>(y, x);
        if (std::isfinite(z)) (z > 0 ? valid : negative)++;
      }
    std::printf("~nerf_depth: %d of %d pixels with depth\n", valid, d.rows * d.cols);
    EXPECT_GT(valid, d.rows * d.cols / 4);
    EXPECT_EQ(negative, 0);
  }

  // ~nerf_cloud: map frame, x y z rgb, points with finite coordinates.
  ASSERT_TRUE(waitFor(20.0, [&] {
    std::lock_guard<std::mutex> lock(o.mutex);
    return o.cloud != nullptr;
  })) << "no ~nerf_cloud";
  sensor_msgs::PointCloud2ConstPtr cloud;
  {
    std::lock_guard<std::mutex> lock(o.mutex);
    cloud = o.cloud;
  }
  EXPECT_EQ(cloud->header.frame_id, map_frame);
  std::vector<std::string> fields;
  for (const auto& f : cloud->fields) fields.push_back(f.name);
  EXPECT_EQ(fields, (std::vector<std::string>{"x", "y", "z", "rgb"}));
  const size_t npts = size_t(cloud->width) * cloud->height;
  std::printf("~nerf_cloud: %zu points, export ms (last) %s\n", npts, diagString(o, "nerf cloud ms (last)").c_str());
  EXPECT_GT(npts, 100u);
  {
    size_t finite = 0;
    for (sensor_msgs::PointCloud2ConstIterator<float> x(*cloud, "x"), y(*cloud, "y"), z(*cloud, "z"); x != x.end();
         ++x, ++y, ++z)
      finite += std::isfinite(*x) && std::isfinite(*y) && std::isfinite(*z);
    EXPECT_EQ(finite, npts);
  }

  // ~occupancy (latched nav_msgs/OccupancyGrid in ~map_frame: 0 free, 100 occupied, -1 unknown, the
  // origin on the floor found) and ~occupied_voxels (voxel centres in ~map_frame); a subscriber that
  // comes later gets the last grid at once (latched); ~save_occupancy writes the OctoMap and the
  // map_server pair.
  {
    nav_msgs::OccupancyGridConstPtr grid;
    sensor_msgs::PointCloud2ConstPtr voxels;
    std::mutex m;
    ros::Subscriber gs = nh.subscribe<nav_msgs::OccupancyGrid>(node + "/occupancy", 1, [&](const auto& g) {
      std::lock_guard<std::mutex> lock(m);
      grid = g;
    });
    ros::Subscriber vs = nh.subscribe<sensor_msgs::PointCloud2>(node + "/occupied_voxels", 1, [&](const auto& c) {
      std::lock_guard<std::mutex> lock(m);
      voxels = c;
    });
    ASSERT_TRUE(waitFor(40.0, [&] {
      std::lock_guard<std::mutex> lock(m);
      return grid && voxels;
    })) << "no ~occupancy or ~occupied_voxels";
    std::lock_guard<std::mutex> lock(m);
    EXPECT_EQ(grid->header.frame_id, map_frame);
    EXPECT_EQ(voxels->header.frame_id, map_frame);
    ASSERT_EQ(grid->data.size(), size_t(grid->info.width) * grid->info.height);
    size_t n_free = 0, n_occ = 0, n_unknown = 0, other = 0;
    for (int8_t c : grid->data) {
      n_free += c == 0;
      n_occ += c == 100;
      n_unknown += c == -1;
      other += c != 0 && c != 100 && c != -1;
    }
    EXPECT_EQ(other, 0u);
    EXPECT_GT(n_free, 20u);
    EXPECT_GT(n_occ, 20u);
    EXPECT_GT(grid->info.resolution, 0.f);
    const auto& q = grid->info.origin.orientation;
    EXPECT_NEAR(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w, 1.0, 1e-6);
    const size_t nvox = size_t(voxels->width) * voxels->height;
    EXPECT_GT(nvox, 50u);
    std::printf(
        "~occupancy: %ux%u cells at %.4f map units, %zu free, %zu occupied, %zu unknown; ~occupied_voxels: "
        "%zu; occupancy updates %g (rebuilds %g), ms (last) %s\n",
        grid->info.width, grid->info.height, grid->info.resolution, n_free, n_occ, n_unknown, nvox,
        diagValue(o, "occupancy updates"), diagValue(o, "occupancy rebuilds"),
        diagString(o, "occupancy ms (last)").c_str());
  }
  {
    nav_msgs::OccupancyGridConstPtr late;
    ros::Subscriber late_sub =
        nh.subscribe<nav_msgs::OccupancyGrid>(node + "/occupancy", 1, [&](const auto& g) { late = g; });
    EXPECT_TRUE(waitFor(2.0, [&] { return late != nullptr; })) << "~occupancy is not latched";
  }
  {
    const fs::path occ_dir = tmp / "occupancy";
    ros::param::set(node + "/occupancy_dir", occ_dir.string());
    std_srvs::Trigger srv;
    ASSERT_TRUE(ros::service::call(node + "/save_occupancy", srv));
    ASSERT_TRUE(srv.response.success) << srv.response.message;
    std::printf("~save_occupancy: %s\n", srv.response.message.c_str());
    EXPECT_TRUE(fs::exists(occ_dir / "occupancy.bt"));
    EXPECT_TRUE(fs::exists(occ_dir / "occupancy.ot"));
    EXPECT_TRUE(fs::exists(occ_dir / "occupancy.meta.yaml"));
    const nerfslam::NavGrid g = nerfslam::loadMapServer(occ_dir / "map.yaml");
    EXPECT_GT(g.width * g.height, 100);
  }

  // 6. ~save_map into an unwritable folder (below a regular file): refused with the reason.
  const fs::path blocker = tmp / "not_a_directory";
  nerfslam::test::writeText(blocker, "a file\n");
  ros::param::set(node + "/map_dir", (blocker / "map").string());
  ASSERT_TRUE(callSaveMap(node, &res));
  EXPECT_FALSE(res.success);
  EXPECT_NE(res.message.find((blocker / "map").string()), std::string::npos) << res.message;
  std::printf("~save_map (unwritable): success=%d message: %s\n", int(res.success), res.message.c_str());

  // 7. ~save_map into a fresh folder (set at run time): the path back, loadable with the NeRF model.
  const fs::path map_dir = tmp / "saved_map";
  ros::param::set(node + "/map_dir", map_dir.string());
  const ros::WallTime t_save = ros::WallTime::now();
  ASSERT_TRUE(callSaveMap(node, &res));
  const double save_s = (ros::WallTime::now() - t_save).toSec();
  ASSERT_TRUE(res.success) << res.message;
  EXPECT_EQ(fs::path(res.message), map_dir);
  std::printf("~save_map: %s in %.2f s\n", res.message.c_str(), save_s);
  const nerfslam::LoadedMap loaded = nerfslam::loadMapFolder(map_dir, cam);
  ASSERT_TRUE(loaded.map);
  EXPECT_GE(loaded.map->numKeyframes(), 2u);
  EXPECT_GT(loaded.map->numPoints(), 50u);
  ASSERT_TRUE(loaded.nerf_model.has_value()) << "the NeRF model was not saved with the map";
  const nerfslam::nerf::NerfModel model = nerfslam::nerf::loadModel(*loaded.nerf_model);
  EXPECT_GT(model.training_steps, 0u);
  std::printf("loaded: %zu keyframes, %zu points, NeRF model with %lu steps\n", loaded.map->numKeyframes(),
              loaded.map->numPoints(), static_cast<unsigned long>(model.training_steps));
  // The options the system ran with (test/ros/nerfslam_node_nerf_config.yaml, then the .test file's
  // ~nerf/psnr_interval_s and ~nerf_nice).
  const nerfslam::SystemOptions saved = nerfslam::loadMapOptions(map_dir);
  EXPECT_EQ(saved.frame_queue, 4);
  EXPECT_EQ(saved.nerf.psnr_interval_s, 1.0);  // the default, over the file's 2.0
  EXPECT_EQ(saved.nerf.nice_increment, 0);
  EXPECT_TRUE(saved.nerf.enabled);

  // 8. The node kept running: its diagnostics keep coming and count one save and two refusals.
  int diag_before = 0;
  {
    std::lock_guard<std::mutex> lock(o.mutex);
    diag_before = o.diag_count;
  }
  EXPECT_TRUE(waitFor(5.0, [&] {
    std::lock_guard<std::mutex> lock(o.mutex);
    return o.diag_count > diag_before + 1;
  })) << "nerfslam_node stopped publishing diagnostics";
  EXPECT_EQ(diagValue(o, "map saves"), 1.0);
  EXPECT_EQ(diagValue(o, "map save failures"), 2.0);
  EXPECT_EQ(diagValue(o, "tracking errors"), 0.0);
  EXPECT_EQ(diagValue(o, "nerf render errors"), 0.0);
  std::printf(
      "frames: %g received, %g processed, %g tracked, %g dropped; tracking ms (mean) %s; image callback ms "
      "mean %s max %s; %.1f s since the test started\n",
      diagValue(o, "frames received"), diagValue(o, "frames processed"), diagValue(o, "frames tracked"),
      diagValue(o, "frames dropped (queue full)"), diagString(o, "tracking ms (mean)").c_str(),
      diagString(o, "image callback ms (mean)").c_str(), diagString(o, "image callback ms (max)").c_str(),
      (ros::WallTime::now() - t_start).toSec());
  publisher_thread.join();
  EXPECT_EQ(publisher.exit_code, 0) << publisher.output;

  // 9. ~set_localization_only: the sequence's first 60 frames again (the camera jumps back to the
  // start): tracked and relocalised against the map, which gains no keyframe; then mapping resumes.
  std_srvs::SetBool loc;
  loc.request.data = true;
  ASSERT_TRUE(ros::service::call(node + "/set_localization_only", loc));
  EXPECT_TRUE(loc.response.success) << loc.response.message;
  // A keyframe made before the switch may still wait for the mapping thread, and the diagnostics are
  // up to a period old: the count to compare with is the one that holds over 3 fresh messages.
  double keyframes_before = -1;
  int stable = 0, seen = 0;
  EXPECT_TRUE(waitFor(30.0, [&] {
    int count = 0;
    {
      std::lock_guard<std::mutex> lock(o.mutex);
      count = o.diag_count;
    }
    if (count == seen) return false;
    seen = count;
    const double k = diagValue(o, "keyframes");
    stable = k == keyframes_before ? stable + 1 : 0;
    keyframes_before = k;
    return stable >= 3;
  })) << "the keyframe count did not settle after the switch to localisation";
  const double processed_before = diagValue(o, "frames processed"), tracked_before = diagValue(o, "frames tracked"),
               received_before = diagValue(o, "frames received");
  const auto replay =
      nerfslam::test::runCommand("timeout 60 '" NERFSLAM_PUBLISHER_PATH "' __name:=nerf_test_publisher2 _dataset:='" +
                                 seq.string() + "' _color:=true _max_frames:=60 _rate:=" + std::to_string(rate) +
                                 " _wait_for_subscribers:=true _exit_when_done:=true");
  EXPECT_EQ(replay.exit_code, 0) << replay.output;
  // The publisher starts when a subscriber (this test's own may be the first) is connected, so the
  // node's connection can miss the first message: wait until the node has processed what it received.
  EXPECT_TRUE(waitFor(60.0,
                      [&] {
                        const double received = diagValue(o, "frames received") - received_before;
                        return received >= 55 && diagValue(o, "frames processed") - processed_before >= received;
                      }))
      << "received " << diagValue(o, "frames received") - received_before << ", processed "
      << diagValue(o, "frames processed") - processed_before << " of the 60 replayed frames";
  const double processed_replay = diagValue(o, "frames processed") - processed_before;
  const double tracked_replay = diagValue(o, "frames tracked") - tracked_before;
  std::printf("localisation only: %g of %g replayed frames tracked, keyframes %g -> %g\n", tracked_replay,
              processed_replay, keyframes_before, diagValue(o, "keyframes"));
  // Measured 60/60 and 59/59 (relocalised on the first replayed frame against the best-voted keyframe).
  EXPECT_GE(tracked_replay, 0.75 * processed_replay);
  EXPECT_GE(processed_replay, 55.0);
  EXPECT_EQ(diagValue(o, "keyframes"), keyframes_before);
  loc.request.data = false;
  ASSERT_TRUE(ros::service::call(node + "/set_localization_only", loc));
  EXPECT_TRUE(loc.response.success);
  EXPECT_EQ(loc.response.message, "mapping resumed");
}

nerfslam::test::CommandResult runNode(const std::string& args) {
  return nerfslam::test::runCommand("timeout 60 '" NERFSLAM_NODE_PATH "' " + args);
}

TEST(NerfslamNodeNerf, InvalidNerfParametersExitNonZeroNamingTheParameter) {
  const auto period = runNode("__name:=bad_nerf_period_node _nerf_publish_period:=0.0");
  EXPECT_EQ(period.exit_code, 1) << period.output;
  EXPECT_NE(period.output.find("~nerf_publish_period: field 'nerf_publish_period': must be > 0 (got 0)"),
            std::string::npos)
      << period.output;

  const auto source = runNode("__name:=bad_nerf_source_node _nerf_cloud_source:=mesh");
  EXPECT_EQ(source.exit_code, 1) << source.output;
  EXPECT_NE(source.output.find(
                "~nerf_cloud_source: field 'nerf_cloud_source': must be one of: depth, density (got \"mesh\")"),
            std::string::npos)
      << source.output;

  const auto threads = runNode("__name:=bad_nerf_threads_node _nerf_threads:=0");
  EXPECT_EQ(threads.exit_code, 1) << threads.output;
  EXPECT_NE(threads.output.find("~nerf_threads: field 'nerf.train.threads': must be in [1, 256] (got 0)"),
            std::string::npos)
      << threads.output;
}

}  // namespace

int main(int argc, char** argv) { return nerfslam::rostest_util::runRosGtest(argc, argv, "nerfslam_node_nerf_test"); }
