// gtest node started by test/ros/nerfslam_node_soak.test (rostest): a 60 Hz camera into nerfslam_node
// with the NeRF on, for ~duration seconds (CI: 120; the documented long run: 1800). The test renders a
// synthetic room (`nerfslam synth`, 640x480 colour, procedural textures: no data needed) and plays it
// with image_folder_publisher at 60 Hz with ~loop (live stamps). It measures and prints
//   - latency: ~pose header stamp (the image's publication time) -> the pose's arrival here
//     (median / p99 / max),
//   - frames received / processed / dropped / refused and tracked (the node's diagnostics),
//   - the node's resident memory ("resident memory (MB)" in its diagnostics) over time,
// and checks: latency p99 below ~max_latency_p99_ms; every received frame accounted for
// (received = processed + dropped + refused + tracking errors once the publisher stopped and the
// queue drained); tracked / processed >= ~min_tracked_fraction and poses in every tenth of the run
// after the warm-up; RSS growth after the warm-up (the first ~warmup_fraction of the run) < 5 %.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <filesystem>
#include <mutex>
#include <string>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <ros/ros.h>

#include "ros_test_util.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using nerfslam::rostest_util::ChildProcess;
using nerfslam::rostest_util::DiagnosticsValues;
using nerfslam::rostest_util::percentile;
using nerfslam::rostest_util::waitFor;

struct Sample {
  double t;  // s since the publisher started
  double received, processed, dropped, refused, tracked, rss_mb, refits, nerf_views;
};

