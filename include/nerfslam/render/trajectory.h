#pragma once
// Camera trajectories through a synthetic scene, continuous in time and deterministic from a seed.
//
//   handheld  smooth walk with realistic shake, looking around (room, corridor) or at the object
//   orbit     circle around the object (turntable), an arc in front of the plane, a small
//             circle looking outwards (room, corridor)
//   forward   forward motion (along the corridor; across the room; towards the plane)
//   rotation  pure rotation about a fixed camera centre (no parallax)
//   fast      handheld with motion bursts (5x speed for ~0.5 s every few seconds, stronger shake)
//   loop      closed loop: the last frame's pose equals the first's
//
// Laps: `loop` can go round its closed path `laps` times over the duration, each lap the same (pose(t) == pose(t +
// duration / laps) for t in the first laps - 1 laps).
//
// Poses are T_world_cam with OpenCV optical axes. The world is z-up; cameras are kept upright
// (no roll beyond the shake).
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "nerfslam/core/pose.h"
#include "nerfslam/render/scene.h"

namespace nerfslam {

const std::vector<std::string>& trajectoryNames();
// The trajectory that suits a scene: room handheld, turntable orbit, plane handheld, corridor loop.
std::string defaultTrajectory(const std::string& scene);

// Camera looking from `eye` at `target`, image "up" towards `up` (x right, y down, z forward).
SE3 lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target,
           const Eigen::Vector3d& up = Eigen::Vector3d::UnitZ());

class CameraTrajectory {
 public:
  CameraTrajectory() = default;
  CameraTrajectory(std::string name, double duration, std::function<SE3(double)> f)
      : name_(std::move(name)), duration_(duration), f_(std::move(f)) {}
  // Pose at time t in seconds (any t; defined beyond [0, duration] too).
  SE3 pose(double t) const { return f_(t); }
  double duration() const { return duration_; }
  const std::string& name() const { return name_; }
  // Poses at t = i / fps, i = 0..frames-1.
  std::vector<SE3> sample(int frames, double fps) const;

 private:
  std::string name_;
  double duration_ = 0;
  std::function<SE3(double)> f_;
};

// `duration`: time of the last frame ((frames - 1) / fps); the loop closes exactly at it (and, with
// `laps` > 1, at every multiple of duration / laps). Throws nerfslam::Error listing the valid names
// for an unknown trajectory, and for laps < 1 or laps > 1 with a trajectory other than loop.
CameraTrajectory makeTrajectory(const Scene& scene, const std::string& name, double duration, uint64_t seed,
                                int laps = 1);
// The trajectories that accept laps > 1.
bool trajectoryHasLaps(const std::string& name);

}  // namespace nerfslam
