#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/pyramid.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <ctime>
#include <limits>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/tracking/brief.h"
#include "nerfslam/tracking/fast.h"

namespace nerfslam {
namespace {

// Stage timings are thread CPU time (see FrameTimings).
double msSince(double t0) { return threadCpuMs() - t0; }

constexpr int kPatchSize = 31;
constexpr int kHalfPatch = 15;
constexpr int kEdge = 19;  // no keypoint closer to a level border (rotated 31x31 BRIEF pattern)

// Intensity-centroid orientation (Rublee et al. 2011), in degrees.
struct CentroidOrientation {
  std::vector<int> umax;
  CentroidOrientation() : umax(kHalfPatch + 1) {
    const int vmax = static_cast<int>(std::floor(kHalfPatch * std::sqrt(2.0) / 2 + 1));
    const int vmin = static_cast<int>(std::ceil(kHalfPatch * std::sqrt(2.0) / 2));
    const double hp2 = kHalfPatch * kHalfPatch;
    for (int v = 0; v <= vmax; ++v) umax[v] = static_cast<int>(std::round(std::sqrt(hp2 - v * v)));
    for (int v = kHalfPatch, v0 = 0; v >= vmin; --v) {
      while (umax[v0] == umax[v0 + 1]) ++v0;
      umax[v] = v0;
      ++v0;
    }
  }
  float angle(const cv::Mat& img, cv::Point2f pt) const {
    const int cx = cvRound(pt.x), cy = cvRound(pt.y);
    const uint8_t* center = img.ptr<uint8_t>(cy) + cx;
    const int step = static_cast<int>(img.step1());
    int m01 = 0, m10 = 0;
    for (int u = -kHalfPatch; u <= kHalfPatch; ++u) m10 += u * center[u];
    for (int v = 1; v <= kHalfPatch; ++v) {
      int v_sum = 0;
      const int d = umax[v];
      for (int u = -d; u <= d; ++u) {
        const int val_plus = center[u + v * step], val_minus = center[u - v * step];
        v_sum += (val_plus - val_minus);
        m10 += u * (val_plus + val_minus);
      }
      m01 += v * v_sum;
    }
    float a = cv::fastAtan2(static_cast<float>(m01), static_cast<float>(m10));
    return a;
  }
};

const CentroidOrientation& orientation() {
  static const CentroidOrientation o;
  return o;
}

// FAST per level with an adaptive threshold per grid cell (ORB-SLAM's scheme): corners at the normal
// threshold, and, only in cells that hold fewer than their quota of those, corners down to the
// minimum threshold. Per cell the strongest corners are kept. One SIMD pass (detectFast) finds every
// corner down to the minimum threshold with its score; a FAST score does not depend on the threshold
// a corner is found with, so splitting that pass by score gives exactly the corners of a pass at the
// normal threshold and of per-cell passes at the minimum one (as cv::FAST would find them).
std::vector<cv::KeyPoint> detectLevel(const cv::Mat& img, int target, const FeatureOptions& opt) {
  std::vector<cv::KeyPoint> out;
  const int w = img.cols, h = img.rows;
  if (w <= 2 * kEdge + 2 || h <= 2 * kEdge + 2 || target <= 0) return out;
  const int high = std::max(opt.min_fast_threshold, opt.fast_threshold);
  const int low = std::min(opt.min_fast_threshold, opt.fast_threshold);
  const int cell = opt.cell_size;
  const int cols = std::max(1, (w - 2 * kEdge + cell - 1) / cell);
  const int rows = std::max(1, (h - 2 * kEdge + cell - 1) / cell);
  std::vector<std::vector<cv::KeyPoint>> cells(static_cast<size_t>(cols * rows));
  std::vector<std::vector<cv::KeyPoint>> weak(cells.size());  // low <= score < high
  static thread_local std::vector<FastCorner> corners;
  detectFast(img, cv::Rect(kEdge, kEdge, w - 2 * kEdge, h - 2 * kEdge), low, &corners);
  for (const FastCorner& c : corners) {
    const int cx = std::min(cols - 1, (c.x - kEdge) / cell);
    const int cy = std::min(rows - 1, (c.y - kEdge) / cell);
    const size_t i = static_cast<size_t>(cy * cols + cx);
    (c.score >= high ? cells[i] : weak[i])
        .emplace_back(static_cast<float>(c.x), static_cast<float>(c.y), 7.f, -1.f, static_cast<float>(c.score));
  }
  // A cell with no more strong corners than it may take also gets its weak ones.
  std::vector<char> has_low(cells.size(), 0);
  auto needLow = [&](size_t c, size_t wanted) {
    if (has_low[c] || cells[c].size() > wanted) return;
    has_low[c] = 1;
    cells[c].insert(cells[c].end(), weak[c].begin(), weak[c].end());
  };
  // Quota per cell; cells with fewer corners pass their unused quota on (two sweeps).
  int quota = std::max(1, (target + cols * rows - 1) / (cols * rows));
  std::vector<char> done(cells.size(), 0);
  int remaining = target;
  for (int sweep = 0; sweep < 2 && remaining > 0; ++sweep) {
    int open = 0;
    for (size_t c = 0; c < cells.size(); ++c) {
      // A cell with no more strong corners than it may take needs its weak ones first (in sweep 0
      // they also decide, for a cell with exactly `quota` strong ones, whether it stays open).
      needLow(c, static_cast<size_t>(quota));
      auto& v = cells[c];
      if (done[c] || v.empty()) continue;
      const int take = std::min<int>(quota, static_cast<int>(v.size()));
      // Strongest first (responses above fast_threshold naturally rank first); ties by position, so
      // the choice does not depend on the order the two passes found the corners in.
      std::partial_sort(v.begin(), v.begin() + take, v.end(), [](const cv::KeyPoint& a, const cv::KeyPoint& b) {
        if (a.response != b.response) return a.response > b.response;
        return a.pt.y != b.pt.y ? a.pt.y < b.pt.y : a.pt.x < b.pt.x;
      });
      out.insert(out.end(), v.begin(), v.begin() + take);
      v.erase(v.begin(), v.begin() + take);
      remaining -= take;
      if (v.empty())
        done[c] = 1;
      else
        ++open;
    }
    if (open == 0 || remaining <= 0) break;
    quota = std::max(1, remaining / open);
  }
  if (static_cast<int>(out.size()) > target) {
    cv::KeyPointsFilter::retainBest(out, target);
    if (static_cast<int>(out.size()) > target) out.resize(static_cast<size_t>(target));
  }
  return out;
}

}  // namespace

namespace {

inline int hamming256(const uint8_t* a, const uint8_t* b) {
  int d = 0;
  for (int i = 0; i < 32; i += 8) {
    uint64_t x, y;
    std::memcpy(&x, a + i, 8);
    std::memcpy(&y, b + i, 8);
    d += __builtin_popcountll(x ^ y);
  }
  return d;
}

// The project builds for baseline x86-64, where __builtin_popcountll is a library call: a copy
// compiled with the POPCNT instruction is used on CPUs that have it (every x86-64 CPU since 2008).
// A plain runtime check, not an ifunc (target_clones): ifunc resolvers run before the sanitizer
// runtimes start and crash TSan/ASan builds.
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
__attribute__((target("popcnt"))) int hamming256Popcnt(const uint8_t* a, const uint8_t* b) { return hamming256(a, b); }
const bool kHasPopcnt = [] {
  __builtin_cpu_init();
  return __builtin_cpu_supports("popcnt") != 0;
}();
#endif

}  // namespace

int descriptorDistance(const uint8_t* a, const uint8_t* b) {
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
  if (kHasPopcnt) return hamming256Popcnt(a, b);
#endif
  return hamming256(a, b);
}

std::vector<int> Frame::featuresInArea(const Eigen::Vector2d& uv, double radius, int min_level, int max_level) const {
  std::vector<int> out;
  featuresInArea(uv, radius, &out, min_level, max_level);
  return out;
}

void Frame::featuresInArea(const Eigen::Vector2d& uv, double radius, std::vector<int>* out, int min_level,
                           int max_level) const {
  out->clear();
  if (grid_cols == 0 || !std::isfinite(uv.x()) || !std::isfinite(uv.y())) return;
  const int x0 = std::max(0, static_cast<int>(std::floor((uv.x() - radius) / grid_cell)));
  const int x1 = std::min(grid_cols - 1, static_cast<int>(std::floor((uv.x() + radius) / grid_cell)));
  const int y0 = std::max(0, static_cast<int>(std::floor((uv.y() - radius) / grid_cell)));
  const int y1 = std::min(grid_rows - 1, static_cast<int>(std::floor((uv.y() + radius) / grid_cell)));
  const double r2 = radius * radius;
  for (int gy = y0; gy <= y1; ++gy)
    for (int gx = x0; gx <= x1; ++gx)
      for (int i : grid[static_cast<size_t>(gy * grid_cols + gx)]) {
        const cv::KeyPoint& k = keypoints[static_cast<size_t>(i)];
        if (k.octave < min_level || (max_level >= 0 && k.octave > max_level)) continue;
        const double dx = k.pt.x - uv.x(), dy = k.pt.y - uv.y();
        if (dx * dx + dy * dy <= r2) out->push_back(i);
      }
}

void Frame::buildGrid() {
  grid_cols = (camera.width + grid_cell - 1) / grid_cell;
  grid_rows = (camera.height + grid_cell - 1) / grid_cell;
  grid.assign(static_cast<size_t>(grid_cols * grid_rows), {});
  for (size_t i = 0; i < keypoints.size(); ++i) {
    const int gx = std::clamp(static_cast<int>(keypoints[i].pt.x / grid_cell), 0, grid_cols - 1);
    const int gy = std::clamp(static_cast<int>(keypoints[i].pt.y / grid_cell), 0, grid_rows - 1);
    grid[static_cast<size_t>(gy * grid_cols + gx)].push_back(static_cast<int>(i));
  }
}

cv::Point2f levelToImage(const cv::Size& image, const cv::Size& level, const cv::Point2f& p) {
  const double sx = static_cast<double>(image.width) / level.width;
  const double sy = static_cast<double>(image.height) / level.height;
  return {static_cast<float>((p.x + 0.5) * sx - 0.5), static_cast<float>((p.y + 0.5) * sy - 0.5)};
}

cv::Point2f imageToLevel(const cv::Size& image, const cv::Size& level, const cv::Point2f& p) {
  const double sx = static_cast<double>(level.width) / image.width;
  const double sy = static_cast<double>(level.height) / image.height;
  return {static_cast<float>((p.x + 0.5) * sx - 0.5), static_cast<float>((p.y + 0.5) * sy - 0.5)};
}

Frame extractFrame(const cv::Mat& image, const Camera& camera, const FeatureOptions& opt, uint64_t id,
                   double timestamp) {
  if (image.empty()) fail("extractFrame: empty image (frame {})", id);
  if (image.cols != camera.width || image.rows != camera.height)
    fail("extractFrame: image {}x{} does not match the camera {}x{} (frame {})", image.cols, image.rows, camera.width,
         camera.height, id);
  Frame f;
  f.id = id;
  f.timestamp = timestamp;
  f.camera = camera;

  auto t0 = threadCpuMs();
  cv::Mat grey;
  if (image.channels() == 3) {
    cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
    if (image.depth() == CV_8U) f.colour = image;
  } else if (image.channels() == 4) {
    cv::cvtColor(image, grey, cv::COLOR_BGRA2GRAY);
    if (image.depth() == CV_8U) cv::cvtColor(image, f.colour, cv::COLOR_BGRA2BGR);
  } else
    grey = image;
  if (grey.depth() != CV_8U) {
    cv::Mat g8;
    grey.convertTo(g8, CV_8U, grey.depth() == CV_16U ? 1.0 / 256 : 1.0);
    grey = g8;
  }
  f.pyramid.push_back(grey);
  f.level_scale.push_back(1.0);
  for (int l = 1; l < opt.num_levels; ++l) {
    const double s = std::pow(opt.scale_factor, l);
    const cv::Size sz(static_cast<int>(std::round(grey.cols / s)), static_cast<int>(std::round(grey.rows / s)));
    if (sz.width < 2 * kEdge + 8 || sz.height < 2 * kEdge + 8) break;
    cv::Mat lvl;
    cv::resize(f.pyramid.back(), lvl, sz, 0, 0, cv::INTER_LINEAR);
    f.pyramid.push_back(lvl);
    f.level_scale.push_back(s);
  }
  f.timings.pyramid_ms = msSince(t0);

  // Features per level proportional to the level area.
  const int L = static_cast<int>(f.pyramid.size());
  double area_sum = 0;
  for (int l = 0; l < L; ++l) area_sum += 1.0 / (f.level_scale[l] * f.level_scale[l]);
  t0 = threadCpuMs();
  std::vector<std::vector<cv::KeyPoint>> level_kps(static_cast<size_t>(L));
  for (int l = 0; l < L; ++l) {
    const int target =
        static_cast<int>(std::round(opt.max_features / area_sum / (f.level_scale[l] * f.level_scale[l])));
    level_kps[l] = detectLevel(f.pyramid[l], target, opt);
  }
  f.timings.fast_ms = msSince(t0);

  t0 = threadCpuMs();
  std::vector<cv::Mat> level_desc(static_cast<size_t>(L));
  cv::Mat smoothed;
  for (int l = 0; l < L; ++l) {
    auto& kps = level_kps[l];
    if (kps.empty()) continue;
    for (size_t i = 0; i < kps.size(); ++i) {
      kps[i].angle = orientation().angle(f.pyramid[l], kps[i].pt);
      kps[i].octave = 0;
      kps[i].size = kPatchSize;
      kps[i].class_id = static_cast<int>(i);
    }
    smoothForBrief(f.pyramid[l], &smoothed);
    computeBrief(smoothed, kps, &level_desc[l]);
  }
  size_t total = 0;
  for (int l = 0; l < L; ++l) total += level_kps[l].size();
  f.keypoints.reserve(total);
  f.descriptors.create(static_cast<int>(total), 32, CV_8U);
  int row = 0;
  for (int l = 0; l < L; ++l) {
    const double s = f.level_scale[l];
    for (size_t i = 0; i < level_kps[l].size(); ++i) {
      cv::KeyPoint k = level_kps[l][i];
      k.pt = levelToImage(grey.size(), f.pyramid[l].size(), k.pt);
      k.size = static_cast<float>(kPatchSize * s);
      k.octave = l;
      k.class_id = -1;
      f.keypoints.push_back(k);
      level_desc[l].row(static_cast<int>(i)).copyTo(f.descriptors.row(row++));
    }
  }
  f.descriptors = f.descriptors.rowRange(0, row);
  f.timings.descriptor_ms = msSince(t0);

  f.undistorted.resize(f.keypoints.size());
  const bool distorted = camera.hasDistortion();
  for (size_t i = 0; i < f.keypoints.size(); ++i) {
    const Eigen::Vector2d uv(f.keypoints[i].pt.x, f.keypoints[i].pt.y);
    f.undistorted[i] = distorted ? camera.undistortPoint(uv) : uv;
  }

  f.buildGrid();
  return f;
}

}  // namespace nerfslam
