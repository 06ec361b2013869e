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

  const RayGenerator gen(camera, T_world_cam, model.scene);
  const MarchParams march = MarchParams::forScene(model.scene.aabb_scale, model.grid->cascades());
  const Eigen::Vector3f z_axis = T_world_cam.rotationMatrix().col(2).cast<float>();
  const float inv_scale = float(1.0 / model.scene.scale);
  const float bg[3] = {float(opt.background[0]), float(opt.background[1]), float(opt.background[2])};
  const int bx_count = (W + kBlockW - 1) / kBlockW, by_count = (H + kBlockH - 1) / kBlockH;
  const int n_tiles = bx_count * by_count;
  std::atomic<int> next_tile{0};
  std::atomic<int64_t> total_samples{0};

  parallelRun(opt.threads, [&](int) {
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
    int64_t samples = 0;
    for (int tile = next_tile++; tile < n_tiles; tile = next_tile++) {
      const int x0 = (tile % bx_count) * kBlockW, y0 = (tile / bx_count) * kBlockH;
      const int x1 = std::min(W, x0 + kBlockW), y1 = std::min(H, y0 + kBlockH);
      marchers.clear();
      rays.clear();
      st.clear();
      live.clear();
      for (const auto& [dx, dy] : kMorton) {
        const int x = x0 + dx, y = y0 + dy;
        if (x >= x1 || y >= y1) continue;
        const Ray r = gen.ray(x, y);
        rays.push_back(r);
        marchers.emplace_back(r, *model.grid, model.scene, march, 0.5f);
        if (!marchers.back().done()) live.push_back(int(st.size()));
        RayState s;
        s.pixel = y * W + x;
        st.push_back(s);
      }
      for (int round = 0; !live.empty(); ++round) {
        const int chunk = round == 0 ? kFirstChunk : kChunk;
        const size_t cap = live.size() * size_t(chunk);
        grow(pos, 3 * cap);
        grow(fpos, 3 * cap);
        grow(t, cap);
        grow(dt, cap);
        grow(sigma, cap);
        grow(owner, cap);
        grow(geo, cap * kDensityOutputs);
        int used = 0;
        for (const int i : live) {
          const int n = marchers[size_t(i)].next(chunk, pos.data() + 3 * used, t.data() + used, dt.data() + used);
          std::fill(owner.data() + used, owner.data() + used + n, i);
          used += n;
        }
        if (used == 0) break;
        samples += used;
        model.toFieldCoords(pos.data(), size_t(used), fpos.data());
        // Density first; colour only for the samples that contribute.
        model.field->queryDensityOutputs(fpos.data(), size_t(used), sigma.data(), geo.data());
        c_idx.clear();
        c_w.clear();
        g_idx.clear();
        g_ray.clear();
        g_w.clear();
        for (int k = 0; k < used; ++k) {
          RayState& s = st[size_t(owner[size_t(k)])];
          if (s.T < kMinTransmittance) continue;
          const float alpha = 1.f - std::exp(-sigma[size_t(k)] * dt[size_t(k)]);
          const float w = s.T * alpha;
          s.dsum += w * t[size_t(k)];
          s.d2sum += w * t[size_t(k)] * t[size_t(k)];
          s.T *= 1.f - alpha;
          if (w < kColorMinWeight && s.skipped + w <= kColorSkipBudget) {
            s.skipped += w;
          } else {
            c_idx.push_back(k);
            c_w.push_back(w);
          }
          if (opt.normals && w > kNormalWeight) {
            g_idx.push_back(k);
            g_ray.push_back(owner[size_t(k)]);
            g_w.push_back(w);
          }
        }
        if (!c_idx.empty()) {
          const size_t nc = c_idx.size();
          c_geo.resize(nc * kDensityOutputs);
          c_dir.resize(3 * nc);
          c_rgb.resize(3 * nc);
          for (size_t j = 0; j < nc; ++j) {
            const size_t k = size_t(c_idx[j]);
            std::copy(geo.data() + k * kDensityOutputs, geo.data() + (k + 1) * kDensityOutputs,
                      c_geo.data() + j * kDensityOutputs);
            const Eigen::Vector3f& d = rays[size_t(owner[k])].dir;
            c_dir[3 * j] = d.x();
            c_dir[3 * j + 1] = d.y();
            c_dir[3 * j + 2] = d.z();
          }
          model.field->queryColor(c_geo.data(), c_dir.data(), nc, c_rgb.data());
          for (size_t j = 0; j < nc; ++j) {
            RayState& s = st[size_t(owner[size_t(c_idx[j])])];
            for (int c = 0; c < 3; ++c) s.rgb[c] += c_w[j] * c_rgb[3 * j + size_t(c)];
          }
        }
        if (!g_idx.empty()) {
          g_pos.resize(3 * g_idx.size());
          grad.resize(3 * g_idx.size());
          for (size_t j = 0; j < g_idx.size(); ++j)
            std::copy(fpos.data() + 3 * g_idx[j], fpos.data() + 3 * g_idx[j] + 3, g_pos.data() + 3 * j);
          model.field->densityGradient(g_pos.data(), g_idx.size(), grad.data());
          for (size_t j = 0; j < g_idx.size(); ++j) {
            const float* g = grad.data() + 3 * j;
            const float len = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
            if (!(len > 0.f) || !std::isfinite(len)) continue;
            RayState& s = st[size_t(g_ray[j])];
            for (int c = 0; c < 3; ++c) s.n[c] -= g_w[j] * g[c] / len;
          }
        }
        // Compact the live rays: those that terminated or left the scene drop out.
        size_t k = 0;
        for (const int i : live)
          if (st[size_t(i)].T >= kMinTransmittance && !marchers[size_t(i)].done()) live[k++] = i;
        live.resize(k);
      }
      for (size_t i = 0; i < st.size(); ++i) {
        const RayState& s = st[i];
        const int x = s.pixel % W, y = s.pixel / W;
        const float op = 1.f - s.T;
        auto& c = res.rgb.at<cv::Vec3f>(y, x);
        for (int k = 0; k < 3; ++k) c[k] = s.rgb[k] + s.T * bg[k];
        res.opacity.at<float>(y, x) = op;
        if (op > 1e-6f) {
          const float mean_t = s.dsum / op;
          const float var = std::max(0.f, s.d2sum / op - mean_t * mean_t);
          res.uncertainty.at<float>(y, x) = std::sqrt(var) * inv_scale;
          if (op >= float(opt.min_opacity)) {
            res.depth.at<float>(y, x) = mean_t * inv_scale * rays[i].dir.dot(z_axis);
            const float len = std::sqrt(s.n[0] * s.n[0] + s.n[1] * s.n[1] + s.n[2] * s.n[2]);
            if (len > 0.f) res.normals.at<cv::Vec3f>(y, x) = cv::Vec3f(s.n[0] / len, s.n[1] / len, s.n[2] / len);
          }
        }
      }
    }
    total_samples += samples;
  });
  res.samples = total_samples;
  return res;
}

}  // namespace nerfslam::nerf
