// Multiresolution hash encoding: level geometry, scalar reference kernels and Highway SIMD kernels
// (compiled once per target through foreach_target.h; see hash_grid.h for the formulas).
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "nerf/hash_grid.cpp"
#include <hwy/cache_control.h>
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include <algorithm>
#include <cmath>

#include "nerfslam/nerf/hash_grid.h"

#ifndef NERFSLAM_NERF_HASH_GRID_ONCE
#define NERFSLAM_NERF_HASH_GRID_ONCE
namespace nerfslam::nerf::detail {

// Clamp to [0,1]; NaN maps to 0 so that bad input can never index outside the tables.
inline float clamp01(float x) { return x > 0.f ? (x < 1.f ? x : 1.f) : 0.f; }

// Corner c (bit 0: +x, bit 1: +y, bit 2: +z) of the cell containing p on `level`: fills the 8
// entry indices (absolute, i.e. including the level offset) and trilinear weights.
inline void cellCorners(const GridLevel& level, const float* p, uint32_t* idx, float* w, float* frac = nullptr,
                        uint32_t* base = nullptr) {
  uint32_t g[3];
  float f[3];
  for (int d = 0; d < 3; ++d) {
    const float x = std::fma(clamp01(p[d]), level.scale, 0.5f);  // tcnn: fmaf(scale, x, 0.5f)
    const float fl = std::floor(x);
    g[d] = uint32_t(int32_t(fl));
    f[d] = x - fl;
  }
  for (int c = 0; c < 8; ++c) {
    const uint32_t cx = g[0] + (c & 1), cy = g[1] + ((c >> 1) & 1), cz = g[2] + ((c >> 2) & 1);
    idx[c] = level.offset + gridIndex(level, cx, cy, cz);
    const float wx = (c & 1) ? f[0] : 1.f - f[0];
    const float wy = (c & 2) ? f[1] : 1.f - f[1];
    const float wz = (c & 4) ? f[2] : 1.f - f[2];
    w[c] = wx * wy * wz;
  }
  if (frac)
    for (int d = 0; d < 3; ++d) frac[d] = f[d];
  if (base)
    for (int d = 0; d < 3; ++d) base[d] = g[d];
}

}  // namespace nerfslam::nerf::detail
#endif

HWY_BEFORE_NAMESPACE();
namespace nerfslam::nerf::HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

// Indices (relative to the level) and weights of the 8 corners for Lanes(df) samples.
template <class DF, class VF = hn::Vec<DF>, class DU = hn::RebindToUnsigned<DF>, class VU = hn::Vec<DU>>
HWY_INLINE void CornersVec(DF df, const GridLevel& L, VF px, VF py, VF pz, VU* idx, VF* w) {
  const DU du;
  const hn::RebindToSigned<DF> di;
  const VF scale = hn::Set(df, L.scale), half = hn::Set(df, 0.5f), one = hn::Set(df, 1.f);
  // Fused multiply-add, as tiny-cuda-nn's fmaf(scale, x, 0.5f) and the scalar reference: every
  // target then picks the same cell and fraction.
  const VF x = hn::MulAdd(px, scale, half), y = hn::MulAdd(py, scale, half), z = hn::MulAdd(pz, scale, half);
  const VF fx = hn::Floor(x), fy = hn::Floor(y), fz = hn::Floor(z);
  const VU gx = hn::BitCast(du, hn::ConvertTo(di, fx)), gy = hn::BitCast(du, hn::ConvertTo(di, fy)),
           gz = hn::BitCast(du, hn::ConvertTo(di, fz));
  const VF wx1 = hn::Sub(x, fx), wy1 = hn::Sub(y, fy), wz1 = hn::Sub(z, fz);
  const VF wx0 = hn::Sub(one, wx1), wy0 = hn::Sub(one, wy1), wz0 = hn::Sub(one, wz1);
  const VU u1 = hn::Set(du, 1u);
  const VU size = hn::Set(du, L.size);
  VU cx[2] = {gx, hn::Add(gx, u1)};
  VU cy[2], cz[2];
  if (L.dense) {
    const VU r = hn::Set(du, L.resolution), r2 = hn::Set(du, L.resolution * L.resolution);
    cy[0] = hn::Mul(gy, r);
    cy[1] = hn::Add(cy[0], r);
    cz[0] = hn::Mul(gz, r2);
    cz[1] = hn::Add(cz[0], r2);
  } else {
    const VU p1 = hn::Set(du, 2654435761u), p2 = hn::Set(du, 805459861u);
    cy[0] = hn::Mul(gy, p1);
    cy[1] = hn::Add(cy[0], p1);  // (y+1)*p1 = y*p1 + p1 in uint32
    cz[0] = hn::Mul(gz, p2);
    cz[1] = hn::Add(cz[0], p2);
  }
  const VU mask = hn::Set(du, L.size - 1);
  const VF wyz[4] = {hn::Mul(wy0, wz0), hn::Mul(wy1, wz0), hn::Mul(wy0, wz1), hn::Mul(wy1, wz1)};
  for (int c = 0; c < 8; ++c) {
    const int bx = c & 1, by = (c >> 1) & 1, bz = (c >> 2) & 1;
    VU i;
    if (L.dense) {
      i = hn::Add(hn::Add(cx[bx], cy[by]), cz[bz]);
      i = hn::Min(i, hn::Sub(i, size));  // i % size: i < 2*size on dense levels
    } else {
      i = hn::And(hn::Xor(hn::Xor(cx[bx], cy[by]), cz[bz]), mask);  // size = T is a power of 2
    }
    idx[c] = i;
    w[c] = hn::Mul(bx ? wx1 : wx0, wyz[by + 2 * bz]);
  }
}

