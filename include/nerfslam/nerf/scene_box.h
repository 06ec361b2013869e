#pragma once
// The NeRF's scene box fitted to a sparse map (points and camera centres), for online training:
// fitSceneBox places a first box, sceneBoxOutgrown tells when the map has left it, and
// refitSceneBox grows it around the map and the old box; shrunkSceneBox fits the box anew when the
// map has become much smaller than it (a monocular map's first points, triangulated over a short
// baseline, reach far beyond what the finished map holds).
//
// The box is the robust extent of the points (per axis the 2nd..98th percentile) widened to hold
// the camera centres that are in the scene (camerasInScene), made a cube of side (largest extent) *
// margin around its centre; the scene transform maps that cube onto the unit cube, and the NeRF's
// box (aabb_scale times the unit cube, with its cascades) extends beyond it. Cameras inside a room
// or on a street are held, so the space around them is mapped; cameras that look at an object from
// outside (a ring of photos around it) are not: a box holding them left the temple of the
// Middlebury ring 20 of the occupancy grid's 128 cells across. Rays from cameras outside the box
// start where they enter it.
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "nerfslam/nerf/rays.h"

namespace nerfslam::nerf {

struct Bounds {
  Eigen::Vector3d lo, hi;  // lo > hi (infinite) when empty
};

// Per axis the 2nd..98th percentile of the points, widened to hold every camera centre. Without
// points or cameras the bounds are empty (lo = +inf, hi = -inf).
Bounds robustBounds(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& cameras);

// A camera farther than this many times the points' largest robust extent outside their robust
// bounds looks at the scene from outside (the temple ring's cameras: 2.4-3.4 extents; cameras in a
// room or on a street are inside the points' bounds or near them).
constexpr double kCameraReach = 1.0;

// Points farther from every camera than this many times the median of the points' distances to
// their nearest camera are left out of the box (they lie in the outer cascades, aabb_scale, or
// beyond as background). A camera driving down a street sees buildings and trees tens of metres
// ahead: on KITTI 06 the 5 % of the points beyond 4.5 median distances stretched the box along the
// road to 1.5 times the side that holds the rest, and the hash grid's and the occupancy grid's
// resolution with it. Rooms (every point within 1.5 medians of a camera) and photos around an
// object (within 1.2) keep every point.
constexpr double kPointReach = 3.0;

// The points within kPointReach median distances of their nearest camera (all of them without cameras).
std::vector<Eigen::Vector3d> pointsNearCameras(const std::vector<Eigen::Vector3d>& points,
                                               const std::vector<Eigen::Vector3d>& cameras);

// The cameras within kCameraReach of the points' robust bounds (all of them without points).
std::vector<Eigen::Vector3d> camerasInScene(const std::vector<Eigen::Vector3d>& points,
                                            const std::vector<Eigen::Vector3d>& cameras);

// The transform mapping the cube of half-side max(margin * (largest extent of `b`) / 2, min_half)
// centred on `b` onto the unit cube, with the given aabb_scale.
SceneTransform cubeTransform(const Bounds& b, double margin, double aabb_scale, double min_half);

// The first box of a map: the robust bounds of the points and the cameras in the scene (camera
// centres in capture order), with a side of at least the distance between the first and the last
// of those cameras (1e-3 at least), so a map that is still nearly flat gets a box of the scale of
// its motion. While the points' extent is below the distance between the first two cameras (a
// map smaller than the step that made it), every camera is held.
SceneTransform fitSceneBox(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& cameras,
                           double margin, double aabb_scale);

// True when the map has points and any camera centre in the scene (camerasInScene), or more than outside_fraction of
// the points, lies outside the unit cube of `scene` (false without points: nothing to fit a new box to).
bool sceneBoxOutgrown(const SceneTransform& scene, const std::vector<Eigen::Vector3d>& points,
                      const std::vector<Eigen::Vector3d>& cameras, double outside_fraction);

// The box fitted afresh to the map (fitSceneBox, with `scene`'s aabb_scale) when its side is below
// `ratio` times the side of `scene`'s; nothing without points, with ratio <= 0, or when `scene` is
// not that much larger. KITTI 06: the box fitted to the first 329 points was 2.5 times the side of
// the box of the finished map's 1,926, so the hash grid and the occupancy grid spent 60 % of their
// resolution on each axis on space the map does not reach.
std::optional<SceneTransform> shrunkSceneBox(const SceneTransform& scene, const std::vector<Eigen::Vector3d>& points,
                                             const std::vector<Eigen::Vector3d>& cameras, double margin, double ratio);

// A new box around the map that keeps the old box inside it and is at least 1.5 times its size, so
// re-fits stay rare.
SceneTransform refitSceneBox(const SceneTransform& old, const std::vector<Eigen::Vector3d>& points,
                             const std::vector<Eigen::Vector3d>& cameras, double margin, double aabb_scale);

bool insideUnitCube(const Eigen::Vector3d& p);

}  // namespace nerfslam::nerf
