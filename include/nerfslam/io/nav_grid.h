#pragma once
// A 2D occupancy grid for ground robots with nav_msgs/OccupancyGrid semantics, and its ROS map_server
// file pair (an image and a YAML file).
//
// Cells are row-major with row 0 at the lowest y (OccupancyGrid's order): cell (x, y) covers
// [origin_x + x * resolution, origin_x + (x + 1) * resolution) in the grid's frame (rotated by
// origin_yaw about the origin), and holds 0 (free), 100 (occupied) or -1 (unknown).
//
// The map_server pair, as map_server's map_saver writes it and map_server reads it in its default
// ("trinary") mode:
//   NAME.yaml   image: NAME.pgm            the image, relative to the YAML file
//               resolution: R              metres (or map units) per cell
//               origin: [x, y, yaw]        the pose of the lower-left pixel's corner
//               negate: 0
//               occupied_thresh: 0.65      p = (255 - pixel) / 255 > 0.65: occupied
//               free_thresh: 0.196         p < 0.196: free, otherwise unknown
//   NAME.pgm    binary 8-bit PGM (P5), top row first (the image is the grid flipped vertically):
//               occupied 0, free 254, unknown 205
#include <cstdint>
#include <filesystem>
#include <vector>

namespace nerfslam {

struct NavGrid {
  static constexpr int8_t kFree = 0;
  static constexpr int8_t kOccupied = 100;
  static constexpr int8_t kUnknown = -1;

  int width = 0, height = 0;
  double resolution = 0;
  double origin_x = 0, origin_y = 0, origin_yaw = 0;
  std::vector<int8_t> cells;  // width * height, index x + width * y

  int8_t at(int x, int y) const { return cells[size_t(x) + size_t(width) * size_t(y)]; }
  int8_t& at(int x, int y) { return cells[size_t(x) + size_t(width) * size_t(y)]; }
};

// map_server's thresholds for the pair we write (occupied_thresh, free_thresh).
constexpr double kMapServerOccupiedThresh = 0.65;
constexpr double kMapServerFreeThresh = 0.196;

// Writes `yaml_path` and the PGM beside it (same stem, .pgm), each atomically; the PGM first, so a
// YAML never names a missing or partial image. Throws an Error naming the file on any failure.
void saveMapServer(const NavGrid& grid, const std::filesystem::path& yaml_path);

// Reads a map_server pair as map_server does in trinary mode (any 8-bit PGM, negate 0 or 1, any
// thresholds). Errors name the file and the field.
NavGrid loadMapServer(const std::filesystem::path& yaml_path);

}  // namespace nerfslam
