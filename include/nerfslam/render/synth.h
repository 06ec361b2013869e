#pragma once
// Ground-truth synthetic sequences: render a scene along a trajectory and write the TUM RGB-D
// layout plus everything our readers and the NeRF need.
//
// Output folder:
//   rgb/<t>.png, depth/<t>.png   t = i / fps with 6 decimals; depth 16-bit, metres x 5000, 0 = none
//                                (nothing drawn, or farther than 13.1 m)
//   rgb.txt, depth.txt           "timestamp filename" (TUM)
//   groundtruth.txt              "timestamp tx ty tz qx qy qz qw", T_world_cam, OpenCV optical axes
//   camera.yaml                  the output camera (saveCameraYaml), including any distortion
//   odometry.txt                 "timestamp tx ty tz qx qy qz qw", T_odom_base: simulated wheel odometry
//                                of a base frame rigidly under the camera (T_base_cam, SynthOdometry),
//                                odom = the base at frame 0; exact when its noise, bias and slip are 0
//   transforms.json              instant-ngp: fl_x fl_y cx cy (pixel corners at 0, i.e. OpenCV cx +
//                                0.5) w h k1 k2 p1 p2, aabb_scale, scale, offset, and per frame
//                                file_path, depth_path and transform_matrix = T_world_cam * diag(1,-1,-1,1)
//                                (OpenGL axes); integer_depth_scale = 1/5000 (metres per unit)
// Images are encoded on a worker thread (bounded queue). The index files are rewritten atomically
// every `index_every` frames and at the end, and only ever list frames whose two PNGs are complete.
//
// Image formation, each part switchable:
//   distortion  radial-tangential k1 k2 p1 p2 applied in post: an ideal pinhole image covering all
//               undistorted rays is rendered (wider when needed) and resampled bilinearly. Depth is
//               given on the same distorted pixel grid (the z of the ideal render's nearest pixel
//               to each distorted pixel's ray, so exact up to half an ideal pixel of ray offset).
//   motion blur average of `blur_samples` renders spread over `shutter` x frame interval, centred
//               on the frame time; pose and depth are those at the frame time.
//   exposure    smooth gain changes (0.7x..1.3x, deterministic from the seed).
//   noise       Gaussian read noise (sigma gray levels) + shot noise (variance shot_noise x I).
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/render/renderer.h"
#include "nerfslam/render/scene.h"
#include "nerfslam/render/trajectory.h"

namespace nerfslam {

// Simulated wheel odometry (odometry.txt). The base is rigidly attached to the camera by T_base_cam
// (the camera's pose in the base frame: base x forward, y left, z up; by default the camera looks
// along the base's x axis, 0.5 m above and 0.1 m ahead of its origin). Each frame-to-frame motion of
// the base (t, R) is reported as
//   t' = (1 + bias) (slip ? 1 + slip_gain : 1) t + noise |t| n,   R' = R exp(rot_noise angle(R) m)
// (slip: in episodes of slip_seconds, a fraction `slip` of the steps in all)
// with n, m normal 3-vectors of covariance I/3 (so the RMS error of a step is noise x its length),
// and integrated from the identity at frame 0.
struct SynthOdometry {
  bool enabled = true;
  SE3 T_base_cam = defaultBaseToCamera();
  double noise = 0.02;        // RMS of each step's translation error, as a fraction of the step
  double rot_noise = 0.02;    // RMS of each step's rotation error, as a fraction of the step's angle
  double bias = 0.0;          // scale error of every translation (0.01: reports 1 % more)
  double slip = 0.0;          // fraction of the frame steps that slip, in episodes of slip_seconds
  double slip_seconds = 0.5;  // length of a slip episode
  double slip_gain = 0.5;     // a slipping step reports (1 + slip_gain) x its translation

  static SE3 defaultBaseToCamera();
  void validate() const;
};

struct SynthOptions {
  std::string scene = "room";
  std::string trajectory;  // empty: defaultTrajectory(scene)
  int frames = 600;
  // Laps of the loop trajectory over the frames (frames - 1 must be a multiple: every lap then
  // has the same frames, frame i and i + (frames - 1) / laps at the same pose).
  int laps = 1;
  double fps = 30.0;
  uint64_t seed = 1;
  std::string textures = "auto";             // SynthSceneOptions::textures
  std::string texture_filter = "trilinear";  // or "mip-nearest" (TextureFilter, renderer.h)
  std::filesystem::path data_dir;            // SynthSceneOptions::data_dir
  // Camera: when camera_yaml is set it is loaded (loadCameraYaml); otherwise width x height with
  // fx = fy = 525 and cx = 319.5, cy = 239.5 scaled from 640 x 480 (pixel-centre aware).
  std::filesystem::path camera_yaml;
  int width = 640;
  int height = 480;
  std::vector<double> distortion;  // k1 k2 p1 p2, empty or all zero: none (overrides the YAML's)
  bool motion_blur = false;
  int blur_samples = 5;
  double shutter = 0.5;  // fraction of the frame interval
  bool exposure_change = false;
  double noise_sigma = 0.0;  // gray levels
  double shot_noise = 0.0;   // variance per gray level
  int index_every = 30;
  int queue_size = 8;
  SynthOdometry odometry;

  // Throws nerfslam::Error for invalid values (sizes outside 1..8192, frames < 1, fps <= 0, ...).
  void validate() const;
};

// The camera SynthOptions describe.
Camera synthCamera(const SynthOptions& opts);

struct SynthFrame {
  int index = 0;
  double timestamp = 0.0;
  SE3 T_world_cam;
  cv::Mat bgr;    // CV_8UC3
  cv::Mat depth;  // CV_32F metres, 0 = none
};

// Renders frames of a sequence on demand (tests use it without writing files).
class SequenceRenderer {
 public:
  explicit SequenceRenderer(const SynthOptions& opts);
  ~SequenceRenderer();
  const Camera& camera() const;
  const Scene& scene() const;
  const CameraTrajectory& trajectory() const;
  double timestamp(int i) const;
  SE3 pose(int i) const;
  SynthFrame render(int i);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The odometry SynthOdometry describes for a camera trajectory at `fps` frames/s: T_odom_base per
// frame (the first is the identity), deterministic from `seed`.
std::vector<SE3> synthOdometry(const std::vector<SE3>& T_world_cam, const SynthOdometry& odometry, uint64_t seed,
                               double fps);

// 16-bit TUM depth (metres x 5000, rounded; 0 for no depth or beyond 65535 / 5000 m).
cv::Mat depthToTum16(const cv::Mat& depth_m);

struct SynthResult {
  int frames = 0;
  double seconds = 0.0;
  Camera camera;
};

// Writes the sequence to `out` (created if missing). `progress(i, n)` is called after each render.
SynthResult writeSynthSequence(const SynthOptions& opts, const std::filesystem::path& out,
                               const std::function<void(int, int)>& progress = {});

}  // namespace nerfslam
