// Steered BRIEF (see brief.h): Highway smoothing, the learned test pattern and 64 pre-rotated copies.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "tracking/brief.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include <algorithm>
#include <array>
#include <cmath>

#include "nerfslam/tracking/brief.h"

HWY_BEFORE_NAMESPACE();
namespace nerfslam::HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

// (a0 + a6) + 6 (a1 + a5) + 15 (a2 + a4) + 20 a3, rounded and divided by 64. Inputs 0..255 as
// int16 lanes: the sum is at most 16320.
template <class D, class V>
HWY_INLINE V Binomial7(D d, V a0, V a1, V a2, V a3, V a4, V a5, V a6) {
  V s = hn::Add(a0, a6);
  s = hn::Add(s, hn::Mul(hn::Add(a1, a5), hn::Set(d, 6)));
  s = hn::Add(s, hn::Mul(hn::Add(a2, a4), hn::Set(d, 15)));
  s = hn::Add(s, hn::Mul(a3, hn::Set(d, 20)));
  return hn::ShiftRight<6>(hn::Add(s, hn::Set(d, 32)));
}

// Vertical pass: rows[0..6] are the 7 source rows, out gets n smoothed values (0..255, int16).
void SmoothColumnsImpl(const uint8_t* const* HWY_RESTRICT rows, size_t n, int16_t* HWY_RESTRICT out) {
  const hn::ScalableTag<int16_t> d;
  const hn::Rebind<uint8_t, decltype(d)> d8;
  const size_t N = hn::Lanes(d);
  auto at = [&](size_t x) {
    auto ld = [&](int r) { return hn::PromoteTo(d, hn::LoadU(d8, rows[r] + x)); };
    hn::StoreU(Binomial7(d, ld(0), ld(1), ld(2), ld(3), ld(4), ld(5), ld(6)), d, out + x);
  };
  size_t x = 0;
  for (; x + N <= n; x += N) at(x);
  if (x < n && n >= N) {
    at(n - N);
    x = n;
  }
  for (; x < n; ++x) {
    const int s =
        rows[0][x] + rows[6][x] + 6 * (rows[1][x] + rows[5][x]) + 15 * (rows[2][x] + rows[4][x]) + 20 * rows[3][x];
    out[x] = static_cast<int16_t>((s + 32) >> 6);
  }
}

