// `nerfslam export`: geometry from a trained NeRF model (world coordinates).
#include <memory>
#include <string>

#include <spdlog/spdlog.h>

#include "command.h"
#include "nerfslam/core/error.h"
#include "nerfslam/nerf/export.h"

namespace nerfslam::cli {
namespace {

struct ExportArgs {
  std::string model, format, out;
  double threshold = 2.5;
  int subdivision = 2;
  int threads = 2;
  size_t max_triangles = nerf::ExportOptions{}.max_triangles;
};

int runExport(const ExportArgs& a) {
  nerf::NerfModel model = nerf::loadModel(a.model);
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

Registrar reg("export", "Export a point cloud (PLY/PCD) or a mesh (PLY) from a NeRF model",
              [](CLI::App& sub) -> Runner {
                auto a = std::make_shared<ExportArgs>();
                sub.add_option("--model", a->model, "model.nerf")->required();
                sub.add_option("--format", a->format, "ply, pcd (point cloud) or mesh (PLY)")
                    ->required()
                    ->check(CLI::IsMember({"ply", "pcd", "mesh"}));
                sub.add_option("--out", a->out, "Output file")->required();
                sub.add_option("--threshold", a->threshold, "Density threshold (1/NeRF-space length)")
                    ->check(nerfslam::cli::kPositive);
                sub.add_option("--subdivision", a->subdivision, "Grid cells per occupancy cell per axis")
                    ->check(CLI::Range(1, 8));
                sub.add_option("--max-triangles", a->max_triangles,
                               "Mesh: above this many triangles the threshold is raised until it fits (0: no limit)");
                sub.add_option("--threads", a->threads, "Threads")->check(CLI::Range(1, 256));
                return [a]() -> int { return runExport(*a); };
              });

}  // namespace
}  // namespace nerfslam::cli
