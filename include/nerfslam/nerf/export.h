#pragma once
// Geometry export from a NeRF model, in world coordinates.
//
// - densityPointCloud: points on a regular grid (occupancy-cell resolution x `subdivision`) inside the
//   occupied cells of the occupancy grid whose density exceeds `density_threshold`, coloured by the
//   field's colour averaged over the six axis-aligned viewing directions.
// - depthPointCloud: back-projected depth renders of given views (e.g. the training views), coloured
//   by the rendered colour; pixels with opacity below min_opacity are skipped.
// - extractMesh: an isosurface of the density at `density_threshold` by marching tetrahedra (each grid
//   cube split into six tetrahedra around its main diagonal; no ambiguous cases, watertight) on a
//   grid of 128 * subdivision cells over cascade 0, evaluated only near occupied cells. Triangles face
//   outwards (towards decreasing density); vertex colours are the field's colour seen along -normal.
//   A mesh over max_triangles is not written whole: the threshold is raised (x1.25 at a time, the
//   density values already queried are reused) until it fits, so a foggy field (a street: tens of
//   millions of triangles, most of them fog) keeps its densest surfaces; MeshStats says what was used.
// The density threshold is in the field's units (1 / NeRF-space length); instant-ngp's default
// mesh threshold is 2.5 in the same units.
#include <filesystem>
#include <vector>

#include <pcl/PolygonMesh.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/nerf/model_io.h"

namespace nerfslam::nerf {

struct ExportOptions {
  double density_threshold = 2.5;
  int subdivision = 2;  // grid cells per occupancy cell along each axis
  int threads = 2;
  double min_opacity = 0.9;          // depthPointCloud
  int pixel_stride = 2;              // depthPointCloud: every n-th pixel in x and y
  size_t max_triangles = 5'000'000;  // extractMesh: raise the threshold above this (0: no limit)
};

pcl::PointCloud<pcl::PointXYZRGB> densityPointCloud(const NerfModel& model, const ExportOptions& options = {});

struct PosedCamera {
  Camera camera;
  SE3 T_world_cam;
};
// What the render said about each point of depthPointCloud: its accumulated opacity and its depth
// uncertainty (standard deviation of the ray's termination distance) relative to its distance. Surfaces
// have both near 1 and near 0; floaters and the sky neither.
struct DepthPointQuality {
  float opacity = 0;
  float relative_uncertainty = 0;
};
pcl::PointCloud<pcl::PointXYZRGB> depthPointCloud(const NerfModel& model, const std::vector<PosedCamera>& views,
                                                  const ExportOptions& options = {},
                                                  std::vector<DepthPointQuality>* quality = nullptr);

struct MeshStats {
  double density_threshold = 0;  // the threshold the mesh was extracted at
  size_t triangles_at_requested_threshold = 0;
};
pcl::PolygonMesh extractMesh(const NerfModel& model, const ExportOptions& options = {}, MeshStats* stats = nullptr);

// Atomic writers (core/atomic_file.h: a temporary file, then rename), every write checked: a full disk
// is an Error naming the file ("mesh.ply: write failed (disk full?)") and leaves no cut-off file. The
// format follows the extension for clouds: .ply (binary little-endian PLY: x y z float, red green
// blue uchar) or .pcd (binary PCD v0.7, PCL's layout for PointXYZRGB); meshes are binary PLY with
// faces as "list uchar int vertex_indices". PCL, MeshLab, Open3D and CloudCompare read them.
void savePointCloud(const pcl::PointCloud<pcl::PointXYZRGB>& cloud, const std::filesystem::path& path);
void saveMesh(const pcl::PolygonMesh& mesh, const std::filesystem::path& path);

}  // namespace nerfslam::nerf
