// FAST-9 scores for whole rows with Highway (see fast.h), then a SIMD 3x3 non-maximum suppression.
//
// Per pixel, with c the centre and p_k the 16 circle pixels in circular order:
//   bright_k = max(p_k - c, 0), dark_k = max(c - p_k, 0)   (8-bit saturating subtractions)
//   raw = max over the 16 arcs of 9 of the arc's minimum, over bright and dark
// A pixel is a corner at threshold t exactly when raw > t, so its score is raw - 1. An arc minimum
// is built by doubling (arcs of 2, 4, 8, then 9), which costs 4 min per start position instead of 8.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "tracking/fast.cpp"
// The kernel keeps arrays of vectors, which sizeless vector types (SVE, RVV) do not allow.
#ifndef HWY_DISABLED_TARGETS
#define HWY_DISABLED_TARGETS (HWY_SVE | HWY_SVE2 | HWY_SVE_256 | HWY_SVE2_128 | HWY_RVV)
#endif
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include <algorithm>
#include <cstddef>

#include "nerfslam/tracking/fast.h"

#ifndef NERFSLAM_FAST_CIRCLE
#define NERFSLAM_FAST_CIRCLE
namespace nerfslam::fast_detail {
// The Bresenham circle of radius 3, clockwise from the top.
constexpr int kCircle[16][2] = {{0, -3}, {1, -3}, {2, -2}, {3, -1}, {3, 0},  {3, 1},   {2, 2},   {1, 3},
                                {0, 3},  {-1, 3}, {-2, 2}, {-3, 1}, {-3, 0}, {-3, -1}, {-2, -2}, {-1, -3}};

inline void circleOffsets(std::ptrdiff_t stride, std::ptrdiff_t off[16]) {
  for (int k = 0; k < 16; ++k) off[k] = kCircle[k][0] + kCircle[k][1] * stride;
}

// raw (see above) of one pixel, scalar.
inline int rawScore(const uint8_t* c, const std::ptrdiff_t off[16]) {
  int bright[16], dark[16];
  for (int k = 0; k < 16; ++k) {
    const int d = int(c[off[k]]) - int(c[0]);
    bright[k] = std::max(d, 0);
    dark[k] = std::max(-d, 0);
  }
  int raw = 0;
  for (int s = 0; s < 16; ++s) {
    int b = 255, k = 255;
    for (int i = 0; i < 9; ++i) {
      b = std::min(b, bright[(s + i) & 15]);
      k = std::min(k, dark[(s + i) & 15]);
    }
    raw = std::max(raw, std::max(b, k));
  }
  return raw;
}
}  // namespace nerfslam::fast_detail
#endif

HWY_BEFORE_NAMESPACE();
namespace nerfslam::HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

template <class D, class V>
HWY_INLINE V ArcMax(D, const V* v) {
  V a2[16], a4[16];
  for (int i = 0; i < 16; ++i) a2[i] = hn::Min(v[i], v[(i + 1) & 15]);
  for (int i = 0; i < 16; ++i) a4[i] = hn::Min(a2[i], a2[(i + 2) & 15]);
  V best = hn::Min(hn::Min(a4[0], a4[4]), v[8]);
  for (int i = 1; i < 16; ++i) best = hn::Max(best, hn::Min(hn::Min(a4[i], a4[(i + 4) & 15]), v[(i + 8) & 15]));
  return best;
}

// raw scores of n consecutive pixels starting at `src` (all at least 3 pixels inside the image).
void FastRawRowImpl(const uint8_t* HWY_RESTRICT src, std::ptrdiff_t stride, size_t n, uint8_t* HWY_RESTRICT out) {
  const hn::ScalableTag<uint8_t> d;
  using V = hn::Vec<decltype(d)>;
  const size_t N = hn::Lanes(d);
  std::ptrdiff_t off[16];
  fast_detail::circleOffsets(stride, off);
  auto vectorAt = [&](size_t x) {
    const uint8_t* p = src + x;
    const V c = hn::LoadU(d, p);
    V bright[16], dark[16];
    for (int k = 0; k < 16; ++k) {
      const V q = hn::LoadU(d, p + off[k]);
      bright[k] = hn::SaturatedSub(q, c);
      dark[k] = hn::SaturatedSub(c, q);
    }
    hn::StoreU(hn::Max(ArcMax(d, bright), ArcMax(d, dark)), d, out + x);
  };
  size_t x = 0;
  for (; x + N <= n; x += N) vectorAt(x);
  // The last partial vector: one more vector ending at the row's end (it recomputes some pixels).
  if (x < n && n >= N) {
    vectorAt(n - N);
    x = n;
  }
  for (; x < n; ++x) out[x] = static_cast<uint8_t>(fast_detail::rawScore(src + x, off));
}

