#include "nerfslam/render/grid_preview.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"

namespace nerfslam {

cv::Mat drawNavGrid(const NavGrid& g, const SE3& T_map_grid, const std::vector<GridTrajectory>& trajectories,
                    int max_side, const std::string& units) {
  if (g.width <= 0 || g.height <= 0 || g.cells.size() != size_t(g.width) * size_t(g.height))
    fail("grid preview: the grid is empty");
  const int scale = std::max(1, max_side / std::max(g.width, g.height));
  cv::Mat img(g.height * scale, g.width * scale, CV_8UC3);
  for (int y = 0; y < g.height; ++y)
    for (int x = 0; x < g.width; ++x) {
      const int8_t c = g.at(x, y);
      const uchar v = c == NavGrid::kOccupied ? 0 : c == NavGrid::kFree ? 254 : 205;
      img(cv::Rect(x * scale, (g.height - 1 - y) * scale, scale, scale)).setTo(cv::Scalar(v, v, v));
    }
  // Map-frame position -> pixel: into the grid's frame, then its rotated origin.
  const SE3 T_grid_map = T_map_grid.inverse();
  const double cy = std::cos(g.origin_yaw), sy = std::sin(g.origin_yaw);
  auto pixel = [&](const Eigen::Vector3d& p_map) {
    const Eigen::Vector3d p = T_grid_map * p_map;
    const double dx = p.x() - g.origin_x, dy = p.y() - g.origin_y;
    const double gx = cy * dx + sy * dy, gy = -sy * dx + cy * dy;  // into the image's axes
    return cv::Point2d(gx / g.resolution * scale, (g.height - gy / g.resolution) * scale);
  };
  const int thick = std::max(1, scale / 2);
  for (const auto& t : trajectories) {
    std::vector<cv::Point> pts;
    for (const auto& p : t.positions) {
      const cv::Point2d q = pixel(p);
      if (std::isfinite(q.x) && std::isfinite(q.y) && std::abs(q.x) < 1e6 && std::abs(q.y) < 1e6)
        pts.emplace_back(int(std::lround(q.x)), int(std::lround(q.y)));
    }
    if (t.dots) {
      for (const auto& q : pts) cv::circle(img, q, thick + 1, cv::Scalar(t.color[0], t.color[1], t.color[2]), -1);
      continue;
    }
    if (pts.size() >= 2)
      cv::polylines(img, pts, false, cv::Scalar(t.color[0], t.color[1], t.color[2]), thick, cv::LINE_AA);
    if (!pts.empty()) cv::circle(img, pts.front(), 2 * thick + 2, cv::Scalar(t.color[0], t.color[1], t.color[2]), -1);
  }
  // Scale bar: 1 unit, or a power of ten that fits.
  double len = 1.0;
  while (len / g.resolution * scale > img.cols / 3.0) len /= 10;
  while (len / g.resolution * scale < img.cols / 30.0) len *= 10;
  const int px = int(len / g.resolution * scale), x0 = 10, y0 = img.rows - 12;
  cv::line(img, {x0, y0}, {x0 + px, y0}, cv::Scalar(0, 120, 0), 3);
  cv::putText(img, fmt::format("{:g} {}", len, units), {x0, y0 - 6}, cv::FONT_HERSHEY_SIMPLEX, 0.5,
              cv::Scalar(0, 120, 0), 1, cv::LINE_AA);
  return img;
}

}  // namespace nerfslam
