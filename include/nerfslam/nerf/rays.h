#pragma once
// Scene normalisation and camera rays in the NeRF's unit-cube coordinates.
//
// Like instant-ngp, the field lives in "NeRF space": world points are mapped by
//   p_nerf = scale * p_world + offset       (isotropic; default scale 0.33, offset (0.5, 0.5, 0.5),
//                                            instant-ngp's defaults for NeRF-synthetic scenes)
// and the scene bounding box is the unit cube [0,1]^3 scaled by aabb_scale around its centre
// (0.5, 0.5, 0.5): aabb = [0.5 - s/2, 0.5 + s/2]^3. Unlike instant-ngp we do not cycle the axes
// (x,y,z) -> (y,z,x); the hash grid does not care. Ray directions are unit vectors in NeRF space
// (rotation only, so identical to world directions) and ray parameters t are NeRF-space lengths
// (world length * scale).
#include <Eigen/Core>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"

namespace nerfslam::nerf {

struct SceneTransform {
  double scale = 0.33;
  Eigen::Vector3d offset = Eigen::Vector3d::Constant(0.5);
  double aabb_scale = 1.0;  // power of two >= 1
  // Marching when aabb_scale > 1 (raymarch.h): the step grows as t * cone_angle up to max_step (NeRF
  // lengths; 0: the diagonal of a cell of the largest cascade). The default, 1/64 unclamped, takes
  // a third of the samples per ray of instant-ngp's 1/256 clamped at 2^(cascades-1) minimal steps
  // (KITTI 06: 122 instead of 333), so three times the rays per step, and gave a better held-out
  // PSNR at the same number of steps on KITTI 06 and the synthetic room than 1/256, 1/128 and 1/32
  // (docs/benchmarks.md). Models saved before these were recorded load with the old march.
  double cone_angle = 1.0 / 64.0;
  double max_step = 0.0;

  Eigen::Vector3d toNerf(const Eigen::Vector3d& p_world) const { return scale * p_world + offset; }
  Eigen::Vector3d toWorld(const Eigen::Vector3d& p_nerf) const { return (p_nerf - offset) / scale; }
  Eigen::Vector3f aabbMin() const { return Eigen::Vector3f::Constant(float(0.5 - 0.5 * aabb_scale)); }
  Eigen::Vector3f aabbMax() const { return Eigen::Vector3f::Constant(float(0.5 + 0.5 * aabb_scale)); }
  // Throws nerfslam::Error when scale/offset/aabb_scale are not finite/positive/power of two.
  void validate(const std::string& source) const;
};

struct Ray {
  Eigen::Vector3f origin;  // NeRF space
  Eigen::Vector3f dir;     // unit
};

// Precomputed per (camera, pose): generates rays for continuous pixel coordinates (OpenCV convention:
// the centre of the top-left pixel is (0,0)). Distorted cameras go through Camera::unproject.
class RayGenerator {
 public:
  RayGenerator(const Camera& camera, const SE3& T_world_cam, const SceneTransform& scene);
  Ray ray(double u, double v) const;

 private:
  Camera camera_;
  Eigen::Matrix3d R_;
  Eigen::Vector3f origin_;
  bool distorted_;
};

// Slab test: [t_near, t_far] of the ray inside [lo, hi]; false when it misses (or t_far <= 0).
bool intersectAabb(const Ray& ray, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi, float* t_near, float* t_far);

}  // namespace nerfslam::nerf
