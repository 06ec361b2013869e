// Rendering a trained NeRF model: 640x480 RGB+depth (and RGB+depth+normals) views from the poses
// of a transforms.json dataset, median wall and CPU time per view, field samples per pixel.
//
//   bench_nerf_render --model out/lego/model.nerf --transforms ../shared/data/lego_train/transforms_train.json
//                     [--views 0,8,16] [--reps 5] [--threads 2] [--size 640x480] [--no-normals-run]
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
  bool normals_run = true;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--model") model_path = next();
    else if (a == "--transforms") transforms = next();
    else if (a == "--views") views_arg = next();
    else if (a == "--reps") reps = std::atoi(next().c_str());
    else if (a == "--threads") threads = std::atoi(next().c_str());
    else if (a == "--size") size = next();
    else if (a == "--no-normals-run") normals_run = false;
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
