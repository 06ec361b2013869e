// `nerfslam export`: geometry from a trained NeRF model (world coordinates).
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <optional>
#include <sstream>
#include <string>

#include <spdlog/spdlog.h>

#include "command.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/parse.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/nerf/export.h"
#include "nerfslam/nerf/voxel_map.h"

namespace nerfslam::cli {
namespace {

struct ExportArgs {
  std::string model, format, out;
  double threshold = 2.5;
  int subdivision = 2;
  int threads = 2;
  size_t max_triangles = nerf::ExportOptions{}.max_triangles;
  // --format octomap | grid
  double resolution = 0.05;
  std::string height_band;  // empty: 0.05 to 0.9 of the keyframes' median height above the floor
  std::string keyframes, camera, floor;
  double metres_per_unit = 0;
  double max_memory_mb = 2048;
  int pixel_stride = 8;
};

std::vector<double> numberList(const std::string& text, size_t n, const char* option) {
  const std::vector<double> v = parseNumberList(text, option);
  if (v.size() != n) fail("{} '{}': expected {} comma-separated numbers, got {}", option, text, n, v.size());
  return v;
}

// Fails before any work when the output's directory does not exist or cannot be written.
void checkWritableDir(const std::filesystem::path& out) {
  const std::filesystem::path dir = out.parent_path().empty() ? "." : out.parent_path();
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) fail("{}: the directory {} does not exist", out.string(), dir.string());
  if (::access(dir.c_str(), W_OK) != 0) fail("{}: the directory {} is not writable", out.string(), dir.string());
}

int runOccupancyExport(const ExportArgs& a, nerf::NerfModel& model) {
  const std::filesystem::path out(a.out);
  if (a.format == "octomap" && out.extension() != ".bt" && out.extension() != ".ot")
    fail("{}: --format octomap writes .bt (binary) or .ot (full, with log-odds)", a.out);
  if (a.format == "grid" && out.extension() != ".yaml")
    fail("{}: --format grid writes the map_server pair NAME.yaml + NAME.pgm: give NAME.yaml", a.out);
  std::vector<double> band;
  if (!a.height_band.empty()) {
    band = numberList(a.height_band, 2, "--height-band");
    if (!(band[0] < band[1])) fail("--height-band '{}': lo must be < hi", a.height_band);
  }
  std::optional<nerf::FloorPlane> floor;
  if (!a.floor.empty()) {
    const auto f = numberList(a.floor, 4, "--floor");
    const Eigen::Vector3d n(f[0], f[1], f[2]);
    if (!(n.norm() > 1e-9)) fail("--floor '{}': the normal (a, b, c) is zero", a.floor);
    floor = nerf::FloorPlane{n.normalized(), f[3] / n.norm(), 0};
  }
  nerf::VoxelMapOptions vo;
  vo.resolution = a.resolution;
  vo.threads = a.threads;
  vo.max_memory_mb = a.max_memory_mb;
  vo.pixel_stride = a.pixel_stride;
  nerf::validate(vo);
  const Camera cam = loadCameraYaml(a.camera);
  const Trajectory kf = readTrajectory(a.keyframes);
  if (kf.empty()) fail("{}: no keyframe poses", a.keyframes);
  std::vector<nerf::PosedCamera> views;
  for (const auto& e : kf) views.push_back({cam, e.pose});
  checkWritableDir(out);
  const auto source = nerf::fieldDensitySource(model);
  const auto t0 = std::chrono::steady_clock::now();
  const nerf::VoxelMap map = nerf::buildVoxelMap(source, views, vo);
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  spdlog::info("export: {}x{}x{} voxels at {} in {:.2f} s: {} occupied, {} free, {} unknown", map.dims.x(),
               map.dims.y(), map.dims.z(), map.resolution, secs, map.count(nerf::VoxelMap::kOccupied),
               map.count(nerf::VoxelMap::kFree), map.count(nerf::VoxelMap::kUnknown));
  if (a.format == "octomap") {
    nerf::writeOctomapFiles(map, out, a.metres_per_unit, a.model);
    spdlog::info("export: OctoMap -> {} (+ {})", a.out, nerf::metaPathFor(out).string());
  } else {
    const nerf::FloorPlane f = floor ? *floor : nerf::detectFloor(map, views);
    if (band.empty()) {
      std::vector<double> h;
      for (const auto& v : views) h.push_back(f.height(v.T_world_cam.translation()));
      std::nth_element(h.begin(), h.begin() + long(h.size() / 2), h.end());
      const double cam_h = h[h.size() / 2];
      if (!(cam_h > 0)) fail("the keyframes are not above the floor found (median height {}): give --floor", cam_h);
      band = {0.05 * cam_h, 0.9 * cam_h};
      spdlog::info("export: height band [{:.4g}, {:.4g}] above the floor (0.05 and 0.9 of the keyframes' height)",
                   band[0], band[1]);
    }
    const auto g = nerf::writeGridFiles(map, views, &f, band[0], band[1], out, a.metres_per_unit, a.model);
    size_t occ = 0, fr = 0;
    for (int8_t c : g.grid.cells) {
      occ += c == NavGrid::kOccupied;
      fr += c == NavGrid::kFree;
    }
    spdlog::info("export: {}x{} grid ({} occupied, {} free cells) -> {} (+ .pgm, {})", g.grid.width, g.grid.height, occ,
                 fr, a.out, nerf::metaPathFor(out).string());
  }
  return 0;
}

int runExport(const ExportArgs& a) {
  nerf::NerfModel model = nerf::loadModel(a.model);
  if (a.format == "octomap" || a.format == "grid") return runOccupancyExport(a, model);
  nerf::ExportOptions o;
  o.density_threshold = a.threshold;
  o.subdivision = a.subdivision;
  o.threads = a.threads;
  o.max_triangles = a.max_triangles;
  const std::filesystem::path out(a.out);
  if (a.format == "mesh") {
    if (out.extension() != ".ply") fail("{}: meshes are written as .ply", a.out);
    nerf::MeshStats ms;
    const auto mesh = nerf::extractMesh(model, o, &ms);
    if (ms.density_threshold > a.threshold)
      spdlog::warn("export: {} triangles at threshold {:.3g}, over --max-triangles {}: threshold raised to {:.3g}",
                   ms.triangles_at_requested_threshold, a.threshold, a.max_triangles, ms.density_threshold);
    nerf::saveMesh(mesh, out);
    spdlog::info("export: mesh with {} triangles and {} vertices -> {}", mesh.polygons.size(),
                 size_t(mesh.cloud.width) * mesh.cloud.height, a.out);
  } else {
    if (out.extension() != "." + a.format)
      fail("{}: the extension must be .{} for --format {}", a.out, a.format, a.format);
    const auto cloud = nerf::densityPointCloud(model, o);
    nerf::savePointCloud(cloud, out);
    spdlog::info("export: {} points -> {}", cloud.size(), a.out);
  }
  return 0;
}

Registrar reg("export",
              "Export a point cloud (PLY/PCD), a mesh (PLY), a 3D occupancy map (OctoMap) or a 2D grid (map_server) "
              "from a NeRF model",
              [](CLI::App& sub) -> Runner {
                auto a = std::make_shared<ExportArgs>();
                sub.add_option("--model", a->model, "model.nerf")->required();
                sub.add_option("--format", a->format,
                               "ply, pcd (point cloud), mesh (PLY), octomap (.bt/.ot) or grid (map_server NAME.yaml)")
                    ->required()
                    ->check(CLI::IsMember({"ply", "pcd", "mesh", "octomap", "grid"}));
                sub.add_option("--out", a->out, "Output file")->required();
                sub.add_option("--resolution", a->resolution,
                               "octomap, grid: voxel/cell side in map units (metres when the map is metric)")
                    ->check(nerfslam::cli::kPositive);
                sub.add_option("--height-band", a->height_band,
                               "grid: lo,hi above the floor projected to the grid, in map units (default: 0.05 and "
                               "0.9 of the keyframes' median height above the floor)");
                sub.add_option("--keyframes", a->keyframes,
                               "octomap, grid: the training views' poses (TUM, e.g. a run's keyframes.txt): their "
                               "rays decide what is free");
                sub.add_option("--camera", a->camera, "octomap, grid: the camera YAML of the keyframes");
                sub.add_option("--floor", a->floor,
                               "grid: the floor plane a,b,c,d (a x + b y + c z + d = 0, "
                               "normal up); default: found in the map");
                sub.add_option("--metres-per-unit", a->metres_per_unit,
                               "octomap, grid: the map's scale, written beside it (0: unknown, map units)")
                    ->check(nerfslam::cli::kNonNegative);
                sub.add_option("--max-memory-mb", a->max_memory_mb, "octomap, grid: refuse larger maps")
                    ->check(nerfslam::cli::kPositive);
                sub.add_option("--pixel-stride", a->pixel_stride, "octomap, grid: one ray per N x N keyframe pixels")
                    ->check(CLI::Range(1, 256));
                sub.add_option("--threshold", a->threshold, "Density threshold (1/NeRF-space length)")
                    ->check(nerfslam::cli::kPositive);
                sub.add_option("--subdivision", a->subdivision, "Grid cells per occupancy cell per axis")
                    ->check(CLI::Range(1, 8));
                sub.add_option("--max-triangles", a->max_triangles,
                               "Mesh: above this many triangles the threshold is raised until it fits (0: no limit)");
                sub.add_option("--threads", a->threads, "Threads")->check(CLI::Range(1, 256));
                return [a]() -> int {
                  if ((a->format == "octomap" || a->format == "grid") && (a->keyframes.empty() || a->camera.empty()))
                    fail("--format {} needs --keyframes and --camera (the training views whose rays find free space)",
                         a->format);
                  return runExport(*a);
                };
              });

}  // namespace
}  // namespace nerfslam::cli
