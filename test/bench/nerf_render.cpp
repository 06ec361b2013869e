// Rendering a trained NeRF model: 640x480 RGB+depth (and RGB+depth+normals) views from the poses
// of a transforms.json dataset, median wall and CPU time per view, field samples per pixel.
//
//   bench_nerf_render --model out/lego/model.nerf --transforms ../shared/data/lego_train/transforms_train.json
//                     [--views 0,8,16] [--reps 5] [--threads 2] [--size 640x480] [--no-normals-run] [--stats]
//
// The camera is the dataset's, rescaled to the requested width (same field of view) with the
// principal point at the image centre, so the scene fills the frame as in the dataset. Without
// --model the benchmark explains what it needs and exits 0 (it is not part of CTest).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <sstream>
#include <string>
#include <vector>

#include "nerfslam/io/dataset.h"
#include "nerfslam/nerf/composite.h"
#include "nerfslam/nerf/raymarch.h"
#include "nerfslam/nerf/renderer.h"

namespace {

using namespace nerfslam;
using Clock = std::chrono::steady_clock;

double processCpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n == 0 ? 0.0 : (n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]));
}

// Where the samples of a view go (one thread, full march per ray, no chunking): per ray, samples
// before the first one with weight >= 1e-3, while T > 0.01 after that, while 0.01 >= T >= 1e-4,
// and the samples a ray would march past its termination.
void sampleStats(const nerf::NerfModel& model, const Camera& cam, const SE3& pose) {
  const nerf::RayGenerator gen(cam, pose, model.scene);
  const nerf::MarchParams mp = nerf::MarchParams::forScene(model.scene, model.grid->cascades());
  std::vector<float> xyz(3 * 4096), q(3 * 4096), t(4096), dt(4096), sigma(4096), geo(4096 * nerf::kDensityOutputs);
  double n_rays = 0, n_hit = 0, s_total = 0, s_before = 0, s_body = 0, s_tail = 0, s_after = 0, s_miss = 0;
  for (int y = 0; y < cam.height; y += 2)
    for (int x = 0; x < cam.width; x += 2) {
      nerf::RayMarcher m(gen.ray(x, y), *model.grid, model.scene, mp, 0.5f);
      const int n = m.next(4096, xyz.data(), t.data(), dt.data());
      n_rays += 1;
      s_total += n;
      if (n == 0) continue;
      model.toFieldCoords(xyz.data(), size_t(n), q.data());
      model.field->queryDensityOutputs(q.data(), size_t(n), sigma.data(), geo.data());
      float T = 1.f;
      bool seen = false;
      int k = 0;
      for (; k < n && T >= nerf::kMinTransmittance; ++k) {
        const float a = 1.f - std::exp(-sigma[size_t(k)] * dt[size_t(k)]);
        const float w = T * a;
        if (w >= 1e-3f) seen = true;
        if (!seen)
          s_before += 1;
        else if (T > 0.01f)
          s_body += 1;
        else
          s_tail += 1;
        T *= 1.f - a;
      }
      s_after += n - k;
      if (1.f - T > 0.5f)
        n_hit += 1;
      else
        s_miss += k;
    }
  std::printf(
      "samples per ray %.2f (rays with opacity > 0.5: %.1f%%): before the first weight >= 1e-3 %.2f, then while "
      "T > 0.01 %.2f, while 0.01 >= T >= 1e-4 %.2f, marched past termination %.2f; on rays with opacity < 0.5 "
      "%.2f\n",
      s_total / n_rays, 100 * n_hit / n_rays, s_before / n_rays, s_body / n_rays, s_tail / n_rays, s_after / n_rays,
      s_miss / n_rays);
}

double loadAverage() {
  double l = 0;
  if (FILE* f = std::fopen("/proc/loadavg", "r")) {
    if (std::fscanf(f, "%lf", &l) != 1) l = 0;
    std::fclose(f);
  }
  return l;
}

}  // namespace

int main(int argc, char** argv) {
  std::string model_path, transforms, views_arg = "0,8,16", size = "640x480";
  int reps = 5, threads = 2;
  bool normals_run = true, stats = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--model")
      model_path = next();
    else if (a == "--transforms")
      transforms = next();
    else if (a == "--views")
      views_arg = next();
    else if (a == "--reps")
      reps = std::atoi(next().c_str());
    else if (a == "--threads")
      threads = std::atoi(next().c_str());
    else if (a == "--size")
      size = next();
    else if (a == "--no-normals-run")
      normals_run = false;
    else if (a == "--stats")
      stats = true;
    else {
      std::fprintf(stderr, "unknown argument %s\n", a.c_str());
      return 2;
    }
  }
  if (model_path.empty() || transforms.empty()) {
    std::printf(
        "bench_nerf_render: give --model FILE (from `nerfslam train`) and --transforms FILE (its dataset, for the "
        "poses)\n");
    return 0;
  }
  int W = 640, H = 480;
  char x = 0;
  std::istringstream ss(size);
  ss >> W >> x >> H;
  const nerf::NerfModel model = nerf::loadModel(model_path);
  auto ds = openDataset("transforms:" + transforms);
  const Camera& dc = ds->camera();
  Camera cam = dc.scaled(double(W) / dc.width);
  cam.width = W;
  cam.height = H;
  cam.cx = (W - 1) / 2.0;
  cam.cy = (H - 1) / 2.0;
  std::vector<size_t> views;
  {
    std::istringstream vs(views_arg);
    std::string tok;
    while (std::getline(vs, tok, ','))
      if (!tok.empty()) views.push_back(size_t(std::stoul(tok)) % ds->size());
  }
  std::printf("model %s, %zu view(s) at %dx%d, %d threads, %d reps, load average %.2f\n", model_path.c_str(),
              views.size(), W, H, threads, reps, loadAverage());
  if (stats) {
    for (size_t v : views) sampleStats(model, cam, *ds->groundTruth(v));
    std::printf("occupancy grid: %.2f%% of cells occupied\n", 100.0 * model.grid->occupiedFraction());
  }
  for (int with_normals = 0; with_normals <= (normals_run ? 1 : 0); ++with_normals) {
    nerf::RenderOptions ro;
    ro.threads = threads;
    ro.normals = with_normals != 0;
    std::vector<double> wall, cpu;
    double samples = 0, hit = 0;
    for (size_t v : views) {
      const SE3 pose = *ds->groundTruth(v);
      for (int r = 0; r < reps; ++r) {
        const double c0 = processCpuSeconds();
        const auto t0 = Clock::now();
        const nerf::RenderResult res = nerf::renderView(model, cam, pose, ro);
        wall.push_back(std::chrono::duration<double>(Clock::now() - t0).count());
        cpu.push_back(processCpuSeconds() - c0);
        if (r == 0) {
          samples += double(res.samples);
          hit += double(cv::countNonZero(res.opacity > 0.5));
        }
      }
    }
    const double px = double(W) * H * double(views.size());
    std::printf(
        "render %dx%d %-18s median wall %8.1f ms  median CPU %8.1f ms  field samples/pixel %6.2f  (per opaque "
        "pixel %6.2f)\n",
        W, H, with_normals ? "RGB+depth+normals" : "RGB+depth", 1e3 * median(wall), 1e3 * median(cpu), samples / px,
        samples / std::max(1.0, hit));
  }
  std::printf("load average after: %.2f\n", loadAverage());
  return 0;
}
