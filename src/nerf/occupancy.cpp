#include "nerfslam/nerf/occupancy.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "nerfslam/core/error.h"

namespace nerfslam::nerf {

OccupancyGrid::OccupancyGrid(int cascades) : cascades_(cascades) {
  if (cascades < 1 || cascades > 8) fail("occupancy grid: cascades must be in [1, 8], got {}", cascades);
  values_.assign(size_t(cascades) * kCells, 0.f);
  bits_.assign(size_t(cascades) * kCells / 64, ~uint64_t(0));
  for (int k = 1; k <= 2; ++k) {
    const size_t r = size_t(kRes >> kBlockShift[k]);
    coarse_[k - 1].assign((size_t(cascades) * r * r * r + 63) / 64, ~uint64_t(0));
  }
}

int OccupancyGrid::cascadesForAabbScale(double aabb_scale) {
  return 1 + std::max(0, int(std::lround(std::log2(std::max(1.0, aabb_scale)))));
}

int OccupancyGrid::mipFromPos(const Eigen::Vector3f& p) const {
  if (cascades_ == 1) return 0;
  const float maxval = (p.array() - 0.5f).abs().maxCoeff();
  if (!std::isfinite(maxval)) return cascades_ - 1;
  // maxval = f * 2^exponent, f in [0.5, 1) (frexp).
  return std::clamp(frexpExponent(maxval) + 1, 0, cascades_ - 1);
}

int OccupancyGrid::mipFromDt(float dt, const Eigen::Vector3f& p) const {
  if (cascades_ == 1) return 0;
  const float x = dt * kRes;
  const int exponent = std::isfinite(x) && x >= 0.f ? frexpExponent(x) : cascades_ - 1;
  return std::clamp(std::max(exponent, mipFromPos(p)), 0, cascades_ - 1);
}

bool OccupancyGrid::occupied(const Eigen::Vector3f& p, int mip) const {
  const float inv = invCascadeScale(mip);
  int c[3];
  for (int a = 0; a < 3; ++a) {
    const float u = ((p[a] - 0.5f) * inv + 0.5f) * kRes;
    if (!(u >= 0.f && u < float(kRes))) return false;
    c[a] = int(u);
  }
  return occupiedCell(mip, c[0], c[1], c[2]);
}

Eigen::Vector3f OccupancyGrid::cellCenter(int mip, int x, int y, int z) const {
  const float s = std::ldexp(1.f, mip);
  return Eigen::Vector3f(((x + 0.5f) / kRes - 0.5f) * s + 0.5f, ((y + 0.5f) / kRes - 0.5f) * s + 0.5f,
                         ((z + 0.5f) / kRes - 0.5f) * s + 0.5f);
}

void OccupancyGrid::fill(float value) {
  std::fill(values_.begin(), values_.end(), value);
  threshold_ = 0;
  std::fill(bits_.begin(), bits_.end(), ~uint64_t(0));
  for (auto& c : coarse_) std::fill(c.begin(), c.end(), ~uint64_t(0));
}

void OccupancyGrid::setValues(std::vector<float> values, float threshold) {
  if (values.size() != values_.size())
    fail("occupancy grid: {} values given, {} expected", values.size(), values_.size());
  values_ = std::move(values);
  threshold_ = threshold;
  rebuildBits();
}

double OccupancyGrid::occupiedFraction() const {
  size_t n = 0;
  for (uint64_t w : bits_) n += size_t(__builtin_popcountll(w));
  return double(n) / double(values_.size());
}

namespace {

// The even bits of x gathered into the low 32 bits (bit 2k -> bit k).
uint64_t gatherEvenBits(uint64_t x) {
  x &= 0x5555555555555555ull;
  x = (x | (x >> 1)) & 0x3333333333333333ull;
  x = (x | (x >> 2)) & 0x0f0f0f0f0f0f0f0full;
  x = (x | (x >> 4)) & 0x00ff00ff00ff00ffull;
  x = (x | (x >> 8)) & 0x0000ffff0000ffffull;
  return (x | (x >> 16)) & 0x00000000ffffffffull;
}

}  // namespace

void OccupancyGrid::sortCellIndices(std::vector<uint32_t>& cells) {
  // LSD radix sort in two passes of 12 bits: indices are below 8 cascades * 2^21 cells = 2^24.
  static_assert(size_t(kCells) * 8 <= (size_t(1) << 24), "cell indices must fit 24 bits");
  std::vector<uint32_t> tmp(cells.size());
  for (int shift = 0; shift < 24; shift += 12) {
    std::vector<uint32_t> start(4097, 0u);
    for (uint32_t c : cells) ++start[((c >> shift) & 4095u) + 1];
    for (size_t d = 1; d < start.size(); ++d) start[d] += start[d - 1];
    for (uint32_t c : cells) tmp[start[(c >> shift) & 4095u]++] = c;
    cells.swap(tmp);
  }
}

void OccupancyGrid::rebuildBits() {
  // 64 consecutive values make one word (a loop the compiler vectorises).
  const float t = threshold_;
  for (size_t w = 0; w < bits_.size(); ++w) {
    const float* v = values_.data() + 64 * w;
    uint64_t b = 0;
    for (int k = 0; k < 64; ++k) b |= uint64_t(v[k] > t) << k;
    bits_[w] = b;
  }
  // Max-pool finer cascades into the overlapping centre of the next coarser one: cell (x, y, z) of
  // cascade m-1 lies in cell (h/2 + x/2, h/2 + y/2, h/2 + z/2) of cascade m. A row of kRes = 128
  // cells is two words; the pairs of x of a word fold into 32 bits of the coarser row.
  static_assert(kRes == 128, "the max-pool below folds rows of two 64-bit words");
  constexpr int h = kRes / 2;
  for (int m = 1; m < cascades_; ++m) {
    const uint64_t* fine = bits_.data() + size_t(m - 1) * kCells / 64;
    uint64_t* coarse = bits_.data() + size_t(m) * kCells / 64;
    for (int z = 0; z < kRes; ++z)
      for (int y = 0; y < kRes; ++y) {
        const uint32_t row = cellIndex(0, y, z) / 64;
        const uint32_t crow = cellIndex(0, h / 2 + y / 2, h / 2 + z / 2) / 64;
        const uint64_t w0 = fine[row], w1 = fine[row + 1];
        if (w0) coarse[crow] |= gatherEvenBits(w0 | (w0 >> 1)) << 32;  // x 0..63 -> coarse x 32..63
        if (w1) coarse[crow + 1] |= gatherEvenBits(w1 | (w1 >> 1));    // x 64..127 -> coarse x 64..95
      }
  }
  rebuildCoarse();
}

void OccupancyGrid::rebuildCoarse() {
  for (int k = 1; k <= 2; ++k) {
    const int sh = kBlockShift[k], r = kRes >> sh;
    const size_t per = size_t(r) * size_t(r) * size_t(r);
    std::vector<uint64_t>& c = coarse_[k - 1];
    std::fill(c.begin(), c.end(), 0);
    for (int m = 0; m < cascades_; ++m) {
      const uint64_t* b = bits_.data() + size_t(m) * kCells / 64;
      // A 64-bit word of cell bits is 64 consecutive x at one (y, z): blocks of 4 or 16 cells in x.
      for (int z = 0; z < kRes; ++z)
        for (int y = 0; y < kRes; ++y) {
          const uint32_t row = cellIndex(0, y, z) / 64;
          for (int wx = 0; wx < kRes / 64; ++wx) {
            uint64_t word = b[row + uint32_t(wx)];
            while (word) {
              const int x = wx * 64 + __builtin_ctzll(word);
              const size_t i =
                  size_t(m) * per + size_t(x >> sh) + size_t(r) * (size_t(y >> sh) + size_t(r) * size_t(z >> sh));
              c[i / 64] |= uint64_t(1) << (i % 64);
              // Skip the rest of this block's cells in the word.
              const int next = ((x >> sh) + 1) << sh;
              if (next - wx * 64 >= 64) break;
              word &= ~((uint64_t(1) << (next - wx * 64)) - 1);
            }
          }
        }
    }
  }
}

void OccupancyGrid::update(const DensityFn& density, const UpdateParams& prm) {
  const size_t total = values_.size();
  std::mt19937_64 rng(prm.seed);
  std::uniform_real_distribution<float> u01(0.f, 1.f);

  const int block = prm.uniform_cells < 0 ? prm.sweep_block : 1;
  if (block < 1 || block > kRes || (block & (block - 1)) != 0)
    fail("occupancy grid: sweep_block must be a power of two in [1, {}], got {}", kRes, block);

  // Cells to sample this round (in a block sweep, each block's lowest corner cell stands for it).
  std::vector<uint32_t> cells;  // global index mip*kCells + cell
  if (prm.uniform_cells < 0) {
    const int nb = kRes / block;
    cells.reserve(size_t(cascades_) * size_t(nb) * size_t(nb) * size_t(nb));
    for (int mip = 0; mip < cascades_; ++mip)
      for (int z = 0; z < kRes; z += block)
        for (int y = 0; y < kRes; y += block)
          for (int x = 0; x < kRes; x += block) cells.push_back(uint32_t(mip) * uint32_t(kCells) + cellIndex(x, y, z));
  } else {
    std::uniform_int_distribution<uint32_t> pick(0, uint32_t(total - 1));
    cells.reserve(size_t(prm.uniform_cells + prm.occupied_cells));
    for (int64_t i = 0; i < prm.uniform_cells; ++i) cells.push_back(pick(rng));
  }
  if (prm.occupied_cells > 0) {
    std::vector<uint32_t> occ;
    for (size_t w = 0; w < bits_.size(); ++w) {
      uint64_t b = bits_[w];
      while (b) {
        const int k = __builtin_ctzll(b);
        occ.push_back(uint32_t(w * 64 + size_t(k)));
        b &= b - 1;
      }
    }
    if (!occ.empty()) {
      std::uniform_int_distribution<size_t> pick(0, occ.size() - 1);
      for (int64_t i = 0; i < prm.occupied_cells; ++i) cells.push_back(occ[pick(rng)]);
    }
  }

  // Evaluate the picks in cell order (sorted: the picks are a multiset of cell indices):
  // neighbouring queries then share hash-table lines, where random order makes every level's
  // lookups miss the cache. The positions stay a pure function of the seed.
  if (prm.uniform_cells >= 0 && !cells.empty()) sortCellIndices(cells);

  // values = max(values * decay, the largest density sampled in the cell): the decay first, then
  // each sample's max (max is exact, so the order does not change a bit).
  for (float& v : values_) v *= prm.decay;
  constexpr size_t kChunk = 1 << 16;
  std::vector<float> xyz(3 * kChunk), sigma(kChunk);
  for (size_t begin = 0; begin < cells.size(); begin += kChunk) {
    const size_t n = std::min(kChunk, cells.size() - begin);
    for (size_t k = 0; k < n; ++k) {
      const uint32_t g = cells[begin + k];
      const int mip = int(g / kCells);
      const uint32_t c = g % kCells;
      const int x = int(c % kRes), y = int((c / kRes) % kRes), z = int(c / (kRes * kRes));
      const float s = std::ldexp(1.f, mip);
      xyz[3 * k + 0] = ((x + block * u01(rng)) / kRes - 0.5f) * s + 0.5f;
      xyz[3 * k + 1] = ((y + block * u01(rng)) / kRes - 0.5f) * s + 0.5f;
      xyz[3 * k + 2] = ((z + block * u01(rng)) / kRes - 0.5f) * s + 0.5f;
    }
    density(xyz.data(), int(n), sigma.data());
    for (size_t k = 0; k < n; ++k) {
      float v = sigma[k] * kMinStep;
      if (!std::isfinite(v)) v = 0.f;  // a diverged field must not poison the grid
      const uint32_t g = cells[begin + k];
      if (block == 1) {
        values_[g] = std::max(values_[g], v);
        continue;
      }
      const uint32_t c = g % kCells;
      const size_t base = size_t(g / kCells) * kCells;
      const int x0 = int(c % kRes), y0 = int((c / kRes) % kRes), z0 = int(c / (kRes * kRes));
      for (int z = z0; z < z0 + block; ++z)
        for (int y = y0; y < y0 + block; ++y)
          for (int x = x0; x < x0 + block; ++x) {
            float& f = values_[base + cellIndex(x, y, z)];
            f = std::max(f, v);
          }
    }
  }
  double sum = 0;
  for (size_t i = 0; i < size_t(kCells); ++i) sum += values_[i];
  threshold_ = std::min(prm.threshold_cap, float(sum / kCells));
  carveSegments(prm.keep_empty);
  pinCells(prm.keep_occupied);
  rebuildBits();
}

void OccupancyGrid::carveSegments(const std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>>& segments) {
  // The cells depend on the segments alone: the same segments as at the last update (the poses and
  // points have not moved, as through a final training) reuse them.
  const bool same = segments.size() == carve_segments_.size() &&
                    std::equal(segments.begin(), segments.end(), carve_segments_.begin(),
                               [](const auto& a, const auto& b) { return a.first == b.first && a.second == b.second; });
  if (!same) {
    carve_segments_ = segments;
    carve_cells_.clear();
    auto carve = [this](const Eigen::Vector3f& p) {
      const int mip = mipFromPos(p);
      const float inv = invCascadeScale(mip);
      int c[3];
      for (int k = 0; k < 3; ++k) {
        const float u = ((p[k] - 0.5f) * inv + 0.5f) * kRes;
        if (!(u >= 0.f && u < float(kRes))) return;
        c[k] = int(u);
      }
      carve_cells_.push_back(uint32_t(mip) * uint32_t(kCells) + cellIndex(c[0], c[1], c[2]));
    };
    for (const auto& [a, b] : segments) {
      if (!a.allFinite() || !b.allFinite()) continue;
      // Steps of half a cell of the cascade at the nearer end (cascades only grow along the segment
      // away from the centre, so no cell is skipped where cells are larger), both ends included.
      const float step = 0.5f * cellSize(std::min(mipFromPos(a), mipFromPos(b)));
      const int n = std::max(1, int(std::ceil((b - a).norm() / step)));
      for (int k = 0; k <= n; ++k) carve(a + (float(k) / float(n)) * (b - a));
    }
    std::sort(carve_cells_.begin(), carve_cells_.end());
    carve_cells_.erase(std::unique(carve_cells_.begin(), carve_cells_.end()), carve_cells_.end());
  }
  for (uint32_t i : carve_cells_) values_[i] = 0.f;
}

void OccupancyGrid::pinCells(const std::vector<Eigen::Vector3f>& points) {
  // The cells' values are raised just over the threshold (not only their bits set), so the values
  // alone (a saved model) give the same occupancy.
  std::vector<uint32_t> pinned;
  for (const Eigen::Vector3f& p : points) {
    if (!p.allFinite()) continue;
    const int mip = mipFromPos(p);
    const float inv = invCascadeScale(mip);
    int c[3];
    bool inside = true;
    for (int a = 0; a < 3; ++a) {
      const float u = ((p[a] - 0.5f) * inv + 0.5f) * kRes;
      inside &= u >= 0.f && u < float(kRes);
      c[a] = inside ? int(u) : 0;
    }
    if (!inside) continue;
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int x = c[0] + dx, y = c[1] + dy, z = c[2] + dz;
          if (x < 0 || y < 0 || z < 0 || x >= kRes || y >= kRes || z >= kRes) continue;
          pinned.push_back(uint32_t(mip) * uint32_t(kCells) + cellIndex(x, y, z));
        }
  }
  const float above = std::nextafter(threshold_, INFINITY);
  for (uint32_t i : pinned) values_[i] = std::max(values_[i], above);
}

}  // namespace nerfslam::nerf
