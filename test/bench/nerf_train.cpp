// NeRF training throughput on lego (400x400, --downscale 2 equivalent): samples/s of fwd + bwd +
// optimiser on 2 threads, per-stage times, a 640x480 render of the partly trained model, and the
// depth triangles of a view's surface points.
//   bench_nerf_train [--benchmark_min_time=...]   (needs the shared data; see test_support.h)
//   NERFSLAM_BENCH_WARMUP_STEPS=N: training steps before measuring (default 200)
//   NERFSLAM_BENCH_SAMPLES_PER_STEP=N: the trainer's target samples per step (default: TrainOptions',
//     2^16; the paper's batch, as instant-ngp's target_batch_size, is 2^18)
//   NERFSLAM_BENCH_SAMPLES_PER_CHUNK=N: samples a thread evaluates and back-propagates at a time
//     (default: TrainOptions', 2^14; a value >= the step's samples is one chunk per thread)
//
// Counters of BM_TrainStep (per step unless named otherwise):
//   samples_per_s      ray samples per wall second (the machine is shared: see samples_per_cpu_s)
//   composited_share   share of the samples before their ray's transmittance fell below 1e-4 (the
//                      rest get a density, but no colour and no backward pass: zero gradient)
//   samples_per_cpu_s  ray samples per CPU second summed over all threads (per-core throughput;
//                      on an idle 2-core machine wall throughput is about twice this)
//   ms_*               wall ms per stage as the trainer reports them (march, field forward,
//                      composite, field backward = MLP backward, optimizer = hash-grid scatter +
//                      Adam, grid = occupancy update amortised over the steps)
//   cpu_ms_scatter, cpu_ms_adam, cpu_ms_mlp_adam   CPU ms of the optimiser's parts (summed over
//                      its workers), entries = hash entries updated per step
//   peak_rss_mb        VmHWM of the process so far
#include <benchmark/benchmark.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <random>
#include <string>

#include "nerfslam/io/dataset.h"
#include "nerfslam/nerf/depth_triangles.h"
#include "nerfslam/nerf/occupancy.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/nerf/trainer.h"
#include "test_support.h"

namespace {

using namespace nerfslam;

double processCpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

double peakRssMb() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  return 0.0;
}

struct Setup {
  std::vector<nerf::TrainingView> views;
  std::unique_ptr<nerf::NerfModel> model;
  std::unique_ptr<nerf::Trainer> trainer;
};

Setup& setup() {
  static Setup s = [] {
    Setup r;
    auto ds = openDataset("transforms:" + (test::dataDir() / "lego_train").string());
    for (size_t i = 0; i < ds->size(); i += 4) {
      const auto f = ds->load(i, ImageMode::kUnchanged);
      r.views.push_back(nerf::makeTrainingView(f.image, ds->camera(), *f.T_world_cam, 2.0));
    }
    nerf::SceneTransform scene;
    r.model = std::make_unique<nerf::NerfModel>(nerf::NerfModel::create(nerf::FieldConfig{}, scene, 0));
    nerf::TrainOptions o;
    o.threads = 2;
    if (const char* sps = std::getenv("NERFSLAM_BENCH_SAMPLES_PER_STEP")) o.samples_per_step = std::atoi(sps);
    if (const char* spc = std::getenv("NERFSLAM_BENCH_SAMPLES_PER_CHUNK")) o.samples_per_chunk = std::atoi(spc);
    r.trainer = std::make_unique<nerf::Trainer>(*r.model, r.views, o);
    // Warm-up: past the first grid updates and into the regime of a 60 s run (rays terminate,
    // the grid is sparse). NERFSLAM_BENCH_WARMUP_STEPS overrides the default 200.
    const char* env = std::getenv("NERFSLAM_BENCH_WARMUP_STEPS");
    const int warmup = env ? std::atoi(env) : 200;
    for (int i = 0; i < warmup; ++i) r.trainer->step();
    return r;
  }();
  return s;
}

void BM_TrainStep(benchmark::State& state) {
  auto& s = setup();
  int64_t samples = 0, composited = 0;
  nerf::StageTimes t;
  double scatter = 0, adam = 0, mlp = 0, entries = 0;
  const double cpu0 = processCpuSeconds();
  for (auto _ : state) {
    const auto st = s.trainer->step();
    samples += st.samples;
    composited += st.samples_composited;
    t.march += st.times.march;
    t.field_forward += st.times.field_forward;
    t.composite += st.times.composite;
    t.field_backward += st.times.field_backward;
    t.optimizer += st.times.optimizer;
    t.grid_update += st.times.grid_update;
    const auto& p = s.model->field->lastStepProfile();
    scatter += p.scatter_seconds;
    adam += p.adam_seconds;
    mlp += p.mlp_seconds;
    entries += double(p.entries_updated);
  }
  const double cpu = processCpuSeconds() - cpu0;
  const double n = double(state.iterations());
  state.counters["samples_per_s"] = benchmark::Counter(double(samples), benchmark::Counter::kIsRate);
  state.counters["samples_per_cpu_s"] = double(samples) / cpu;
  state.counters["samples_per_step"] = double(samples) / n;
  state.counters["composited_share"] = samples > 0 ? double(composited) / double(samples) : 0.0;
  state.counters["ms_march"] = 1e3 * t.march / n;
  state.counters["ms_field_fwd"] = 1e3 * t.field_forward / n;
  state.counters["ms_composite"] = 1e3 * t.composite / n;
  state.counters["ms_field_bwd"] = 1e3 * t.field_backward / n;
  state.counters["ms_optimizer"] = 1e3 * t.optimizer / n;
  state.counters["ms_grid"] = 1e3 * t.grid_update / n;
  state.counters["cpu_ms_scatter"] = 1e3 * scatter / n;
  state.counters["cpu_ms_adam"] = 1e3 * adam / n;
  state.counters["cpu_ms_mlp_adam"] = 1e3 * mlp / n;
  state.counters["entries"] = entries / n;
  state.counters["peak_rss_mb"] = peakRssMb();
}
BENCHMARK(BM_TrainStep)->Unit(benchmark::kMillisecond)->Iterations(20)->UseRealTime();

