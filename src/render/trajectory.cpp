#include "nerfslam/render/trajectory.h"

#include <algorithm>
#include <array>
#include <cmath>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "nerfslam/core/error.h"

namespace nerfslam {
using Eigen::Vector2d;
using Eigen::Vector3d;

namespace {

// Band-limited smooth noise in [-1, 1]: a sum of sinusoids with random frequencies in [f_lo, f_hi]
// (Hz) and phases; amplitudes sum to 1.
class SmoothNoise {
 public:
  SmoothNoise() = default;
  SmoothNoise(cv::RNG& rng, double f_lo, double f_hi, int terms = 4) {
    double total = 0;
    for (int i = 0; i < terms; ++i) {
      Term t{rng.uniform(f_lo, f_hi), rng.uniform(0.0, 2 * M_PI), rng.uniform(0.5, 1.0)};
      total += t.a;
      terms_.push_back(t);
    }
    for (auto& t : terms_) t.a /= total;
  }
  double operator()(double t) const {
    double s = 0;
    for (const auto& k : terms_) s += k.a * std::sin(2 * M_PI * k.f * t + k.phase);
    return s;
  }

 private:
  struct Term {
    double f, phase, a;
  };
  std::vector<Term> terms_;
};

struct Noise3 {
  SmoothNoise x, y, z;
  Noise3(cv::RNG& rng, double lo, double hi) : x(rng, lo, hi), y(rng, lo, hi), z(rng, lo, hi) {}
  Vector3d operator()(double t) const { return {x(t), y(t), z(t)}; }
};

// Hand shake: small rotation (rad) and translation (m) at 4-12 Hz, applied in the camera frame.
struct Shake {
  Noise3 rot, trans;
  double rot_amp, trans_amp;
  Shake(cv::RNG& rng, double rot_deg, double trans_m)
      : rot(rng, 4.0, 12.0), trans(rng, 4.0, 12.0), rot_amp(rot_deg * M_PI / 180), trans_amp(trans_m) {}
  SE3 apply(const SE3& T_world_cam, double t, double gain = 1.0) const {
    const Vector3d w = rot(t) * rot_amp * gain;
    const Eigen::Matrix3d R =
        Eigen::AngleAxisd(w.norm(), w.norm() > 0 ? w.normalized() : Vector3d::UnitZ()).toRotationMatrix();
    return T_world_cam * SE3(R, trans(t) * trans_amp * gain);
  }
};

Vector3d direction(double yaw, double pitch) {
  return {std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw), std::sin(pitch)};
}

// Closed polyline parametrised by arc length, with a smoothed tangent.
class ClosedPath {
 public:
  explicit ClosedPath(std::vector<Vector2d> pts) : pts_(std::move(pts)) {
    cum_.push_back(0);
    for (size_t i = 0; i < pts_.size(); ++i)
      cum_.push_back(cum_.back() + (pts_[(i + 1) % pts_.size()] - pts_[i]).norm());
  }
  double length() const { return cum_.back(); }
  Vector2d at(double s) const {
    const double L = length();
    s = std::fmod(s, L);
    if (s < 0) s += L;
    const size_t i =
        std::min<size_t>(std::upper_bound(cum_.begin(), cum_.end(), s) - cum_.begin() - 1, pts_.size() - 1);
    const double f = (s - cum_[i]) / std::max(1e-12, cum_[i + 1] - cum_[i]);
    return pts_[i] + f * (pts_[(i + 1) % pts_.size()] - pts_[i]);
  }
  Vector2d tangent(double s, double half_window = 0.5) const {
    return (at(s + half_window) - at(s - half_window)).normalized();
  }

 private:
  std::vector<Vector2d> pts_;
  std::vector<double> cum_;
};

std::vector<Vector2d> ellipse(const Vector2d& c, double rx, double ry, int n = 72) {
  std::vector<Vector2d> p;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    p.push_back(c + Vector2d(rx * std::cos(a), ry * std::sin(a)));
  }
  return p;
}

Vector2d rot2(const Vector2d& v, double a) {
  return {std::cos(a) * v.x() - std::sin(a) * v.y(), std::sin(a) * v.x() + std::cos(a) * v.y()};
}

}  // namespace