// Corners of buffer row y (1..h): raw > t and strictly above the 8 neighbours. The buffer has a
// zero frame one pixel wide and rows of `bstride` bytes with room for a vector past the frame.
void FastNmsRowImpl(const uint8_t* HWY_RESTRICT buf, size_t bstride, size_t w, size_t y, int t, int x0, int y0,
                    std::vector<FastCorner>* corners) {
  const hn::ScalableTag<uint8_t> d;
  const size_t N = hn::Lanes(d);
  const uint8_t* up = buf + (y - 1) * bstride;
  const uint8_t* row = buf + y * bstride;
  const uint8_t* dn = buf + (y + 1) * bstride;
  const auto vt = hn::Set(d, static_cast<uint8_t>(t));
  HWY_ALIGN uint8_t lanes[HWY_MAX_BYTES];
  for (size_t x = 1; x <= w; x += N) {
    const auto c = hn::LoadU(d, row + x);
    auto m = hn::Gt(c, vt);
    if (hn::AllFalse(d, m)) continue;
    m = hn::And(m, hn::And(hn::Gt(c, hn::LoadU(d, row + x - 1)), hn::Gt(c, hn::LoadU(d, row + x + 1))));
    m = hn::And(m, hn::And(hn::Gt(c, hn::LoadU(d, up + x - 1)), hn::Gt(c, hn::LoadU(d, up + x))));
    m = hn::And(m, hn::And(hn::Gt(c, hn::LoadU(d, up + x + 1)), hn::Gt(c, hn::LoadU(d, dn + x - 1))));
    m = hn::And(m, hn::And(hn::Gt(c, hn::LoadU(d, dn + x)), hn::Gt(c, hn::LoadU(d, dn + x + 1))));
    if (hn::AllFalse(d, m)) continue;
    hn::Store(hn::VecFromMask(d, m), d, lanes);
    const size_t end = std::min(N, w + 1 - x);
    for (size_t i = 0; i < end; ++i)
      if (lanes[i]) corners->push_back({x0 + int(x + i) - 1, y0 + int(y) - 1, int(row[x + i]) - 1});
  }
}

}  // namespace nerfslam::HWY_NAMESPACE
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace nerfslam {

HWY_EXPORT(FastRawRowImpl);
HWY_EXPORT(FastNmsRowImpl);

void detectFast(const cv::Mat& image, const cv::Rect& area, int threshold, std::vector<FastCorner>* corners) {
  CV_Assert(image.type() == CV_8UC1);
  CV_Assert(area.x >= 3 && area.y >= 3 && area.x + area.width <= image.cols - 3 &&
            area.y + area.height <= image.rows - 3);
  corners->clear();
  if (area.width <= 0 || area.height <= 0) return;
  // A corner must score above its non-corner neighbours, which cv::FAST's suppression counts as 0:
  // corners of score 0 are never kept, so threshold 0 is threshold 1.
  const int t = std::clamp(threshold, 1, 254);
  const size_t w = size_t(area.width), h = size_t(area.height);
  // raw scores of the area with a zero frame; the bytes past the frame are read by the NMS's
  // vectors but never used. The padding is a constant, not HWY_MAX_BYTES: outside the per-target
  // code that macro is the baseline target's (16 bytes), shorter than an AVX-512 vector.
  constexpr size_t kPad = 256;  // the widest vector of any Highway target (SVE 2048-bit)
  const size_t bstride = w + 2 + kPad;
  static thread_local std::vector<uint8_t> buf;
  if (buf.size() < (h + 2) * bstride + kPad) buf.resize((h + 2) * bstride + kPad);
  std::fill(buf.begin(), buf.begin() + std::ptrdiff_t(bstride), uint8_t(0));
  std::fill(buf.begin() + std::ptrdiff_t((h + 1) * bstride), buf.begin() + std::ptrdiff_t((h + 2) * bstride),
            uint8_t(0));
  const std::ptrdiff_t stride = std::ptrdiff_t(image.step1());
  for (size_t y = 1; y <= h; ++y) {
    uint8_t* row = buf.data() + y * bstride;
    row[0] = 0;
    // Dispatched per call: a pointer taken before the first call would stay the target-choosing
    // trampoline (CPUID on every row).
    HWY_DYNAMIC_DISPATCH(FastRawRowImpl)(image.ptr<uint8_t>(area.y + int(y) - 1) + area.x, stride, w, row + 1);
    row[w + 1] = 0;
  }
  for (size_t y = 1; y <= h; ++y)
    HWY_DYNAMIC_DISPATCH(FastNmsRowImpl)(buf.data(), bstride, w, y, t, area.x, area.y, corners);
}

int fastScore(const uint8_t* centre, std::ptrdiff_t stride) {
  std::ptrdiff_t off[16];
  fast_detail::circleOffsets(stride, off);
  return fast_detail::rawScore(centre, off) - 1;
}

}  // namespace nerfslam
#endif
