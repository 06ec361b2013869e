#pragma once
// Sparse depth densified over surfaces: Delaunay triangles over a view's surface points (its map
// points) in its image, kept where the three corners lie on one surface, so that depth-supervised
// rays reach the pixels between the keypoints too.
//
// A camera driving forward sees a road and facades at grazing angles: the keypoints on them are
// sparse (a few hundred in a 613x185 view), and between them the field is free to put its density
// anywhere along the ray (the road of KITTI 06 rendered as speckled fog in the depth image). A
// triangle whose corners are at similar depths and close together in the image is, almost always,
// a piece of one surface (road, wall, facade); one that spans a depth jump (a tree in front of a
// house) or a large stretch of image (sky between two rooftops) is not, and is dropped. A ray drawn
// inside a kept triangle is supervised like a ray through a map point, its target the distance to
// the triangle's plane along it: the corners are the map points' current positions, so the target
// follows bundle adjustment as the points' own do.
#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"

namespace nerfslam::nerf {

struct SurfacePoint;

// Kept when the corners' depths (z in the view) are within this ratio of each other...
constexpr double kTriangleMaxDepthRatio = 1.25;
// ...and no edge is longer than this fraction of the image's larger side.
constexpr double kTriangleMaxEdge = 0.1;
// A triangle's weight is its corners' smallest weight times this: an interpolated surface is
// trusted less than the map point a keypoint measured.
constexpr float kTriangleWeight = 0.5f;

struct DepthTriangle {
  std::array<uint32_t, 3> corner;  // indices into the view's surface points
  float weight = 0.f;
};

struct DepthTriangles {
  std::vector<DepthTriangle> triangles;
  std::vector<double> cumulative_area;  // pixels^2, for drawing a point uniformly over their area
  bool empty() const { return triangles.empty(); }
};

// Delaunay triangulation of the points that project into the image at T_world_cam (points behind
// the camera or outside it are left out), filtered by kTriangleMaxDepthRatio and kTriangleMaxEdge.
DepthTriangles triangulateSurfacePoints(const std::vector<SurfacePoint>& points, const Camera& camera,
                                        const SE3& T_world_cam);

struct TriangleSample {
  Eigen::Vector2d uv;   // the pixel (OpenCV convention, continuous)
  double distance = 0;  // world distance from the camera centre to the triangle's plane along the pixel's ray
  float weight = 0.f;
};

// A point drawn uniformly over the triangles' image area (u_area, r1, r2 uniform in [0, 1)), its
// pixel where the corners project at T_world_cam now and its distance to the plane through their
// positions now. Nothing when the triangle's corners no longer project in front of the camera, the
// ray is near-parallel to its plane or the pixel has no ray.
std::optional<TriangleSample> sampleDepthTriangle(const DepthTriangles& triangles,
                                                  const std::vector<SurfacePoint>& points, const Camera& camera,
                                                  const SE3& T_world_cam, double u_area, double r1, double r2);

}  // namespace nerfslam::nerf
