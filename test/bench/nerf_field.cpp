// Radiance-field kernels, per SIMD target: peak FMA throughput (measured here), hash encoding
// forward/backward, MLP forward/backward, optimiser step, and the end-to-end training step on
// 1 and 2 threads (paper configuration: L=16, T=2^19, N_max=2048, 64-wide MLPs).
//
// Counters: samples/s, GFLOP/s and %peak (against the same target's FMA loop, times the threads
// used), GB/s of table bytes gathered/scattered (128 corners x 8 bytes per sample).
// Run: build-*/test/bench/bench_nerf_field --benchmark_repetitions=5
//      --benchmark_report_aggregates_only=true   (medians are the figures to report)
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <map>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "nerfslam/core/timing.h"
#include "nerfslam/nerf/field.h"
#include "nerfslam/nerf/hash_grid.h"
#include "nerfslam/nerf/mlp.h"
#include "nerfslam/nerf/simd.h"

namespace nerfslam::nerf {
namespace {

// Multiply-adds per sample of the paper network (hidden 64, outputs padded to 16).
constexpr double kFwdFlops = 2.0 * (32 * 64 + 64 * 16 + 32 * 64 + 64 * 64 + 64 * 16);
// Backward: weight gradients (same as forward) + data gradients (c2, c1, c0 density half, d1, d0).
constexpr double kBwdFlops = kFwdFlops + 2.0 * (16 * 64 + 64 * 64 + 64 * 16 + 16 * 64 + 64 * 32);
constexpr double kGatherBytes = 16 * 8 * 8;  // levels x corners x (2 floats)

std::map<std::string, double> g_peak;

double processCpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

double threadCpuSeconds() { return 1e-3 * threadCpuMs(); }  // GFLOP/s of one core per target

// Samples along rays (ray order, as the trainer produces them) through random origins and
// directions of the unit cube, `dt` apart: 0.01 (sparse, pessimistic: no reuse on the fine levels)
// or sqrt(3)/1024 (instant-ngp's smallest march step, aabb_scale 1).
struct Samples {
  std::vector<float> pos, dir;
};
Samples raySamples(size_t n, uint32_t seed, size_t per_ray = 64, float dt = 0.01f) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::normal_distribution<float> g;
  Samples s;
  s.pos.resize(3 * n);
  s.dir.resize(3 * n);
  float o[3] = {}, d[3] = {};
  for (size_t i = 0; i < n; ++i) {
    if (i % per_ray == 0) {
      float r = 0;
      for (int k = 0; k < 3; ++k) {
        o[k] = u(rng);
        d[k] = g(rng);
        r += d[k] * d[k];
      }
      for (int k = 0; k < 3; ++k) d[k] /= std::sqrt(r);
    }
    const float t = dt * float(i % per_ray);
    for (int k = 0; k < 3; ++k) {
      float x = o[k] + t * d[k];
      x = x - std::floor(x);  // wrap into the cube
      s.pos[3 * i + size_t(k)] = x;
      s.dir[3 * i + size_t(k)] = d[k];
    }
  }
  return s;
}

RadianceField& paperField() {
  static RadianceField f(FieldConfig(), 1);
  return f;
}

struct TargetScope {
  explicit TargetScope(int64_t t) { hwy::SetSupportedTargetsForTest(t); }
  ~TargetScope() { hwy::SetSupportedTargetsForTest(0); }
};

void setFlops(benchmark::State& st, double samples, double flops_per_sample, const std::string& target,
              int threads = 1) {
  st.counters["samples/s"] = benchmark::Counter(samples, benchmark::Counter::kIsRate);
  st.counters["GFLOP/s"] = benchmark::Counter(samples * flops_per_sample * 1e-9, benchmark::Counter::kIsRate);
  // %peak is derived after the run from GFLOP/s; store the peak for reference.
  st.counters["peak_GFLOP/s"] = g_peak[target] * threads;
}

// A hash table of 2^log2_t entries per level (19: the paper's 64 MiB; 14: 1.3 MiB, cache-resident).
struct Table {
  std::vector<GridLevel> levels;
  HugeVector<float> data;
  explicit Table(int log2_t) : levels(gridLevels(16, 16, 2048.0, log2_t)) {
    data.resize(2 * size_t(levels.back().offset + levels.back().size));
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(-1e-4f, 1e-4f);
    for (float& x : data) x = u(rng);
  }
  HashGridView view() const { return {levels.data(), int(levels.size()), data.data()}; }
};

void BM_EncodeForward(benchmark::State& st, int64_t target) {
  TargetScope ts(target);
  const Table tab(int(st.range(0)));
  const HashGridView grid = tab.view();
  const size_t n = 1 << 14;
  const Samples s = raySamples(n, 1);
  std::vector<float> enc(32 * n);
  for (auto _ : st) {
    hashEncode(grid, s.pos.data(), n, enc.data(), n);
    benchmark::DoNotOptimize(enc.data());
  }
  st.counters["samples/s"] =
      benchmark::Counter(double(n), benchmark::Counter::kIsRate | benchmark::Counter::kIsIterationInvariant);
  st.counters["GB/s"] = benchmark::Counter(double(n) * kGatherBytes * 1e-9,
                                           benchmark::Counter::kIsRate | benchmark::Counter::kIsIterationInvariant);
}

void BM_EncodeBackward(benchmark::State& st, int64_t target) {
  TargetScope ts(target);
  const Table tab(int(st.range(0)));
  const HashGridView grid = tab.view();
  const size_t n = 1 << 14;
  const Samples s = raySamples(n, 2);
  std::vector<float> d_enc(32 * n, 1e-3f);
  HugeVector<float> grad(tab.data.size(), 0.f);
  std::vector<uint64_t> touched(tab.data.size() / 128 + 1, 0);
  for (auto _ : st) {
    hashEncodeBackward(grid, s.pos.data(), n, d_enc.data(), grad.data(), touched.data());
    benchmark::ClobberMemory();
  }
  st.counters["samples/s"] =
      benchmark::Counter(double(n), benchmark::Counter::kIsRate | benchmark::Counter::kIsIterationInvariant);
  st.counters["GB/s"] = benchmark::Counter(double(n) * kGatherBytes * 1e-9,
                                           benchmark::Counter::kIsRate | benchmark::Counter::kIsIterationInvariant);
}

// The MLP layers of one 64-sample tile, as the field runs them.
struct MlpTile {
  static constexpr size_t T = 64;
  std::vector<float> enc, h1, cin, c1, c2, logit, w_d0, w_d1, w_c0, w_c1, w_c2, t_d0, t_d1, t_c0, t_c1, t_c2, dlog, dc2,
      dc1, dd, dh1, denc, g_d0, g_d1, g_c0, g_c1, g_c2;
  MlpTile() {
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(-0.3f, 0.3f);
    auto r = [&](size_t n) {
      std::vector<float> v(n);
      for (float& x : v) x = u(rng);
      return v;
    };
    enc = r(32 * T), h1 = r(T * 64), cin = r(T * 32), c1 = r(T * 64), c2 = r(T * 64), logit = r(T * 16);
    w_d0 = r(32 * 64), w_d1 = r(64 * 16), w_c0 = r(32 * 64), w_c1 = r(64 * 64), w_c2 = r(64 * 16);
    t_d0 = r(64 * 32), t_d1 = r(16 * 64), t_c0 = r(64 * 32), t_c1 = r(64 * 64), t_c2 = r(16 * 64);
    dlog = r(T * 16), dc2 = r(T * 64), dc1 = r(T * 64), dd = r(T * 16), dh1 = r(T * 64), denc = r(T * 32);
    g_d0 = r(32 * 64), g_d1 = r(64 * 16), g_c0 = r(32 * 64), g_c1 = r(64 * 64), g_c2 = r(64 * 16);
  }
  static GemmArgs mm(size_t M, size_t N, size_t K, const float* a, size_t ams, size_t aks, const float* b, size_t ldb,
                     float* c, size_t ldc, Epilogue e = Epilogue::kNone, const float* mask = nullptr,
                     bool acc = false) {
    GemmArgs g;
    g.M = M, g.N = N, g.K = K, g.a = a, g.a_ms = ams, g.a_ks = aks, g.b = b, g.ldb = ldb, g.c = c, g.ldc = ldc,
    g.epilogue = e, g.mask = mask, g.ldm = N, g.accumulate = acc;
    return g;
  }
  void forward() {
    gemm(mm(T, 64, 32, enc.data(), 1, T, w_d0.data(), 64, h1.data(), 64, Epilogue::kRelu));
    gemm(mm(T, 16, 64, h1.data(), 64, 1, w_d1.data(), 16, cin.data() + 16, 32));
    gemm(mm(T, 64, 32, cin.data(), 32, 1, w_c0.data(), 64, c1.data(), 64, Epilogue::kRelu));
    gemm(mm(T, 64, 64, c1.data(), 64, 1, w_c1.data(), 64, c2.data(), 64, Epilogue::kRelu));
    gemm(mm(T, 16, 64, c2.data(), 64, 1, w_c2.data(), 16, logit.data(), 16));
  }
  void backward() {
    gemm(mm(64, 16, T, c2.data(), 1, 64, dlog.data(), 16, g_c2.data(), 16, Epilogue::kNone, nullptr, true));
    gemm(mm(T, 64, 16, dlog.data(), 16, 1, t_c2.data(), 64, dc2.data(), 64, Epilogue::kReluMask, c2.data()));
    gemm(mm(64, 64, T, c1.data(), 1, 64, dc2.data(), 64, g_c1.data(), 64, Epilogue::kNone, nullptr, true));
    gemm(mm(T, 64, 64, dc2.data(), 64, 1, t_c1.data(), 64, dc1.data(), 64, Epilogue::kReluMask, c1.data()));
    gemm(mm(32, 64, T, cin.data(), 1, 32, dc1.data(), 64, g_c0.data(), 64, Epilogue::kNone, nullptr, true));
    gemm(mm(T, 16, 64, dc1.data(), 64, 1, t_c0.data() + 16, 32, dd.data(), 16));
    gemm(mm(64, 16, T, h1.data(), 1, 64, dd.data(), 16, g_d1.data(), 16, Epilogue::kNone, nullptr, true));
    gemm(mm(T, 64, 16, dd.data(), 16, 1, t_d1.data(), 64, dh1.data(), 64, Epilogue::kReluMask, h1.data()));
    gemm(mm(32, 64, T, enc.data(), T, 1, dh1.data(), 64, g_d0.data(), 64, Epilogue::kNone, nullptr, true));
    gemm(mm(T, 32, 64, dh1.data(), 64, 1, t_d0.data(), 32, denc.data(), 32));
  }
};

void BM_MlpForward(benchmark::State& st, int64_t target) {
  TargetScope ts(target);
  MlpTile t;
  for (auto _ : st) {
    t.forward();
    benchmark::ClobberMemory();
  }
  setFlops(st, double(st.iterations() * MlpTile::T), kFwdFlops, hwy::TargetName(target));
}

void BM_MlpBackward(benchmark::State& st, int64_t target) {
  TargetScope ts(target);
  MlpTile t;
  for (auto _ : st) {
    t.backward();
    benchmark::ClobberMemory();
  }
  setFlops(st, double(st.iterations() * MlpTile::T), kBwdFlops, hwy::TargetName(target));
}

// Optimiser step after a backward pass over n ray-ordered samples (touching ~what a training
// step of n samples touches).
void BM_OptimizerStep(benchmark::State& st, int64_t target) {
  TargetScope ts(target);
  RadianceField& f = paperField();
  const size_t n = size_t(st.range(0));
  const int threads = int(st.range(1));
  const Samples s = raySamples(n, 4);
  auto ws = f.makeWorkspace();
  auto gs = f.makeGradients();
  std::vector<float> sigma(n), rgb(3 * n), ds(n, 1e-3f), dc(3 * n, 1e-3f);
  size_t touched = 0;
  for (auto _ : st) {
    st.PauseTiming();
    f.forward(ws, s.pos.data(), s.dir.data(), n, sigma.data(), rgb.data());
    f.backward(ws, ds.data(), dc.data(), gs);
    if (touched == 0) {
      const FloatArray g = f.gradients(gs)[0];
      for (size_t i = 0; i < g.size; i += 2) touched += (g.data[i] != 0.f || g.data[i + 1] != 0.f);
    }
    st.ResumeTiming();
    f.step({&gs}, 1e-4f, threads);
  }
  st.counters["entries"] = double(touched);
  st.counters["samples/s"] =
      benchmark::Counter(double(n), benchmark::Counter::kIsRate | benchmark::Counter::kIsIterationInvariant);
}

// End to end: `threads` workers each forward+backward their share of n samples, then step().
void BM_TrainStep(benchmark::State& st, int64_t target) {
  TargetScope ts(target);
  RadianceField& f = paperField();
  const size_t n = size_t(st.range(0));
  const int threads = int(st.range(1));
  const float dt = st.range(2) == 0 ? 0.01f : std::sqrt(3.f) / 1024.f;
  const Samples s = raySamples(n, 5, 64, dt);
  std::vector<RadianceField::Workspace> ws;
  std::vector<RadianceField::Gradients> gs;
  std::vector<RadianceField::Gradients*> gp;
  for (int t = 0; t < threads; ++t) {
    ws.push_back(f.makeWorkspace());
    gs.push_back(f.makeGradients());
  }
  for (auto& g : gs) gp.push_back(&g);
  std::vector<float> sigma(n), rgb(3 * n), ds(n), dc(3 * n);
  for (size_t i = 0; i < n; ++i) ds[i] = 1e-4f * float(i % 7);
  for (size_t i = 0; i < 3 * n; ++i) dc[i] = 1e-3f * (float(i % 5) - 2.f);
  auto work = [&](int t) {
    const size_t s0 = n * size_t(t) / size_t(threads), s1 = n * size_t(t + 1) / size_t(threads);
    const size_t m = s1 - s0;
    f.forward(ws[size_t(t)], &s.pos[3 * s0], &s.dir[3 * s0], m, &sigma[s0], &rgb[3 * s0]);
    f.backward(ws[size_t(t)], &ds[s0], &dc[3 * s0], gs[size_t(t)]);
  };
  const double cpu0 = processCpuSeconds();
  for (auto _ : st) {
    std::vector<std::thread> pool;
    for (int t = 1; t < threads; ++t) pool.emplace_back(work, t);
    work(0);
    for (auto& th : pool) th.join();
    f.step(gp, 1e-4f, threads);
  }
  // Samples per second of CPU time summed over all threads: the throughput per core, which is
  // what the 2-core machine delivers per core when it is not shared (wall time here is not).
  st.counters["samples/cpu_s"] = double(st.iterations()) * double(n) / (processCpuSeconds() - cpu0);
  setFlops(st, double(st.iterations()) * double(n), kFwdFlops + kBwdFlops, hwy::TargetName(target), threads);
}

}  // namespace
}  // namespace nerfslam::nerf