TEST(NerfslamNodeSoak, SixtyHertzCameraLatencyDropsTrackingAndMemory) {
  ros::NodeHandle nh, pnh("~");
  std::string node;
  double duration = 0, rate = 0, max_latency_p99_ms = 0, min_tracked_fraction = 0, warmup_fraction = 0,
         max_rss_growth = 0;
  int frames = 0;
  ASSERT_TRUE(pnh.getParam("node", node));
  ASSERT_TRUE(pnh.getParam("duration", duration));
  ASSERT_TRUE(pnh.getParam("rate", rate));
  ASSERT_TRUE(pnh.getParam("frames", frames));
  ASSERT_TRUE(pnh.getParam("max_latency_p99_ms", max_latency_p99_ms));
  ASSERT_TRUE(pnh.getParam("min_tracked_fraction", min_tracked_fraction));
  ASSERT_TRUE(pnh.getParam("warmup_fraction", warmup_fraction));
  ASSERT_TRUE(pnh.getParam("max_rss_growth", max_rss_growth));

  // 1. The sequence: the room at 640x480, rendered at the playback rate (the camera moves as fast as
  //    a hand-held camera, not twice as fast).
  nerfslam::test::TempDir tmp;
  const fs::path seq = tmp / "room";
  const auto synth = nerfslam::test::runCli("synth --scene room --frames " + std::to_string(frames) + " --fps " +
                                            std::to_string(rate) + " --size 640x480 --textures procedural --out '" +
                                            seq.string() + "'");
  ASSERT_EQ(synth.exit_code, 0) << synth.output;

  DiagnosticsValues diag(nh, "nerfslam_node");
  std::mutex mutex;
  std::vector<std::pair<double, double>> latencies;  // (s since start, ms)
  ros::WallTime t0;
  std::atomic<bool> started{false};
  ros::Subscriber pose_sub =
      nh.subscribe<geometry_msgs::PoseStamped>(node + "/pose", 1000, [&](const geometry_msgs::PoseStampedConstPtr& m) {
        const ros::Time now = ros::Time::now();
        if (!started) return;
        std::lock_guard<std::mutex> lock(mutex);
        latencies.emplace_back((ros::WallTime::now() - t0).toSec(), 1e3 * (now - m->header.stamp).toSec());
      });
  ASSERT_TRUE(waitFor(30.0, [&] { return diag.count() > 0; })) << "no diagnostics from " << node;

  // 2. The camera: 60 Hz, colour, looping, live stamps.
  const std::string log = (tmp / "publisher.log").string();
  t0 = ros::WallTime::now();
  started = true;
  ChildProcess publisher({NERFSLAM_PUBLISHER_PATH, "__name:=soak_camera", "_dataset:=" + seq.string(), "_color:=true",
                          "_loop:=true", "_rate:=" + std::to_string(rate), "_wait_for_subscribers:=true"},
                         log);
  std::vector<Sample> samples;
  std::printf("soak: %.0f s of %d frames 640x480 at %.0f Hz (looping)\n", duration, frames, rate);
  std::printf("%8s %9s %9s %8s %8s %8s %8s\n", "t (s)", "received", "processed", "dropped", "refused", "tracked",
              "RSS MB");
  double next_print = 0;
  while (ros::ok() && (ros::WallTime::now() - t0).toSec() < duration) {
    ros::WallDuration(1.0).sleep();
    ASSERT_TRUE(publisher.running()) << "the publisher exited: " << nerfslam::rostest_util::readText(log);
    const double t = (ros::WallTime::now() - t0).toSec();
    const Sample s{t,
                   diag.num("frames received"),
                   diag.num("frames processed"),
                   diag.num("frames dropped (queue full)"),
                   diag.refused(),
                   diag.num("frames tracked"),
                   diag.num("resident memory (MB)"),
                   diag.num("nerf refits"),
                   diag.num("nerf views")};
    samples.push_back(s);
    if (t >= next_print) {
      next_print += duration / 20.0;
      std::printf("%8.0f %9.0f %9.0f %8.0f %8.0f %8.0f %8.1f\n", s.t, s.received, s.processed, s.dropped, s.refused,
                  s.tracked, s.rss_mb);
      std::fflush(stdout);
    }
  }
  publisher.stop();
  started = false;

  // 3. Every frame accounted for once the queue drained.
  auto accounted = [&] { return diag.accounted(); };
  const int diag_now = diag.count();
  EXPECT_TRUE(waitFor(20.0, [&] { return diag.count() > diag_now + 2 && accounted() == diag.num("frames received"); }))
      << "received " << diag.num("frames received") << " != processed + dropped + refused + errors " << accounted();
  const double received = diag.num("frames received"), processed = diag.num("frames processed"),
               dropped = diag.num("frames dropped (queue full)"), tracked = diag.num("frames tracked");
  const double refused = accounted() - processed - dropped;
  const double lost = diag.num("frames lost before the node (seq gaps)");
  const double sent = rate * duration;
  // What the publisher says it published at the end of its last complete pass.
  double published = 0, passes = 0;
  {
    const std::string out = nerfslam::rostest_util::readText(log);
    for (size_t at = out.find("pass "); at != std::string::npos; at = out.find("pass ", at + 5)) {
      unsigned long pass = 0, total = 0;
      if (std::sscanf(out.c_str() + at, "pass %lu done: %lu frames published in total", &pass, &total) == 2) {
        passes = double(pass);
        published = double(total);
      }
    }
  }

  // 4. Latency.
  std::vector<std::pair<double, double>> lat;
  {
    std::lock_guard<std::mutex> lock(mutex);
    lat = latencies;
  }
  std::vector<double> ms;
  for (const auto& l : lat) ms.push_back(l.second);
  const double p50 = percentile(ms, 0.5), p99 = percentile(ms, 0.99), pmax = ms.empty() ? 0 : ms.back();

  // 5. Memory after the warm-up, which ends at the latest of: the first warmup_fraction of the run's
  //    time; the time by which the node had processed warmup_fraction of the frames it processed in
  //    all (a warm-up is an amount of work: a slow start on a loaded machine processed 214 frames in
  //    its first 36 s and 1,525 in the next 84, and reached its memory plateau at 42 s); the NeRF's
  //    last re-fit of its scene box to the growing map (a one-off reallocation: the old field is
  //    distilled into a new one); the NeRF's last new view (its training views are part of the
  //    model's memory by design). The `after` check below fails when these leave too little.
  double t_refit = 0, refits = 0, t_views = 0, views = 0, t_work = 0;
  const double processed_total = samples.empty() ? 0 : samples.back().processed;
  for (const auto& s : samples) {
    if (s.refits > refits) {
      refits = s.refits;
      t_refit = s.t;
    }
    if (s.nerf_views != views) {
      views = s.nerf_views;
      t_views = s.t;
    }
    if (t_work == 0 && s.processed >= warmup_fraction * processed_total) t_work = s.t;
  }
  const double t_warm = std::max({warmup_fraction * duration, t_work, t_refit + 5.0, t_views + 5.0});
  double rss_warm = 0, rss_max_after = 0, rss_first = 0, rss_last = 0;
  size_t after = 0;
  for (const auto& s : samples) {
    if (rss_first == 0) rss_first = s.rss_mb;
    rss_last = s.rss_mb;
    if (s.t < t_warm) continue;
    if (rss_warm == 0) rss_warm = s.rss_mb;
    ++after;
    rss_max_after = std::max(rss_max_after, s.rss_mb);
  }
  const double growth = rss_warm > 0 ? (rss_max_after - rss_warm) / rss_warm : 1.0;

  std::printf(
      "soak result: %.0f s at %.0f Hz (~%.0f frames sent): %.0f lost before the node, %.0f received, %.0f processed, "
      "%.0f dropped (queue), %.0f "
      "refused; %.0f tracked = %.1f %% of processed (%.1f %% of received); processed %.1f frames/s; the publisher "
      "had published %.0f frames at the end of its pass %.0f (%.0f %% of %.0f Hz over the run)\n",
      duration, rate, sent, lost, received, processed, dropped, refused, tracked,
      processed > 0 ? 100.0 * tracked / processed : 0.0, received > 0 ? 100.0 * tracked / received : 0.0,
      processed / duration, published, passes, 100.0 * received / sent, rate);
  std::printf("soak latency (image stamp -> ~pose received), %zu poses: median %.1f ms, p99 %.1f ms, max %.1f ms\n",
              ms.size(), p50, p99, pmax);
  std::printf(
      "soak RSS: %.1f MB at the first sample, %.1f MB at %.0f s (end of warm-up: %.0f %% of the run, %.0f %% of the "
      "frames processed at %.0f s, last of "
      "%.0f NeRF scene-box refits at %.0f s, %.0f NeRF views from %.0f s), max after %.1f MB, last %.1f MB: growth "
      "after warm-up %.2f %%; node: "
      "tracking ms (mean) %s, keyframes %s, map points %s, nerf steps "
      "%s, nerf views %s\n",
      rss_first, rss_warm, t_warm, 100 * warmup_fraction, 100 * warmup_fraction, t_work, refits, t_refit, views,
      t_views, rss_max_after, rss_last, 100.0 * growth, diag.str("tracking ms (mean)").c_str(),
      diag.str("keyframes").c_str(), diag.str("map points").c_str(), diag.str("nerf steps").c_str(),
      diag.str("nerf views").c_str());
  std::fflush(stdout);

  // The camera was close to 60 Hz (the publisher decodes a 640x480 PNG per frame: measured 93 % of
  // 60 Hz over 2 minutes and 72 % over 30 minutes at load 6-10), and the node received every frame of
  // the passes the publisher completed (frames lost below the node, in roscpp's subscriber queue,
  // would not be counted by it).
  EXPECT_GT(received, 0.5 * sent) << "the camera was far below " << rate << " Hz";
  EXPECT_GE(received + lost, published) << "frames published but neither received nor counted as lost";
  EXPECT_LT(p99, max_latency_p99_ms);
  ASSERT_GT(processed, 0);
  EXPECT_GE(tracked / processed, min_tracked_fraction);
  // Tracking keeps going: poses in every tenth of the run after the warm-up.
  for (int k = 0; k < 10; ++k) {
    const double t_w = warmup_fraction * duration;
    const double a = t_w + k * (duration - t_w) / 10, b = t_w + (k + 1) * (duration - t_w) / 10;
    const auto n = std::count_if(lat.begin(), lat.end(), [&](const auto& l) { return l.first >= a && l.first < b; });
    EXPECT_GT(n, 0) << "no pose between " << a << " and " << b << " s";
  }
  EXPECT_GE(after, samples.size() / 10) << "the map kept growing until " << t_warm << " s: no steady state to measure";
  EXPECT_LT(growth, max_rss_growth) << "RSS grew from " << rss_warm << " to " << rss_max_after << " MB";
}

}  // namespace

int main(int argc, char** argv) { return nerfslam::rostest_util::runRosGtest(argc, argv, "nerfslam_node_soak_test"); }
