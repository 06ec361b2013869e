#include "nerfslam/nerf/raymarch.h"

#include <cmath>

namespace nerfslam::nerf {

MarchParams MarchParams::forScene(double aabb_scale, int cascades) {
  MarchParams p;
  p.cone_angle = aabb_scale > 1.0 ? 1.f / 256.f : 0.f;
  p.max_step = kMinStep * float(1 << (cascades - 1));
  return p;
}

RayMarcher::RayMarcher(const Ray& ray, const OccupancyGrid& grid, const SceneTransform& scene,
                       const MarchParams& params, float jitter)
    : ray_(ray), grid_(&grid), params_(params) {
  inv_dir_ = ray.dir.cwiseInverse();
  float tn, tf;
  if (!intersectAabb(ray, scene.aabbMin(), scene.aabbMax(), &tn, &tf)) {
    done_ = true;
    return;
  }
  t_far_ = tf;
  t0_ = tn + params_.dt(tn) * jitter;
  t_ = t0_;
}

float RayMarcher::distanceToNextCell(const Eigen::Vector3f& p, int mip, int shift) const {
  // In the cascade's cell units: cell coordinate u = ((p - 0.5) / 2^mip + 0.5) * res; blocks of
  // 2^shift cells. The exit boundary along an axis is the next block face in the direction of
  // travel: floor(u / B) + 1 going up, floor(u / B) going down (0 away when exactly on a face).
  const float res = OccupancyGrid::kRes;
  const float inv = OccupancyGrid::invCascadeScale(mip);
  const float B = float(1 << shift), invB = 1.f / B;
  float best = INFINITY;
  for (int a = 0; a < 3; ++a) {
    if (ray_.dir[a] == 0.f) continue;
    const float u = ((p[a] - 0.5f) * inv + 0.5f) * res;
    const float ub = std::floor(u * invB);
    const float boundary = (ray_.dir[a] > 0 ? ub + 1.f : ub) * B;
    const float dist = (boundary - u) / res / inv * inv_dir_[a];  // back to NeRF length
    best = std::min(best, dist);
  }
  return std::max(best, 0.f);
}

int RayMarcher::next(int max, float* xyz, float* t_out, float* dt_out) {
  int n = 0;
  const bool constant = params_.cone_angle == 0.f;
  const OccupancyGrid& grid = *grid_;
  constexpr int kRes = OccupancyGrid::kRes;
  while (!done_ && n < max) {
    if (t_ >= t_far_) {
      done_ = true;
      break;
    }
    const float dt = params_.dt(t_);
    const Eigen::Vector3f p = ray_.origin + t_ * ray_.dir;
    const int mip = grid.mipFromDt(dt, p);
    // The cell (and, when empty, the largest empty block around it) at this cascade.
    const float inv = OccupancyGrid::invCascadeScale(mip);
    int c[3];
    bool inside = true;
    for (int a = 0; a < 3; ++a) {
      const float u = ((p[a] - 0.5f) * inv + 0.5f) * kRes;
      inside &= u >= 0.f && u < float(kRes);
      c[a] = inside ? int(u) : 0;
    }
    if (inside && grid.occupiedCell(mip, c[0], c[1], c[2])) {
      xyz[3 * n + 0] = p.x();
      xyz[3 * n + 1] = p.y();
      xyz[3 * n + 2] = p.z();
      t_out[n] = t_;
      dt_out[n] = dt;
      ++n;
      if (constant)
        t_ = t0_ + float(++k_) * kMinStep;
      else
        t_ += dt;
      continue;
    }
    int shift = 0;
    if (inside) {
      if (!grid.occupiedBlock(mip, 2, c[0] >> 4, c[1] >> 4, c[2] >> 4))
        shift = 4;
      else if (!grid.occupiedBlock(mip, 1, c[0] >> 2, c[1] >> 2, c[2] >> 2))
        shift = 2;
    }
    const float t_target = t_ + distanceToNextCell(p, mip, shift);
    if (constant) {
      const int64_t k_target = int64_t(std::ceil((t_target - t0_) / kMinStep - 1e-3f));
      k_ = std::max(k_ + 1, k_target);
      t_ = t0_ + float(k_) * kMinStep;
    } else {
      do {
        t_ += params_.dt(t_);
      } while (t_ < t_target);
    }
  }
  return n;
}

}  // namespace nerfslam::nerf
