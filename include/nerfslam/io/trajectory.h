#pragma once
// Trajectory files in the formats the evaluation tools use (evo, the TUM RGB-D and KITTI
// benchmarks). Poses are T_world_cam (camera-to-world), as in those files.
//
//   TUM:   `timestamp tx ty tz qx qy qz qw` per line; lines starting with '#' are comments.
//   KITTI: 12 numbers per line, the first three rows of the 4x4 camera-to-world matrix (row-major).
//          No timestamps: entries get their index (0, 1, 2, ...) or the values of a separate times
//          file (one number per line, as KITTI's times.txt).
//   EuRoC: the ground-truth CSV (`timestamp[ns], px, py, pz, qw, qx, qy, qz[, ...]`, at least 8
//          columns), read as evo's `euroc` format does; timestamps are converted to seconds.
//
// Readers accept numbers separated by any mix of spaces, tabs and commas, ignore blank lines, and
// reject anything else with an Error naming the file and line: a wrong column count, a
// non-numeric or non-finite value, a zero or non-unit quaternion (|‖q‖ − 1| > 1e-3; smaller
// deviations, i.e. rounding in the file, are normalised away) or a non-rotation KITTI matrix.
// Writers are atomic (core/atomic_file.h) and print timestamps with 9 decimals and pose values in
// the shortest form that reads back to the identical double.
#include <filesystem>
#include <string>
#include <vector>

#include "nerfslam/core/pose.h"

namespace nerfslam {

struct TrajectoryEntry {
  double timestamp = 0.0;  // seconds
  SE3 pose;                // T_world_cam
};
using Trajectory = std::vector<TrajectoryEntry>;

enum class TrajectoryFormat { kAuto, kTum, kKitti, kEuroc };

// "auto", "tum", "kitti" or "euroc"; throws an Error listing the valid names otherwise.
TrajectoryFormat parseTrajectoryFormat(const std::string& name);
std::string trajectoryFormatName(TrajectoryFormat format);

// Guesses the format from the first data line: 12 numbers -> KITTI, 8 numbers -> TUM, a comma
// separated line of at least 8 numbers whose first is an integer nanosecond stamp (> 1e12) -> EuRoC.
// Throws an Error naming the file if it cannot be read, has no data line, or matches no format.
TrajectoryFormat detectTrajectoryFormat(const std::filesystem::path& path);

Trajectory readTumTrajectory(const std::filesystem::path& path);
// `times_path` empty: timestamps are the line indices 0, 1, 2, ...
Trajectory readKittiTrajectory(const std::filesystem::path& path, const std::filesystem::path& times_path = {});
Trajectory readEurocTrajectory(const std::filesystem::path& path);
// Dispatches on `format` (kAuto: detectTrajectoryFormat). `kitti_times` is used for KITTI only.
Trajectory readTrajectory(const std::filesystem::path& path, TrajectoryFormat format = TrajectoryFormat::kAuto,
                          const std::filesystem::path& kitti_times = {});

void writeTumTrajectory(const std::filesystem::path& path, const Trajectory& trajectory);
// Writes the poses; when `times_path` is not empty also the timestamps there (one per line).
void writeKittiTrajectory(const std::filesystem::path& path, const Trajectory& trajectory,
                          const std::filesystem::path& times_path = {});

}  // namespace nerfslam