// Horizontal pass: out[x] for x in [3, n - 3) from the vertical pass's row `in` of n values.
void SmoothRowImpl(const int16_t* HWY_RESTRICT in, size_t n, uint8_t* HWY_RESTRICT out) {
  const hn::ScalableTag<int16_t> d;
  const hn::Rebind<uint8_t, decltype(d)> d8;
  const size_t N = hn::Lanes(d);
  if (n < 7) return;
  auto at = [&](size_t x) {
    auto ld = [&](int k) { return hn::LoadU(d, in + x + size_t(k) - 3); };
    hn::StoreU(hn::DemoteTo(d8, Binomial7(d, ld(0), ld(1), ld(2), ld(3), ld(4), ld(5), ld(6))), d8, out + x);
  };
  const size_t end = n - 3;
  size_t x = 3;
  for (; x + N <= end; x += N) at(x);
  if (x < end && end >= N + 3) {
    at(end - N);
    x = end;
  }
  for (; x < end; ++x) {
    const int s = in[x - 3] + in[x + 3] + 6 * (in[x - 2] + in[x + 2]) + 15 * (in[x - 1] + in[x + 1]) + 20 * in[x];
    out[x] = static_cast<uint8_t>((s + 32) >> 6);
  }
}

}  // namespace nerfslam::HWY_NAMESPACE
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace nerfslam {

HWY_EXPORT(SmoothColumnsImpl);
HWY_EXPORT(SmoothRowImpl);

void smoothForBrief(const cv::Mat& src, cv::Mat* dst) {
  CV_Assert(src.type() == CV_8UC1 && dst->data != src.data);
  if (src.rows < 7 || src.cols < 7) {
    src.copyTo(*dst);
    return;
  }
  dst->create(src.size(), CV_8UC1);
  // The 3-pixel border stays unsmoothed: copied, the rest written by the two passes.
  for (int y : {0, 1, 2, src.rows - 3, src.rows - 2, src.rows - 1}) src.row(y).copyTo(dst->row(y));
  const size_t w = size_t(src.cols);
  static thread_local std::vector<int16_t> column;
  column.resize(w);
  for (int y = 3; y < src.rows - 3; ++y) {
    const uint8_t* rows[7];
    for (int k = 0; k < 7; ++k) rows[k] = src.ptr<uint8_t>(y + k - 3);
    uint8_t* out = dst->ptr<uint8_t>(y);
    HWY_DYNAMIC_DISPATCH(SmoothColumnsImpl)(rows, w, column.data());
    HWY_DYNAMIC_DISPATCH(SmoothRowImpl)(column.data(), w, out);
    for (size_t x : {size_t(0), size_t(1), size_t(2), w - 3, w - 2, w - 1}) out[x] = rows[3][x];
  }
}

namespace {

constexpr int kTests = 8 * kBriefBytes;
constexpr int kAngles = 64;

// The pattern rotated by k * 360/64 degrees, points rounded to pixels.
struct RotatedPatterns {
  std::array<std::array<cv::Vec<int8_t, 4>, kTests>, kAngles> tests{};  // (x1, y1, x2, y2) offsets
  RotatedPatterns() {
    const std::vector<cv::Vec4i>& p = briefPattern();
    for (int k = 0; k < kAngles; ++k) {
      const double a = 2.0 * M_PI * k / kAngles, c = std::cos(a), s = std::sin(a);
      for (int i = 0; i < kTests; ++i)
        for (int j : {0, 2}) {
          const int x = p[size_t(i)][j], y = p[size_t(i)][j + 1];
          tests[size_t(k)][size_t(i)][j] = int8_t(std::lround(x * c - y * s));
          tests[size_t(k)][size_t(i)][j + 1] = int8_t(std::lround(x * s + y * c));
        }
    }
  }
};

const RotatedPatterns& rotatedPatterns() {
  static const RotatedPatterns r;
  return r;
}

}  // namespace

const std::vector<cv::Vec4i>& briefPattern() {
  static const std::vector<cv::Vec4i> p = {
#include "tracking/brief_pattern.inc"
  };
  return p;
}

void computeBrief(const cv::Mat& smoothed, const std::vector<cv::KeyPoint>& keypoints, cv::Mat* descriptors) {
  CV_Assert(smoothed.type() == CV_8UC1);
  descriptors->create(int(keypoints.size()), kBriefBytes, CV_8U);
  const RotatedPatterns& rp = rotatedPatterns();
  const int step = int(smoothed.step1());
  const int margin = kBriefRadius;
  for (size_t i = 0; i < keypoints.size(); ++i) {
    const cv::KeyPoint& kp = keypoints[i];
    const int x = cvRound(kp.pt.x), y = cvRound(kp.pt.y);
    CV_Assert(x >= margin && y >= margin && x < smoothed.cols - margin && y < smoothed.rows - margin);
    const float angle = kp.angle >= 0 ? kp.angle : 0.f;
    const int k = int(std::lround(angle * kAngles / 360.0)) & (kAngles - 1);
    const auto& tests = rp.tests[size_t(k)];
    const uint8_t* centre = smoothed.ptr<uint8_t>(y) + x;
    uint8_t* out = descriptors->ptr<uint8_t>(int(i));
    auto at = [&](int dx, int dy) { return centre[dy * step + dx]; };
    for (int b = 0; b < kBriefBytes; ++b) {
      uint8_t byte = 0;
      for (int j = 0; j < 8; ++j) {
        const cv::Vec<int8_t, 4>& t = tests[size_t(8 * b + j)];
        byte = uint8_t(byte | ((at(t[0], t[1]) < at(t[2], t[3])) << j));
      }
      out[b] = byte;
    }
  }
}

}  // namespace nerfslam
#endif
