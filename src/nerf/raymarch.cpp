#include "nerfslam/nerf/raymarch.h"

#include <cmath>

namespace nerfslam::nerf {

MarchParams MarchParams::forScene(const SceneTransform& scene, int cascades) {
  MarchParams p;
  p.cone_angle = scene.aabb_scale > 1.0 ? float(scene.cone_angle) : 0.f;
  p.max_step = scene.max_step > 0 ? float(scene.max_step) : OccupancyGrid::cellSize(cascades - 1) * 1.7320508f;
  p.max_step = std::max(p.max_step, kMinStep);
  return p;
}

RayMarcher::RayMarcher(const Ray& ray, const OccupancyGrid& grid, const SceneTransform& scene,
                       const MarchParams& params, float jitter)
    : ray_(ray), grid_(&grid), params_(params) {
  inv_dir_ = ray.dir.cwiseInverse();
  // NeRF length per cascade-0 cell unit along each axis (kRes is a power of two: exact).
  cell_len_ = inv_dir_ * (1.f / float(OccupancyGrid::kRes));
  float tn, tf;
  if (!intersectAabb(ray, scene.aabbMin(), scene.aabbMax(), &tn, &tf)) {
    done_ = true;
    return;
  }
  t_far_ = tf;
  t0_ = tn + params_.dt(tn) * jitter;
  t_ = t0_;
}

int RayMarcher::next(int max, float* xyz, float* t_out, float* dt_out) {
  // The state lives in locals during the loop: the output pointers may alias the members as far
  // as the compiler knows, which would otherwise put a store and a reload of t_ and k_ on the
  // latency chain of every step.
  int n = 0;
  if (done_) return 0;
  const bool constant = params_.cone_angle == 0.f;
  const OccupancyGrid& grid = *grid_;
  const MarchParams params = params_;
  const Eigen::Vector3f origin = ray_.origin, dir = ray_.dir;
  const float t0 = t0_, t_far = t_far_;
  float t = t_;
  int64_t k = k_;
  bool done = false;
  constexpr int kRes = OccupancyGrid::kRes;
  while (n < max) {
    if (t >= t_far) {
      done = true;
      break;
    }
    const float dt = params.dt(t);
    const Eigen::Vector3f p = origin + t * dir;
    const int mip = grid.mipFromDt(dt, p);
    // The cell (and, when empty, the largest empty block around it) at this cascade, in cell units
    // u = ((p - 0.5) / 2^mip + 0.5) * res.
    const float inv = OccupancyGrid::invCascadeScale(mip);
    float u[3];
    int c[3];
    bool inside = true;
    for (int a = 0; a < 3; ++a) {
      u[a] = ((p[a] - 0.5f) * inv + 0.5f) * kRes;
      inside &= u[a] >= 0.f && u[a] < float(kRes);
      c[a] = inside ? int(u[a]) : 0;
    }
    if (inside && grid.occupiedCell(mip, c[0], c[1], c[2])) {
      xyz[3 * n + 0] = p.x();
      xyz[3 * n + 1] = p.y();
      xyz[3 * n + 2] = p.z();
      t_out[n] = t;
      dt_out[n] = dt;
      ++n;
      if (constant)
        t = t0 + float(++k) * kMinStep;
      else
        t += dt;
      continue;
    }
    int shift = 0;
    if (inside) {
      if (!grid.occupiedBlock(mip, 2, c[0] >> 4, c[1] >> 4, c[2] >> 4))
        shift = 4;
      else if (!grid.occupiedBlock(mip, 1, c[0] >> 2, c[1] >> 2, c[2] >> 2))
        shift = 2;
    }
    const float t_target = t + distanceToNextCell(u, mip, shift);
    if (constant) {
      const int64_t k_target = ceilSmall((t_target - t0) * kInvMinStep - 1e-3f);
      k = std::max(k + 1, k_target);
      t = t0 + float(k) * kMinStep;
    } else {
      do {
        t += params.dt(t);
      } while (t < t_target);
    }
  }
  t_ = t;
  k_ = k;
  done_ = done;
  return n;
}

}  // namespace nerfslam::nerf
