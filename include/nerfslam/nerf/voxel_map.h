#pragma once
// Maps a robot can plan in, from a density field: a 3D voxel occupancy map (OctoMap's tree, log-odds
// and .bt/.ot files) and a 2D occupancy grid for ground robots (nav_grid.h, map_server's files).
// Not to be confused with occupancy.h, the NeRF's training occupancy grid for empty-space skipping.
//
// How a voxel is classified (VoxelMapper):
//   1. Density: the field's density at samples_per_axis^3 points in each voxel; the voxel keeps the
//      largest (a thin wall anywhere in it counts). Points the NeRF's training occupancy grid marks
//      empty are not queried (density 0).
//   2. Rays: from every training view (keyframe), one ray per pixel_stride x pixel_stride pixels is
//      marched voxel by voxel (exact grid traversal). A voxel the ray crosses while it still sees
//      through (the voxel's opacity over one side, 1 - exp(-sigma * resolution), below
//      occupied_opacity, and the transmittance so far above stop_transmittance) is a miss (free
//      space); the voxel where the ray stops is a hit, and so are the thickness_voxels voxels behind
//      it along the ray (the inside of the surface).
//      A voxel that rays of fewer than min_hit_views views hit keeps no hits (the NeRF's floaters
//      explain one view and are seen through, or not seen, from the others).
//   3. Log-odds, as OctoMap's sensor model: L = hits * logit(prob_hit) + misses * logit(prob_miss),
//      clamped to [logit(clamp_min), logit(clamp_max)]. Occupied when L > 0, free when L <= 0 with
//      evidence, unknown without evidence (no ray reached it).
//   4. Speckles: an occupied cluster (26-connected) of fewer than min_cluster_voxels voxels keeps only
//      its misses (free with them, else unknown): the field's small floaters, which block a planner's
//      paths, not obstacles at this resolution (a 5 cm post 1 m tall is 20 voxels).
// Coordinates: the output frame, the model's world frame mapped by T_out_world (a Sim(3): e.g. the
// ground-truth alignment of a monocular map, which makes it metric). Voxels are aligned to multiples
// of the resolution from the frame's origin, as OctoMap's keys are, so each voxel is one OctoMap leaf.
//
// The density and the views are inputs (DensitySource, PosedCamera), so tests classify analytic
// densities (a box, a sphere) and the NeRF is one source among others (fieldDensitySource).
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/io/nav_grid.h"
#include "nerfslam/nerf/export.h"

namespace nerfslam::nerf {

struct DensitySource {
  // sigma (1 / output-frame length) at n output-frame points xyz[3n]. Called concurrently from the
  // mapper's threads.
  std::function<void(const float* xyz, size_t n, float* sigma)> density;
  // Optional: false when the point certainly has no density (skips its query).
  std::function<bool(const Eigen::Vector3f& p)> may_be_dense;
  // Where the density may be (output frame); the map covers it and the views' centres.
  Eigen::AlignedBox3d bounds;
};

// The NeRF as a density source in the frame T_out_world * world. Throws when the model has no field
// or no occupied cell (an empty model).
DensitySource fieldDensitySource(const NerfModel& model, const Sim3& T_out_world = Sim3());

struct VoxelMapOptions {
  double resolution = 0.05;         // output-frame units (metres when the frame is metric)
  double occupied_opacity = 0.5;    // a voxel is a surface when 1 - exp(-sigma * resolution) >= this
  double stop_transmittance = 0.5;  // a ray stops where its transmittance falls below this
  int thickness_voxels = 1;         // voxels behind the surface marked occupied
  int min_cluster_voxels = 4;       // occupied clusters smaller than this are dropped (speckles)
  int samples_per_axis = 2;         // density samples per voxel along each axis
  int pixel_stride = 8;             // one ray per pixel_stride^2 pixels of each view
  int min_hit_views = 2;            // hits count only from a voxel hit by rays of this many views
  double prob_hit = 0.7, prob_miss = 0.4, clamp_min = 0.1192, clamp_max = 0.971;  // OctoMap's defaults
  double max_memory_mb = 2048;  // refuse maps larger than this (the error says the size they would have)
  int threads = 2;

