#include "nerfslam/nerf/distill.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "nerfslam/core/error.h"

namespace nerfslam::nerf {
namespace {

// One step's points: positions in both models' NeRF spaces, and directions.
struct DistillBatch {
  std::vector<float> p_from, p_to, dir;
  std::vector<uint8_t> inside;  // the point is inside the student's box (others teach nothing)
};

// Draws the points of every step from one generator and one set of distributions (the normal
// distribution keeps state between calls).
class PointSampler {
 public:
  explicit PointSampler(uint64_t seed) : rng_(seed ^ 0x64697374ull), cell_(0, OccupancyGrid::kRes - 1) {}

  // Each point in one of from's cascades, drawn uniformly (cascade m is the cube of side 2^m around
  // the unit cube's centre: with aabb_scale > 1 the far scenery lives in the outer ones); half the
  // points uniform in that cube, half (odd indices) inside its occupied cells (uniform when 64 tries
  // find no occupied cell).
  void draw(const NerfModel& from, const NerfModel& to, int n, DistillBatch* b) {
    std::uniform_int_distribution<int> cascade(0, std::max(1, from.grid->cascades()) - 1);
    for (int i = 0; i < n; ++i) {
      const int m = cascade(rng_);
      const float side = std::ldexp(1.f, m);
      Eigen::Vector3f p = Eigen::Vector3f::Constant(0.5f) +
                          side * Eigen::Vector3f(u01_(rng_) - 0.5f, u01_(rng_) - 0.5f, u01_(rng_) - 0.5f);
      if (i % 2 == 1) {
        for (int tries = 0; tries < 64; ++tries) {
          const int x = cell_(rng_), y = cell_(rng_), z = cell_(rng_);
          if (!from.grid->occupiedCell(m, x, y, z)) continue;
          const float c = OccupancyGrid::cellSize(m);
          p = from.grid->cellCenter(m, x, y, z) +
              c * Eigen::Vector3f(u01_(rng_) - 0.5f, u01_(rng_) - 0.5f, u01_(rng_) - 0.5f);
          break;
        }
      }
      const Eigen::Vector3d pt = to.scene.toNerf(from.scene.toWorld(p.cast<double>()));
      const Eigen::Vector3f q = pt.cast<float>();
      b->inside[size_t(i)] =
          (q.array() >= to.scene.aabbMin().array()).all() && (q.array() <= to.scene.aabbMax().array()).all() ? 1 : 0;
      Eigen::Vector3f d(gauss_(rng_), gauss_(rng_), gauss_(rng_));
      d /= std::max(d.norm(), 1e-6f);
      for (int a = 0; a < 3; ++a) {
        const size_t j = size_t(3 * i + a);
        b->p_from[j] = p[a];
        b->p_to[j] = float(pt[a]);
        b->dir[j] = d[a];
      }
    }
  }

 private:
  std::mt19937_64 rng_;
  std::uniform_real_distribution<float> u01_{0.f, 1.f};
  std::normal_distribution<float> gauss_{0.f, 1.f};
  std::uniform_int_distribution<int> cell_;
};

}  // namespace

double distill(const NerfModel& from, NerfModel& to, const DistillOptions& options) {
  if (options.steps < 0 || options.samples_per_step < 1) fail("distill: steps must be >= 0 and samples_per_step >= 1");
  const int n = options.samples_per_step;
  const size_t un = size_t(n);
  const double k = from.scene.scale / to.scene.scale;
  const float log_floor = std::log(0.1f);
  PointSampler sampler(options.seed);
  auto ws = to.field->makeWorkspace();
  auto grads = to.field->makeGradients();
  DistillBatch b{std::vector<float>(3 * un), std::vector<float>(3 * un), std::vector<float>(3 * un),
                 std::vector<uint8_t>(un)};
  std::vector<float> q_from(3 * un), q_to(3 * un), sig_f(un), rgb_f(3 * un), sig_t(un), rgb_t(3 * un), d_sig(un),
      d_rgb(3 * un);
  double loss = 0;
  for (int it = 0; it < options.steps; ++it) {
    sampler.draw(from, to, n, &b);
    from.toFieldCoords(b.p_from.data(), un, q_from.data());
    to.toFieldCoords(b.p_to.data(), un, q_to.data());
    from.field->query(q_from.data(), b.dir.data(), un, sig_f.data(), rgb_f.data());
    to.field->forward(ws, q_to.data(), b.dir.data(), un, sig_t.data(), rgb_t.data());
    loss = 0;
    for (int i = 0; i < n; ++i) {
      if (!b.inside[size_t(i)]) {  // outside the student's box: its clamped coordinates must not learn it
        d_sig[size_t(i)] = 0.f;
        for (int c = 0; c < 3; ++c) d_rgb[size_t(3 * i + c)] = 0.f;
        continue;
      }
      const float target_sigma = float(sig_f[size_t(i)] * k);
      const float target = std::max(std::log(std::max(target_sigma, 1e-30f)), log_floor);
      const float s = std::max(sig_t[size_t(i)], 1e-30f);
      float e = std::log(s) - target;
      if (target <= log_floor && e < 0) e = 0;  // empty space: anything below the floor will do
      loss += double(e) * e;
      d_sig[size_t(i)] = 2.f * e / s / float(n);
      const float w = 1.f - std::exp(-0.01f * target_sigma);  // colour matters where the old field is dense
      for (int c = 0; c < 3; ++c) {
        const size_t j = size_t(3 * i + c);
        const float ec = rgb_t[j] - rgb_f[j];
        loss += double(w) * ec * ec;
        d_rgb[j] = 2.f * w * ec / float(n);
      }
    }
    loss /= n;
    to.field->backward(ws, d_sig.data(), d_rgb.data(), grads);
    to.field->step({&grads}, float(options.lr), 1);
  }
  to.training_steps += uint64_t(options.steps);
  return loss;
}

}  // namespace nerfslam::nerf
