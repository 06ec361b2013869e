// `nerfslam synth`: render a ground-truth synthetic sequence (TUM RGB-D layout + transforms.json).
#include <memory>
#include <sstream>

#include <spdlog/spdlog.h>
#include <opencv2/videoio.hpp>

#include "command.h"
#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/parse.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/synth.h"

namespace {

// --odometry-from: the odometry of a dataset's ground-truth camera poses (every frame needs one).
void writeOdometryFrom(const std::string& spec, const nerfslam::SynthOptions& o, const std::filesystem::path& out) {
  o.odometry.validate();
  const auto ds = nerfslam::openDataset(spec, nerfslam::DatasetOptions{});
  if (!ds->hasGroundTruth()) nerfslam::fail("--odometry-from {}: the dataset has no ground truth", spec);
  std::vector<nerfslam::SE3> poses;
  nerfslam::Trajectory odo;
  for (std::size_t i = 0; i < ds->size(); ++i) {
    const auto gt = ds->groundTruth(i);
    if (!gt) nerfslam::fail("--odometry-from {}: frame {} has no ground-truth pose", spec, i);
    poses.push_back(*gt);
  }
  // The frame rate of the dataset's stamps (slip episodes are in seconds).
  const double span = ds->size() > 1 ? ds->timestamp(ds->size() - 1) - ds->timestamp(0) : 0.0;
  const double fps = span > 0 ? (ds->size() - 1) / span : o.fps;
  const auto T = nerfslam::synthOdometry(poses, o.odometry, o.seed, fps);
  for (std::size_t i = 0; i < T.size(); ++i) odo.push_back(nerfslam::TrajectoryEntry{ds->timestamp(i), T[i]});
  nerfslam::ensureDirectory(out);
  nerfslam::writeTumTrajectory(out / "odometry.txt", odo);
  spdlog::info("synth: wrote {} odometry samples of {} to {} (noise {}, rotation noise {}, bias {}, slip {})",
               odo.size(), spec, (out / "odometry.txt").string(), o.odometry.noise, o.odometry.rot_noise,
               o.odometry.bias, o.odometry.slip);
}

// --video: the colour frames, in order, as OUT/rgb.mkv (FFV1, lossless) or, without that codec,
// OUT/rgb.avi (HuffYUV, lossless; else MJPG, lossy), at the sequence's frame rate.
void writeSequenceVideo(const std::filesystem::path& out, double fps) {
  const auto ds = nerfslam::openDataset("tum", out, nerfslam::DatasetOptions{});
  const cv::Size size(ds->camera().width, ds->camera().height);
  for (const auto& [fourcc, name] :
       {std::pair{"FFV1", "rgb.mkv"}, std::pair{"HFYU", "rgb.avi"}, std::pair{"MJPG", "rgb.avi"}}) {
    nerfslam::AtomicOutput o(out / name);
    cv::VideoWriter w(o.tempPath().string(), cv::CAP_FFMPEG,
                      cv::VideoWriter::fourcc(fourcc[0], fourcc[1], fourcc[2], fourcc[3]), fps, size);
    if (!w.isOpened()) continue;
    for (std::size_t i = 0; i < ds->size(); ++i) w.write(ds->load(i, nerfslam::ImageMode::kColor).image);
    w.release();
    o.commit();
    spdlog::info("synth: wrote {} ({}, {} frames at {} frames/s{})", o.path().string(), fourcc, ds->size(), fps,
                 std::string(fourcc) == "MJPG" ? ", lossy: no lossless codec here" : ", lossless");
    return;
  }
  nerfslam::fail("{}: OpenCV here has no video codec to write the sequence with (tried FFV1, HuffYUV, MJPG)",
                 out.string());
}

struct SynthArgs {
  nerfslam::SynthOptions opts;
  std::string size;
  std::string distortion;
  std::string out;
  int64_t seed = 1;
  bool no_odometry = false;
  std::string odometry_from;
  bool video = false;
};

nerfslam::cli::Registrar reg(
    "synth", "Render a ground-truth synthetic RGB-D sequence (TUM layout, camera.yaml, transforms.json)",
    [](CLI::App& sub) -> nerfslam::cli::Runner {
      auto a = std::make_shared<SynthArgs>();
      auto& o = a->opts;
      o.trajectory = "";
      sub.add_option("--scene", o.scene, "Scene: room, turntable, plane, corridor")->capture_default_str();
      sub.add_option("--trajectory", o.trajectory,
                     "Trajectory: handheld, orbit, forward, rotation, fast, loop (default: the scene's)");
      sub.add_option("--frames", o.frames, "Number of frames")->capture_default_str();
      sub.add_option("--laps", o.laps,
                     "Laps of the loop trajectory over the frames, all identical (frames - 1 must be a "
                     "multiple of it)")
          ->capture_default_str();
      sub.add_option("--fps", o.fps, "Frame rate")->capture_default_str();
      sub.add_option("--size", a->size, "Image size WxH (default 640x480; intrinsics scale with it)");
      sub.add_option("--camera", o.camera_yaml, "Camera YAML (our format or ROS camera_info) instead of --size");
      sub.add_option("--seed", a->seed, "Random seed (textures, trajectory, noise)")->capture_default_str();
      sub.add_option("--distortion", a->distortion, "Radial-tangential distortion k1,k2,p1,p2");
      sub.add_flag("--blur", o.motion_blur, "Motion blur (average of sub-frame renders)");
      sub.add_option("--blur-samples", o.blur_samples, "Sub-frame renders per blurred frame")->capture_default_str();
      sub.add_option("--noise", o.noise_sigma, "Gaussian sensor noise sigma in gray levels (0: off)");
      sub.add_option("--shot-noise", o.shot_noise, "Shot-noise variance per gray level (0: off)");
      sub.add_flag("--exposure", o.exposure_change, "Smooth exposure (gain) changes");
      sub.add_option("--textures", o.textures, "auto (photos when the shared data is found), procedural or photo")
          ->capture_default_str();
      sub.add_option("--texture-filter", o.texture_filter,
                     "trilinear, or mip-nearest (bilinear in the nearest mipmap level: 0.7x the render CPU, less "
                     "accurate SLAM)")
          ->check(CLI::IsMember({"trilinear", "mip-nearest"}))
          ->capture_default_str();
      auto& od = o.odometry;
      sub.add_option("--odometry-noise", od.noise,
                     "odometry.txt: RMS of each frame step's translation error, fraction of the step (0: exact)")
          ->capture_default_str();
      sub.add_option("--odometry-rot-noise", od.rot_noise,
                     "odometry.txt: RMS of each frame step's rotation error, fraction of the step's angle")
          ->capture_default_str();
      sub.add_option("--odometry-bias", od.bias, "odometry.txt: scale error of every translation (0.01: 1 % more)")
          ->capture_default_str();
      sub.add_option("--odometry-slip", od.slip,
                     "odometry.txt: fraction of the frame steps that slip, in episodes of --odometry-slip-seconds")
          ->capture_default_str();
      sub.add_option("--odometry-slip-seconds", od.slip_seconds, "odometry.txt: length of a slip episode")
          ->capture_default_str();
      sub.add_option("--odometry-slip-gain", od.slip_gain,
                     "odometry.txt: a slipping step reports (1 + gain) x its translation")
          ->capture_default_str();
      sub.add_flag("--no-odometry", a->no_odometry, "Write no odometry.txt");
      sub.add_option("--odometry-from", a->odometry_from,
                     "[kind:]PATH of a dataset with ground truth: write only OUT/odometry.txt, simulated from its "
                     "camera poses (the --odometry-* flags apply), rendering nothing");
      sub.add_flag("--video", a->video,
                   "Also write the colour frames as a video: rgb.mkv (FFV1, lossless), else rgb.avi (HuffYUV; MJPG, "
                   "lossy, when neither is available)");
      sub.add_option("--out", a->out, "Output folder")->required();
      return [a]() -> int {
        auto& o = a->opts;
        if (a->seed < 0) nerfslam::fail("--seed must be >= 0 (got {})", a->seed);
        o.seed = static_cast<uint64_t>(a->seed);
        if (a->no_odometry) o.odometry.enabled = false;
        if (!a->odometry_from.empty()) {
          if (a->no_odometry) nerfslam::fail("--odometry-from writes odometry: not with --no-odometry");
          writeOdometryFrom(a->odometry_from, o, a->out);
          return 0;
        }
        if (!a->size.empty()) {
          if (!o.camera_yaml.empty()) nerfslam::fail("give either --size or --camera, not both");
          nerfslam::parseImageSize(a->size, "--size", 1, &o.width, &o.height);
        }
        if (!a->distortion.empty()) {
          o.distortion = nerfslam::parseNumberList(a->distortion, "--distortion");
          if (o.distortion.size() != 4) nerfslam::fail("--distortion '{}': need 4 numbers k1,k2,p1,p2", a->distortion);
        }
        const auto r = nerfslam::writeSynthSequence(o, a->out);
        if (a->video) writeSequenceVideo(a->out, o.fps);
        spdlog::info("synth: wrote {} frames to {} in {:.1f} s ({:.1f} frames/s); camera {}", r.frames, a->out,
                     r.seconds, r.frames / std::max(1e-9, r.seconds), r.camera.describe());
        return 0;
      };
    });

}  // namespace
