// Camera model throughput against OpenCV in the same run: project vs cv::projectPoints and
// unproject vs cv::undistortPoints (OpenCV's default 5 fixed-point iterations, and iterated until
// 1e-7 px like ours), per distortion model, 1000 points per call; undistortImage with cached maps.
// Run: build-*/test/bench/bench_camera --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include <opencv2/calib3d.hpp>

#include "nerfslam/core/camera.h"

namespace nerfslam {
namespace {

Camera benchCamera(int model) {
  if (model == 0) return Camera::pinhole(640, 480, 525, 525, 319.5, 239.5);
  if (model == 1) {
    Camera c = Camera::pinhole(640, 480, 517.306408, 516.469215, 318.643040, 255.313989);
    c.distortion_model = DistortionModel::kRadTan;
    c.distortion = {0.262383, -0.953104, -0.005358, 0.002628, 1.163314};
    return c;
  }
  Camera c = Camera::pinhole(848, 800, 286.181, 286.389, 416.938, 403.684);
  c.distortion_model = DistortionModel::kEquidistant;
  c.distortion = {-0.0110425, 0.0489719, -0.0459712, 0.00886949};
  return c;
}

// Pixels in the central 80% of the image and the 3D points they see.
struct Data {
  std::vector<Eigen::Vector2d> px;
  std::vector<Eigen::Vector3d> pts;
  std::vector<cv::Point2d> cv_px;
  std::vector<cv::Point3d> cv_pts;
};

Data makeData(const Camera& c) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(0.1, 0.9), depth(1, 5);
  Data d;
  while (d.px.size() < 1000) {
    const Eigen::Vector2d px(u(rng) * c.width, u(rng) * c.height);
    const Eigen::Vector3d ray = c.unproject(px);
    if (!ray.allFinite()) continue;
    const Eigen::Vector3d p = ray * depth(rng);
    d.px.push_back(px);
    d.pts.push_back(p);
    d.cv_px.emplace_back(px.x(), px.y());
    d.cv_pts.emplace_back(p.x(), p.y(), p.z());
  }
  return d;
}

void setLabel(benchmark::State& state, const Camera& c) {
  state.SetLabel(toString(c.distortion_model));
  state.SetItemsProcessed(state.iterations() * 1000);
}

void BM_Project(benchmark::State& state) {
  const Camera c = benchCamera(static_cast<int>(state.range(0)));
  const Data d = makeData(c);
  for (auto _ : state) {
    double acc = 0;
    for (const auto& p : d.pts) acc += c.project(p).x();
    benchmark::DoNotOptimize(acc);
  }
  setLabel(state, c);
}

void BM_CvProjectPoints(benchmark::State& state) {
  const Camera c = benchCamera(static_cast<int>(state.range(0)));
  const Data d = makeData(c);
  const cv::Mat K = c.cvK(), D = c.cvDist();
  std::vector<cv::Point2d> out;
  for (auto _ : state) {
    if (c.distortion_model == DistortionModel::kEquidistant)
      cv::fisheye::projectPoints(d.cv_pts, out, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D);
    else
      cv::projectPoints(d.cv_pts, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D, out);
    benchmark::DoNotOptimize(out.data());
  }
  setLabel(state, c);
}

void BM_Unproject(benchmark::State& state) {
  const Camera c = benchCamera(static_cast<int>(state.range(0)));
  const Data d = makeData(c);
  for (auto _ : state) {
    double acc = 0;
    for (const auto& p : d.px) acc += c.unproject(p).x();
    benchmark::DoNotOptimize(acc);
  }
  setLabel(state, c);
}

// range(1): 0 = OpenCV defaults, 1 = iterate to 1e-7 px.
void BM_CvUndistortPoints(benchmark::State& state) {
  const Camera c = benchCamera(static_cast<int>(state.range(0)));
  const Data d = makeData(c);
  const cv::Mat K = c.cvK(), D = c.cvDist();
  const bool tight = state.range(1) == 1;
  const cv::TermCriteria crit(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 1000, 1e-7 / c.fx);
  std::vector<cv::Point2d> out;
  for (auto _ : state) {
    if (c.distortion_model == DistortionModel::kEquidistant) {
      if (tight)
        cv::fisheye::undistortPoints(d.cv_px, out, K, D, cv::noArray(), cv::noArray(), crit);
      else
        cv::fisheye::undistortPoints(d.cv_px, out, K, D);
    } else {
      if (tight)
        cv::undistortPoints(d.cv_px, out, K, D, cv::noArray(), cv::noArray(), crit);
      else
        cv::undistortPoints(d.cv_px, out, K, D);
    }
    benchmark::DoNotOptimize(out.data());
  }
  setLabel(state, c);
  state.counters["tight"] = tight ? 1 : 0;
}

void BM_UndistortImage(benchmark::State& state) {
  const Camera c = benchCamera(static_cast<int>(state.range(0)));
  cv::Mat img(c.height, c.width, CV_8UC1);
  cv::randu(img, 0, 255);
  benchmark::DoNotOptimize(c.undistortImage(img).data);  // builds the cached maps
  for (auto _ : state) benchmark::DoNotOptimize(c.undistortImage(img).data);
  state.SetLabel(toString(c.distortion_model) + " " + std::to_string(c.width) + "x" + std::to_string(c.height));
}

BENCHMARK(BM_Project)->Arg(0)->Arg(1)->Arg(2);
BENCHMARK(BM_CvProjectPoints)->Arg(0)->Arg(1)->Arg(2);
BENCHMARK(BM_Unproject)->Arg(1)->Arg(2);
BENCHMARK(BM_CvUndistortPoints)->Args({1, 0})->Args({1, 1})->Args({2, 0})->Args({2, 1});
BENCHMARK(BM_UndistortImage)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace nerfslam

BENCHMARK_MAIN();