HWY_INLINE void LoadPositions(const float* pos, size_t s, size_t lanes, float* xs, float* ys, float* zs) {
  for (size_t j = 0; j < lanes; ++j) {
    const float* p = pos + 3 * (s + j);
    xs[j] = detail::clamp01(p[0]);
    ys[j] = detail::clamp01(p[1]);
    zs[j] = detail::clamp01(p[2]);
  }
}

// ---- Blocked, software-pipelined encoding.
//
// The hashed (and the large dense) levels are random accesses into tables far larger than L2: the
// kernel is bound by how many cache misses it keeps in flight, not by arithmetic. Samples are
// processed in blocks of kBlock; for each block an index pass computes the 8 corner indices and
// weights of every sample on one level, stores them in a small ring of scratch slots and
// prefetches the lines, kAhead levels ahead of the gather pass that interpolates. By the time a
// level is gathered its lines have been requested for the whole block (kBlock x 4 lines per level
// in flight rather than one vector's worth), and the gathers read both features of a corner as one
// 64-bit element.
constexpr size_t kBlock = 64;
constexpr int kAhead = 2;
constexpr int kRing = 4;  // > kAhead
// Levels with at most this many entries (<= 128 KiB) are cache resident: not prefetched.
constexpr uint32_t kPrefetchMinEntries = 1u << 14;

struct BlockScratch {
  HWY_ALIGN float xs[kBlock], ys[kBlock], zs[kBlock];
  HWY_ALIGN uint32_t idx[kRing][8][kBlock];  // relative to the level
  HWY_ALIGN float w[kRing][8][kBlock];
};

// Positions of samples [s0, s0 + m) as clamped SoA, padded up to a whole number of vectors with
// copies of the first sample (padding lanes compute valid indices and are never stored).
HWY_INLINE size_t LoadBlock(const float* pos, size_t s0, size_t m, size_t lanes, BlockScratch& b) {
  LoadPositions(pos, s0, m, b.xs, b.ys, b.zs);
  const size_t padded = (m + lanes - 1) / lanes * lanes;
  for (size_t j = m; j < padded; ++j) {
    b.xs[j] = b.xs[0];
    b.ys[j] = b.ys[0];
    b.zs[j] = b.zs[0];
  }
  return padded;
}

