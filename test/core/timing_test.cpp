#include "nerfslam/core/timing.h"

#include <chrono>

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <thread>

#include "nerfslam/core/error.h"
#include "nerfslam/core/logging.h"

namespace nerfslam {
namespace {

TEST(Timing, NearestRankStatisticsOfKnownSamples) {
  TimingStats s;
  // 1..100 in scrambled order.
  for (int i = 0; i < 100; ++i) s.add(static_cast<double>((i * 37) % 100 + 1));
  EXPECT_EQ(s.count(), 100u);
  EXPECT_DOUBLE_EQ(s.mean(), 50.5);
  EXPECT_DOUBLE_EQ(s.min(), 1.0);
  EXPECT_DOUBLE_EQ(s.max(), 100.0);
  EXPECT_DOUBLE_EQ(s.median(), 50.0);  // ceil(0.5 * 100) = 50th smallest
  EXPECT_DOUBLE_EQ(s.p99(), 99.0);     // ceil(0.99 * 100) = 99th smallest
  EXPECT_DOUBLE_EQ(s.percentile(0), 1.0);
  EXPECT_DOUBLE_EQ(s.percentile(100), 100.0);
  EXPECT_DOUBLE_EQ(s.percentile(99.5), 100.0);
  EXPECT_DOUBLE_EQ(s.percentile(1), 1.0);
  EXPECT_DOUBLE_EQ(s.percentile(1.5), 2.0);
  EXPECT_THROW(s.percentile(101), Error);
  EXPECT_THROW(s.percentile(-1), Error);
  EXPECT_THROW(s.percentile(std::nan("")), Error);
}

TEST(Timing, SmallAndOddCounts) {
  TimingStats s;
  for (double x : {5.0, 1.0, 3.0}) s.add(x);
  EXPECT_DOUBLE_EQ(s.median(), 3.0);  // ceil(1.5) = 2nd
  EXPECT_DOUBLE_EQ(s.p99(), 5.0);     // ceil(2.97) = 3rd
  s.add(4.0);
  EXPECT_DOUBLE_EQ(s.median(), 3.0);  // even count: the lower middle sample
  EXPECT_DOUBLE_EQ(s.mean(), 13.0 / 4);
  TimingStats one;
  one.add(7.0);
  EXPECT_DOUBLE_EQ(one.median(), 7.0);
  EXPECT_DOUBLE_EQ(one.p99(), 7.0);
  // 1000 samples 1..1000: p99 is the 990th smallest.
  TimingStats k;
  for (int i = 1000; i >= 1; --i) k.add(i);
  EXPECT_DOUBLE_EQ(k.p99(), 990.0);
  EXPECT_DOUBLE_EQ(k.median(), 500.0);
}

TEST(Timing, EmptyIsNaN) {
  TimingStats s;
  EXPECT_EQ(s.count(), 0u);
  EXPECT_TRUE(std::isnan(s.median()));
  EXPECT_TRUE(std::isnan(s.p99()));
  EXPECT_TRUE(std::isnan(s.mean()));
  EXPECT_TRUE(std::isnan(s.max()));
  EXPECT_EQ(s.summary(), "n=0");
  s.add(2);
  s.clear();
  EXPECT_EQ(s.count(), 0u);
}

TEST(Timing, SummaryAndCopy) {
  TimingStats s;
  for (double x : {1.0, 2.0, 3.0, 10.0}) s.add(x);
  EXPECT_EQ(s.summary(), "n=4 mean=4.000 median=2.000 p99=10.000 max=10.000 ms");
  TimingStats c = s;
  c.add(100);
  EXPECT_EQ(s.count(), 4u);
  EXPECT_EQ(c.count(), 5u);
  s = c;
  EXPECT_EQ(s.samples(), c.samples());
}

TEST(Timing, StopwatchAndScopedTimerMeasureSleeps) {
  Stopwatch w;
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const double lap = w.lapMs();
  EXPECT_GE(lap, 20.0);
  EXPECT_LT(lap, 2000.0);  // generous: the machine is shared
  EXPECT_LT(w.elapsedMs(), lap);
  TimingStats stats;
  for (int i = 0; i < 3; ++i) {
    ScopedTimer t(stats);
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_EQ(stats.count(), 3u);
  EXPECT_GE(stats.min(), 5.0);
}

TEST(Timing, ConcurrentAddsAreAllKept) {
  TimingStats s;
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t)
    threads.emplace_back([&s, t] {
      for (int i = 0; i < 1000; ++i) s.add(t * 1000 + i);
    });
  for (auto& th : threads) th.join();
  EXPECT_EQ(s.count(), 4000u);
  EXPECT_DOUBLE_EQ(s.max(), 3999.0);
  EXPECT_DOUBLE_EQ(s.median(), 1999.0);
}

TEST(Logging, ValidatesLevel) {
  EXPECT_EQ(parseLogLevel("warn"), spdlog::level::warn);
  EXPECT_EQ(parseLogLevel("error"), spdlog::level::err);
  EXPECT_EQ(parseLogLevel("off"), spdlog::level::off);
  try {
    setupLogging("inf");
    FAIL() << "accepted a bad level";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("'inf'"), std::string::npos) << msg;
    EXPECT_NE(msg.find("did you mean 'info'"), std::string::npos) << msg;
  }
  setupLogging("debug");
  EXPECT_EQ(spdlog::get_level(), spdlog::level::debug);
  setupLogging("info");
  EXPECT_EQ(spdlog::get_level(), spdlog::level::info);
}

}  // namespace
TEST(Timing, ThreadCpuTimeCountsWorkNotSleep) {
  const double t0 = threadCpuMs();
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const double slept = threadCpuMs() - t0;
  EXPECT_LT(slept, 20.0) << "sleeping must not consume thread CPU time";
  const double t1 = threadCpuMs();
  volatile double x = 0;
  Stopwatch sw;
  while (sw.elapsedMs() < 30) x = x + 1.0;
  EXPECT_GT(threadCpuMs() - t1, 1.0) << "busy work must consume thread CPU time";
}

}  // namespace nerfslam
