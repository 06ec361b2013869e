// Tracking latency of the full SLAM system on a real sequence (KITTI 06, first 51 frames; New
// Tsukuba with --tsukuba), in one process, two passes over the same frames:
//   concurrent: frames are fed as fast as tracking returns, the mapping thread runs alongside
//               (tracking competes with mapping for the Map lock and the CPU);
//   idle:       after each frame the feeder waits until mapping is idle, so tracking never overlaps
//               mapping (the lock-step offline mode of `nerfslam run`).
// Per pass: tracking latency (median, p99, max) as wall time and as the tracking thread's CPU time
// (CLOCK_THREAD_CPUTIME_ID: wall minus CPU is time spent preempted or blocked), and the longest and
// total time the tracking thread waited for the Map lock (Map::threadLockWait). Image decoding is
// done before timing. Prints one line per pass; also reported as Google Benchmark counters.
#include <benchmark/benchmark.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "nerfslam/core/timing.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/system/slam_system.h"
#include "test_support.h"

namespace nerfslam {
namespace {

std::string g_sequence = "kitti06_first51";

double processCpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5));
  return v[i];
}

struct PassResult {
  std::vector<double> wall_ms, cpu_ms;
  MapLockWait lock;
  int keyframes = 0;
  int tracked = 0;
  int frames = 0;
  double other_threads_cpu_ms = 0;      // process CPU minus the tracking thread's: mostly mapping
  std::vector<double> mapping_wait_ms;  // idle pass: wall time waiting for mapping after each keyframe
};

PassResult runPass(const Dataset& ds, const std::vector<cv::Mat>& images, bool concurrent) {
  SystemOptions sys;
  sys.nerf.enabled = false;  // sparse SLAM only; bench_nerf_slam_latency measures tracking beside the NeRF
  SlamSystem slam(ds.camera(), sys);
  PassResult r;
  Map::resetThreadLockWait();
  const double p0 = processCpuMs(), t0cpu = threadCpuMs();
  for (size_t i = 0; i < images.size(); ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    const double c0 = threadCpuMs();
    const FrameRecord rec = slam.trackFrame(images[i], ds.timestamp(i), i);
    const double c1 = threadCpuMs();
    const auto t1 = std::chrono::steady_clock::now();
    ++r.frames;
    // Frames before initialisation only feed the initialiser: not tracking latency.
    if (rec.state != TrackingState::kNotInitialized && rec.message.rfind("initialised", 0) != 0) {
      r.wall_ms.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
      r.cpu_ms.push_back(c1 - c0);
      if (c1 - c0 > 40)
        std::printf("  %s frame %zu: %.1f ms CPU (%s)\n", concurrent ? "concurrent" : "idle", i, c1 - c0,
                    rec.message.c_str());
    }
    r.tracked += rec.tracked;
    if (!concurrent && rec.keyframe) {
      const auto w0 = std::chrono::steady_clock::now();
      slam.waitMappingIdle();
      r.mapping_wait_ms.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - w0).count());
    }
  }
  r.lock = Map::threadLockWait();
  slam.waitMappingIdle();
  r.other_threads_cpu_ms = (processCpuMs() - p0) - (threadCpuMs() - t0cpu);
  r.keyframes = static_cast<int>(slam.map().numKeyframes());
  slam.finish(false);
  return r;
}

void BM_SlamTrackingLatency(benchmark::State& state) {
  const auto root = test::dataDir() / g_sequence;
  if (!std::filesystem::exists(root)) {
    state.SkipWithError(("no data at " + root.string()).c_str());
    return;
  }
  const auto ds = openDataset(root.string());
  std::vector<cv::Mat> images;
  for (size_t i = 0; i < ds->size(); ++i) images.push_back(ds->load(i, ImageMode::kGray).image);
  PassResult conc, idle;
  for (auto _ : state) {
    conc = runPass(*ds, images, true);
    idle = runPass(*ds, images, false);
  }
  auto print = [&](const char* name, const PassResult& p) {
    std::printf(
        "%-10s %s: %zu timed frames (%d tracked, %d keyframes) | wall median %.1f p99 %.1f max %.1f ms | "
        "thread CPU median %.1f p99 %.1f max %.1f ms | map lock: %llu/%llu acquisitions waited, longest %.2f ms, "
        "total %.2f ms\n",
        name, g_sequence.c_str(), p.wall_ms.size(), p.tracked, p.keyframes, percentile(p.wall_ms, 0.5),
        percentile(p.wall_ms, 0.99), percentile(p.wall_ms, 1.0), percentile(p.cpu_ms, 0.5), percentile(p.cpu_ms, 0.99),
        percentile(p.cpu_ms, 1.0), static_cast<unsigned long long>(p.lock.contended),
        static_cast<unsigned long long>(p.lock.acquisitions), p.lock.max_ms, p.lock.total_ms);
  };
  print("concurrent", conc);
  print("idle", idle);
  std::printf(
      "mapping (idle pass): %zu keyframes processed, wall per keyframe median %.1f max %.1f ms; CPU of "
      "non-tracking threads %.0f ms (concurrent pass %.0f ms)\n",
      idle.mapping_wait_ms.size(), percentile(idle.mapping_wait_ms, 0.5), percentile(idle.mapping_wait_ms, 1.0),
      idle.other_threads_cpu_ms, conc.other_threads_cpu_ms);
  state.counters["conc_wall_median_ms"] = percentile(conc.wall_ms, 0.5);
  state.counters["conc_wall_p99_ms"] = percentile(conc.wall_ms, 0.99);
  state.counters["conc_cpu_p99_ms"] = percentile(conc.cpu_ms, 0.99);
  state.counters["conc_lock_wait_max_ms"] = conc.lock.max_ms;
  state.counters["idle_wall_median_ms"] = percentile(idle.wall_ms, 0.5);
  state.counters["idle_wall_p99_ms"] = percentile(idle.wall_ms, 0.99);
  state.counters["idle_cpu_p99_ms"] = percentile(idle.cpu_ms, 0.99);
}
BENCHMARK(BM_SlamTrackingLatency)->Iterations(1)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace nerfslam

int main(int argc, char** argv) {
  // --tsukuba: run on new_tsukuba_150 instead of kitti06_first51.
  std::vector<char*> args;
  for (int i = 0; i < argc; ++i) {
    if (std::strcmp(argv[i], "--tsukuba") == 0)
      nerfslam::g_sequence = "new_tsukuba_150";
    else
      args.push_back(argv[i]);
  }
  int n = static_cast<int>(args.size());
  benchmark::Initialize(&n, args.data());
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