const std::vector<std::string>& trajectoryNames() {
  static const std::vector<std::string> n = {"handheld", "orbit", "forward", "rotation", "fast", "loop"};
  return n;
}

std::string defaultTrajectory(const std::string& scene) {
  if (scene == "turntable") return "orbit";
  if (scene == "corridor") return "loop";
  return "handheld";
}

SE3 lookAt(const Vector3d& eye, const Vector3d& target, const Vector3d& up) {
  const Vector3d z = (target - eye).normalized();
  Vector3d x = z.cross(up);
  if (x.norm() < 1e-9) x = z.cross(Vector3d::UnitX());
  x.normalize();
  const Vector3d y = z.cross(x);
  Eigen::Matrix3d R;
  R.col(0) = x;
  R.col(1) = y;
  R.col(2) = z;
  return SE3(R, eye);
}

bool trajectoryHasLaps(const std::string& name) { return name == "loop"; }

std::vector<SE3> CameraTrajectory::sample(int frames, double fps) const {
  std::vector<SE3> out;
  out.reserve(std::max(0, frames));
  for (int i = 0; i < frames; ++i) out.push_back(pose(i / fps));
  return out;
}

namespace {

// What every trajectory is made from: the scene's camera region, where to look, and the closed path
// around it (the scene's loop path, else an ellipse in the camera region), with the start on it and
// an initial heading drawn from the trajectory's random generator.
struct Motion {
  Vector3d cmin, cmax, centre, half, focus, anchor;
  double loop_h = 0;
  bool outward = false;
  double sweep = 0;
  double base_angle = 0, base_radius = 0;
  bool has_path = false;
  ClosedPath path{std::vector<Vector2d>{}};
  double start_s = 0, yaw0 = 0;
};

Motion sceneMotion(const Scene& sc, cv::RNG& rng) {
  Motion m;
  m.cmin = sc.camera_min;
  m.cmax = sc.camera_max;
  m.centre = 0.5 * (m.cmin + m.cmax);
  m.half = 0.5 * (m.cmax - m.cmin);
  m.focus = sc.focus;
  m.anchor = sc.anchor;
  m.loop_h = sc.loop_height;
  m.outward = sc.look_outward;
  m.sweep = sc.handheld_sweep;
  m.base_angle = std::atan2(m.anchor.y() - m.focus.y(), m.anchor.x() - m.focus.x());
  m.base_radius = std::max(0.3, (m.anchor - m.focus).head<2>().norm());
  m.has_path = !sc.loop_path.empty();
  m.path = ClosedPath(m.has_path ? sc.loop_path : ellipse(m.centre.head<2>(), 0.85 * m.half.x(), 0.85 * m.half.y()));
  m.start_s = rng.uniform(0.0, 1.0) * (m.has_path ? 0.0 : m.path.length());
  m.yaw0 = rng.uniform(-M_PI, M_PI);
  return m;
}

// handheld and fast: a wandering walk with hand shake (fast: stronger, with bursts of speed).
CameraTrajectory handheldTrajectory(const Motion& m, cv::RNG& rng, const std::string& name, double duration) {
  const bool fast = name == "fast";
  Noise3 walk(rng, 0.025, 0.09), look(rng, 0.03, 0.11), aim(rng, 0.04, 0.12);
  Shake shake(rng, fast ? 0.8 : 0.35, fast ? 0.006 : 0.003);
  // Time warp for bursts: dtau/dt = 1 + 4 sum_k exp(-(t - t_k)^2 / (2 sigma^2)).
  std::vector<double> bursts;
  const double sigma = 0.18;
  if (fast)
    for (double tb = rng.uniform(0.8, 2.0); tb < duration; tb += rng.uniform(2.0, 4.0)) bursts.push_back(tb);
  auto tau = [bursts, sigma](double t) {
    double s = t;
    for (double tb : bursts)
      s += 4.0 * sigma * std::sqrt(M_PI / 2) * (std::erf((t - tb) / (sigma * std::sqrt(2.0))) + 1.0);
    return s;
  };
  return CameraTrajectory(name, duration, [=](double t) {
    const double u = tau(t);
    const double gain = fast ? 1.0 + 2.0 * (tau(t + 0.01) - tau(t - 0.01)) / 0.02 / 5.0 : 1.0;
    Vector3d eye, target;
    if (m.has_path) {  // walk along the corridor at 0.7 m/s, swaying and looking around
      const double s = m.start_s + 0.7 * u;
      const Vector2d p = m.path.at(s), tg = m.path.tangent(s);
      const Vector2d n(-tg.y(), tg.x());
      eye << p + 0.3 * walk.x(u) * n, m.loop_h + 0.15 * walk.z(u);
      const Vector2d d = rot2(tg, 0.6 * look.x(u));
      target = eye + direction(std::atan2(d.y(), d.x()), -0.1 + 0.15 * look.y(u));
    } else if (m.outward) {
      eye = m.centre + m.half.cwiseProduct(walk(u));
      target = eye + direction(m.yaw0 + 2.2 * look.x(u), -0.12 + 0.22 * look.y(u));
    } else {  // around the object / in front of the plane, at a wandering angle and distance
      const double a = m.base_angle + m.sweep * walk.x(u);
      const double rad = m.base_radius * (1.0 + 0.15 * walk.y(u));
      eye = Vector3d(m.focus.x() + rad * std::cos(a), m.focus.y() + rad * std::sin(a), m.anchor.z() + 0.2 * walk.z(u));
      target = m.focus + 0.25 * aim(u);
    }
    return shake.apply(lookAt(eye, target), u, gain);
  });
}

// rotation: fixed centre, only R changes (no shake translation).
CameraTrajectory rotationTrajectory(const Motion& m, cv::RNG& rng, const std::string& name, double duration) {
  Noise3 look(rng, 0.04, 0.12);
  const Vector3d eye = m.anchor;
  const Vector3d fwd = m.outward ? direction(m.yaw0, 0) : (m.focus - eye).normalized();
  const double yaw_f = std::atan2(fwd.y(), fwd.x()), pitch_f = std::asin(std::clamp(fwd.z(), -1.0, 1.0));
  const double yaw_amp = m.outward ? 1.2 : 0.35;
  return CameraTrajectory(name, duration, [=](double t) {
    const Vector3d d = direction(yaw_f + yaw_amp * look.x(t), pitch_f + 0.15 * look.y(t));
    SE3 T = lookAt(eye, eye + d);
    const double roll = 0.05 * look.z(t);
    return SE3(T.rotationMatrix() * Eigen::AngleAxisd(roll, Vector3d::UnitZ()).toRotationMatrix(), eye);
  });
}

// orbit: one revolution over the sequence.
CameraTrajectory orbitTrajectory(const Motion& m, cv::RNG& rng, const std::string& name, double duration) {
  SmoothNoise bob(rng, 0.05, 0.15);
  const double phase = rng.uniform(0.0, 2 * M_PI);
  const double omega = 2 * M_PI / duration;  // one revolution over the sequence
  if (m.outward) {                           // panoramic orbit: small circle around the anchor, looking outwards
    const Vector3d c = m.anchor;
    return CameraTrajectory(name, duration, [=](double t) {
      const double a = phase + omega * t;
      const Vector3d eye = c + Vector3d(0.4 * std::cos(a), 0.4 * std::sin(a), 0.1 * bob(t));
      return lookAt(eye, eye + direction(a, -0.1));
    });
  }
  const Vector3d f = m.focus;
  const double radius = std::max(0.3, (m.anchor - f).head<2>().norm());
  // A full revolution around objects (turntable); an arc in front of one-sided scenes (plane).
  const bool full = m.sweep >= 1.0;
  const double base_angle = m.base_angle, sweep = m.sweep, anchor_z = m.anchor.z();
  return CameraTrajectory(name, duration, [=](double t) {
    const double a = full ? phase + omega * t : base_angle + 1.5 * sweep * std::sin(omega * t);
    const Vector3d eye(f.x() + radius * std::cos(a), f.y() + radius * std::sin(a), anchor_z + 0.15 * bob(t));
    return lookAt(eye, f);
  });
}

// forward: along the path, across the camera region, or towards the focus.
CameraTrajectory forwardTrajectory(const Motion& m, cv::RNG& rng, const std::string& name, double duration) {
  Noise3 sway(rng, 0.1, 0.3);
  if (m.has_path) {
    return CameraTrajectory(name, duration, [=](double t) {
      const double s = m.start_s + 0.9 * t;
      const Vector2d p = m.path.at(s), tg = m.path.tangent(s);
      const Vector3d eye(p.x(), p.y(), m.loop_h + 0.02 * sway.z(t));
      return lookAt(eye, eye + Vector3d(tg.x(), tg.y(), 0.02 * sway.y(t)));
    });
  }
  if (m.outward) {  // across the box along x, looking forward
    return CameraTrajectory(name, duration, [=](double t) {
      const double s = std::clamp(t / duration, 0.0, 1.0);
      const Vector3d eye(m.cmin.x() + s * (m.cmax.x() - m.cmin.x()), m.centre.y() + 0.1 * sway.y(t),
                         m.centre.z() + 0.05 * sway.z(t));
      return lookAt(eye, eye + Vector3d(1.0, 0.05 * sway.x(t), -0.05));
    });
  }
  // Towards the focus from the far side of the camera box, stopping at half the distance.
  const Vector3d from = m.anchor, focus = m.focus;
  return CameraTrajectory(name, duration, [=](double t) {
    const double s = std::clamp(t / duration, 0.0, 1.0);
    const Vector3d eye = from + 0.5 * s * (focus - from) + 0.02 * sway(t);
    return lookAt(eye, focus + 0.05 * sway(t));
  });
}

// loop: `laps` times around the closed path; periodic components and a shake vanishing at the ends
// of every lap make the pose at the end of a lap equal the first.
CameraTrajectory loopTrajectory(const Motion& m, cv::RNG& rng, const std::string& name, double duration, int laps) {
  Shake shake(rng, 0.3, 0.003);
  const int look_cycles = 2;
  // Time within the current lap: laps repeat exactly; before the first lap and after the last, the
  // first and last laps continue. With one lap it is t itself.
  const double lap = duration / laps;
  auto lapTime = [lap, laps](double t) { return t - std::clamp(std::floor(t / lap), 0.0, double(laps - 1)) * lap; };
  return CameraTrajectory(name, duration, [=](double t_seq) {
    const double t = lapTime(t_seq);
    const double s01 = t / lap;
    const double s = m.start_s + s01 * m.path.length();
    const Vector2d p = m.path.at(s), tg = m.path.tangent(s);
    const Vector3d eye(p.x(), p.y(), m.loop_h + 0.08 * std::sin(2 * M_PI * 3 * s01));
    Vector3d target;
    if (m.outward) {
      const double yaw =
          std::atan2(tg.y(), tg.x()) + (m.has_path ? 0.25 : -0.6) * std::sin(2 * M_PI * look_cycles * s01);
      target = eye + direction(yaw, -0.08);
    } else {
      target = m.focus;
    }
    const double env = std::sin(M_PI * std::clamp(s01, 0.0, 1.0));
    return shake.apply(lookAt(eye, target), t, env);
  });
}

}  // namespace

CameraTrajectory makeTrajectory(const Scene& sc, const std::string& name, double duration, uint64_t seed, int laps) {
  const auto& names = trajectoryNames();
  if (std::find(names.begin(), names.end(), name) == names.end()) {
    std::string list;
    for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
    fail("unknown trajectory '{}' (valid trajectories: {})", name, list);
  }
  if (laps < 1 || laps > 10000) fail("laps must be in 1..10000 (got {})", laps);
  if (laps > 1 && !trajectoryHasLaps(name)) fail("trajectory '{}' has no laps (only loop has)", name);
  if (!(duration > 0) || !std::isfinite(duration)) duration = 1.0;
  cv::RNG rng(seed * 0x9E3779B97F4A7C15ull + 12345u);
  const Motion m = sceneMotion(sc, rng);
  if (name == "handheld" || name == "fast") return handheldTrajectory(m, rng, name, duration);
  if (name == "rotation") return rotationTrajectory(m, rng, name, duration);
  if (name == "orbit") return orbitTrajectory(m, rng, name, duration);
  if (name == "forward") return forwardTrajectory(m, rng, name, duration);
  return loopTrajectory(m, rng, name, duration, laps);
}

}  // namespace nerfslam