// Index pass of one level for a block: corner indices and weights into ring slot `slot`, and a
// prefetch of the lines of corners 0, 2, 4, 6 (with pi_1 = 1 the +x neighbour is almost always in
// the same 64-byte line) from `base` (the level's first entry, 2 floats per entry).
HWY_INLINE void IndexPass(const GridLevel& L, size_t padded, BlockScratch& b, int slot, const float* base) {
  const hn::ScalableTag<float> df;
  const hn::RebindToUnsigned<decltype(df)> du;
  const size_t N = hn::Lanes(df);
  const bool prefetch = L.size > kPrefetchMinEntries;
  for (size_t s = 0; s < padded; s += N) {
    hn::Vec<decltype(du)> idx[8];
    hn::Vec<decltype(df)> w[8];
    CornersVec(df, L, hn::Load(df, b.xs + s), hn::Load(df, b.ys + s), hn::Load(df, b.zs + s), idx, w);
    for (int c = 0; c < 8; ++c) {
      hn::Store(idx[c], du, b.idx[slot][c] + s);
      hn::Store(w[c], df, b.w[slot][c] + s);
    }
    if (prefetch) {
      for (int c = 0; c < 8; c += 2)
        for (size_t j = 0; j < N; ++j) hwy::Prefetch(base + 2 * size_t(b.idx[slot][c][s + j]));
    }
  }
}

// Gather pass of one level for a block: enc[2l][s], enc[2l+1][s] for the block's m samples.
HWY_INLINE void GatherPass(const float* t, size_t m, size_t padded, const BlockScratch& b, int slot, float* enc0,
                           float* enc1) {
#if HWY_ARCH_X86 && HWY_TARGET <= HWY_AVX2
  // Hardware gathers: each corner is one 64-bit element (both features); lanes alternate f0, f1.
  const hn::ScalableTag<float> df;
  const size_t N = hn::Lanes(df);
  const hn::Repartition<uint64_t, decltype(df)> d64;  // N/2 lanes
  const hn::Rebind<uint32_t, decltype(d64)> d32h;     // N/2 lanes of uint32
  const hn::Rebind<float, decltype(d64)> dfh;         // N/2 lanes of float
  const hn::RebindToSigned<decltype(d64)> di64;
  const uint64_t* t64 = reinterpret_cast<const uint64_t*>(t);
  HWY_ALIGN float tmp0[HWY_MAX_BYTES / 4], tmp1[HWY_MAX_BYTES / 4];
  for (size_t s = 0; s < padded; s += N) {
    auto acc0 = hn::Zero(df), acc1 = hn::Zero(df);
    for (int c = 0; c < 8; ++c) {
      for (size_t h = 0; h < 2; ++h) {
        const size_t o = s + h * (N / 2);
        const auto i64 = hn::PromoteTo(d64, hn::Load(d32h, b.idx[slot][c] + o));
        const auto v = hn::BitCast(df, hn::GatherIndex(d64, t64, hn::BitCast(di64, i64)));
        const auto wu = hn::PromoteTo(d64, hn::BitCast(d32h, hn::Load(dfh, b.w[slot][c] + o)));
        const auto w2 = hn::BitCast(df, hn::Or(wu, hn::ShiftLeft<32>(wu)));  // (w, w) per sample
        if (h == 0)
          acc0 = hn::MulAdd(w2, v, acc0);
        else
          acc1 = hn::MulAdd(w2, v, acc1);
      }
    }
    const auto f0 = hn::ConcatEven(df, acc1, acc0), f1 = hn::ConcatOdd(df, acc1, acc0);
    if (s + N <= m) {
      hn::StoreU(f0, df, enc0 + s);
      hn::StoreU(f1, df, enc1 + s);
    } else {
      hn::Store(f0, df, tmp0);
      hn::Store(f1, df, tmp1);
      for (size_t j = 0; s + j < m; ++j) {
        enc0[s + j] = tmp0[j];
        enc1[s + j] = tmp1[j];
      }
    }
  }
#else
  (void)padded;
  for (size_t s = 0; s < m; ++s) {
    float f0 = 0.f, f1 = 0.f;
    for (int c = 0; c < 8; ++c) {
      const float* e = t + 2 * size_t(b.idx[slot][c][s]);
      const float w = b.w[slot][c][s];
      f0 += w * e[0];
      f1 += w * e[1];
    }
    enc0[s] = f0;
    enc1[s] = f1;
  }
#endif
}

void HashEncodeImpl(const HashGridView& grid, const float* pos, size_t n, float* enc, size_t ld) {
  const hn::ScalableTag<float> df;
  const size_t N = hn::Lanes(df);
  BlockScratch b;
  const int L = grid.n_levels;
  for (size_t s0 = 0; s0 < n; s0 += kBlock) {
    const size_t m = std::min(kBlock, n - s0);
    const size_t padded = LoadBlock(pos, s0, m, N, b);
    auto index = [&](int l) {
      IndexPass(grid.levels[l], padded, b, l % kRing, grid.table + 2 * size_t(grid.levels[l].offset));
    };
    for (int l = 0; l < std::min(kAhead, L); ++l) index(l);
    for (int l = 0; l < L; ++l) {
      if (l + kAhead < L) index(l + kAhead);
      GatherPass(grid.table + 2 * size_t(grid.levels[l].offset), m, padded, b, l % kRing, enc + size_t(2 * l) * ld + s0,
                 enc + size_t(2 * l + 1) * ld + s0);
    }
  }
}

