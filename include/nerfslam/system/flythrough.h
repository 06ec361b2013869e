#pragma once
// A fly-through of a NeRF map: renders at poses interpolated along a trajectory, written as a video
// (OpenCV's VideoWriter: H.264 'avc1', else MPEG-4 'mp4v') or, when no codec works, as a PNG
// sequence.
//
//   const FlythroughResult r = writeFlythrough(model, camera, trajectory, FlythroughOptions{}, out / "nerf");
//   // r.path: out/nerf/flythrough.mp4, or out/nerf/flythrough/ holding 000000.png ... 000059.png
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/nerf/model_io.h"

namespace nerfslam {

// `frames` poses evenly spread in time over the trajectory (first and last included; geodesic
// interpolation between the two poses around each time). Empty for an empty trajectory or frames <= 0.
std::vector<SE3> flythroughPoses(const Trajectory& trajectory, int frames);

struct FlythroughOptions {
  int frames = 60;
  // Time budget in seconds (0: none): when the first render says `frames` would take longer, fewer
  // frames (at least 2) are rendered, over the same trajectory.
  double max_seconds = 0;
  int threads = 2;
  std::vector<std::string> codecs = {"avc1", "mp4v"};  // FourCCs tried in turn; none: PNGs
};

struct FlythroughResult {
  std::filesystem::path path;  // the video file, or the folder of PNGs
  std::string codec;           // "avc1", "mp4v", or "png"
  int frames = 0;              // written
  int frames_requested = 0;    // FlythroughOptions::frames (more than `frames` when the budget cut them)
  cv::Size size;               // frame size: the camera's, rounded down to even numbers (video codecs need them)
  double fps = 0;              // frames per second of the video
  double seconds = 0;          // wall time of rendering and writing
};

// Renders the model from `camera` at flythroughPoses(trajectory, frames) and writes dir/flythrough.mp4
// with the first codec whose file reads back with every frame at its size, or, when none does,
// dir/flythrough/NNNNNN.png. Both are written under a temporary name, then renamed. Throws Error
// naming the file when nothing can be written; frames must be > 0 and the trajectory not empty.
FlythroughResult writeFlythrough(const nerf::NerfModel& model, const Camera& camera, const Trajectory& trajectory,
                                 const FlythroughOptions& options, const std::filesystem::path& dir);

}  // namespace nerfslam
