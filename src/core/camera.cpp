#include "nerfslam/core/camera.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <list>
#include <memory>
#include <mutex>

#include <fmt/format.h>
#include <Eigen/LU>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"

namespace nerfslam {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

double coeff(const std::vector<double>& d, size_t i) { return i < d.size() ? d[i] : 0.0; }

// Normalised ideal (x, y) -> normalised distorted coordinates.
Eigen::Vector2d distortNormalized(const Camera& c, const Eigen::Vector2d& p) {
  const double x = p.x(), y = p.y();
  switch (c.distortion_model) {
    case DistortionModel::kNone:
      return p;
    case DistortionModel::kRadTan: {
      const double k1 = coeff(c.distortion, 0), k2 = coeff(c.distortion, 1), p1 = coeff(c.distortion, 2),
                   p2 = coeff(c.distortion, 3), k3 = coeff(c.distortion, 4);
      const double r2 = x * x + y * y;
      const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
      return {x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
              y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y};
    }
    case DistortionModel::kEquidistant: {
      const double k1 = coeff(c.distortion, 0), k2 = coeff(c.distortion, 1), k3 = coeff(c.distortion, 2),
                   k4 = coeff(c.distortion, 3);
      const double r = std::sqrt(x * x + y * y);
      if (r < 1e-12) return p;  // theta_d / r -> 1
      const double th = std::atan(r);
      const double t2 = th * th;
      const double th_d = th * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))));
      const double s = th_d / r;
      return {x * s, y * s};
    }
  }
  return p;
}

// Jacobian of distortNormalized (radtan only).
Eigen::Matrix2d radtanJacobian(const Camera& c, const Eigen::Vector2d& p) {
  const double x = p.x(), y = p.y();
  const double k1 = coeff(c.distortion, 0), k2 = coeff(c.distortion, 1), p1 = coeff(c.distortion, 2),
               p2 = coeff(c.distortion, 3), k3 = coeff(c.distortion, 4);
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
  const double dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
  const double drx = 2.0 * x * dradial_dr2, dry = 2.0 * y * dradial_dr2;
  Eigen::Matrix2d J;
  J(0, 0) = radial + x * drx + 2.0 * p1 * y + 6.0 * p2 * x;
  J(0, 1) = x * dry + 2.0 * p1 * x + 2.0 * p2 * y;
  J(1, 0) = y * drx + 2.0 * p1 * x + 2.0 * p2 * y;
  J(1, 1) = radial + y * dry + 6.0 * p1 * y + 2.0 * p2 * x;
  return J;
}

// Normalised distorted -> normalised ideal coordinates. NaN when it does not converge (a pixel
// outside the region where the distortion model is invertible) or, for the fisheye model, when the
// ray is at or beyond 90 degrees from the optical axis.
Eigen::Vector2d undistortNormalized(const Camera& c, const Eigen::Vector2d& pd) {
  // Stop when the residual is far below a micro-pixel.
  const double tol = 1e-10 / std::max({c.fx, c.fy, 1.0});
  switch (c.distortion_model) {
    case DistortionModel::kNone:
      return pd;
    case DistortionModel::kRadTan: {
      // Start from dividing out the radial factor at the distorted point (exact for small
      // distortion), then damped Newton on distort(p) = pd.
      const Eigen::Vector2d d0 = distortNormalized(c, pd);
      const double radial0 = (d0 - pd).norm() < 1e-300 ? 1.0 : d0.norm() / std::max(pd.norm(), 1e-300);
      Eigen::Vector2d p = (radial0 > 0.1 && radial0 < 10.0) ? Eigen::Vector2d(pd / radial0) : pd;
      Eigen::Vector2d res = distortNormalized(c, p) - pd;
      double err = res.norm();
      for (int it = 0; it < 100 && err > tol; ++it) {
        const Eigen::Matrix2d J = radtanJacobian(c, p);
        const double det = J(0, 0) * J(1, 1) - J(0, 1) * J(1, 0);
        if (!(std::abs(det) > 1e-300)) break;
        const Eigen::Vector2d step((J(1, 1) * res.x() - J(0, 1) * res.y()) / det,
                                   (J(0, 0) * res.y() - J(1, 0) * res.x()) / det);
        if (!step.allFinite()) break;
        // Damped Newton: halve the step until the residual decreases.
        double scale = 1.0;
        bool improved = false;
        for (int h = 0; h < 30 && !improved; ++h, scale *= 0.5) {
          const Eigen::Vector2d cand = p - scale * step;
          const Eigen::Vector2d cand_res = distortNormalized(c, cand) - pd;
          const double cand_err = cand_res.norm();
          if (cand_err < err) {
            p = cand;
            res = cand_res;
            err = cand_err;
            improved = true;
          }
        }
        if (!improved) break;
      }
      if (!(err <= 1e3 * tol)) return {kNaN, kNaN};
      return p;
    }
    case DistortionModel::kEquidistant: {
      const double k1 = coeff(c.distortion, 0), k2 = coeff(c.distortion, 1), k3 = coeff(c.distortion, 2),
                   k4 = coeff(c.distortion, 3);
      const double th_d = pd.norm();
      if (th_d < 1e-12) return pd;
      double th = std::min(th_d, M_PI / 2);
      double err = 0;
      for (int it = 0; it < 100; ++it) {
        const double t2 = th * th;
        const double f = th * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - th_d;
        const double df = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)));
        err = std::abs(f);
        if (err <= tol || df == 0.0) break;
        th = std::clamp(th - f / df, 0.0, M_PI / 2);
      }
      if (!(err <= 1e3 * tol) || th >= M_PI / 2) return {kNaN, kNaN};
      const double s = std::tan(th) / th_d;
      return pd * s;
    }
  }
  return pd;
}

