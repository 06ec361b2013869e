#include "nerfslam/nerf/renderer.h"

#include <atomic>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/composite.h"
#include "nerfslam/nerf/raymarch.h"
#include "nerfslam/nerf/trainer.h"

namespace nerfslam::nerf {
namespace {

// Pixels per work item: a 32x16 block (neighbouring rays share occupancy cells and table lines).
constexpr int kBlockW = 32, kBlockH = 16;
constexpr float kNormalWeight = 1e-3f;  // samples below this weight do not contribute to normals
// Colour is evaluated only for samples that matter: a sample whose compositing weight is below
// kColorMinWeight is left out while the ray's left-out weight stays within kColorSkipBudget, so
// the colour differs from compositing every sample by at most kColorSkipBudget (of a [0,1] range;
// a quarter of an 8-bit level). Depth, opacity and uncertainty use every sample.
constexpr float kColorMinWeight = 1e-4f;
constexpr float kColorSkipBudget = 1e-3f;

// Samples per live ray and round: the first round marches 8 (most rays have few samples or reach
// their surface within them), later rounds 4. Samples a ray marches past its termination (T <
// kMinTransmittance) within a round are evaluated for nothing, so small later rounds waste fewer
// (lego 640x480: 12.6 -> 9.4 field samples per pixel against 8/16/32); the rounds themselves are
// cheap, the batches stay large (every live ray of the tile).
constexpr int kFirstChunk = 8;
constexpr int kChunk = 4;

// Pixel offsets of a block in Z order: rays next to each other in a batch are neighbours in the
// image, so their samples share more hash-table lines (lego: ~3% less CPU than row order).
const std::vector<std::pair<int, int>> kMorton = [] {
  std::vector<std::pair<int, int>> v;
  for (int i = 0; v.size() < size_t(kBlockW * kBlockH); ++i) {
    int x = 0, y = 0;
    for (int b = 0; b < 8; ++b) {
      x |= ((i >> (2 * b)) & 1) << b;
      y |= ((i >> (2 * b + 1)) & 1) << b;
    }
    if (x < kBlockW && y < kBlockH) v.emplace_back(x, y);
  }
  return v;
}();

template <class T>
void grow(std::vector<T>& v, size_t n) {
  if (v.size() < n) v.resize(n);
}

struct RayState {
  int pixel;
  float T = 1.f, rgb[3] = {0, 0, 0}, dsum = 0, d2sum = 0, n[3] = {0, 0, 0}, skipped = 0;
};

// What every tile of a view shares.
struct ViewSetup {
  const NerfModel& model;
  const RenderOptions& opt;
  RayGenerator gen;
  MarchParams march;
  Eigen::Vector3f z_axis;  // the camera's optical axis in the world
  float inv_scale;         // NeRF length -> world length
  float bg[3];
  const Background* learned_bg;  // null: bg
  int W, H, bx_count;
};

// A thread's buffers, reused from tile to tile.
struct TileWork {
  std::vector<RayMarcher> marchers;
  std::vector<Ray> rays;
  std::vector<RayState> st;
  std::vector<float> pos, fpos, t, dt, sigma, geo, grad;
  std::vector<int> owner;  // ray of each batch sample
  std::vector<int> live;   // rays of the tile still marching
  std::vector<int> c_idx;  // samples whose colour is evaluated
  std::vector<float> c_w, c_geo, c_dir, c_rgb;
  std::vector<int> g_idx, g_ray;  // samples whose normals are needed
  std::vector<float> g_w, g_pos;
};

// The rays of the tile's pixels (x0..x1, y0..y1) in Z order.
void startTile(const ViewSetup& v, int x0, int y0, int x1, int y1, TileWork& w) {
  w.marchers.clear();
  w.rays.clear();
  w.st.clear();
  w.live.clear();
  for (const auto& [dx, dy] : kMorton) {
    const int x = x0 + dx, y = y0 + dy;
    if (x >= x1 || y >= y1) continue;
    const Ray r = v.gen.ray(x, y);
    w.rays.push_back(r);
    w.marchers.emplace_back(r, *v.model.grid, v.model.scene, v.march, 0.5f);
    if (!w.marchers.back().done()) w.live.push_back(int(w.st.size()));
    RayState s;
    s.pixel = y * v.W + x;
    w.st.push_back(s);
  }
}

// Marches up to `chunk` samples of every live ray into the batch; returns the batch's samples.
int marchRound(int chunk, TileWork& w) {
  const size_t cap = w.live.size() * size_t(chunk);
  grow(w.pos, 3 * cap);
  grow(w.fpos, 3 * cap);
  grow(w.t, cap);
  grow(w.dt, cap);
  grow(w.sigma, cap);
  grow(w.owner, cap);
  grow(w.geo, cap * kDensityOutputs);
  int used = 0;
  for (const int i : w.live) {
    const int n = w.marchers[size_t(i)].next(chunk, w.pos.data() + 3 * used, w.t.data() + used, w.dt.data() + used);
    std::fill(w.owner.data() + used, w.owner.data() + used + n, i);
    used += n;
  }
  return used;
}

// Composites the batch's densities front to back into each ray's transmittance and depth moments,
// and lists the samples whose colour (weight that matters) and normal (with normals) are needed.
void compositeDensities(const ViewSetup& v, int used, TileWork& w) {
  w.c_idx.clear();
  w.c_w.clear();
  w.g_idx.clear();
  w.g_ray.clear();
  w.g_w.clear();
  for (int k = 0; k < used; ++k) {
    RayState& s = w.st[size_t(w.owner[size_t(k)])];
    if (s.T < kMinTransmittance) continue;
    const float alpha = 1.f - std::exp(-w.sigma[size_t(k)] * w.dt[size_t(k)]);
    const float wt = s.T * alpha;
    s.dsum += wt * w.t[size_t(k)];
    s.d2sum += wt * w.t[size_t(k)] * w.t[size_t(k)];
    s.T *= 1.f - alpha;
    if (wt < kColorMinWeight && s.skipped + wt <= kColorSkipBudget) {
      s.skipped += wt;
    } else {
      w.c_idx.push_back(k);
      w.c_w.push_back(wt);
    }
    if (v.opt.normals && wt > kNormalWeight) {
      w.g_idx.push_back(k);
      w.g_ray.push_back(w.owner[size_t(k)]);
      w.g_w.push_back(wt);
    }
  }
}

// Colour of the listed samples, added to their rays with their weights.
void shadeColours(const ViewSetup& v, TileWork& w) {
  if (w.c_idx.empty()) return;
  const size_t nc = w.c_idx.size();
  w.c_geo.resize(nc * kDensityOutputs);
  w.c_dir.resize(3 * nc);
  w.c_rgb.resize(3 * nc);
  for (size_t j = 0; j < nc; ++j) {
    const size_t k = size_t(w.c_idx[j]);
    std::copy(w.geo.data() + k * kDensityOutputs, w.geo.data() + (k + 1) * kDensityOutputs,
              w.c_geo.data() + j * kDensityOutputs);
    const Eigen::Vector3f& d = w.rays[size_t(w.owner[k])].dir;
    w.c_dir[3 * j] = d.x();
    w.c_dir[3 * j + 1] = d.y();
    w.c_dir[3 * j + 2] = d.z();
  }
  v.model.field->queryColor(w.c_geo.data(), w.c_dir.data(), nc, w.c_rgb.data());
  for (size_t j = 0; j < nc; ++j) {
    RayState& s = w.st[size_t(w.owner[size_t(w.c_idx[j])])];
    for (int c = 0; c < 3; ++c) s.rgb[c] += w.c_w[j] * w.c_rgb[3 * j + size_t(c)];
  }
}

// Normals (negative density gradients) of the listed samples, added to their rays with their weights.
void shadeNormals(const ViewSetup& v, TileWork& w) {
  if (w.g_idx.empty()) return;
  w.g_pos.resize(3 * w.g_idx.size());
  w.grad.resize(3 * w.g_idx.size());
  for (size_t j = 0; j < w.g_idx.size(); ++j)
    std::copy(w.fpos.data() + 3 * w.g_idx[j], w.fpos.data() + 3 * w.g_idx[j] + 3, w.g_pos.data() + 3 * j);
  v.model.field->densityGradient(w.g_pos.data(), w.g_idx.size(), w.grad.data());
  for (size_t j = 0; j < w.g_idx.size(); ++j) {
    const float* g = w.grad.data() + 3 * j;
    const float len = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    if (!(len > 0.f) || !std::isfinite(len)) continue;
    RayState& s = w.st[size_t(w.g_ray[j])];
    for (int c = 0; c < 3; ++c) s.n[c] -= w.g_w[j] * g[c] / len;
  }
}

// Rays that terminated or left the scene drop out of the live list.
void compactLive(TileWork& w) {
  size_t k = 0;
  for (const int i : w.live)
    if (w.st[size_t(i)].T >= kMinTransmittance && !w.marchers[size_t(i)].done()) w.live[k++] = i;
  w.live.resize(k);
}

// Writes the tile's rays into the result images.
void writeTile(const ViewSetup& v, const TileWork& w, RenderResult& res) {
  for (size_t i = 0; i < w.st.size(); ++i) {
    const RayState& s = w.st[i];
    const int x = s.pixel % v.W, y = s.pixel / v.W;
    const float op = 1.f - s.T;
    auto& c = res.rgb.at<cv::Vec3f>(y, x);
    float bg[3] = {v.bg[0], v.bg[1], v.bg[2]};
    if (v.learned_bg) v.learned_bg->eval(w.rays[i].dir.data(), bg);
    for (int k = 0; k < 3; ++k) c[k] = s.rgb[k] + s.T * bg[k];
    res.opacity.at<float>(y, x) = op;
    if (op > 1e-6f) {
      const float mean_t = s.dsum / op;
      const float var = std::max(0.f, s.d2sum / op - mean_t * mean_t);
      res.uncertainty.at<float>(y, x) = std::sqrt(var) * v.inv_scale;
      if (op >= float(v.opt.min_opacity)) {
        res.depth.at<float>(y, x) = mean_t * v.inv_scale * w.rays[i].dir.dot(v.z_axis);
        const float len = std::sqrt(s.n[0] * s.n[0] + s.n[1] * s.n[1] + s.n[2] * s.n[2]);
        if (len > 0.f) res.normals.at<cv::Vec3f>(y, x) = cv::Vec3f(s.n[0] / len, s.n[1] / len, s.n[2] / len);
      }
    }
  }
}

// Renders one tile (wavefront rounds over its live rays); returns the field samples evaluated.
int64_t renderTile(const ViewSetup& v, int tile, TileWork& w, RenderResult& res) {
  const int x0 = (tile % v.bx_count) * kBlockW, y0 = (tile / v.bx_count) * kBlockH;
  startTile(v, x0, y0, std::min(v.W, x0 + kBlockW), std::min(v.H, y0 + kBlockH), w);
  int64_t samples = 0;
  for (int round = 0; !w.live.empty(); ++round) {
    const int used = marchRound(round == 0 ? kFirstChunk : kChunk, w);
    if (used == 0) break;
    samples += used;
    v.model.toFieldCoords(w.pos.data(), size_t(used), w.fpos.data());
    // Density first; colour only for the samples that contribute.
    v.model.field->queryDensityOutputs(w.fpos.data(), size_t(used), w.sigma.data(), w.geo.data());
    compositeDensities(v, used, w);
    shadeColours(v, w);
    shadeNormals(v, w);
    compactLive(w);
  }
  writeTile(v, w, res);
  return samples;
}

}  // namespace

cv::Mat toBgr8(const cv::Mat& rgb) {
  cv::Mat bgr, out;
  cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
  bgr.convertTo(out, CV_8U, 255.0);
  return out;
}

RenderResult renderView(const NerfModel& model, const Camera& camera, const SE3& T_world_cam,
                        const RenderOptions& opt) {
  camera.validate("render camera");
  if (!T_world_cam.matrix().allFinite()) fail("render: the pose is not finite");
  if (opt.background.size() != 3) fail("render: background must have 3 values");
  const int W = camera.width, H = camera.height;
  RenderResult res;
  res.rgb = cv::Mat(H, W, CV_32FC3, cv::Scalar::all(0));
  res.depth = cv::Mat(H, W, CV_32FC1, cv::Scalar(0));
  res.normals = cv::Mat(H, W, CV_32FC3, cv::Scalar::all(0));
  res.uncertainty = cv::Mat(H, W, CV_32FC1, cv::Scalar(0));
  res.opacity = cv::Mat(H, W, CV_32FC1, cv::Scalar(0));

  const ViewSetup v{model,
                    opt,
                    RayGenerator(camera, T_world_cam, model.scene),
                    MarchParams::forScene(model.scene, model.grid->cascades()),
                    T_world_cam.rotationMatrix().col(2).cast<float>(),
                    float(1.0 / model.scene.scale),
                    {float(opt.background[0]), float(opt.background[1]), float(opt.background[2])},
                    opt.learned_background ? model.background.get() : nullptr,
                    W,
                    H,
                    (W + kBlockW - 1) / kBlockW};
  const int n_tiles = v.bx_count * ((H + kBlockH - 1) / kBlockH);
  std::atomic<int> next_tile{0};
  std::atomic<int64_t> total_samples{0};
  parallelRun(opt.threads, [&](int) {
    TileWork w;
    int64_t samples = 0;
    for (int tile = next_tile++; tile < n_tiles; tile = next_tile++) samples += renderTile(v, tile, w, res);
    total_samples += samples;
  });
  res.samples = total_samples;
  return res;
}

}  // namespace nerfslam::nerf
