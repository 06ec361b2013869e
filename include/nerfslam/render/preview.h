#pragma once
// Headless map previews: sparse or dense point clouds, trajectories and keyframe frustums drawn to
// an image with OSMesa (no display), from a given or an automatic viewpoint (fitting the content).
//
//   PreviewScene s;
//   s.clouds.push_back(loadPointCloudPly("map.ply"));
//   s.trajectories.push_back({readTumTrajectory(...) poses, {0, 0, 255}, "estimate"});
//   cv::Mat img = renderPreview(s, PreviewOptions{});
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "nerfslam/core/pose.h"

namespace nerfslam {

struct PreviewCloud {
  std::vector<Eigen::Vector3f> points;
  std::vector<cv::Vec3b> colors;  // BGR per point; empty: coloured by height along `up`
  std::string label;
};

struct PreviewTrajectory {
  std::vector<SE3> poses;      // T_world_cam
  cv::Vec3b color{0, 0, 255};  // BGR
  std::string label;
};

struct PreviewScene {
  std::vector<PreviewCloud> clouds;
  std::vector<PreviewTrajectory> trajectories;
  std::vector<SE3> keyframes;  // drawn as camera frustums
  cv::Vec3b keyframe_color{255, 160, 0};
};

struct PreviewOptions {
  int width = 1280;
  int height = 960;
  std::optional<Eigen::Vector3d> eye;  // both set: this viewpoint; otherwise automatic
  std::optional<Eigen::Vector3d> target;
  Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
  double fov_deg = 60.0;      // along the shorter image side
  float point_size = 2.0f;    // pixels
  float line_width = 2.0f;    // pixels (trajectories, frustums)
  double frustum_size = 0.0;  // metres; 0: 3% of the content's bounding-box diagonal
  cv::Vec3b background{40, 34, 30};
  bool legend = true;
  std::optional<double> max_height;  // points higher than this along `up` are not drawn (a cut-away ceiling)
};

// Reads a PLY point cloud (ASCII or binary) with PCL; colours when the file has them.
// Throws nerfslam::Error naming the file when it is missing or unreadable; non-finite points are dropped.
PreviewCloud loadPointCloudPly(const std::filesystem::path& path);

// Parses "eye=x,y,z,target=x,y,z" (order free, spaces allowed). Throws Error on bad syntax.
void parseView(const std::string& spec, Eigen::Vector3d* eye, Eigen::Vector3d* target);

// Colour names for the CLI: red green blue yellow cyan magenta orange white black gray, or #rrggbb.
cv::Vec3b parseColor(const std::string& name);

// The automatic viewpoint: looks at the content's robust bounding box (1st-99th percentile of the
// points, all trajectory positions) from above and aside so the box fits the view.
void autoView(const PreviewScene& scene, const PreviewOptions& opts, Eigen::Vector3d* eye, Eigen::Vector3d* target);

// A viewpoint from which a reconstructed surface (`points`) seen by cameras at `cameras` (T_world_cam,
// in order) reads at a glance, with opts.up as up and opts.fov_deg:
// - a traversal (an open camera path long against the scene, or a fifth of it with the cameras looking
//   along it, e.g. a drive; not cameras that all look at the scene's centre from directions more than
//   60 degrees apart, photos around an object): from behind and above the path's start, looking along
//   its main direction;
// - a compact scene (a room, an object): from outside the points' bounds and above them (30 degrees
//   into a room, 35 onto an object), looking at their centre from behind the cameras' mean viewing
//   direction; when the cameras are inside the bounds (a room), `max_height` is set a quarter of the
//   room's height above the highest camera, so a ceiling does not hide the room; when they are
//   outside (photos around an object), the view holds them too.
// Throws Error when there are no points or no cameras.
struct Overview {
  Eigen::Vector3d eye, target;
  // The up direction it was chosen with (draw with it): opts.up, or for photos around an object the
  // normal of the cameras' plane on their side (the cameras' own axes mislead when the photos were
  // taken rotated).
  Eigen::Vector3d up;
  std::optional<double> max_height;
  bool traversal = false;
};
Overview overviewViewpoint(const std::vector<Eigen::Vector3f>& points, const std::vector<SE3>& cameras,
                           const PreviewOptions& opts);

// Renders the preview (BGR 8-bit). Throws Error when there is nothing to draw or the size is
// outside 16..8192.
cv::Mat renderPreview(const PreviewScene& scene, const PreviewOptions& opts);

}  // namespace nerfslam
