#include "nerfslam/nerf/rays.h"

#include <cmath>

#include "nerfslam/core/error.h"

namespace nerfslam::nerf {

void SceneTransform::validate(const std::string& source) const {
  if (!std::isfinite(scale) || scale <= 0) throw fieldError(source, "scale", "must be a finite number > 0");
  if (!offset.allFinite()) throw fieldError(source, "offset", "must be finite");
  if (!std::isfinite(aabb_scale) || aabb_scale < 1 || aabb_scale > 128 ||
      std::exp2(std::round(std::log2(aabb_scale))) != aabb_scale)
    throw fieldError(source, "aabb_scale", fmt::format("must be a power of two in [1, 128], got {}", aabb_scale));
  if (!std::isfinite(cone_angle) || cone_angle < 0 || cone_angle > 1)
    throw fieldError(source, "cone_angle", fmt::format("must be in [0, 1], got {}", cone_angle));
  if (!std::isfinite(max_step) || max_step < 0 || max_step > 10)
    throw fieldError(source, "max_step", fmt::format("must be in [0, 10] (0: automatic), got {}", max_step));
}

RayGenerator::RayGenerator(const Camera& camera, const SE3& T_world_cam, const SceneTransform& scene)
    : camera_(camera), R_(T_world_cam.rotationMatrix()), distorted_(camera.hasDistortion()) {
  origin_ = scene.toNerf(T_world_cam.translation()).cast<float>();
}

Ray RayGenerator::ray(double u, double v) const {
  Eigen::Vector3d d_cam;
  if (distorted_)
    d_cam = camera_.unproject(Eigen::Vector2d(u, v));
  else
    d_cam = Eigen::Vector3d((u - camera_.cx) / camera_.fx, (v - camera_.cy) / camera_.fy, 1.0);
  Ray r;
  r.origin = origin_;
  r.dir = (R_ * d_cam).normalized().cast<float>();
  return r;
}

bool intersectAabb(const Ray& ray, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi, float* t_near, float* t_far) {
  float tn = -INFINITY, tf = INFINITY;
  for (int a = 0; a < 3; ++a) {
    const float inv = 1.f / ray.dir[a];  // +-inf for axis-parallel rays: handled by IEEE
    float t0 = (lo[a] - ray.origin[a]) * inv;
    float t1 = (hi[a] - ray.origin[a]) * inv;
    if (std::isnan(t0) || std::isnan(t1)) {  // origin exactly on a slab plane with a parallel ray
      if (ray.origin[a] < lo[a] || ray.origin[a] > hi[a]) return false;
      continue;
    }
    if (t0 > t1) std::swap(t0, t1);
    tn = std::max(tn, t0);
    tf = std::min(tf, t1);
  }
  if (tf <= std::max(tn, 0.f)) return false;
  *t_near = std::max(tn, 0.f);
  *t_far = tf;
  return true;
}

}  // namespace nerfslam::nerf
