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

float RayMarcher::distanceToNextCell(const Eigen::Vector3f& p, int mip) const {
  // In the cascade's cell units: cell coordinate u = ((p - 0.5) / 2^mip + 0.5) * res.
  const float res = OccupancyGrid::kRes;
  const float inv = std::ldexp(1.f, -mip);
  float best = INFINITY;
  for (int a = 0; a < 3; ++a) {
    if (ray_.dir[a] == 0.f) continue;
    const float u = ((p[a] - 0.5f) * inv + 0.5f) * res;
    const float boundary = ray_.dir[a] > 0 ? std::floor(u) + 1.f : std::ceil(u) - 1.f;
    const float dist = (boundary - u) / res / inv * inv_dir_[a];  // back to NeRF length
    best = std::min(best, dist);
  }
  return std::max(best, 0.f);
}

int RayMarcher::next(int max, float* xyz, float* t_out, float* dt_out) {
  int n = 0;
  const bool constant = params_.cone_angle == 0.f;
  while (!done_ && n < max) {
    if (t_ >= t_far_) {
      done_ = true;
      break;
    }
    const float dt = params_.dt(t_);
    const Eigen::Vector3f p = ray_.origin + t_ * ray_.dir;
    const int mip = grid_->mipFromDt(dt, p);
    if (grid_->occupied(p, mip)) {
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
    } else {
      const float t_target = t_ + distanceToNextCell(p, mip);
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
  }
  return n;
}

}  // namespace nerfslam::nerf
