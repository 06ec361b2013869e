#pragma once
// A 2D top view of camera trajectories, drawn with OpenCV as evo draws its plots: the plane of
// largest motion (two world axes), equal scale on both axes, a grid with tick labels in the given
// unit, a title (e.g. the ATE) and a legend.
//
//   PlotSeries gt{positions_gt, {0, 160, 0}, "ground truth"}, est{positions_est, {200, 80, 0}, "estimate"};
//   TrajectoryPlotOptions o;
//   o.title = "ATE RMSE 0.021 m (0.05 % of the 41.2 m path)";
//   cv::Mat img = plotTrajectories({gt, est}, o).image;
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace nerfslam {

struct PlotSeries {
  std::vector<Eigen::Vector3d> positions;
  cv::Vec3b color{0, 0, 255};  // BGR
  std::string label;
};

struct TrajectoryPlotOptions {
  int width = 1200;
  int height = 900;
  std::string unit = "m";  // axis labels: "x [m]"; e.g. "map units" when the scale is unknown
  std::string title;       // first line above the plot
  // The scene's up direction (e.g. from the cameras), when known: the world axis closest to it is the
  // one not shown (a top view), whatever the motion along it.
  std::optional<Eigen::Vector3d> up;
};

struct TrajectoryPlot {
  cv::Mat image;                         // BGR 8-bit
  cv::Rect frame;                        // the plot area (inside the axes), in pixels
  int axis_h = 0, axis_v = 1;            // world axes shown horizontally and vertically (0 x, 1 y, 2 z)
  double h_lo = 0, h_hi = 1;             // world coordinates at the frame's left and right edges
  double v_lo = 0, v_hi = 1;             // ... at its bottom and top edges
  std::vector<double> h_ticks, v_ticks;  // labelled tick values, 1, 2 or 5 times a power of ten apart
  std::string plane;                     // e.g. "x-z plane"

  // Where a world point lands in the image (its coordinates on the two axes; the third is ignored).
  cv::Point2d toPixel(const Eigen::Vector3d& p) const;
};

// The plane is that of the two world axes along which the first series (the reference) spreads most,
// or those across options.up, lower axis index horizontal; every series fits in the frame, whose ends on each axis are
// ticks or beyond them. Throws Error when no series has a position or the size is outside 200..8192.
TrajectoryPlot plotTrajectories(const std::vector<PlotSeries>& series, const TrajectoryPlotOptions& options);

}  // namespace nerfslam
