#pragma once
// instant-ngp's multi-scale occupancy grid for empty-space skipping.
//
// `cascades` nested grids of 128^3 cells; cascade m covers the cube of side 2^m centred at
// (0.5, 0.5, 0.5) in NeRF space (cascade 0 is the unit cube, the last one the scene AABB). Each cell
// keeps a decaying maximum of sampled "opacity units": density * kMinStep, i.e. the optical
// thickness of one minimal march step (instant-ngp's units). An update evaluates the density at one
// random point in each selected cell, sets value = max(value * decay, new) for every cell (cells not
// sampled in this update just decay), then marks cells occupied when value > min(threshold_cap,
// mean value of cascade 0). Coarser cascades are OR-ed with their finer children where they overlap,
// so a coarse lookup never hides a finely occupied cell.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <vector>

#include <Eigen/Core>

namespace nerfslam::nerf {

// Smallest march step: sqrt(3)/1024 (1024 steps across the unit cube's diagonal).
constexpr float kMinStep = 1.7320508f / 1024.f;

class OccupancyGrid {
 public:
  static constexpr int kRes = 128;
  static constexpr int kCells = kRes * kRes * kRes;

  // Densities (sigma, in 1/NeRF-length units) for n NeRF-space points xyz[3n]. May run threads inside.
  using DensityFn = std::function<void(const float* xyz, int n, float* sigma)>;

  explicit OccupancyGrid(int cascades = 1);

  int cascades() const { return cascades_; }
  // Cascades for an aabb_scale (power of two): log2(aabb_scale) + 1.
  static int cascadesForAabbScale(double aabb_scale);

  struct UpdateParams {
    // Cells sampled uniformly: one random cell in each of uniform_cells equal runs of the grid's cells
    // (stratified: even coverage, no repeats); -1: every cell once.
    int64_t uniform_cells = -1;
    // With uniform_cells -1: cubes of sweep_block^3 cells share one sample (a random point in the
    // cube), so the sweep costs 1/sweep_block^3 of the queries. A power of two in [1, kRes].
    int sweep_block = 1;
    int64_t occupied_cells = 0;  // extra samples among the currently occupied cells (stratified likewise)
    float decay = 0.95f;
    float threshold_cap = 0.01f;  // threshold = min(threshold_cap, mean value of cascade 0)
    uint64_t seed = 0;            // the sample positions are a pure function of this seed
    // NeRF-space points of known surfaces (e.g. sparse map points): their cells and the 26 around
    // them stay occupied, whatever their density, until the next update (a field that has not yet
    // put density there still gets samples at the surface for a depth loss to act on).
    std::vector<Eigen::Vector3f> keep_occupied;
    // NeRF-space segments known to be free space (a camera's line of sight to a surface it sees, short
    // of the surface): the cells they cross (at the finest cascade holding each point) are emptied
    // after the update, so neither training nor rendering samples there. keep_occupied wins.
    std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>> keep_empty;
  };
  void update(const DensityFn& density, const UpdateParams& params);

  // Cell containing NeRF-space point p at cascade `mip` (false outside that cascade's cube).
  bool occupied(const Eigen::Vector3f& p, int mip) const;
  bool occupiedCell(int mip, int x, int y, int z) const {
    const uint32_t i = cellIndex(x, y, z);
    return (bits_[size_t(mip) * kCells / 64 + i / 64] >> (i % 64)) & 1u;
  }
  // Coarse occupancy for skipping empty space in larger jumps: block (x, y, z) of level k (k = 1:
  // blocks of 4^3 cells, 32^3 blocks per cascade; k = 2: blocks of 16^3 cells, 8^3 per cascade) is
  // occupied when any of its cells is. Kept in sync with the cell bits.
  static constexpr int kBlockShift[3] = {0, 2, 4};
  bool occupiedBlock(int mip, int level, int x, int y, int z) const {
    const int r = kRes >> kBlockShift[level];
    const uint32_t i = uint32_t(x) + uint32_t(r) * (uint32_t(y) + uint32_t(r) * uint32_t(z));
    return (coarse_[size_t(level - 1)][size_t(mip) * size_t(r * r * r) / 64 + i / 64] >> (i % 64)) & 1u;
  }
  // Smallest cascade whose cube contains p (clamped to the last).
  int mipFromPos(const Eigen::Vector3f& p) const;
  // As instant-ngp: also coarse enough that a step of dt is not much smaller than a cell.
  int mipFromDt(float dt, const Eigen::Vector3f& p) const;
  // frexp's exponent for finite x >= 0 (x = f * 2^e, f in [0.5, 1); 0 for x = 0), without libm.
  static int frexpExponent(float x) {
    uint32_t b;
    std::memcpy(&b, &x, 4);
    const int e = int((b >> 23) & 0xffu);
    if (e == 0) return b == 0 ? 0 : -126;  // zero; subnormals (only ever clamped to mip 0)
    return e - 126;
  }
  // 2^-mip, exactly, without a division (the march calls this at every step); mip in [0, 126].
  static float invCascadeScale(int mip) {
    const uint32_t b = uint32_t(127 - mip) << 23;
    float f;
    std::memcpy(&f, &b, 4);
    return f;
  }

  // Sets every value to `value` and marks every cell occupied regardless of it (start of training:
  // everything is a candidate until the first update).
  void fill(float value);
  // Sets the cell values directly (tests, loading) and rebuilds the occupancy bits with `threshold`.
  void setValues(std::vector<float> values, float threshold);
  const std::vector<float>& values() const { return values_; }  // cascades * kCells, index mip*kCells + cell
  float threshold() const { return threshold_; }
  size_t occupiedCells() const;  // over every cascade
  double occupiedFraction() const;
  // Centre of a cell in NeRF space and the side length of cells in cascade mip.
  Eigen::Vector3f cellCenter(int mip, int x, int y, int z) const;
  static float cellSize(int mip) { return std::ldexp(1.f, mip) / kRes; }

  static uint32_t cellIndex(int x, int y, int z) { return uint32_t(x) + kRes * (uint32_t(y) + kRes * uint32_t(z)); }

 private:
  void rebuildBits();
  void rebuildCoarse();
  void pinCells(const std::vector<Eigen::Vector3f>& points);
  void carveSegments(const std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>>& segments);

  int cascades_;
  float threshold_ = 0;
  std::vector<float> values_;
  std::vector<uint64_t> bits_;       // cascades * kCells bits
  std::vector<uint64_t> coarse_[2];  // block levels 1 and 2 (see occupiedBlock)
  // carveSegments' last segments and the cells they cross (sorted, unique).
  std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>> carve_segments_;
  std::vector<uint32_t> carve_cells_;
};

}  // namespace nerfslam::nerf