// Backward of one level, pipelined by block: the index pass of block k+1 (which prefetches the
// gradient lines) runs before the scatter of block k. The scatter is scalar and in sample order
// (samples of a block often share corners).
void HashEncodeBackwardLevelImpl(const HashGridView& grid, int level, const float* pos, size_t n, const float* d_level,
                                 float* grad, uint64_t* touched) {
  const hn::ScalableTag<float> df;
  const size_t N = hn::Lanes(df);
  const GridLevel& L = grid.levels[level];
  BlockScratch b;
  auto scatter = [&](size_t s0, size_t m, int slot) {
    for (size_t j = 0; j < m; ++j) {
      const float d0 = d_level[2 * (s0 + j)], d1 = d_level[2 * (s0 + j) + 1];
      if (d0 == 0.f && d1 == 0.f) continue;
      for (int c = 0; c < 8; ++c) {
        const uint32_t e = b.idx[slot][c][j];
        const float wc = b.w[slot][c][j];
        grad[2 * e] += wc * d0;
        grad[2 * e + 1] += wc * d1;
        touched[e >> 6] |= uint64_t(1) << (e & 63);
      }
    }
  };
  size_t prev_s0 = 0, prev_m = 0;
  int slot = 0;
  for (size_t s0 = 0; s0 < n; s0 += kBlock) {
    const size_t m = std::min(kBlock, n - s0);
    const size_t padded = LoadBlock(pos, s0, m, N, b);
    IndexPass(L, padded, b, slot, grad);
    if (prev_m) scatter(prev_s0, prev_m, slot ^ 1);
    prev_s0 = s0;
    prev_m = m;
    slot ^= 1;
  }
  if (prev_m) scatter(prev_s0, prev_m, slot ^ 1);
}

// Software prefetch of the table lines the Lanes(df) samples starting at `s` will touch on the
// hashed levels (the full-table backward below, used by tests and diagnostics).
HWY_INLINE void PrefetchChunk(const HashGridView& grid, const float* base, const float* pos, size_t s, size_t n) {
  const hn::ScalableTag<float> df;
  const hn::RebindToUnsigned<decltype(df)> du;
  const size_t N = hn::Lanes(df);
  if (s + N > n) return;
  HWY_ALIGN float xs[HWY_MAX_BYTES / 4], ys[HWY_MAX_BYTES / 4], zs[HWY_MAX_BYTES / 4];
  HWY_ALIGN uint32_t ib[HWY_MAX_BYTES / 4];
  LoadPositions(pos, s, N, xs, ys, zs);
  const auto px = hn::Load(df, xs), py = hn::Load(df, ys), pz = hn::Load(df, zs);
  for (int l = 0; l < grid.n_levels; ++l) {
    const GridLevel& L = grid.levels[l];
    if (L.dense) continue;
    hn::Vec<decltype(du)> idx[8];
    hn::Vec<decltype(df)> w[8];
    CornersVec(df, L, px, py, pz, idx, w);
    const float* t = base + 2 * size_t(L.offset);
    for (int c = 0; c < 8; c += 2) {
      hn::Store(idx[c], du, ib);
      for (size_t j = 0; j < N; ++j) hwy::Prefetch(t + 2 * size_t(ib[j]));
    }
  }
}

