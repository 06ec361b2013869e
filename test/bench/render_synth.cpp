// Render + readback speed of a 640x480 textured frame (room scene) with OSMesa/llvmpipe.
// Prints frames/s (median over repetitions) for: colour + depth readback (the synth path; also
// with --texture-filter mip-nearest), colour only, draw only (no readback), and the full SequenceRenderer
// frame (+ BGR conversion); the baseline in the same run is an empty scene (clear + readback only).
//   bench_render_synth --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
// LP_NUM_THREADS (llvmpipe rasteriser threads) defaults to the core count; set it to compare.
#include <benchmark/benchmark.h>

#include <ctime>

#include <algorithm>

#include "nerfslam/render/renderer.h"
#include "nerfslam/render/scene.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/render/trajectory.h"

namespace {
using namespace nerfslam;

// CPU seconds of the whole process (all llvmpipe threads): on a machine shared with other jobs the
// wall time is noisy, the CPU cost per frame is not. 2 idle cores give about 2 / cpu_per_frame fps.
double processCpu() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

struct Fixture {
  Scene scene;
  CameraTrajectory traj;
  Renderer renderer;
  Camera cam = Camera::pinhole(640, 480, 525, 525, 319.5, 239.5);
  Fixture() {
    SynthSceneOptions so;
    so.name = "room";
    so.textures = "procedural";
    scene = makeScene(so);
    traj = makeTrajectory(scene, "handheld", 20.0, 1);
    uploadScene(scene, renderer);
  }
  static Fixture& get() {
    static Fixture f;
    return f;
  }
};

void run(benchmark::State& state, bool color, bool depth, bool empty,
         TextureFilter filter = TextureFilter::kTrilinear) {
  Fixture& f = Fixture::get();
  Renderer empty_renderer;
  Renderer& r = empty ? empty_renderer : f.renderer;
  r.setTextureFilter(filter);
  cv::Mat bgr, d;
  int i = 0;
  const double c0 = processCpu();
  for (auto _ : state) {
    r.render(f.cam, f.traj.pose((i++ % 600) / 30.0), color ? &bgr : nullptr, depth ? &d : nullptr);
    if (!color && !depth) r.finish();  // otherwise llvmpipe only queues the frame
    benchmark::DoNotOptimize(bgr.data);
  }
  state.counters["cpu_ms_per_frame"] = 1e3 * (processCpu() - c0) / std::max<double>(1, state.iterations());
  state.counters["fps"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}

void BM_RenderColorDepth(benchmark::State& s) { run(s, true, true, false); }
// The same with textures sampled in the nearest mipmap level (synth --texture-filter mip-nearest).
void BM_RenderColorDepthMipNearest(benchmark::State& s) { run(s, true, true, false, TextureFilter::kMipNearest); }
void BM_RenderColorOnly(benchmark::State& s) { run(s, true, false, false); }
void BM_RenderNoReadback(benchmark::State& s) { run(s, false, false, false); }
void BM_EmptySceneColorDepth(benchmark::State& s) { run(s, true, true, true); }

void BM_SequenceFrame(benchmark::State& state) {
  SynthOptions o;
  o.textures = "procedural";
  o.frames = 600;
  SequenceRenderer seq(o);
  int i = 0;
  const double c0 = processCpu();
  for (auto _ : state) {
    SynthFrame f = seq.render(i++ % 600);
    benchmark::DoNotOptimize(f.bgr.data);
  }
  state.counters["cpu_ms_per_frame"] = 1e3 * (processCpu() - c0) / std::max<double>(1, state.iterations());
  state.counters["fps"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}

BENCHMARK(BM_RenderColorDepth)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
BENCHMARK(BM_RenderColorDepthMipNearest)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
BENCHMARK(BM_RenderColorOnly)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
BENCHMARK(BM_RenderNoReadback)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
BENCHMARK(BM_EmptySceneColorDepth)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
BENCHMARK(BM_SequenceFrame)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);

}  // namespace

BENCHMARK_MAIN();
