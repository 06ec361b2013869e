#pragma once
// A procedural scene for NeRF tests: an opaque sphere of radius 0.8 at the origin coloured by its
// normal, seen from cameras on a sphere of radius 3 looking at the origin (RGBA images with a
// transparent background), and a small field, training schedule and scene transform for it.
#include <cmath>

#include <opencv2/core.hpp>

#include "nerfslam/nerf/trainer.h"

namespace nerfslam::nerf {

constexpr double kSphereRadius = 0.8;

inline SE3 lookAt(const Eigen::Vector3d& eye) {
  const Eigen::Vector3d z = (-eye).normalized();
  Eigen::Vector3d x = z.cross(Eigen::Vector3d::UnitZ());
  if (x.norm() < 1e-6) x = Eigen::Vector3d::UnitX();
  x.normalize();
  const Eigen::Vector3d y = z.cross(x);
  Eigen::Matrix3d R;
  R << x, y, z;
  return SE3(R, eye);
}

// View i of n (azimuths evenly spread, elevations varied), size x size pixels, from `distance`
// (below about 1.9 the sphere fills the image).
inline TrainingView syntheticView(int i, int n, int size, double distance = 3.0) {
  const double az = 2 * M_PI * i / n, el = 0.3 + 0.5 * std::sin(3.0 * i);
  const Eigen::Vector3d eye =
      distance * Eigen::Vector3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
  TrainingView v;
  v.camera = Camera::pinhole(size, size, 1.1 * size, 1.1 * size, (size - 1) / 2.0, (size - 1) / 2.0);
  v.T_world_cam = lookAt(eye);
  v.image = cv::Mat(size, size, CV_8UC4, cv::Scalar::all(0));
  const Eigen::Matrix3d R = v.T_world_cam.rotationMatrix();
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      const Eigen::Vector3d d = (R * v.camera.unproject({double(x), double(y)})).normalized();
      const double b = eye.dot(d), c = eye.squaredNorm() - kSphereRadius * kSphereRadius;
      const double disc = b * b - c;
      if (disc < 0) continue;
      const Eigen::Vector3d p = eye + (-b - std::sqrt(disc)) * d;
      const Eigen::Vector3d nrm = p.normalized();
      auto& px = v.image.at<cv::Vec4b>(y, x);
      for (int k = 0; k < 3; ++k) px[k] = cv::saturate_cast<uint8_t>(255.0 * (0.5 + 0.45 * nrm[k]));
      px[3] = 255;
    }
  return v;
}

// A small field, a training schedule and the scene transform (the sphere fills the middle of the
// unit cube) for the sphere.
inline FieldConfig sphereField() {
  FieldConfig c;
  c.n_levels = 8;
  c.log2_hashmap_size = 15;
  c.finest_resolution = 256;
  c.hidden = 32;
  return c;
}

inline TrainOptions sphereTraining(int threads) {
  TrainOptions o;
  o.samples_per_step = 1 << 13;
  o.threads = threads;
  o.seed = 3;
  o.grid_warmup_steps = 32;
  o.grid_update_fraction = 1.0 / 8.0;
  return o;
}

inline SceneTransform sphereScene() {
  SceneTransform s;
  s.scale = 0.33;  // the sphere (radius 0.8) fills the middle of the unit cube
  return s;
}

}  // namespace nerfslam::nerf