void HashEncodeBackwardImpl(const HashGridView& grid, const float* pos, size_t n, const float* d_enc, float* grad_table,
                            uint64_t* touched) {
  const hn::ScalableTag<float> df;
  const hn::RebindToUnsigned<decltype(df)> du;
  const size_t N = hn::Lanes(df);
  const size_t nf = size_t(2 * grid.n_levels);
  HWY_ALIGN float xs[HWY_MAX_BYTES / 4], ys[HWY_MAX_BYTES / 4], zs[HWY_MAX_BYTES / 4];
  HWY_ALIGN uint32_t ib[8][HWY_MAX_BYTES / 4];
  HWY_ALIGN float wb[8][HWY_MAX_BYTES / 4];
  size_t s = 0;
  PrefetchChunk(grid, grad_table, pos, 0, n);
  for (; s + N <= n; s += N) {
    PrefetchChunk(grid, grad_table, pos, s + N, n);
    LoadPositions(pos, s, N, xs, ys, zs);
    const auto px = hn::Load(df, xs), py = hn::Load(df, ys), pz = hn::Load(df, zs);
    for (int l = 0; l < grid.n_levels; ++l) {
      const GridLevel& L = grid.levels[l];
      hn::Vec<decltype(du)> idx[8];
      hn::Vec<decltype(df)> w[8];
      CornersVec(df, L, px, py, pz, idx, w);
      for (int c = 0; c < 8; ++c) {
        hn::Store(idx[c], du, ib[c]);
        hn::Store(w[c], df, wb[c]);
      }
      // Scatter-add is scalar: samples of a vector often share corners (coarse levels).
      float* g = grad_table + 2 * size_t(L.offset);
      for (size_t j = 0; j < N; ++j) {
        const float d0 = d_enc[(s + j) * nf + 2 * l], d1 = d_enc[(s + j) * nf + 2 * l + 1];
        if (d0 == 0.f && d1 == 0.f) continue;
        for (int c = 0; c < 8; ++c) {
          const uint32_t e = ib[c][j];
          const float wc = wb[c][j];
          g[2 * e] += wc * d0;
          g[2 * e + 1] += wc * d1;
          const uint32_t a = L.offset + e;
          touched[a >> 6] |= uint64_t(1) << (a & 63);
        }
      }
    }
  }
  if (s < n) {
    hashEncodeBackwardScalar(grid, pos + 3 * s, n - s, d_enc + s * nf, grad_table, touched);
  }
}