bool nearlyEqual(double a, double b) { return std::abs(a - b) <= 1e-9 * std::max({1.0, std::abs(a), std::abs(b)}); }

// Remap tables for undistortImage, shared between copies of equal cameras.
struct UndistortMaps {
  Camera camera;
  cv::Mat map1, map2;
};

bool sameCamera(const Camera& a, const Camera& b) {
  return a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy && a.cx == b.cx && a.cy == b.cy &&
         a.distortion_model == b.distortion_model && a.distortion == b.distortion;
}

std::shared_ptr<const UndistortMaps> undistortMaps(const Camera& cam) {
  static std::mutex mutex;
  static std::list<std::shared_ptr<const UndistortMaps>> cache;  // most recently used first
  constexpr size_t kMaxEntries = 8;
  {
    std::lock_guard<std::mutex> lock(mutex);
    for (auto it = cache.begin(); it != cache.end(); ++it) {
      if (sameCamera((*it)->camera, cam)) {
        auto hit = *it;
        cache.erase(it);
        cache.push_front(hit);
        return hit;
      }
    }
  }
  auto maps = std::make_shared<UndistortMaps>();
  maps->camera = cam;
  cv::Mat mapx(cam.height, cam.width, CV_32FC1), mapy(cam.height, cam.width, CV_32FC1);
  cv::parallel_for_(cv::Range(0, cam.height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      float* mx = mapx.ptr<float>(v);
      float* my = mapy.ptr<float>(v);
      for (int u = 0; u < cam.width; ++u) {
        const Eigen::Vector2d src = cam.distortPoint(Eigen::Vector2d(u, v));
        const bool ok = src.allFinite();
        mx[u] = ok ? static_cast<float>(src.x()) : -1e6f;
        my[u] = ok ? static_cast<float>(src.y()) : -1e6f;
      }
    }
  });
  cv::convertMaps(mapx, mapy, maps->map1, maps->map2, CV_16SC2);
  std::lock_guard<std::mutex> lock(mutex);
  cache.push_front(maps);
  if (cache.size() > kMaxEntries) cache.pop_back();
  return maps;
}

}  // namespace

