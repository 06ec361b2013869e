#pragma once
// `nerfslam run`: plays a dataset through SlamSystem with three threads — a reader (decodes images,
// paces them at their timestamps with --realtime), the tracking thread, and the mapping thread — and
// writes trajectory.txt (TUM, every tracked frame), keyframes.txt (TUM), map_points.ply and
// report.json into the output directory, all atomically. runSlam reads as its three parts: reading
// (the reader thread and its queue), the system (tracking; mapping and the NeRF on SlamSystem's
// threads), outputs (files, report.json: the timing fields come from RunStats, system/run_stats.h).
#include <cstddef>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "nerfslam/io/frame_stream.h"
#include "nerfslam/system/slam_system.h"

namespace nerfslam {

struct RunOptions {
  // [kind:]PATH; empty: the demo — the synthetic furnished room (handheld camera, demo_frames frames,
  // 640x480) is rendered with OSMesa into OUT/sequence and run with its ground truth.
  // camera:/dev/videoN or camera:N: a live camera (io/frame_stream.h), read at its rate with
  // `realtime` semantics (implied: a frame arriving while tracking is busy drops the oldest waiting
  // one), `camera` required. Every frame that reaches tracking is recorded in OUT/frames, a `folder:`
  // dataset the end-of-run outputs read and that replays the run; `max_frames` ends the run after that
  // many frames reached tracking, a stop request (Ctrl-C) keeps what was done, and a device that
  // stops delivering ends it with an error naming the device.
  std::string dataset;
  // Opens the stream of a camera: dataset instead of the device (given its name): tests drive the
  // streaming path from a video file (openVideoFileStream) or a synthetic source. With it, `realtime`
  // is as given (false: the reader waits for tracking, as offline runs do, so a run is repeatable).
  std::function<std::unique_ptr<FrameStream>(const std::string& device)> open_stream;
  int demo_frames = 300;
  std::optional<std::filesystem::path> camera;
  std::optional<std::filesystem::path> config;
  std::filesystem::path out;
  std::size_t max_frames = 0;  // 0: all (a camera: until stopped)
  double fps = 0;              // DatasetOptions::fps (--fps): timestamps of a folder without times.txt
  bool realtime = false;
  bool nerf = true;                     // false: SystemOptions::nerf.enabled = false (--no-nerf)
  bool progress = true;                 // progress line on stderr
  std::optional<SystemOptions> system;  // used instead of defaults + config when set (tests)
  // Saved maps (system/map_store.h). `map`: start from this map folder in `map_mode` (kLocalize or
  // kExtend; the map's options are used unless `config` or `system` is given, and its camera must be
  // the dataset's). The map folder is saved at the end to `save_map`, else to OUT/map when
  // `save_default_map` (not after kLocalize, which leaves the map as loaded).
  std::optional<std::filesystem::path> map;
  MapMode map_mode = MapMode::kSlam;
  std::optional<std::filesystem::path> save_map;
  bool save_default_map = true;
  // Wheel odometry (mapping/odometry.h): a TUM file of T_odom_base, the extrinsic from
  // SystemOptions::odometry.T_base_cam. The map gets a metric scale once enough motion is seen; the
  // report adds scale_source, odometry (the scale over time) and the ATE under SE(3) alignment.
  // A dataset's own odometry (a bag's nav_msgs/Odometry topic, Dataset::odometry()) is used the
  // same way when `odometry` is not given (the file wins; not with `map`).
  std::optional<std::filesystem::path> odometry;
  // A bag's topics (DatasetOptions::image_topic ...; empty: detected) and tf frames
  // (DatasetOptions::odom_frame ...: the odometry, or the ground truth, from tf).
  std::string image_topic;
  std::string camera_info_topic;
  std::string odometry_topic;
  std::string groundtruth_topic;
  std::string odom_frame, base_frame;
  std::string groundtruth_parent_frame, groundtruth_child_frame;
};

struct RunResult {
  nlohmann::json report;  // also written to out/report.json
  bool initialized = false;
  int exit_code = 0;  // 0 also when the run ends uninitialised (the report says why)
};

// Throws nerfslam::Error for bad arguments (unknown dataset kind, unreadable config, calibration
// that does not match the images, unwritable output directory).
RunResult runSlam(const RunOptions& options);

// Binary-little-endian-free ASCII PLY of the map points (x y z, number of observations), atomic.
void writeMapPly(const std::filesystem::path& path, const Map& map);

}  // namespace nerfslam