int main(int argc, char** argv) {
  using namespace nerfslam::nerf;
  benchmark::Initialize(&argc, argv);
  // Measure each target's single-core FMA peak first (median of 5 runs of ~0.1 s).
  for (int64_t t : availableSimdTargets()) {
    TargetScope ts(t);
    std::vector<double> r;
    for (int rep = 0; rep < 5; ++rep) {
      // Thread CPU time, like the kernels' counters: the machine is shared, wall time is not ours.
      const double t0 = threadCpuSeconds();
      const double flops = fmaPeakLoop(uint64_t(20) << 20);
      const double sec = threadCpuSeconds() - t0;
      r.push_back(flops / sec * 1e-9);
    }
    std::sort(r.begin(), r.end());
    g_peak[hwy::TargetName(t)] = r[2];
    std::printf("FMA peak %-8s %8.1f GFLOP/s per core (median of 5)\n", hwy::TargetName(t), r[2]);
  }
  for (int64_t t : availableSimdTargets()) {
    const std::string name = hwy::TargetName(t);
    benchmark::RegisterBenchmark(("EncodeForward/" + name).c_str(), BM_EncodeForward, t)->Arg(19)->Arg(14);
    benchmark::RegisterBenchmark(("EncodeBackward/" + name).c_str(), BM_EncodeBackward, t)->Arg(19)->Arg(14);
    benchmark::RegisterBenchmark(("MlpForward/" + name).c_str(), BM_MlpForward, t);
    benchmark::RegisterBenchmark(("MlpBackward/" + name).c_str(), BM_MlpBackward, t);
  }
  const int64_t best = availableSimdTargets().front();
  const std::string bn = hwy::TargetName(best);
  benchmark::RegisterBenchmark(("OptimizerStep/" + bn).c_str(), BM_OptimizerStep, best)
      ->Args({1 << 16, 1})
      ->Args({1 << 16, 2})
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
  for (int64_t t : availableSimdTargets()) {
    const std::string name = hwy::TargetName(t);
    if (t != best && name != "AVX2" && name != "SSE4") continue;
    // Args: samples per step, threads, sample spacing (0: 1 cm, 1: sqrt(3)/1024).
    benchmark::RegisterBenchmark(("TrainStep/" + name).c_str(), BM_TrainStep, t)
        ->Args({1 << 16, 1, 0})
        ->Args({1 << 16, 2, 0})
        ->Args({1 << 16, 1, 1})
        ->Args({1 << 16, 2, 1})
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
  }
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
