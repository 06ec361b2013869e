#pragma once
// A 2D occupancy grid (io/nav_grid.h) drawn top-down with trajectories on it, for `render-preview
// --grid`: free cells light, occupied black, unknown grey (map_server's image), the trajectories as
// coloured polylines (their positions projected on the grid's plane) and a 1 m (or 1 map unit)
// scale bar.
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/core/pose.h"
#include "nerfslam/io/nav_grid.h"

namespace nerfslam {

struct GridTrajectory {
  std::vector<Eigen::Vector3d> positions;  // map frame
  cv::Vec3b color{0, 0, 255};              // BGR
  bool dots = false;                       // positions as dots (keyframes), not a line
};

// T_map_grid: the grid's frame in the map frame (map.meta.yaml's T_map_grid; identity when the grid
// is the map's x-y plane). `max_side`: the image's longer side in pixels (cells are scaled up by an
// integer factor to fit it, at least one pixel each). Throws an Error on an empty grid.
cv::Mat drawNavGrid(const NavGrid& grid, const SE3& T_map_grid, const std::vector<GridTrajectory>& trajectories,
                    int max_side = 1200, const std::string& units = "m");

}  // namespace nerfslam
