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

// Software prefetch of the table lines the Lanes(df) samples starting at `s` will touch on the
// hashed levels (dense levels are small and cache-resident). With pi_1 = 1 the x-neighbours of a
// corner usually share its cache line, so corners 0, 2, 4, 6 cover a cell. The hashed levels are
// random accesses into tables larger than L2: without this the gathers wait on memory serially.
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

void HashEncodeImpl(const HashGridView& grid, const float* pos, size_t n, float* enc, size_t ld) {
  const hn::ScalableTag<float> df;
  const hn::RebindToUnsigned<decltype(df)> du;
  const hn::RebindToSigned<decltype(df)> di;
  const size_t N = hn::Lanes(df);
  HWY_ALIGN float xs[HWY_MAX_BYTES / 4], ys[HWY_MAX_BYTES / 4], zs[HWY_MAX_BYTES / 4];
  size_t s = 0;
  PrefetchChunk(grid, grid.table, pos, 0, n);
  for (; s + N <= n; s += N) {
    PrefetchChunk(grid, grid.table, pos, s + N, n);
    LoadPositions(pos, s, N, xs, ys, zs);
    const auto px = hn::Load(df, xs), py = hn::Load(df, ys), pz = hn::Load(df, zs);
    for (int l = 0; l < grid.n_levels; ++l) {
      const GridLevel& L = grid.levels[l];
      hn::Vec<decltype(du)> idx[8];
      hn::Vec<decltype(df)> w[8];
      CornersVec(df, L, px, py, pz, idx, w);
      const float* t = grid.table + 2 * size_t(L.offset);
      auto f0 = hn::Zero(df), f1 = hn::Zero(df);
      for (int c = 0; c < 8; ++c) {
        const auto i2 = hn::BitCast(di, hn::Add(idx[c], idx[c]));
        f0 = hn::MulAdd(w[c], hn::GatherIndex(df, t, i2), f0);
        f1 = hn::MulAdd(w[c], hn::GatherIndex(df, t + 1, i2), f1);
      }
      hn::StoreU(f0, df, enc + size_t(2 * l) * ld + s);
      hn::StoreU(f1, df, enc + size_t(2 * l + 1) * ld + s);
    }
  }
  if (s < n) {
    // Tail: shift the pointers so the scalar reference writes columns s..n-1.
    hashEncodeScalar(grid, pos + 3 * s, n - s, enc + s, ld);
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

}  // namespace nerfslam::nerf
#endif  // HWY_ONCE
