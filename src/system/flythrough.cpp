#include "nerfslam/system/flythrough.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <unistd.h>
#include <opencv2/videoio.hpp>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/nerf/renderer.h"

namespace nerfslam {
namespace fs = std::filesystem;

namespace {

constexpr double kFps = 15.0;

// Decodes the whole video: true when it has `frames` frames of `size`.
bool readsBack(const fs::path& file, int frames, cv::Size size) {
  cv::VideoCapture cap(file.string());
  if (!cap.isOpened()) return false;
  int n = 0;
  cv::Mat f;
  while (cap.read(f)) {
    if (f.size() != size) return false;
    ++n;
  }
  return n == frames;
}

// Replaces the folder `to` by `from` (a rename each; `to`'s old contents are removed afterwards).
void replaceFolder(const fs::path& from, const fs::path& to) {
  std::error_code ec;
  const fs::path old = to.parent_path() / fmt::format("{}.old.{}", to.filename().string(), long(::getpid()));
  if (fs::exists(to)) {
    fs::rename(to, old, ec);
    if (ec) fail("{}: could not replace the folder: {}", to.string(), ec.message());
  }
  fs::rename(from, to, ec);
  if (ec) fail("{}: could not rename {} to it: {}", to.string(), from.string(), ec.message());
  fs::remove_all(old, ec);
}

}  // namespace

std::vector<SE3> flythroughPoses(const Trajectory& traj, int frames) {
  std::vector<SE3> out;
  if (traj.empty() || frames <= 0) return out;
  // The parameter: timestamps when they increase over the trajectory, else the index.
  const bool timed = traj.back().timestamp > traj.front().timestamp;
  auto param = [&](size_t i) { return timed ? traj[i].timestamp : double(i); };
  const double t0 = param(0), t1 = param(traj.size() - 1);
  size_t seg = 0;
  for (int k = 0; k < frames; ++k) {
    const double t = frames == 1 ? t0 : t0 + (t1 - t0) * double(k) / double(frames - 1);
    while (seg + 1 < traj.size() - 1 && param(seg + 1) <= t) ++seg;
    if (traj.size() == 1) {
      out.push_back(traj[0].pose);
      continue;
    }
    const double a = param(seg), b = param(seg + 1);
    const double s = b > a ? std::clamp((t - a) / (b - a), 0.0, 1.0) : 0.0;
    out.push_back(SE3::interpolate(traj[seg].pose, traj[seg + 1].pose, s));
  }
  return out;
}

FlythroughResult writeFlythrough(const nerf::NerfModel& model, const Camera& camera, const Trajectory& traj,
                                 const FlythroughOptions& opt, const fs::path& dir) {
  if (opt.frames <= 0 || traj.empty()) fail("{}: a fly-through needs frames > 0 and a trajectory", dir.string());
  if (!(opt.max_seconds >= 0)) fail("{}: the fly-through's time budget must be >= 0", dir.string());
  const auto t_start = std::chrono::steady_clock::now();
  auto seconds = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count(); };
  FlythroughResult res;
  res.frames = res.frames_requested = opt.frames;
  res.fps = kFps;
  res.size = cv::Size(camera.width & ~1, camera.height & ~1);
  nerf::RenderOptions ro;
  ro.threads = opt.threads;
  ro.normals = false;
  ro.background = {0.0, 0.0, 0.0};
  auto renderAt = [&](const SE3& pose) -> cv::Mat {
    const nerf::RenderResult r = nerf::renderView(model, camera, pose, ro);
    return nerf::toBgr8(cv::min(cv::max(r.rgb, 0.0), 1.0))(cv::Rect(cv::Point(0, 0), res.size)).clone();
  };
  // The first frame (the trajectory's first pose, whatever the count) says what the rest will cost.
  const cv::Mat first = renderAt(traj.front().pose);
  const double per_frame = seconds();
  if (opt.max_seconds > 0 && per_frame * opt.frames > opt.max_seconds) {
    res.frames = std::max(2, std::min(opt.frames, int(opt.max_seconds / std::max(per_frame, 1e-9))));
    spdlog::warn("fly-through: {:.2f} s a frame: {} frames instead of {} (time budget {} s)", per_frame, res.frames,
                 opt.frames, opt.max_seconds);
  }
  const std::vector<SE3> poses = flythroughPoses(traj, res.frames);
  auto render = [&](size_t i) { return i == 0 ? first : renderAt(poses[i]); };
  ensureDirectory(dir);
  for (const std::string& codec : opt.codecs) {
    if (codec.size() != 4) fail("{}: codec '{}' is not a FourCC", (dir / "flythrough.mp4").string(), codec);
    AtomicOutput o(dir / "flythrough.mp4");
    cv::VideoWriter w(o.tempPath().string(), cv::VideoWriter::fourcc(codec[0], codec[1], codec[2], codec[3]), kFps,
                      res.size, true);
    if (!w.isOpened()) continue;
    for (size_t i = 0; i < poses.size(); ++i) w.write(render(i));
    w.release();
    if (!readsBack(o.tempPath(), res.frames, res.size)) {
      spdlog::warn("{}: codec '{}' wrote a video that does not read back; trying the next", o.path().string(), codec);
      continue;
    }
    o.commit();
    res.path = o.path();
    res.codec = codec;
    res.seconds = seconds();
    return res;
  }
  // No codec: a PNG sequence, written into a temporary folder renamed at the end.
  const fs::path final_dir = dir / "flythrough";
  const fs::path tmp = dir / fmt::format("flythrough.tmp.{}", long(::getpid()));
  std::error_code ec;
  fs::remove_all(tmp, ec);
  ensureDirectory(tmp);
  try {
    for (size_t i = 0; i < poses.size(); ++i) writeImageAtomic(tmp / fmt::format("{:06d}.png", i), render(i));
  } catch (...) {
    fs::remove_all(tmp, ec);  // a full disk: no half-written sequence left behind
    throw;
  }
  replaceFolder(tmp, final_dir);
  res.path = final_dir;
  res.codec = "png";
  res.seconds = seconds();
  return res;
}

}  // namespace nerfslam