  template <class V>
  void visit(V& v) {
    v("resolution", resolution, "Voxel side in output units (metres when the map is metric, else map units)",
      check::range(1e-6, 1e6));
    v("occupied_opacity", occupied_opacity, "A voxel is a surface when its opacity over one side reaches this",
      check::range(1e-3, 0.999));
    v("stop_transmittance", stop_transmittance, "A keyframe ray stops where its transmittance falls below this",
      check::range(1e-3, 0.999));
    v("thickness_voxels", thickness_voxels, "Voxels behind a surface along each ray that are marked occupied",
      check::range(0, 100));
    v("min_cluster_voxels", min_cluster_voxels,
      "Occupied clusters (26-connected) of fewer voxels are dropped as speckles (1: none)", check::range(1, 1000));
    v("samples_per_axis", samples_per_axis, "Density samples per voxel along each axis (the voxel keeps the largest)",
      check::range(1, 8));
    v("pixel_stride", pixel_stride, "One ray per pixel_stride x pixel_stride pixels of each training view",
      check::range(1, 256));
    v("min_hit_views", min_hit_views,
      "A voxel's hits count only when rays of this many views hit it (a floater explains one view)",
      check::range(1, 1000));
    v("prob_hit", prob_hit, "OctoMap sensor model: occupancy probability of a hit", check::range(0.5, 0.999));
    v("prob_miss", prob_miss, "OctoMap sensor model: occupancy probability of a miss", check::range(0.001, 0.5));
    v("clamp_min", clamp_min, "OctoMap clamping threshold (lower)", check::range(0.001, 0.5));
    v("clamp_max", clamp_max, "OctoMap clamping threshold (upper)", check::range(0.5, 0.999));
    v("max_memory_mb", max_memory_mb, "Largest map the extraction builds, in MB (larger ones are refused)",
      check::range(1.0, 1e7));
  }
};
// Throws an Error naming the field of an invalid option (also checks what visit() cannot).
void validate(const VoxelMapOptions& options);

struct VoxelMap {
  enum State : uint8_t { kUnknown = 0, kFree = 1, kOccupied = 2 };
  double resolution = 0;
  Eigen::Vector3i origin = Eigen::Vector3i::Zero();  // index of voxel (0,0,0) in multiples of resolution
  Eigen::Vector3i dims = Eigen::Vector3i::Zero();
  std::vector<float> log_odds;  // 0 where there is no evidence
  std::vector<uint8_t> state;

  size_t size() const { return size_t(dims.x()) * size_t(dims.y()) * size_t(dims.z()); }
  size_t index(int x, int y, int z) const {
    return size_t(x) + size_t(dims.x()) * (size_t(y) + size_t(dims.y()) * size_t(z));
  }
  Eigen::Vector3d center(int x, int y, int z) const {
    return resolution * (origin.cast<double>() + Eigen::Vector3d(x + 0.5, y + 0.5, z + 0.5));
  }
  // The voxel containing p, or false outside the map.
  bool voxelAt(const Eigen::Vector3d& p, Eigen::Vector3i* v) const;
  uint8_t stateAt(const Eigen::Vector3d& p) const;  // kUnknown outside
  size_t count(State s) const;
};

// The voxel count and bytes a map over `bounds` at `options.resolution` needs; throws, with both
// figures, when it exceeds options.max_memory_mb (or the count overflows).
size_t voxelMapBytes(const Eigen::AlignedBox3d& bounds, const VoxelMapOptions& options, Eigen::Vector3i* dims = nullptr,
                     Eigen::Vector3i* origin = nullptr);

// Builds and keeps a map up to date. The first updateDensity(-1) is a full extraction; later calls
// with a budget re-evaluate the oldest voxels first (a round-robin sweep), so each costs at most the
// budget's field queries. carve() re-casts the rays of the given views and re-classifies.
class VoxelMapper {
 public:
  // bounds: the region to map (output frame). Throws on invalid options or a map over the memory limit.
  VoxelMapper(const VoxelMapOptions& options, const Eigen::AlignedBox3d& bounds);

  // Re-evaluates the density of up to `budget` voxels (-1: all); returns how many.
  size_t updateDensity(const DensitySource& source, int64_t budget = -1);
  // Casts the views' rays through the current densities and re-classifies every voxel.
  void carve(const std::vector<PosedCamera>& views);

  const VoxelMap& map() const { return map_; }
  const VoxelMapOptions& options() const { return options_; }
  const std::vector<float>& density() const { return density_; }  // largest sample per voxel

 private:
  VoxelMapOptions options_;
  VoxelMap map_;
  void removeSpeckles(const std::vector<std::vector<uint32_t>>& misses);