// NOLINTNEXTLINE(google-readability-namespace-comments)
}  // namespace nerfslam::nerf::HWY_NAMESPACE
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace nerfslam::nerf {

HWY_EXPORT(HashEncodeImpl);
HWY_EXPORT(HashEncodeBackwardImpl);
HWY_EXPORT(HashEncodeBackwardLevelImpl);

std::vector<GridLevel> gridLevels(int n_levels, int base_resolution, double finest_resolution, int log2_hashmap_size) {
  std::vector<GridLevel> levels(size_t(std::max(n_levels, 0)));
  const uint64_t T = uint64_t(1) << log2_hashmap_size;
  const double log2_b = n_levels > 1 ? std::log2(finest_resolution / base_resolution) / (n_levels - 1) : 0.0;
  uint64_t offset = 0;
  for (int l = 0; l < n_levels; ++l) {
    GridLevel& L = levels[size_t(l)];
    // tiny-cuda-nn: scale = exp2f(level * log2_per_level_scale) * base_resolution - 1.0f.
    L.scale = float(std::exp2(l * log2_b) * base_resolution - 1.0);
    L.resolution = uint32_t(std::ceil(L.scale)) + 1;
    const uint64_t r = L.resolution;
    const uint64_t cells = r * r * r;
    const uint64_t padded = (cells + 7) / 8 * 8;
    L.dense = cells <= T;
    L.size = uint32_t(std::min(padded, T));
    L.offset = uint32_t(offset);
    offset += L.size;
  }
  return levels;
}

void hashEncodeScalar(const HashGridView& grid, const float* pos, size_t n, float* enc, size_t ld) {
  for (size_t s = 0; s < n; ++s) {
    for (int l = 0; l < grid.n_levels; ++l) {
      uint32_t idx[8];
      float w[8];
      detail::cellCorners(grid.levels[l], pos + 3 * s, idx, w);
      float f0 = 0.f, f1 = 0.f;
      for (int c = 0; c < 8; ++c) {
        f0 += w[c] * grid.table[2 * size_t(idx[c])];
        f1 += w[c] * grid.table[2 * size_t(idx[c]) + 1];
      }
      enc[size_t(2 * l) * ld + s] = f0;
      enc[size_t(2 * l + 1) * ld + s] = f1;
    }
  }
}

void hashEncodeBackwardScalar(const HashGridView& grid, const float* pos, size_t n, const float* d_enc,
                              float* grad_table, uint64_t* touched) {
  const size_t nf = size_t(2 * grid.n_levels);
  for (size_t s = 0; s < n; ++s) {
    for (int l = 0; l < grid.n_levels; ++l) {
      const float d0 = d_enc[s * nf + 2 * l], d1 = d_enc[s * nf + 2 * l + 1];
      if (d0 == 0.f && d1 == 0.f) continue;
      uint32_t idx[8];
      float w[8];
      detail::cellCorners(grid.levels[l], pos + 3 * s, idx, w);
      for (int c = 0; c < 8; ++c) {
        grad_table[2 * size_t(idx[c])] += w[c] * d0;
        grad_table[2 * size_t(idx[c]) + 1] += w[c] * d1;
        touched[idx[c] >> 6] |= uint64_t(1) << (idx[c] & 63);
      }
    }
  }
}

void hashEncodeBackwardLevelScalar(const HashGridView& grid, int level, const float* pos, size_t n,
                                   const float* d_level, float* grad_level, uint64_t* touched_level) {
  const GridLevel& L = grid.levels[level];
  for (size_t s = 0; s < n; ++s) {
    const float d0 = d_level[2 * s], d1 = d_level[2 * s + 1];
    if (d0 == 0.f && d1 == 0.f) continue;
    uint32_t idx[8];
    float w[8];
    detail::cellCorners(L, pos + 3 * s, idx, w);
    for (int c = 0; c < 8; ++c) {
      const uint32_t e = idx[c] - L.offset;
      grad_level[2 * size_t(e)] += w[c] * d0;
      grad_level[2 * size_t(e) + 1] += w[c] * d1;
      touched_level[e >> 6] |= uint64_t(1) << (e & 63);
    }
  }
}

void hashEncodePositionGradient(const HashGridView& grid, const float* pos, size_t n, const float* d_enc, float* out) {
  const size_t nf = size_t(2 * grid.n_levels);
  for (size_t s = 0; s < n; ++s) {
    double g[3] = {0, 0, 0};
    const float* p = pos + 3 * s;
    for (int l = 0; l < grid.n_levels; ++l) {
      const GridLevel& L = grid.levels[l];
      uint32_t idx[8];
      float w[8], f[3];
      detail::cellCorners(L, p, idx, w, f);
      const float d0 = d_enc[s * nf + 2 * l], d1 = d_enc[s * nf + 2 * l + 1];
      for (int c = 0; c < 8; ++c) {
        const float v = d0 * grid.table[2 * size_t(idx[c])] + d1 * grid.table[2 * size_t(idx[c]) + 1];
        const float wx = (c & 1) ? f[0] : 1.f - f[0], sx = (c & 1) ? 1.f : -1.f;
        const float wy = (c & 2) ? f[1] : 1.f - f[1], sy = (c & 2) ? 1.f : -1.f;
        const float wz = (c & 4) ? f[2] : 1.f - f[2], sz = (c & 4) ? 1.f : -1.f;
        g[0] += double(v) * sx * wy * wz * L.scale;
        g[1] += double(v) * wx * sy * wz * L.scale;
        g[2] += double(v) * wx * wy * sz * L.scale;
      }
    }
    // Clamped coordinates have zero derivative outside [0,1].
    for (int d = 0; d < 3; ++d) out[3 * s + d] = (p[d] < 0.f || p[d] > 1.f) ? 0.f : float(g[d]);
  }
}

void hashEncode(const HashGridView& grid, const float* pos, size_t n, float* enc, size_t ld) {
  HWY_DYNAMIC_DISPATCH(HashEncodeImpl)(grid, pos, n, enc, ld);
}

void hashEncodeBackward(const HashGridView& grid, const float* pos, size_t n, const float* d_enc, float* grad_table,
                        uint64_t* touched) {
  HWY_DYNAMIC_DISPATCH(HashEncodeBackwardImpl)(grid, pos, n, d_enc, grad_table, touched);
}

void hashEncodeBackwardLevel(const HashGridView& grid, int level, const float* pos, size_t n, const float* d_level,
                             float* grad_level, uint64_t* touched_level) {
  HWY_DYNAMIC_DISPATCH(HashEncodeBackwardLevelImpl)(grid, level, pos, n, d_level, grad_level, touched_level);
}

}  // namespace nerfslam::nerf
#endif  // HWY_ONCE
