#include "nerfslam/nerf/scene_box.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace nerfslam::nerf {

namespace {

// Per axis the 2nd..98th percentile of the points (empty bounds without points).
Bounds pointBounds(const std::vector<Eigen::Vector3d>& points) {
  Bounds b;
  b.lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  b.hi = -b.lo;
  if (points.empty()) return b;
  for (int a = 0; a < 3; ++a) {
    std::vector<double> v;
    v.reserve(points.size());
    for (const auto& p : points) v.push_back(p[a]);
    const size_t k0 = size_t(0.02 * double(v.size() - 1)), k1 = size_t(0.98 * double(v.size() - 1));
    std::nth_element(v.begin(), v.begin() + long(k0), v.end());
    b.lo[a] = v[k0];
    std::nth_element(v.begin(), v.begin() + long(k1), v.end());
    b.hi[a] = v[k1];
  }
  return b;
}

Bounds widened(Bounds b, const std::vector<Eigen::Vector3d>& cameras) {
  for (const auto& c : cameras) {
    b.lo = b.lo.cwiseMin(c);
    b.hi = b.hi.cwiseMax(c);
  }
  return b;
}

// camerasInScene with the points' bounds already computed (`pts` empty: every camera).
std::vector<Eigen::Vector3d> inScene(const Bounds& pts, const std::vector<Eigen::Vector3d>& cameras) {
  if ((pts.lo.array() > pts.hi.array()).any()) return cameras;
  const double reach = kCameraReach * (pts.hi - pts.lo).maxCoeff();
  std::vector<Eigen::Vector3d> in;
  for (const auto& c : cameras)
    if ((pts.lo - c).cwiseMax(c - pts.hi).maxCoeff() <= reach) in.push_back(c);
  return in;
}

}  // namespace

std::vector<Eigen::Vector3d> pointsNearCameras(const std::vector<Eigen::Vector3d>& points,
                                               const std::vector<Eigen::Vector3d>& cameras) {
  if (points.empty() || cameras.empty()) return points;
  std::vector<double> dist(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& c : cameras) best = std::min(best, (points[i] - c).squaredNorm());
    dist[i] = std::sqrt(best);
  }
  std::vector<double> sorted = dist;
  std::nth_element(sorted.begin(), sorted.begin() + long(sorted.size() / 2), sorted.end());
  const double reach = kPointReach * sorted[sorted.size() / 2];
  std::vector<Eigen::Vector3d> near;
  near.reserve(points.size());
  for (size_t i = 0; i < points.size(); ++i)
    if (dist[i] <= reach) near.push_back(points[i]);
  return near;
}

Bounds robustBounds(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& cameras) {
  return widened(pointBounds(points), cameras);
}

std::vector<Eigen::Vector3d> camerasInScene(const std::vector<Eigen::Vector3d>& points,
                                            const std::vector<Eigen::Vector3d>& cameras) {
  return inScene(pointBounds(points), cameras);
}

SceneTransform cubeTransform(const Bounds& b, double margin, double aabb_scale, double min_half) {
  SceneTransform s;
  const Eigen::Vector3d centre = 0.5 * (b.lo + b.hi);
  const double half = std::max(0.5 * (b.hi - b.lo).maxCoeff() * margin, min_half);
  s.scale = 0.5 / half;
  s.offset = Eigen::Vector3d::Constant(0.5) - s.scale * centre;
  s.aabb_scale = aabb_scale;
  return s;
}

SceneTransform fitSceneBox(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& cameras,
                           double margin, double aabb_scale) {
  // A map smaller than the step between its first two views is not yet a scene to fit to.
  const Bounds pts = pointBounds(pointsNearCameras(points, cameras));
  const bool tiny = cameras.size() >= 2 && (pts.hi - pts.lo).maxCoeff() < (cameras[0] - cameras[1]).norm();
  const std::vector<Eigen::Vector3d> in = tiny ? cameras : inScene(pts, cameras);
  // At least as wide as the cameras' first-to-last distance (a half side of half of it): a long
  // drive is held by the widened bounds already, and a half side of the whole distance doubled its box.
  const double baseline = in.empty() ? 0.0 : (in.front() - in.back()).norm();
  return cubeTransform(widened(pts, in), margin, aabb_scale, std::max(0.5 * baseline, 1e-3));
}

bool sceneBoxOutgrown(const SceneTransform& scene, const std::vector<Eigen::Vector3d>& points,
                      const std::vector<Eigen::Vector3d>& cameras, double outside_fraction) {
  if (points.empty()) return false;
  const std::vector<Eigen::Vector3d> near = pointsNearCameras(points, cameras);
  size_t outside = 0;
  for (const auto& p : near) outside += !insideUnitCube(scene.toNerf(p));
  bool camera_out = false;
  for (const auto& c : camerasInScene(near, cameras)) camera_out |= !insideUnitCube(scene.toNerf(c));
  return camera_out || double(outside) > outside_fraction * double(near.size());
}

std::optional<SceneTransform> shrunkSceneBox(const SceneTransform& scene, const std::vector<Eigen::Vector3d>& points,
                                             const std::vector<Eigen::Vector3d>& cameras, double margin, double ratio) {
  if (points.empty() || ratio <= 0) return std::nullopt;
  // Sides in world units are 1 / scale; the aabb_scale is the same for both boxes.
  const SceneTransform fitted = fitSceneBox(points, cameras, margin, scene.aabb_scale);
  if (fitted.scale * ratio > scene.scale) return fitted;
  return std::nullopt;
}

SceneTransform refitSceneBox(const SceneTransform& old, const std::vector<Eigen::Vector3d>& points,
                             const std::vector<Eigen::Vector3d>& cameras, double margin, double aabb_scale) {
  const Bounds pts = pointBounds(pointsNearCameras(points, cameras));
  Bounds b = widened(pts, inScene(pts, cameras));
  b.lo = b.lo.cwiseMin(old.toWorld(Eigen::Vector3d::Zero()));
  b.hi = b.hi.cwiseMax(old.toWorld(Eigen::Vector3d::Ones()));
  const double old_half = 0.5 / old.scale;
  return cubeTransform(b, margin, aabb_scale, 1.5 * old_half);
}

bool insideUnitCube(const Eigen::Vector3d& p) { return (p.array() >= 0.0).all() && (p.array() <= 1.0).all(); }

}  // namespace nerfslam::nerf
