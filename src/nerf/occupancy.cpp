#include "nerfslam/nerf/occupancy.h"

#include <algorithm>
#include <cmath>
#include <cstring>

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

size_t OccupancyGrid::occupiedCells() const {
  size_t n = 0;
  for (uint64_t w : bits_) n += size_t(__builtin_popcountll(w));
  return n;
}

double OccupancyGrid::occupiedFraction() const { return double(occupiedCells()) / double(values_.size()); }

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

void OccupancyGrid::rebuildBits() {
  // 64 consecutive values make one word, 8 at a time: eight 0/1 bytes (compares the compiler
  // vectorises) gathered into 8 bits by one multiplication (byte i lands on bit 56 + i, no carries).
  const float t = threshold_;
  for (size_t w = 0; w < bits_.size(); ++w) {
    const float* v = values_.data() + 64 * w;
    uint64_t b = 0;
    for (int g = 0; g < 8; ++g) {
      uint8_t m[8];
      for (int k = 0; k < 8; ++k) m[k] = uint8_t(v[8 * g + k] > t);
      uint64_t x;
      std::memcpy(&x, m, 8);
      b |= ((x * 0x0102040810204080ull) >> 56) << (8 * g);
    }
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

namespace {

// splitmix64's finaliser: a counter-based generator, so the draws of pick k are a function of the
// seed and k alone (no sequential state to share between picks or threads).
uint64_t mix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// 16 bits of h (from bit `shift`) as a float in [0, 1): with a cell index below 2^7 the sum x + u
// holds in a float's 24 bits exactly, so a point drawn in a cell never rounds into the next one.
float unit16(uint64_t h, int shift) { return float((h >> shift) & 0xffffu) * (1.f / 65536.f); }

// n stratified draws over [0, count): draw k is uniform in [k count / n, (k + 1) count / n), so the
// draws come out sorted, spread evenly, and (for n <= count) without repeats.
void stratifiedRanks(uint64_t count, int64_t n, uint64_t seed, std::vector<uint64_t>* out) {
  out->resize(size_t(n));
  const double stride = double(count) / double(n);
  for (int64_t k = 0; k < n; ++k) {
    const double u = double(mix64(seed + uint64_t(k)) >> 11) * (1.0 / 9007199254740992.0);
    (*out)[size_t(k)] = std::min<uint64_t>(count - 1, uint64_t((double(k) + u) * stride));
  }
}

}  // namespace

void OccupancyGrid::update(const DensityFn& density, const UpdateParams& prm) {
  const size_t total = values_.size();
  const int block = prm.uniform_cells < 0 ? prm.sweep_block : 1;
  if (block < 1 || block > kRes || (block & (block - 1)) != 0)
    fail("occupancy grid: sweep_block must be a power of two in [1, {}], got {}", kRes, block);
  const uint64_t seed_uniform = mix64(prm.seed), seed_occupied = mix64(prm.seed ^ 0x6A09E667F3BCC909ull),
                 seed_position = mix64(prm.seed ^ 0xBB67AE8584CAA73Bull);

  // Cells to sample this round (global index mip*kCells + cell; in a block sweep, each block's
  // lowest corner cell stands for it), in cell order: neighbouring queries then share hash-table
  // lines, where random order makes every level's lookups miss the cache. The picks are stratified
  // (one in each of uniform_cells equal runs of cells, one in each of occupied_cells equal runs of
  // the occupied cells), so they come sorted, cover the grid evenly and repeat no cell.
  std::vector<uint32_t> cells;
  if (prm.uniform_cells < 0) {
    const int nb = kRes / block;
    cells.reserve(size_t(cascades_) * size_t(nb) * size_t(nb) * size_t(nb));
    for (int mip = 0; mip < cascades_; ++mip)
      for (int z = 0; z < kRes; z += block)
        for (int y = 0; y < kRes; y += block)
          for (int x = 0; x < kRes; x += block) cells.push_back(uint32_t(mip) * uint32_t(kCells) + cellIndex(x, y, z));
  } else {
    std::vector<uint64_t> ranks;
    stratifiedRanks(total, prm.uniform_cells, seed_uniform, &ranks);
    cells.reserve(size_t(prm.uniform_cells + std::max<int64_t>(0, prm.occupied_cells)));
    for (uint64_t r : ranks) cells.push_back(uint32_t(r));
    const uint64_t occupied = occupiedCells();
    if (prm.occupied_cells > 0 && occupied > 0) {
      // The ranks among the occupied cells, then the cells: a walk over the words, counting bits.
      stratifiedRanks(occupied, prm.occupied_cells, seed_occupied, &ranks);
      const size_t mid = cells.size();
      size_t w = 0;
      uint64_t before = 0;  // occupied cells in the words before w
      int in_word = __builtin_popcountll(bits_[0]);
      for (uint64_t r : ranks) {
        while (before + uint64_t(in_word) <= r) {
          before += uint64_t(in_word);
          in_word = __builtin_popcountll(bits_[++w]);
        }
        uint64_t b = bits_[w];
        for (uint64_t j = r - before; j > 0; --j) b &= b - 1;
        cells.push_back(uint32_t(w * 64 + size_t(__builtin_ctzll(b))));
      }
      std::inplace_merge(cells.begin(), cells.begin() + std::ptrdiff_t(mid), cells.end());
    }
  }

  // values = max(values * decay, the largest density sampled in the cell): the decay first, then
  // each sample's max (max is exact, so the order does not change a bit).
  const float decay = prm.decay;  // a local: prm could alias values_, which stops the loop's vectorisation
  for (float& v : values_) v *= decay;
  constexpr size_t kChunk = 1 << 16;
  std::vector<float> xyz(3 * kChunk), sigma(kChunk);
  for (size_t begin = 0; begin < cells.size(); begin += kChunk) {
    const size_t n = std::min(kChunk, cells.size() - begin);
    for (size_t k = 0; k < n; ++k) {
      const uint32_t g = cells[begin + k];
      const int mip = int(g / kCells);
      const uint32_t c = g % kCells;
      const int x = int(c % kRes), y = int((c / kRes) % kRes), z = int(c / (kRes * kRes));
      const float s = float(1u << mip), fb = float(block);
      const uint64_t h = mix64(seed_position + begin + k);  // a random point in the cell (block)
      xyz[3 * k + 0] = ((float(x) + fb * unit16(h, 0)) / kRes - 0.5f) * s + 0.5f;
      xyz[3 * k + 1] = ((float(y) + fb * unit16(h, 16)) / kRes - 0.5f) * s + 0.5f;
      xyz[3 * k + 2] = ((float(z) + fb * unit16(h, 32)) / kRes - 0.5f) * s + 0.5f;
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
  // The mean of cascade 0 in eight running sums (independent additions pipeline; a fixed order).
  double part[8] = {};
  for (size_t i = 0; i < size_t(kCells); i += 8)
    for (int j = 0; j < 8; ++j) part[j] += double(values_[i + size_t(j)]);
  const double sum = ((part[0] + part[1]) + (part[2] + part[3])) + ((part[4] + part[5]) + (part[6] + part[7]));
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
  const float above = std::nextafter(threshold_, INFINITY);
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
          float& f = values_[size_t(mip) * kCells + cellIndex(x, y, z)];
          f = std::max(f, above);
        }
  }
}

}  // namespace nerfslam::nerf