std::optional<CalibrationDifference> calibrationDifference(const Camera& a, const Camera& b) {
  if (a.width != b.width) return CalibrationDifference{"width", std::to_string(a.width), std::to_string(b.width)};
  if (a.height != b.height) return CalibrationDifference{"height", std::to_string(a.height), std::to_string(b.height)};
  const std::pair<const char*, std::pair<double, double>> k[] = {
      {"fx", {a.fx, b.fx}}, {"fy", {a.fy, b.fy}}, {"cx", {a.cx, b.cx}}, {"cy", {a.cy, b.cy}}};
  for (const auto& [name, v] : k)
    if (!nearlyEqual(v.first, v.second))
      return CalibrationDifference{name, formatDouble(v.first), formatDouble(v.second)};
  if (a.distortion_model != b.distortion_model)
    return CalibrationDifference{"distortion_model", toString(a.distortion_model), toString(b.distortion_model)};
  auto list = [](const std::vector<double>& d) {
    std::string s = "[";
    for (size_t i = 0; i < d.size(); ++i) s += (i ? ", " : "") + formatDouble(d[i]);
    return s + "]";
  };
  bool same = a.distortion.size() == b.distortion.size();
  for (size_t i = 0; same && i < a.distortion.size(); ++i) same = nearlyEqual(a.distortion[i], b.distortion[i]);
  if (!same) return CalibrationDifference{"distortion", list(a.distortion), list(b.distortion)};
  return std::nullopt;
}

std::string toString(DistortionModel m) {
  switch (m) {
    case DistortionModel::kNone:
      return "none";
    case DistortionModel::kRadTan:
      return "radtan";
    case DistortionModel::kEquidistant:
      return "equidistant";
  }
  return "unknown";
}

Camera Camera::pinhole(int width, int height, double fx, double fy, double cx, double cy) {
  Camera c;
  c.width = width;
  c.height = height;
  c.fx = fx;
  c.fy = fy;
  c.cx = cx;
  c.cy = cy;
  return c;
}

void Camera::validate(const std::string& source) const {
  if (width <= 0) throw fieldError(source, "width", fmt::format("must be > 0 (got {})", width));
  if (height <= 0) throw fieldError(source, "height", fmt::format("must be > 0 (got {})", height));
  const std::pair<const char*, double> focal[] = {{"fx", fx}, {"fy", fy}};
  for (const auto& [name, v] : focal) {
    if (!std::isfinite(v)) throw fieldError(source, name, fmt::format("must be a finite number (got {})", v));
    if (v <= 0) throw fieldError(source, name, fmt::format("must be > 0 (got {})", v));
  }
  if (!std::isfinite(cx)) throw fieldError(source, "cx", fmt::format("must be a finite number (got {})", cx));
  if (!std::isfinite(cy)) throw fieldError(source, "cy", fmt::format("must be a finite number (got {})", cy));
  if (cx < -0.5 || cx > width - 0.5)
    throw fieldError(source, "cx",
                     fmt::format("principal point {} is outside the image (width {}: must be in [-0.5, {}])", cx, width,
                                 width - 0.5));
  if (cy < -0.5 || cy > height - 0.5)
    throw fieldError(source, "cy",
                     fmt::format("principal point {} is outside the image (height {}: must be in [-0.5, {}])", cy,
                                 height, height - 0.5));
  switch (distortion_model) {
    case DistortionModel::kNone:
      if (!distortion.empty())
        throw fieldError(source, "distortion",
                         fmt::format("distortion_model 'none' takes no coefficients (got {})", distortion.size()));
      break;
    case DistortionModel::kRadTan:
      if (distortion.size() != 4 && distortion.size() != 5)
        throw fieldError(source, "distortion",
                         fmt::format("radtan needs 4 or 5 coefficients k1 k2 p1 p2 [k3] (got {})", distortion.size()));
      break;
    case DistortionModel::kEquidistant:
      if (distortion.size() != 4)
        throw fieldError(source, "distortion",
                         fmt::format("equidistant needs 4 coefficients k1 k2 k3 k4 (got {})", distortion.size()));
      break;
  }
  for (size_t i = 0; i < distortion.size(); ++i)
    if (!std::isfinite(distortion[i]))
      throw fieldError(source, "distortion",
                       fmt::format("coefficient {} must be a finite number (got {})", i, distortion[i]));
}

Eigen::Matrix3d Camera::K() const {
  Eigen::Matrix3d k;
  k << fx, 0, cx, 0, fy, cy, 0, 0, 1;
  return k;
}

cv::Mat Camera::cvK() const { return (cv::Mat_<double>(3, 3) << fx, 0, cx, 0, fy, cy, 0, 0, 1); }

