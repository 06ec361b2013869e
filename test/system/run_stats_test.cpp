// RunStats: the timing fields of report.json from per-frame and per-keyframe records.
#include "nerfslam/system/run_stats.h"

#include <gtest/gtest.h>

namespace nerfslam {
namespace {

FrameRecord initAttempt(double cpu, double extract, double klt, double models) {
  FrameRecord r;
  r.tracking_ms = 2 * cpu;
  r.tracking_cpu_ms = cpu;
  r.extract_cpu_ms = extract;
  r.init_klt_cpu_ms = klt;
  r.init_models_cpu_ms = models;
  return r;
}

FrameRecord trackedFrame(double cpu, double extract, double local_map, double track, double relocalize) {
  FrameRecord r;
  r.tracking_ms = 2 * cpu;
  r.tracking_cpu_ms = cpu;
  r.extract_cpu_ms = extract;
  r.extract_stages.pyramid_ms = 0.25 * extract;
  r.extract_stages.fast_ms = 0.25 * extract;
  r.extract_stages.descriptor_ms = 0.5 * extract;
  r.local_map_cpu_ms = local_map;
  r.track_cpu_ms = track;
  r.relocalize_cpu_ms = relocalize;
  return r;
}

RunStats framesOfCpu(const std::vector<std::pair<std::size_t, double>>& runs) {
  RunStats s;
  for (const auto& [n, cpu] : runs)
    for (std::size_t i = 0; i < n; ++i) s.addFrame(trackedFrame(cpu, cpu / 2, 0, cpu / 4, 0), true);
  return s;
}

TEST(RunStats, PercentileInterpolatesBetweenTheNearestSamples) {
  EXPECT_EQ(runPercentile({}, 0.5), 0.0);
  EXPECT_DOUBLE_EQ(runPercentile({7}, 0.99), 7.0);
  EXPECT_DOUBLE_EQ(runPercentile({4, 1, 3, 2}, 0.5), 2.5);  // unsorted input
  EXPECT_DOUBLE_EQ(runPercentile({4, 1, 3, 2}, 1.0), 4.0);
  EXPECT_DOUBLE_EQ(runPercentile({4, 1, 3, 2}, 0.0), 1.0);
  EXPECT_NEAR(runPercentile({0, 100}, 0.99), 99.0, 1e-9);
}

TEST(RunStats, SplitsInitialisationAttemptsFromTrackedFramesPerStage) {
  RunStats s;
  s.addFrame(initAttempt(10, 4, 3, 1), false);       // other 2
  s.addFrame(initAttempt(30, 5, 4, 2), false);       // other 19
  s.addFrame(initAttempt(20, 6, 5, 3), false);       // other 6
  s.addFrame(trackedFrame(8, 5, 1, 1, 0), true);     // other 1
  s.addFrame(trackedFrame(12, 7, 1, 2, 0.5), true);  // other 1.5
  // With the map but not tracked against it (no tracking stage): after-init time, no stage times.
  FrameRecord lost;
  lost.tracking_ms = 200;
  lost.tracking_cpu_ms = 100;
  s.addFrame(lost, true);
  EXPECT_EQ(s.frames(), 6u);
  nlohmann::json rep;
  s.writeReport(rep, false);

  // All frames' CPU times sorted: 8 10 12 20 30 100; wall times are twice these.
  EXPECT_DOUBLE_EQ(rep.at("tracking_cpu_ms_median").get<double>(), 16.0);
  EXPECT_NEAR(rep.at("tracking_cpu_ms_p99").get<double>(), 30 + 0.95 * 70, 1e-9);
  EXPECT_DOUBLE_EQ(rep.at("tracking_ms_median").get<double>(), 32.0);
  EXPECT_NEAR(rep.at("tracking_ms_p99").get<double>(), 2 * (30 + 0.95 * 70), 1e-9);
  EXPECT_DOUBLE_EQ(rep.at("tracking_cpu_ms_after_init_median").get<double>(), 12.0);  // 8 12 100
  EXPECT_NEAR(rep.at("tracking_cpu_ms_after_init_p99").get<double>(), 12 + 0.98 * 88, 1e-9);
  EXPECT_EQ(rep.at("initialization_frames").get<int>(), 3);
  EXPECT_DOUBLE_EQ(rep.at("initialization_cpu_ms_median").get<double>(), 20.0);
  EXPECT_DOUBLE_EQ(rep.at("initialization_cpu_ms_max").get<double>(), 30.0);

  const auto& is = rep.at("initialization_stage_cpu_ms");
  EXPECT_EQ(is.size(), 4u);
  EXPECT_DOUBLE_EQ(is.at("extract").at("median").get<double>(), 5.0);
  EXPECT_DOUBLE_EQ(is.at("klt").at("max").get<double>(), 5.0);
  EXPECT_DOUBLE_EQ(is.at("models").at("median").get<double>(), 2.0);
  EXPECT_DOUBLE_EQ(is.at("other").at("median").get<double>(), 6.0);
  EXPECT_DOUBLE_EQ(is.at("other").at("max").get<double>(), 19.0);

  const auto& ts = rep.at("tracking_stage_cpu_ms");
  EXPECT_EQ(ts.size(), 8u);
  EXPECT_DOUBLE_EQ(ts.at("extract").at("median").get<double>(), 6.0);
  EXPECT_NEAR(ts.at("extract").at("p99").get<double>(), 5 + 0.99 * 2, 1e-9);
  EXPECT_DOUBLE_EQ(ts.at("extract.descriptors").at("median").get<double>(), 3.0);
  EXPECT_DOUBLE_EQ(ts.at("extract.pyramid").at("median").get<double>(), 1.5);
  EXPECT_DOUBLE_EQ(ts.at("track").at("median").get<double>(), 1.5);
  EXPECT_DOUBLE_EQ(ts.at("relocalize").at("median").get<double>(), 0.25);
  EXPECT_DOUBLE_EQ(ts.at("local_map").at("p99").get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(ts.at("other").at("median").get<double>(), 1.25);
  EXPECT_FALSE(rep.contains("tracking_ms_median_with_nerf"));
}

TEST(RunStats, NoFramesGivesZerosAndNoStageFields) {
  RunStats s;
  nlohmann::json rep;
  s.writeReport(rep, false);
  EXPECT_EQ(rep.at("tracking_ms_median").get<double>(), 0.0);
  EXPECT_EQ(rep.at("initialization_frames").get<int>(), 0);
  EXPECT_EQ(rep.at("ba_ms_max").get<double>(), 0.0);
  EXPECT_EQ(rep.at("mapping_ms_median").get<double>(), 0.0);
  EXPECT_FALSE(rep.contains("initialization_stage_cpu_ms"));
  EXPECT_FALSE(rep.contains("tracking_stage_cpu_ms"));
  ASSERT_TRUE(rep.at("tracking_ms_windows").is_array());
  EXPECT_TRUE(rep.at("tracking_ms_windows").empty());
}

TEST(RunStats, WindowsOf200FramesWithTheStateAtTheirEnd) {
  // 200 frames of 1 ms CPU, 200 of 2 ms, 50 of 3 ms: the last 50 are under half a window, left out.
  RunStats s = framesOfCpu({{200, 1.0}, {200, 2.0}, {50, 3.0}});
  s.addWindowSample({100.0, 5, 500});
  s.addWindowSample({120.0, 9, 900});
  nlohmann::json rep;
  s.writeReport(rep, false);
  const auto& w = rep.at("tracking_ms_windows");
  ASSERT_EQ(w.size(), 2u) << w.dump(2);
  EXPECT_EQ(w[0].at("first_frame").get<int>(), 0);
  EXPECT_EQ(w[1].at("first_frame").get<int>(), 200);
  EXPECT_EQ(w[1].at("frames").get<int>(), 200);
  EXPECT_DOUBLE_EQ(w[0].at("cpu_ms_median").get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(w[1].at("cpu_ms_p99").get<double>(), 2.0);
  EXPECT_DOUBLE_EQ(w[1].at("wall_ms_median").get<double>(), 4.0);
  EXPECT_DOUBLE_EQ(w[0].at("rss_mb").get<double>(), 100.0);
  EXPECT_EQ(w[1].at("keyframes").get<int>(), 9);
  EXPECT_EQ(w[1].at("map_points").get<int>(), 900);

  // 50 more: a last window of 100 frames is kept, without the state (not a full window).
  for (int i = 0; i < 50; ++i) s.addFrame(trackedFrame(3.0, 1.5, 0, 0.75, 0), true);
  s.addWindowSample({140.0, 12, 1200});
  s.writeReport(rep, false);
  const auto& w3 = rep.at("tracking_ms_windows");
  ASSERT_EQ(w3.size(), 3u) << w3.dump(2);
  EXPECT_EQ(w3[2].at("first_frame").get<int>(), 400);
  EXPECT_EQ(w3[2].at("frames").get<int>(), 100);
  EXPECT_DOUBLE_EQ(w3[2].at("wall_ms_p99").get<double>(), 6.0);
  EXPECT_FALSE(w3[2].contains("rss_mb"));
  EXPECT_FALSE(w3[2].contains("keyframes"));
}

TEST(RunStats, AShortRunIsOneWindowAndAFullWindowWithoutASampleHasNoState) {
  RunStats short_run = framesOfCpu({{51, 1.0}});
  nlohmann::json rep;
  short_run.writeReport(rep, false);
  ASSERT_EQ(rep.at("tracking_ms_windows").size(), 1u);
  EXPECT_EQ(rep.at("tracking_ms_windows")[0].at("frames").get<int>(), 51);
  EXPECT_FALSE(rep.at("tracking_ms_windows")[0].contains("rss_mb"));

  // --realtime can track fewer frames than the reader queued, or the reader may not have sampled.
  RunStats full = framesOfCpu({{200, 1.0}});
  full.writeReport(rep, false);
  ASSERT_EQ(rep.at("tracking_ms_windows").size(), 1u);
  EXPECT_EQ(rep.at("tracking_ms_windows")[0].at("frames").get<int>(), 200);
  EXPECT_FALSE(rep.at("tracking_ms_windows")[0].contains("rss_mb"));
}

TEST(RunStats, MappingTimesAndTheNerfField) {
  RunStats s = framesOfCpu({{3, 4.0}});
  MappingStats a, b, c;
  a.ba_ms = 5;
  a.total_ms = 10;
  b.ba_ms = 1;
  b.total_ms = 30;
  c.ba_ms = 9;
  c.total_ms = 20;
  s.setMapping({a, b, c});
  nlohmann::json rep;
  s.writeReport(rep, true);
  EXPECT_DOUBLE_EQ(rep.at("ba_ms_median").get<double>(), 5.0);
  EXPECT_DOUBLE_EQ(rep.at("ba_ms_max").get<double>(), 9.0);
  EXPECT_DOUBLE_EQ(rep.at("mapping_ms_median").get<double>(), 20.0);
  EXPECT_DOUBLE_EQ(rep.at("tracking_ms_median_with_nerf").get<double>(), 8.0);
  EXPECT_DOUBLE_EQ(rep.at("tracking_ms_median_with_nerf").get<double>(), rep.at("tracking_ms_median").get<double>());
  // Set again (not appended): the mapping thread's final list.
  s.setMapping({b});
  s.writeReport(rep, true);
  EXPECT_DOUBLE_EQ(rep.at("ba_ms_max").get<double>(), 1.0);
}

}  // namespace
}  // namespace nerfslam
