#pragma once
// Multiresolution hash encoding (Müller et al. 2022) with instant-ngp's exact level geometry
// (tiny-cuda-nn grid.h):
//   b        = exp(ln(N_max / N_min) / (L - 1))          (per-level scale)
//   scale_l  = N_min * b^l - 1                            (computed as exp2(l*log2 b)*N_min - 1)
//   res_l    = ceil(scale_l) + 1                          (grid vertices per axis)
//   pos      = fma(x, scale_l, 0.5) (one rounding, as tcnn's fmaf); corner = floor(pos);  frac = pos - corner
//   size_l   = min(next_multiple(res_l^3, 8), T)          (table entries of the level)
//   index    = dense (x + y*res + z*res^2) while res^3 <= T, else the spatial hash
//              (x*1) ^ (y*2654435761) ^ (z*805459861) in uint32 arithmetic; then mod size_l.
// The +1 corner of a cell at x close to 1 reaches coordinate res_l, which a dense level wraps
// into the next row exactly as tiny-cuda-nn does; inputs are positions in [0,1]^3 (clamped).
// Features are trilinearly interpolated from the 8 corners; 2 features per entry, stored
// entry-major, levels concatenated.
#include <sys/mman.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <new>
#include <vector>

namespace nerfslam::nerf {

struct GridLevel {
  float scale = 0;          // scale_l above
  uint32_t resolution = 0;  // res_l above
  uint32_t size = 0;        // entries in this level's table
  uint32_t offset = 0;      // first entry of the level in the concatenated table
  bool dense = false;       // true when res^3 <= T (no hashing, no collisions)
};

// Allocator for the large tables (parameters, moments, gradients): 2 MiB-aligned and advised as
// transparent huge pages. The fine levels are random accesses over tens of MiB; with 4 KiB pages
// nearly every one is also a TLB miss.
template <class T>
struct HugePageAllocator {
  using value_type = T;
  HugePageAllocator() = default;
  template <class U>
  HugePageAllocator(const HugePageAllocator<U>&) {}  // NOLINT(google-explicit-constructor)
  T* allocate(size_t n) {
    constexpr size_t kHuge = size_t(2) << 20;
    const size_t bytes = n * sizeof(T);
    const size_t align = bytes >= kHuge ? kHuge : alignof(std::max_align_t) * 4;
    void* p = std::aligned_alloc(align, (bytes + align - 1) / align * align);
    if (!p) throw std::bad_alloc();
#ifdef MADV_HUGEPAGE
    if (bytes >= kHuge) madvise(p, (bytes + kHuge - 1) / kHuge * kHuge, MADV_HUGEPAGE);
#endif
    return static_cast<T*>(p);
  }
  void deallocate(T* p, size_t) { std::free(p); }
  template <class U>
  bool operator==(const HugePageAllocator<U>&) const {
    return true;
  }
  template <class U>
  bool operator!=(const HugePageAllocator<U>&) const {
    return false;
  }
};
template <class T>
using HugeVector = std::vector<T, HugePageAllocator<T>>;

// Level geometry for L levels, N_min, N_max, log2 T.
std::vector<GridLevel> gridLevels(int n_levels, int base_resolution, double finest_resolution, int log2_hashmap_size);

// The spatial hash and the level index of an integer grid corner (instant-ngp's grid_index).
inline uint32_t gridHash(uint32_t x, uint32_t y, uint32_t z) { return x ^ (y * 2654435761u) ^ (z * 805459861u); }
inline uint32_t gridIndex(const GridLevel& level, uint32_t x, uint32_t y, uint32_t z) {
  const uint32_t r = level.resolution;
  const uint32_t i = level.dense ? x + y * r + z * r * r : gridHash(x, y, z);
  return i % level.size;
}

// Kernels over a batch of n samples. pos is n*3 in [0,1]. Encodings are feature-major
// ("SoA"): enc[k * ld + s] for feature k = 2*level + f of sample s (ld >= n).
// table: the concatenated level tables (size sum(levels.size) * 2 floats).
struct HashGridView {
  const GridLevel* levels = nullptr;
  int n_levels = 0;
  const float* table = nullptr;
};

// Forward encoding (dispatched to the best SIMD target) and its scalar reference.
void hashEncode(const HashGridView& grid, const float* pos, size_t n, float* enc, size_t ld);
void hashEncodeScalar(const HashGridView& grid, const float* pos, size_t n, float* enc, size_t ld);

// Backward: grad_table[2*e + f] += sum over samples and corners of w * d_enc; d_enc is
// sample-major [s][2*L] here (what the MLP backward produces). `touched` is a bitmap over entries
// (bit e set when entry e received a gradient). Dispatched and scalar reference.
void hashEncodeBackward(const HashGridView& grid, const float* pos, size_t n, const float* d_enc, float* grad_table,
                        uint64_t* touched);
void hashEncodeBackwardScalar(const HashGridView& grid, const float* pos, size_t n, const float* d_enc,
                              float* grad_table, uint64_t* touched);

// Backward of one level l (the training path: the optimiser scatters level by level, so each
// level's gradient buffer stays in cache and levels run on different threads without locks):
// grad_level[2*e + f] += sum over samples and corners of w * d_level[2*s + f], for entries e
// relative to the level (size levels[l].size), d_level sample-major [s][2]. touched_level is a
// bitmap over the level's entries (bit e set when entry e received a non-zero sample gradient, the
// same rule as hashEncodeBackward). Contributions are added in sample order, corners 0..7.
void hashEncodeBackwardLevel(const HashGridView& grid, int level, const float* pos, size_t n, const float* d_level,
                             float* grad_level, uint64_t* touched_level);
void hashEncodeBackwardLevelScalar(const HashGridView& grid, int level, const float* pos, size_t n,
                                   const float* d_level, float* grad_level, uint64_t* touched_level);

// d enc / d pos contracted with d_enc (sample-major [s][2L]): out[s*3 + d] = sum_k d_enc[s][k] *
// d enc_k / d pos_d. Scalar (used for normals, not in the training loop).
void hashEncodePositionGradient(const HashGridView& grid, const float* pos, size_t n, const float* d_enc, float* out);

}  // namespace nerfslam::nerf