cv::Mat Camera::cvDist() const {
  if (distortion_model == DistortionModel::kNone || distortion.empty()) return cv::Mat();
  cv::Mat d(1, static_cast<int>(distortion.size()), CV_64F);
  for (size_t i = 0; i < distortion.size(); ++i) d.at<double>(0, static_cast<int>(i)) = distortion[i];
  return d;
}

bool Camera::hasDistortion() const {
  if (distortion_model == DistortionModel::kNone) return false;
  return std::any_of(distortion.begin(), distortion.end(), [](double d) { return d != 0.0; });
}

Eigen::Vector2d Camera::project(const Eigen::Vector3d& p_cam) const {
  if (!(p_cam.z() > 0)) return {kNaN, kNaN};
  const Eigen::Vector2d d = distortNormalized(*this, Eigen::Vector2d(p_cam.x() / p_cam.z(), p_cam.y() / p_cam.z()));
  return {fx * d.x() + cx, fy * d.y() + cy};
}

bool Camera::projectInImage(const Eigen::Vector3d& p_cam, Eigen::Vector2d* uv, double border) const {
  const Eigen::Vector2d p = project(p_cam);
  if (uv) *uv = p;
  if (!p.allFinite()) return false;
  // Pixel centres run from 0 to width-1; the image area from -0.5 to width-0.5.
  return p.x() >= -0.5 + border && p.x() <= width - 0.5 - border && p.y() >= -0.5 + border &&
         p.y() <= height - 0.5 - border;
}

Eigen::Vector3d Camera::unproject(const Eigen::Vector2d& uv) const {
  const Eigen::Vector2d pd((uv.x() - cx) / fx, (uv.y() - cy) / fy);
  const Eigen::Vector2d p = undistortNormalized(*this, pd);
  return {p.x(), p.y(), 1.0};
}

Eigen::Vector2d Camera::undistortPoint(const Eigen::Vector2d& uv) const {
  const Eigen::Vector3d r = unproject(uv);
  return {fx * r.x() + cx, fy * r.y() + cy};
}

Eigen::Vector2d Camera::distortPoint(const Eigen::Vector2d& uv_ideal) const {
  return project(Eigen::Vector3d((uv_ideal.x() - cx) / fx, (uv_ideal.y() - cy) / fy, 1.0));
}

cv::Mat Camera::undistortImage(const cv::Mat& image) const {
  if (image.empty()) throw Error("undistortImage: empty image");
  if (image.cols != width || image.rows != height)
    fail("undistortImage: image is {}x{} but the camera is {}x{}", image.cols, image.rows, width, height);
  if (!hasDistortion()) return image.clone();
  const auto maps = undistortMaps(*this);
  cv::Mat out;
  cv::remap(image, out, maps->map1, maps->map2, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return out;
}

Camera Camera::undistorted() const {
  Camera c = *this;
  c.distortion_model = DistortionModel::kNone;
  c.distortion.clear();
  return c;
}

Camera Camera::scaled(double factor) const {
  if (!(factor > 0) || !std::isfinite(factor)) fail("Camera::scaled: factor must be > 0 (got {})", factor);
  Camera c = *this;
  c.width = std::max(1, static_cast<int>(std::lround(width * factor)));
  c.height = std::max(1, static_cast<int>(std::lround(height * factor)));
  // A pixel centre u maps to (u + 0.5) * factor - 0.5 in the resized image.
  c.fx = fx * factor;
  c.fy = fy * factor;
  c.cx = (cx + 0.5) * factor - 0.5;
  c.cy = (cy + 0.5) * factor - 0.5;
  return c;
}

std::string Camera::describe() const {
  std::string s = fmt::format("{}x{} pinhole fx={} fy={} cx={} cy={} distortion={}", width, height, formatDouble(fx),
                              formatDouble(fy), formatDouble(cx), formatDouble(cy), toString(distortion_model));
  if (!distortion.empty()) {
    s += " [";
    for (size_t i = 0; i < distortion.size(); ++i) s += (i ? ", " : "") + formatDouble(distortion[i]);
    s += "]";
  }
  return s;
}

}  // namespace nerfslam
