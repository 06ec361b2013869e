// NeRF training throughput on lego (400x400, --downscale 2 equivalent): samples/s of fwd + bwd +
// optimiser on 2 threads, per-stage times, and a 640x480 render of the partly trained model.
//   bench_nerf_train [--benchmark_min_time=...]   (needs the shared data; see test_support.h)
#include <benchmark/benchmark.h>

#include <chrono>
#include <cstdio>

#include "nerfslam/io/dataset.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/nerf/trainer.h"
#include "test_support.h"

namespace {

using namespace nerfslam;

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
    r.trainer = std::make_unique<nerf::Trainer>(*r.model, r.views, o);
    for (int i = 0; i < 40; ++i) r.trainer->step();  // past the first grid updates
    return r;
  }();
  return s;
}

void BM_TrainStep(benchmark::State& state) {
  auto& s = setup();
  int64_t samples = 0;
  nerf::StageTimes t;
  for (auto _ : state) {
    const auto st = s.trainer->step();
    samples += st.samples;
    t.march += st.times.march;
    t.field_forward += st.times.field_forward;
    t.composite += st.times.composite;
    t.field_backward += st.times.field_backward;
    t.optimizer += st.times.optimizer;
    t.grid_update += st.times.grid_update;
  }
  const double n = double(state.iterations());
  state.counters["samples_per_s"] = benchmark::Counter(double(samples), benchmark::Counter::kIsRate);
  state.counters["ms_march"] = 1e3 * t.march / n;
  state.counters["ms_field_fwd"] = 1e3 * t.field_forward / n;
  state.counters["ms_composite"] = 1e3 * t.composite / n;
  state.counters["ms_field_bwd"] = 1e3 * t.field_backward / n;
  state.counters["ms_optimizer"] = 1e3 * t.optimizer / n;
  state.counters["ms_grid"] = 1e3 * t.grid_update / n;
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
  for (auto _ : state) samples += nerf::renderView(*s.model, cam, pose, ro).samples;
  state.counters["field_samples"] = double(samples) / double(state.iterations());
}
BENCHMARK(BM_Render640x480)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->Iterations(3)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