void BM_Render640x480(benchmark::State& state) {
  auto& s = setup();
  const Camera cam = Camera::pinhole(640, 480, 600, 600, 319.5, 239.5);
  const SE3 pose = s.views[0].T_world_cam;
  nerf::RenderOptions ro;
  ro.threads = 2;
  ro.normals = state.range(0) != 0;
  int64_t samples = 0;
  const double cpu0 = processCpuSeconds();
  for (auto _ : state) samples += nerf::renderView(*s.model, cam, pose, ro).samples;
  state.counters["field_samples"] = double(samples) / double(state.iterations());
  state.counters["cpu_ms"] = 1e3 * (processCpuSeconds() - cpu0) / double(state.iterations());
}
BENCHMARK(BM_Render640x480)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->Iterations(3)->UseRealTime();

// The depth triangles of one view (nerf/depth_triangles.h), made anew for every view whenever
// bundle adjustment moves the map: n surface points spread over a 640x480 view at depths 2..20.
// Target: under 1 ms for a keyframe's 500 points, so re-triangulating 100 views costs the NeRF
// thread under 0.1 s per map change.
void BM_TriangulateSurfacePoints(benchmark::State& state) {
  const Camera cam = Camera::pinhole(640, 480, 500, 500, 319.5, 239.5);
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(-1.f, 1.f), z(2.f, 20.f);
  std::vector<nerf::SurfacePoint> pts;
  for (int64_t i = 0; i < state.range(0); ++i) {
    const float d = z(rng);
    pts.push_back({Eigen::Vector3f(0.6f * d * u(rng), 0.45f * d * u(rng), d), 1.f});
  }
  size_t triangles = 0;
  for (auto _ : state) triangles = nerf::triangulateSurfacePoints(pts, cam, SE3()).triangles.size();
  state.counters["triangles"] = double(triangles);
}
BENCHMARK(BM_TriangulateSurfacePoints)->Arg(500)->Arg(2000)->Unit(benchmark::kMicrosecond);

// One occupancy-grid update of a room-sized model (aabb_scale 2: two cascades of 128^3 cells) after
// warm-up: 1/16 of the cells uniformly plus as many occupied ones, 20,000 surface points pinned and
// 20,000 free-space segments carved, as the trainer's updateGrid does every grid_update_interval
// steps. The density is analytic (a sphere shell, free) so the figure is the update's own work
// (picks, sort, decay, max, threshold, carve, pins, bits and their max-pool), not the field's.
// Arg: threads of the density function (the bookkeeping's own threads come from the grid).
void BM_OccupancyUpdate(benchmark::State& state) {
  nerf::OccupancyGrid grid(2);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  nerf::OccupancyGrid::UpdateParams p;
  const int64_t total = int64_t(grid.cascades()) * nerf::OccupancyGrid::kCells;
  p.uniform_cells = total / 16;
  p.occupied_cells = total / 16;
  const Eigen::Vector3f centre(0.5f, 0.5f, 0.5f);
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector3f d = Eigen::Vector3f(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f).normalized();
    const Eigen::Vector3f surf = centre + 0.4f * d;
    p.keep_occupied.push_back(surf);
    p.keep_empty.emplace_back(centre + 0.05f * d, centre + 0.38f * d);
  }
  // A shell of thickness 0.02 around radius 0.4: about 10 % of cascade 0 occupied.
  auto density = [](const float* xyz, int n, float* sigma) {
    for (int k = 0; k < n; ++k) {
      const float dx = xyz[3 * k] - 0.5f, dy = xyz[3 * k + 1] - 0.5f, dz = xyz[3 * k + 2] - 0.5f;
      const float r = std::sqrt(dx * dx + dy * dy + dz * dz);
      sigma[k] = std::abs(r - 0.4f) < 0.04f ? 100.f : 0.f;
    }
  };
  nerf::OccupancyGrid::UpdateParams first = p;
  first.uniform_cells = -1;
  first.sweep_block = 2;
  grid.update(density, first);
  uint64_t seed = 1;
  for (auto _ : state) {
    p.seed = seed++;
    grid.update(density, p);
  }
  state.counters["occupied_percent"] = 100.0 * grid.occupiedFraction();
}
BENCHMARK(BM_OccupancyUpdate)->Unit(benchmark::kMillisecond)->Iterations(20)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
