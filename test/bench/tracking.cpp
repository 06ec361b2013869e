// Tracking front-end speed on real frames, one core (cv::setNumThreads(1)).
// Part 1 (printed table): New Tsukuba 640x480 -- initialise from the first frames, then track the
// following frames against the initial map; per-stage medians and p99 per frame. KITTI 1226x370
// feature extraction for comparison. Part 2: Google Benchmark timings of the same stages.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/timing.h"
#include "nerfslam/tracking/initializer.h"
#include "nerfslam/tracking/tracker.h"
#include "test_support.h"

namespace nerfslam {
namespace {

// Thread CPU time: the one-core cost, independent of how loaded the machine is.
double cpuMs() { return threadCpuMs(); }
struct Clock {
  static double now() { return cpuMs(); }
};
double msSince(double t0) { return cpuMs() - t0; }
using WallClock = std::chrono::steady_clock;
double wallMsSince(WallClock::time_point t0) {
  return std::chrono::duration<double, std::milli>(WallClock::now() - t0).count();
}

struct Stats {
  double median = 0, p99 = 0, max = 0;
};
Stats stats(std::vector<double> v) {
  Stats s;
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  s.median = v[v.size() / 2];
  s.p99 = v[std::min(v.size() - 1, static_cast<size_t>(0.99 * static_cast<double>(v.size())))];
  s.max = v.back();
  return s;
}

std::vector<cv::Mat> loadTsukuba(int n) {
  std::vector<cv::Mat> out;
  for (int i = 0; i < n; ++i) {
    char name[64];
    std::snprintf(name, sizeof(name), "new_tsukuba_150/images/rgb_%05d.png", i);
    cv::Mat img = cv::imread((test::dataDir() / name).string(), cv::IMREAD_GRAYSCALE);
    if (img.empty()) break;
    out.push_back(img);
  }
  return out;
}

std::vector<cv::Mat> loadKitti(int n) {
  std::vector<cv::Mat> out;
  for (int i = 0; i < n; ++i) {
    char name[64];
    std::snprintf(name, sizeof(name), "kitti06_first51/image_l/%06d.png", i);
    cv::Mat img = cv::imread((test::dataDir() / name).string(), cv::IMREAD_GRAYSCALE);
    if (img.empty()) break;
    out.push_back(img);
  }
  return out;
}

const Camera kTsukuba = Camera::pinhole(640, 480, 615, 615, 320, 240);
const Camera kKitti = Camera::pinhole(1226, 370, 707.0912, 707.0912, 601.8873, 183.1104);

std::vector<TrackingMapPoint> mapFromInit(const InitializationResult& r, const Frame& ref) {
  std::vector<TrackingMapPoint> map;
  for (size_t i = 0; i < r.points.size(); ++i) {
    TrackingMapPoint p;
    p.id = i;
    p.p_world = r.points[i].p_world;
    p.descriptor = ref.descriptors.row(r.points[i].ref_feature).clone();
    p.angle = ref.keypoints[static_cast<size_t>(r.points[i].ref_feature)].angle;
    map.push_back(p);
  }
  return map;
}

void printPipeline() {
  const std::vector<cv::Mat> imgs = loadTsukuba(150);
  if (imgs.size() < 60) {
    std::printf("new_tsukuba_150 not found under %s: pipeline table skipped\n", test::dataDir().c_str());
    return;
  }
  Initializer init;
  InitializationResult ir;
  size_t i = 0;
  std::vector<double> init_ms, init_klt, init_models;
  for (; i < imgs.size() && !ir.success; ++i) {
    const auto t0 = Clock::now();
    ir = init.addFrame(extractFrame(imgs[i], kTsukuba, {}, i));
    init_ms.push_back(msSince(t0));
    if (i > 0) {  // frame 0 only becomes the reference
      init_klt.push_back(ir.klt_cpu_ms);
      init_models.push_back(ir.models_cpu_ms);
    }
  }
  if (!ir.success) {
    std::printf("initialisation failed: %s\n", ir.reason.c_str());
    return;
  }
  const std::vector<TrackingMapPoint> map = mapFromInit(ir, init.reference());
  Tracker tracker;
  tracker.setPose(ir.T_world_cur);
  std::vector<double> pyr, fast, desc, match, opt, total, wall;
  int good = 0, weak = 0, lost = 0, n = 0;
  double inliers = 0;
  for (; i < imgs.size(); ++i) {
    const auto t0 = Clock::now();
    const auto w0 = WallClock::now();
    const Frame f = extractFrame(imgs[i], kTsukuba, {}, i);
    const TrackingResult r = tracker.track(f, map);
    total.push_back(msSince(t0));
    wall.push_back(wallMsSince(w0));
    pyr.push_back(f.timings.pyramid_ms);
    fast.push_back(f.timings.fast_ms);
    desc.push_back(f.timings.descriptor_ms);
    match.push_back(r.timings.matching_ms);
    opt.push_back(r.timings.optimization_ms);
    good += r.quality == TrackingQuality::kGood;
    weak += r.quality == TrackingQuality::kWeak;
    lost += r.quality == TrackingQuality::kLost;
    inliers += r.num_inliers;
    ++n;
    if (r.quality == TrackingQuality::kLost) break;  // the map is never extended here
  }
  const Stats si = stats(init_ms);
  std::printf(
      "New Tsukuba 640x480, one core: initialised at frame %llu (%zu points, %s); init per frame median "
      "%.1f ms, max %.1f ms\n",
      static_cast<unsigned long long>(ir.cur_frame_id), ir.points.size(), ir.model.c_str(), si.median, si.max);
  const Stats sk = stats(init_klt), sm = stats(init_models);
  std::printf("  of which KLT median %.1f ms (max %.1f), models and reconstruction median %.1f ms (max %.1f)\n",
              sk.median, sk.max, sm.median, sm.max);
  std::printf("tracked %d frames against the initial map (good %d, weak %d, lost %d, mean inliers %.0f)\n", n, good,
              weak, lost, n ? inliers / n : 0.0);
  std::printf("thread CPU time per frame (wall clock depends on the machine's load):\n");
  std::printf("%-14s %9s %9s %9s\n", "stage", "median", "p99", "max");
  auto row = [](const char* name, const std::vector<double>& v) {
    const Stats s = stats(v);
    std::printf("%-14s %7.2fms %7.2fms %7.2fms\n", name, s.median, s.p99, s.max);
  };
  row("pyramid", pyr);
  row("FAST+grid", fast);
  row("descriptors", desc);
  row("matching", match);
  row("optimisation", opt);
  row("total/frame", total);
  row("(wall clock)", wall);

  // Extraction over every frame of the sequence, back to back and with the tracking thread idle
  // between frames as it is in the system (a camera frame every 33 ms): the second shows what caches
  // and the CPU lose while a thread sleeps.
  for (const int gap_ms : {0, 30}) {
    std::vector<double> ex;
    for (const cv::Mat& img : imgs) {
      if (gap_ms > 0) std::this_thread::sleep_for(std::chrono::milliseconds(gap_ms));
      const double t0 = Clock::now();
      const Frame f = extractFrame(img, kTsukuba, {});
      benchmark::DoNotOptimize(f.descriptors.data);
      ex.push_back(msSince(t0));
    }
    const Stats s = stats(ex);
    std::printf("New Tsukuba extraction, all %zu frames, %2d ms idle between frames: median %.2f ms, p99 %.2f ms\n",
                imgs.size(), gap_ms, s.median, s.p99);
  }

  const std::vector<cv::Mat> k = loadKitti(20);
  if (!k.empty()) {
    FeatureOptions fo;
    fo.max_features = 1500;
    std::vector<double> kt;
    for (const cv::Mat& img : k) {
      const auto t0 = Clock::now();
      const Frame f = extractFrame(img, kKitti, fo);
      benchmark::DoNotOptimize(f.keypoints.data());
      kt.push_back(msSince(t0));
    }
    const Stats s = stats(kt);
    std::printf("KITTI 1226x370 extraction (1500 features): median %.2f ms, max %.2f ms\n", s.median, s.max);
  }
}

void BM_ExtractTsukuba(benchmark::State& state) {
  static const std::vector<cv::Mat> imgs = loadTsukuba(20);
  if (imgs.empty()) {
    state.SkipWithError("no data");
    return;
  }
  size_t i = 0;
  for (auto _ : state) {
    Frame f = extractFrame(imgs[i++ % imgs.size()], kTsukuba, {});
    benchmark::DoNotOptimize(f.descriptors.data);
  }
}
BENCHMARK(BM_ExtractTsukuba)->Unit(benchmark::kMillisecond);

void BM_ExtractKitti(benchmark::State& state) {
  static const std::vector<cv::Mat> imgs = loadKitti(10);
  if (imgs.empty()) {
    state.SkipWithError("no data");
    return;
  }
  FeatureOptions fo;
  fo.max_features = 1500;
  size_t i = 0;
  for (auto _ : state) {
    Frame f = extractFrame(imgs[i++ % imgs.size()], kKitti, fo);
    benchmark::DoNotOptimize(f.descriptors.data);
  }
}
BENCHMARK(BM_ExtractKitti)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace nerfslam

int main(int argc, char** argv) {
  cv::setNumThreads(1);
  nerfslam::printPipeline();
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  return 0;
}
