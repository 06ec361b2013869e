// Local bundle adjustment cost: a 10-keyframe window (plus 10 fixed anchor keyframes) over N points,
// 1 px noise and 5% outliers, default BundleAdjustmentOptions (what the mapping thread runs per
// keyframe). Target: <= 100 ms per keyframe for the 10-keyframe window. Accuracy counters against the
// noise-free truth: cam_err_mm (mean centre error of the 10 free cameras, the 10 fixed ones fix the
// gauge) and pt_err_mm (median point error), so a faster setting can be checked for what it costs.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <random>

#include "nerfslam/mapping/bundle_adjustment.h"

namespace nerfslam {
namespace {

// The window before the perturbation of the free cameras and the points.
BaProblem makeWindow(int n_points, uint32_t seed, BaProblem* truth) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0, 1);
  std::uniform_real_distribution<double> u(-1, 1);
  BaProblem p;
  p.fx = p.fy = 700;
  p.cx = 600;
  p.cy = 180;
  // 20 cameras driving forward along z, the first 10 fixed (anchors), the last 10 free.
  for (int i = 0; i < 20; ++i)
    p.cameras.push_back({SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 0.05 * i)), i < 10});
  for (int j = 0; j < n_points; ++j)
    p.points.push_back({Eigen::Vector3d(3 * u(rng), 0.8 * u(rng), 3 + 2 * (u(rng) + 1)), false});
  for (int i = 0; i < 20; ++i)
    for (int j = 0; j < n_points; ++j) {
      if ((i + j) % 3 == 0) continue;  // not every camera sees every point
      const Eigen::Vector3d pc = p.cameras[i].T_world_cam.inverse() * p.points[j].position;
      Eigen::Vector2d uv(p.fx * pc.x() / pc.z() + p.cx, p.fy * pc.y() / pc.z() + p.cy);
      uv += (u(rng) > 0.9 ? 20.0 : 1.0) * Eigen::Vector2d(g(rng), g(rng));
      p.observations.push_back({i, j, uv, 1.0});
    }
  *truth = p;
  for (int i = 10; i < 20; ++i) {
    Vector6d xi;
    for (int k = 0; k < 6; ++k) xi(k) = 0.003 * g(rng);
    p.cameras[i].T_world_cam = p.cameras[i].T_world_cam * SE3::exp(xi);
  }
  for (auto& pt : p.points) pt.position += 0.02 * Eigen::Vector3d(g(rng), g(rng), g(rng));
  return p;
}

void BM_LocalBa10Keyframes(benchmark::State& state) {
  BaProblem truth;
  const BaProblem base = makeWindow(static_cast<int>(state.range(0)), 1, &truth);
  double rmse = 0, cam_err = 0, pt_err = 0;
  int iterations = 0;
  for (auto _ : state) {
    BaProblem p = base;
    const BaResult r = bundleAdjust(p, {});
    state.PauseTiming();
    rmse = r.final_rmse_px;
    iterations = r.iterations;
    cam_err = 0;
    for (int i = 10; i < 20; ++i)
      cam_err += (p.cameras[i].T_world_cam.translation() - truth.cameras[i].T_world_cam.translation()).norm() / 10;
    std::vector<double> e;
    for (size_t j = 0; j < p.points.size(); ++j) e.push_back((p.points[j].position - truth.points[j].position).norm());
    std::nth_element(e.begin(), e.begin() + static_cast<long>(e.size() / 2), e.end());
    pt_err = e[e.size() / 2];
    state.ResumeTiming();
    benchmark::DoNotOptimize(r);
  }
  state.counters["points"] = static_cast<double>(state.range(0));
  state.counters["observations"] = static_cast<double>(base.observations.size());
  state.counters["final_rmse_px"] = rmse;
  state.counters["iterations"] = iterations;
  state.counters["cam_err_mm"] = 1000 * cam_err;
  state.counters["pt_err_mm"] = 1000 * pt_err;
}
BENCHMARK(BM_LocalBa10Keyframes)
    ->Arg(500)
    ->Arg(1000)
    ->Arg(2000)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Repetitions(3)
    ->ReportAggregatesOnly(true);

}  // namespace
}  // namespace nerfslam

BENCHMARK_MAIN();
