#include "nerfslam/nerf/depth_triangles.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "nerfslam/nerf/trainer.h"

namespace nerfslam::nerf {

DepthTriangles triangulateSurfacePoints(const std::vector<SurfacePoint>& points, const Camera& camera,
                                        const SE3& T_world_cam) {
  DepthTriangles out;
  if (points.size() < 3 || camera.width <= 0 || camera.height <= 0) return out;
  const SE3 T_cam_world = T_world_cam.inverse();
  // The projected points; Subdiv2D keeps the coordinates it is given, so a triangle's corners are
  // found again by their exact float coordinates (a second point on the same pixel position is
  // the first one's vertex and is left out).
  cv::Subdiv2D subdiv(cv::Rect(0, 0, camera.width, camera.height));
  std::map<std::pair<float, float>, uint32_t> index;
  std::vector<double> depth(points.size(), 0.0);
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d p_cam = T_cam_world * points[i].position.cast<double>();
    Eigen::Vector2d uv;
    if (!camera.projectInImage(p_cam, &uv)) continue;
    const cv::Point2f q(float(uv.x()), float(uv.y()));
    if (!(q.x >= 0.f && q.y >= 0.f && q.x < float(camera.width) && q.y < float(camera.height))) continue;
    if (!index.emplace(std::make_pair(q.x, q.y), uint32_t(i)).second) continue;
    depth[i] = p_cam.z();
    subdiv.insert(q);
  }
  if (index.size() < 3) return out;
  std::vector<cv::Vec6f> list;
  subdiv.getTriangleList(list);
  const double max_edge = kTriangleMaxEdge * double(std::max(camera.width, camera.height));
  double area_sum = 0.0;
  for (const cv::Vec6f& t : list) {
    DepthTriangle tri;
    bool ok = true;
    Eigen::Vector2d c[3];
    for (int k = 0; k < 3 && ok; ++k) {
      const auto it = index.find({t[2 * k], t[2 * k + 1]});
      ok = it != index.end();  // Subdiv2D's outer virtual vertices are not ours
      if (ok) {
        tri.corner[size_t(k)] = it->second;
        c[k] = Eigen::Vector2d(t[2 * k], t[2 * k + 1]);
      }
    }
    if (!ok) continue;
    double zmin = INFINITY, zmax = 0.0;
    float w = 1.f;
    for (const uint32_t i : tri.corner) {
      zmin = std::min(zmin, depth[i]);
      zmax = std::max(zmax, depth[i]);
      w = std::min(w, points[i].weight);
    }
    if (!(zmax <= kTriangleMaxDepthRatio * zmin)) continue;
    if ((c[0] - c[1]).norm() > max_edge || (c[1] - c[2]).norm() > max_edge || (c[2] - c[0]).norm() > max_edge) continue;
    const Eigen::Vector2d e1 = c[1] - c[0], e2 = c[2] - c[0];
    const double area = 0.5 * std::abs(e1.x() * e2.y() - e1.y() * e2.x());
    if (!(area > 0.0)) continue;
    tri.weight = kTriangleWeight * w;
    area_sum += area;
    out.triangles.push_back(tri);
    out.cumulative_area.push_back(area_sum);
  }
  return out;
}

std::optional<TriangleSample> sampleDepthTriangle(const DepthTriangles& triangles,
                                                  const std::vector<SurfacePoint>& points, const Camera& camera,
                                                  const SE3& T_world_cam, double u_area, double r1, double r2) {
  if (triangles.empty()) return std::nullopt;
  const double target = std::clamp(u_area, 0.0, 1.0) * triangles.cumulative_area.back();
  const size_t k =
      std::min(size_t(std::upper_bound(triangles.cumulative_area.begin(), triangles.cumulative_area.end(), target) -
                      triangles.cumulative_area.begin()),
               triangles.triangles.size() - 1);
  const DepthTriangle& tri = triangles.triangles[k];
  const SE3 T_cam_world = T_world_cam.inverse();
  Eigen::Vector3d P[3];
  Eigen::Vector2d uv[3];
  for (int j = 0; j < 3; ++j) {
    const uint32_t i = tri.corner[size_t(j)];
    if (i >= points.size()) return std::nullopt;
    P[j] = points[i].position.cast<double>();
    const Eigen::Vector3d p_cam = T_cam_world * P[j];
    if (!(p_cam.z() > 0.0)) return std::nullopt;
    uv[j] = camera.project(p_cam);
  }
  // Uniform over the triangle: barycentric (1 - sqrt(r1), sqrt(r1) (1 - r2), sqrt(r1) r2).
  const double s = std::sqrt(std::clamp(r1, 0.0, 1.0));
  const double b1 = s * (1.0 - r2), b2 = s * r2;
  TriangleSample out;
  out.uv = (1.0 - s) * uv[0] + b1 * uv[1] + b2 * uv[2];
  if (!(out.uv.x() >= -0.5 && out.uv.y() >= -0.5 && out.uv.x() < camera.width - 0.5 &&
        out.uv.y() < camera.height - 0.5))
    return std::nullopt;
  const Eigen::Vector3d d_cam = camera.unproject(out.uv);
  if (!d_cam.allFinite()) return std::nullopt;
  const Eigen::Vector3d d = (T_world_cam.rotationMatrix() * d_cam).normalized();
  const Eigen::Vector3d c = T_world_cam.translation();
  const Eigen::Vector3d n = (P[1] - P[0]).cross(P[2] - P[0]);
  const double nn = n.norm(), nd = n.dot(d);
  // Grazing rays (within ~3 degrees of the plane) put the target anywhere along a long stretch.
  if (!(nn > 0.0) || !(std::abs(nd) > 0.05 * nn)) return std::nullopt;
  out.distance = n.dot(P[0] - c) / nd;
  if (!(out.distance > 0.0) || !std::isfinite(out.distance)) return std::nullopt;
  out.weight = tri.weight;
  return out;
}

}  // namespace nerfslam::nerf
