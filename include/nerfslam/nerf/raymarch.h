#pragma once
// Ray marching through the occupancy grid (instant-ngp's scheme).
//
// Steps start at the ray's entry into the scene AABB plus a random fraction of one step. The step is
// dt(t) = clamp(t * cone_angle, kMinStep, max_step): constant sqrt(3)/1024 when cone_angle = 0 (used
// for aabb_scale 1), growing exponentially with distance otherwise (SceneTransform::cone_angle,
// 1/64 by default, instant-ngp's 1/256 in older models). At each step the occupancy cell (at the cascade picked from
// position and step size) is tested: occupied -> emit a sample at t with length dt; empty -> jump to the first step
// position at or past the next cell boundary along the ray (DDA skip). Jumps are whole steps, so samples always land on
// the same step lattice as an unskipped march: skipping never drops an occupied cell's sample. With cone_angle = 0, t_k
// = t_0 + k * dt exactly (no accumulated rounding). In empty space the jump goes to the exit of the largest empty block
// around the cell (16^3 or 4^3 cells, see OccupancyGrid::occupiedBlock) rather than of the cell alone: fewer tests, the
// same samples.
#include <algorithm>
#include <cmath>

#include "nerfslam/nerf/occupancy.h"
#include "nerfslam/nerf/rays.h"

namespace nerfslam::nerf {

struct MarchParams {
  float cone_angle = 0.f;     // 0 for aabb_scale 1, the scene's cone_angle otherwise
  float max_step = kMinStep;  // the scene's max_step, or the diagonal of a cell of the largest cascade
  static MarchParams forScene(const SceneTransform& scene, int cascades);
  float dt(float t) const { return std::clamp(t * cone_angle, kMinStep, max_step); }
};

// Resumable march of one ray: next() emits up to `max` samples and can be called again (rendering
// marches in growing chunks and stops when the ray terminates).
class RayMarcher {
 public:
  // `jitter` in [0,1): fraction of the first step to offset the start by.
  RayMarcher(const Ray& ray, const OccupancyGrid& grid, const SceneTransform& scene, const MarchParams& params,
             float jitter);
  bool done() const { return done_; }
  // Writes positions xyz[3*k], t[k] (parameter at the sample), dt[k]; returns the count.
  int next(int max, float* xyz, float* t, float* dt);
  float tFar() const { return t_far_; }

 private:
  // Distance along the ray from the point at cell coordinates u (cascade mip) to where it leaves
  // its block of 2^shift cells: the exit boundary along an axis is the next block face in the
  // direction of travel, floor(u / B) + 1 going up, floor(u / B) going down (0 away when exactly on
  // a face). No divisions: cell_len_ holds 1 / (dir * kRes) and the powers of two are exact.
  float distanceToNextCell(const float u[3], int mip, int shift) const {
    const float B = float(1u << shift), invB = OccupancyGrid::invCascadeScale(shift);
    const float scale = float(1u << mip);
    float best = INFINITY;
    for (int a = 0; a < 3; ++a) {
      if (ray_.dir[a] == 0.f) continue;
      const float ub = floorSmall(u[a] * invB);
      const float boundary = (ray_.dir[a] > 0 ? ub + 1.f : ub) * B;
      best = std::min(best, (boundary - u[a]) * (cell_len_[a] * scale));  // back to NeRF length
    }
    return std::max(best, 0.f);
  }

  // floor and ceil for |x| < 2^31 through integer conversion (the baseline x86-64 target has no
  // rounding instruction: std::floor/ceil compile to a longer sequence on the march's latency chain).
  static float floorSmall(float x) {
    const float i = float(int32_t(x));
    return x < i ? i - 1.f : i;
  }
  static int64_t ceilSmall(float x) {
    const int32_t i = int32_t(x);
    return int64_t(i) + (float(i) < x ? 1 : 0);
  }

  static constexpr float kInvMinStep = 1024.f / 1.7320508f;

  Ray ray_;
  Eigen::Vector3f inv_dir_, cell_len_;
  const OccupancyGrid* grid_;
  MarchParams params_;
  float t0_ = 0, t_ = 0, t_far_ = 0;
  int64_t k_ = 0;  // step index (cone_angle 0)
  bool done_ = false;
};

}  // namespace nerfslam::nerf
