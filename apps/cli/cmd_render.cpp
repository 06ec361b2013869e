// `nerfslam render`: renders a NeRF model from a pose or along a trajectory: RGB, depth (16-bit PNG in
// millimetres of world units and a colourised PNG), normals and uncertainty PNGs per pose.
#include <cmath>
#include <memory>
#include <sstream>
#include <string>

#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>

#include "command.h"
#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/nerf/renderer.h"

namespace nerfslam::cli {
namespace {

struct RenderArgs {
  std::string model, pose, trajectory, size = "640x480", out;
  double fov_deg = 50.0;
  int threads = 2;
};

void writePng(const std::filesystem::path& path, const cv::Mat& img) { writeImageAtomic(path, img); }

SE3 parsePose(const std::string& s) {
  std::istringstream in(s);
  double v[7];
  for (double& x : v)
    if (!(in >> x)) fail("--pose: expected 7 numbers \"tx ty tz qx qy qz qw\", got \"{}\"", s);
  std::string rest;
  if (in >> rest) fail("--pose: expected 7 numbers, got more: \"{}\"", s);
  for (double x : v)
    if (!std::isfinite(x)) fail("--pose: values must be finite: \"{}\"", s);
  const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (std::fabs(q.norm() - 1.0) > 1e-3) fail("--pose: the quaternion must have unit norm (|q| = {})", q.norm());
  return SE3(q, Eigen::Vector3d(v[0], v[1], v[2]));
}

void renderOne(const nerf::NerfModel& model, const Camera& cam, const SE3& pose, const std::filesystem::path& dir,
               const std::string& stem, int threads) {
  nerf::RenderOptions ro;
  ro.threads = threads;
  const auto r = nerf::renderView(model, cam, pose, ro);
  writePng(dir / (stem + "_rgb.png"), nerf::toBgr8(cv::min(cv::max(r.rgb, 0.0), 1.0)));
  cv::Mat mm;
  r.depth.convertTo(mm, CV_16U, 1000.0);  // depth in 1/1000 world units (mm for metric scenes), 0 = none
  writePng(dir / (stem + "_depth.png"), mm);
  double lo = 0, hi = 0;
  cv::minMaxLoc(r.depth, nullptr, &hi);
  cv::Mat valid = r.depth > 0, d8, colour;
  if (cv::countNonZero(valid) > 0) cv::minMaxLoc(r.depth, &lo, nullptr, nullptr, nullptr, valid);
  r.depth.convertTo(d8, CV_8U, hi > lo ? 255.0 / (hi - lo) : 0.0, hi > lo ? -lo * 255.0 / (hi - lo) : 0.0);
  cv::applyColorMap(d8, colour, cv::COLORMAP_TURBO);
  colour.setTo(cv::Scalar::all(0), ~valid);
  writePng(dir / (stem + "_depth_color.png"), colour);
  cv::Mat n8;
  r.normals.convertTo(n8, CV_8U, 127.5, 127.5);  // world-frame normals, (n + 1) / 2
  cv::cvtColor(n8, n8, cv::COLOR_RGB2BGR);
  n8.setTo(cv::Scalar::all(0), ~valid);
  writePng(dir / (stem + "_normals.png"), n8);
  double umax = 0;
  cv::minMaxLoc(r.uncertainty, nullptr, &umax);
  cv::Mat u8;
  r.uncertainty.convertTo(u8, CV_8U, umax > 0 ? 255.0 / umax : 0.0);
  writePng(dir / (stem + "_uncertainty.png"), u8);
}

int runRender(const RenderArgs& a) {
  int w = 0, h = 0;
  char x = 0;
  std::istringstream ss(a.size);
  if (!(ss >> w >> x >> h) || x != 'x' || w <= 0 || h <= 0 || w > 16384 || h > 16384)
    fail("--size: expected WxH (e.g. 640x480), got \"{}\"", a.size);
  if (a.pose.empty() == a.trajectory.empty()) fail("render: give exactly one of --pose and --trajectory");
  std::vector<SE3> poses;
  if (!a.pose.empty()) {
    poses.push_back(parsePose(a.pose));
  } else {
    for (const auto& e : readTrajectory(a.trajectory)) poses.push_back(e.pose);
    if (poses.empty()) fail("{}: the trajectory is empty", a.trajectory);
  }
  const nerf::NerfModel model = nerf::loadModel(a.model);
  const double f = 0.5 * w / std::tan(0.5 * a.fov_deg * M_PI / 180.0);
  const Camera cam = Camera::pinhole(w, h, f, f, (w - 1) / 2.0, (h - 1) / 2.0);
  const std::filesystem::path dir(a.out);
  ensureDirectory(dir);
  for (size_t i = 0; i < poses.size(); ++i) renderOne(model, cam, poses[i], dir, fmt::format("{:06d}", i), a.threads);
  spdlog::info("render: {} view(s) of {}x{} -> {}", poses.size(), w, h, a.out);
  return 0;
}

Registrar reg(
    "render", "Render RGB, depth, normals and uncertainty images from a NeRF model", [](CLI::App& sub) -> Runner {
      auto a = std::make_shared<RenderArgs>();
      sub.add_option("--model", a->model, "model.nerf")->required();
      sub.add_option("--pose", a->pose, "T_world_cam as \"tx ty tz qx qy qz qw\" (OpenCV camera axes)");
      sub.add_option("--trajectory", a->trajectory, "Trajectory file (TUM, KITTI or EuRoC)");
      sub.add_option("--size", a->size, "Image size WxH");
      sub.add_option("--fov", a->fov_deg, "Horizontal field of view in degrees")->check(CLI::Range(1.0, 170.0));
      sub.add_option("--threads", a->threads, "Threads")->check(CLI::Range(1, 256));
      sub.add_option("--out", a->out, "Output directory")->required();
      return [a]() -> int { return runRender(*a); };
    });

}  // namespace
}  // namespace nerfslam::cli