  std::vector<float> density_;
  size_t cursor_ = 0;
};

// The region to map: the source's bounds and the views' centres, padded by one voxel.
Eigen::AlignedBox3d voxelMapBounds(const DensitySource& source, const std::vector<PosedCamera>& views,
                                   double resolution);
// The part of voxelMapBounds the views observe: a pass at 4x the resolution (rays and densities), then
// the box of its voxels with evidence, one coarse voxel wider. Nothing outside it can be known.
Eigen::AlignedBox3d observedBounds(const DensitySource& source, const std::vector<PosedCamera>& views,
                                   const VoxelMapOptions& options);
// Everything at once: observedBounds, density, carving.
VoxelMap buildVoxelMap(const DensitySource& source, const std::vector<PosedCamera>& views,
                       const VoxelMapOptions& options);
// The same over bounds already found (observedBounds at options.resolution, e.g. by fittingResolution).
VoxelMap buildVoxelMap(const DensitySource& source, const std::vector<PosedCamera>& views,
                       const VoxelMapOptions& options, const Eigen::AlignedBox3d& bounds);

// The finest of options.resolution * 2^k (k = 0..max_doublings) at which buildVoxelMap fits in
// options.max_memory_mb (its coarse pass over voxelMapBounds and the map over the observed bounds);
// options.resolution itself when none does. For maps whose extent is not known in advance (a street
// run at the resolution of a room); an explicit resolution should be refused instead. *observed, when
// given and a resolution fits: its observedBounds, for buildVoxelMap (the coarse pass is not repeated).
double fittingResolution(const DensitySource& source, const std::vector<PosedCamera>& views,
                         const VoxelMapOptions& options, int max_doublings = 8,
                         Eigen::AlignedBox3d* observed = nullptr);

// OctoMap files (liboctomap): .bt (maximum-likelihood tree, free/occupied bits) or .ot (full tree with
// the log-odds), by extension; written atomically. octovis and every OctoMap tool read them.
void saveOctomap(const VoxelMap& map, const std::filesystem::path& path);

// ---- The 2D grid.
// The floor plane: normal . p + offset = 0, normal pointing up (towards the cameras).
struct FloorPlane {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  double offset = 0;
  int support = 0;               // occupied voxels on it (0 when given)
  std::string method = "given";  // "plane", "bottom of the walls" or "given"
  double height(const Eigen::Vector3d& p) const { return normal.dot(p) + offset; }
};
// The floor from the map. "Up" is the views' mean image -y axis (the world's z without views), refined
// by the surfaces' orientations (one of their principal normal directions, within 15 degrees). The
// floor is the lowest layer of occupied voxels below the cameras with 3x the voxels of a typical layer,
// refined by a plane fit ("plane"); when the cameras saw too little of it (looking out level), the
// lowest layer with a third of a typical layer's voxels, where the walls and furniture stand
// ("bottom of the walls"). Throws when there is no occupied voxel below the cameras.
FloorPlane detectFloor(const VoxelMap& map, const std::vector<PosedCamera>& views);

struct GridProjection {
  NavGrid grid;
  // The grid's frame in the output frame: z the floor's normal, z = 0 on the floor, x the output
  // frame's x (or y) projected on the floor. The grid's origin (origin_x, origin_y) is in this frame.
  SE3 T_out_grid;
};
// A height band [lo, hi] above the floor (output units) projected down: a cell is occupied when an
// occupied voxel is in its column within the band, free when a free one is and no occupied one,
// unknown otherwise. Throws when lo >= hi.
GridProjection projectToGrid(const VoxelMap& map, const FloorPlane& floor, double lo, double hi);

// The sidecar YAML of a map (NAME.meta.yaml beside NAME.bt or NAME.yaml): units and scale, frame,
// resolution, the floor and band of a grid, counts. Written atomically.
struct MapMeta {
  std::string kind;  // "octomap" or "grid"
  std::string frame = "map";
  double resolution = 0;
  double metres_per_unit = 0;  // 0: unknown (a monocular map without ground truth)
  std::string source;          // the model or run it came from
  const VoxelMap* voxels = nullptr;
  const GridProjection* grid = nullptr;
  const FloorPlane* floor = nullptr;
  double band_lo = 0, band_hi = 0;
};
void saveMapMeta(const MapMeta& meta, const std::filesystem::path& path);
// NAME.meta.yaml beside NAME.bt / NAME.yaml.
std::filesystem::path metaPathFor(const std::filesystem::path& map_path);

// The files a planner reads, with their sidecars: saveOctomap(path) (.bt/.ot) and NAME.meta.yaml.
void writeOctomapFiles(const VoxelMap& map, const std::filesystem::path& path, double metres_per_unit,
                       const std::string& source);
// The floor (`floor`, or detectFloor), the band projected (projectToGrid), the map_server pair at `yaml_path`
// (saveMapServer) and NAME.meta.yaml.
GridProjection writeGridFiles(const VoxelMap& map, const std::vector<PosedCamera>& views, const FloorPlane* floor,
                              double band_lo, double band_hi, const std::filesystem::path& yaml_path,
                              double metres_per_unit, const std::string& source);

}  // namespace nerfslam::nerf
