#include "nerfslam/render/preview.h"
#include "nerfslam/io/ply_header.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>

#include <pcl/PCLPointCloud2.h>
#include <pcl/conversions.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>
#include <Eigen/Eigenvalues>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/parse.h"
#include "nerfslam/render/renderer.h"
#include "nerfslam/render/trajectory.h"

namespace nerfslam {
namespace fs = std::filesystem;
using Eigen::Vector3d;

namespace {

// One numeric PLY property of point `i`, whatever its stored type (PCL keeps PLY's types).
double fieldValue(const pcl::PCLPointCloud2& blob, const pcl::PCLPointField& f, size_t i) {
  const uint8_t* p = blob.data.data() + i * blob.point_step + f.offset;
  switch (f.datatype) {
    case pcl::PCLPointField::INT8:
      return *reinterpret_cast<const int8_t*>(p);
    case pcl::PCLPointField::UINT8:
      return *p;
    case pcl::PCLPointField::INT16: {
      int16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case pcl::PCLPointField::UINT16: {
      uint16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case pcl::PCLPointField::INT32: {
      int32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case pcl::PCLPointField::UINT32: {
      uint32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case pcl::PCLPointField::FLOAT32: {
      float v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case pcl::PCLPointField::FLOAT64: {
      double v;
      std::memcpy(&v, p, 8);
      return v;
    }
    default:
      return std::numeric_limits<double>::quiet_NaN();
  }
}

const pcl::PCLPointField* findField(const pcl::PCLPointCloud2& blob, std::initializer_list<const char*> names) {
  for (const char* n : names)
    for (const auto& f : blob.fields)
      if (f.name == n) return &f;
  return nullptr;
}

}  // namespace

PreviewCloud loadPointCloudPly(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) fail("{}: point cloud file not found", path.string());
  checkPlyFile(path);  // declared sizes against the file's before PCL allocates them
  pcl::PCLPointCloud2 blob;
  pcl::PLYReader reader;
  if (reader.read(path.string(), blob) < 0) fail("{}: not a readable PLY point cloud", path.string());
  const pcl::PCLPointField* fx = findField(blob, {"x"});
  const pcl::PCLPointField* fy = findField(blob, {"y"});
  const pcl::PCLPointField* fz = findField(blob, {"z"});
  if (!fx || !fy || !fz) fail("{}: field 'x', 'y' or 'z': the PLY vertices have no position", path.string());
  // Colours: packed rgb/rgba (PCL merges PLY red/green/blue into it), else the number of
  // observations of a sparse map point (more observations: warmer), else none (coloured by height).
  const pcl::PCLPointField* frgb = findField(blob, {"rgb", "rgba"});
  const pcl::PCLPointField* fobs = frgb ? nullptr : findField(blob, {"observations"});
  const size_t n = blob.width * blob.height;
  PreviewCloud c;
  c.label = path.filename().string();
  double max_obs = 1;
  if (fobs)
    for (size_t i = 0; i < n; ++i) max_obs = std::max(max_obs, fieldValue(blob, *fobs, i));
  for (size_t i = 0; i < n; ++i) {
    const Vector3d p(fieldValue(blob, *fx, i), fieldValue(blob, *fy, i), fieldValue(blob, *fz, i));
    if (!p.allFinite()) continue;
    c.points.push_back(p.cast<float>());
    if (frgb) {
      uint32_t packed;
      std::memcpy(&packed, blob.data.data() + i * blob.point_step + frgb->offset, 4);
      c.colors.emplace_back(packed & 0xff, (packed >> 8) & 0xff, (packed >> 16) & 0xff);
    } else if (fobs) {
      const double t = std::log(std::max(1.0, fieldValue(blob, *fobs, i))) / std::log(std::max(2.0, max_obs));
      cv::Mat1b level(1, 1, static_cast<uchar>(std::clamp(t, 0.0, 1.0) * 255));
      cv::Mat3b bgr;
      cv::applyColorMap(level, bgr, cv::COLORMAP_TURBO);
      c.colors.push_back(bgr(0, 0));
    }
  }
  if (fobs) c.label += " (colour: observations)";
  return c;
}

namespace {

Vertex vtx(const Vector3d& p, const cv::Vec3b& bgr) {
  Vertex v;
  v.x = static_cast<float>(p.x());
  v.y = static_cast<float>(p.y());
  v.z = static_cast<float>(p.z());
  v.r = bgr[2] / 255.f;
  v.g = bgr[1] / 255.f;
  v.b = bgr[0] / 255.f;
  return v;
}

}  // namespace

void parseView(const std::string& spec, Eigen::Vector3d* eye, Eigen::Vector3d* target) {
  // Split at "eye=" and "target=".
  const auto pe = spec.find("eye="), pt = spec.find("target=");
  if (pe == std::string::npos || pt == std::string::npos)
    fail("--view '{}': expected \"eye=x,y,z,target=x,y,z\"", spec);
  auto part = [&](size_t start, size_t other) {
    const size_t end = other > start ? other : spec.size();
    std::string s = spec.substr(start, end - start);
    while (!s.empty() && (s.back() == ',' || s.back() == ' ' || s.back() == ';')) s.pop_back();
    return s;
  };
  const auto e = parseNumberList(part(pe + 4, pt), "--view eye"),
             t = parseNumberList(part(pt + 7, pe), "--view target");
  if (e.size() != 3 || t.size() != 3) fail("--view '{}': eye and target need 3 numbers each", spec);
  *eye = Vector3d(e[0], e[1], e[2]);
  *target = Vector3d(t[0], t[1], t[2]);
  if ((*eye - *target).norm() < 1e-9) fail("--view '{}': eye and target coincide", spec);
}

cv::Vec3b parseColor(const std::string& name) {
  static const std::vector<std::pair<std::string, cv::Vec3b>> named = {
      {"red", {40, 40, 230}},  {"green", {60, 200, 60}},   {"blue", {230, 120, 30}},  {"yellow", {0, 220, 240}},
      {"cyan", {230, 220, 0}}, {"magenta", {220, 0, 220}}, {"orange", {0, 140, 255}}, {"white", {255, 255, 255}},
      {"black", {0, 0, 0}},    {"gray", {150, 150, 150}}};
  for (const auto& [n, c] : named)
    if (n == name) return c;
  if (name.size() == 7 && name[0] == '#' && std::all_of(name.begin() + 1, name.end(), [](char ch) {
        return std::isxdigit(static_cast<unsigned char>(ch));
      })) {
    const unsigned long v = std::stoul(name.substr(1), nullptr, 16);
    return cv::Vec3b(v & 0xff, (v >> 8) & 0xff, (v >> 16) & 0xff);
  }
  std::string list;
  for (const auto& [n, c] : named) list += n + ", ";
  fail("unknown colour '{}' (valid: {}or #rrggbb)", name, list);
}

void autoView(const PreviewScene& scene, const PreviewOptions& opts, Vector3d* eye, Vector3d* target) {
  std::vector<double> xs[3];
  for (const auto& c : scene.clouds)
    for (const auto& p : c.points)
      for (int k = 0; k < 3; ++k) xs[k].push_back(p[k]);
  Vector3d lo = Vector3d::Constant(1e300), hi = Vector3d::Constant(-1e300);
  for (int k = 0; k < 3; ++k) {
    if (xs[k].empty()) continue;
    auto& v = xs[k];
    const size_t a = v.size() / 100, b = v.size() - 1 - v.size() / 100;
    std::nth_element(v.begin(), v.begin() + a, v.end());
    lo[k] = v[a];
    std::nth_element(v.begin(), v.begin() + b, v.end());
    hi[k] = v[b];
  }
  auto grow = [&](const Vector3d& p) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  };
  for (const auto& t : scene.trajectories)
    for (const auto& p : t.poses) grow(p.translation());
  for (const auto& p : scene.keyframes) grow(p.translation());
  if (lo.x() > hi.x()) fail("preview: nothing to draw (no points, trajectories or keyframes)");
  const Vector3d centre = 0.5 * (lo + hi);
  const double radius = std::max(0.05, 0.5 * (hi - lo).norm());
  const Vector3d up = opts.up.normalized();
  Vector3d side = up.cross(Vector3d::UnitX());
  if (side.norm() < 0.3) side = up.cross(Vector3d::UnitY());
  side.normalize();
  const Vector3d fwd = up.cross(side).normalized();
  // From the front-left, 35 degrees above the horizon.
  const Vector3d dir = (std::cos(0.61) * (0.6 * side - 0.8 * fwd).normalized() + std::sin(0.61) * up).normalized();
  const double half_fov = 0.5 * opts.fov_deg * M_PI / 180.0;
  *target = centre;
  *eye = centre + dir * (radius / std::sin(half_fov) * 1.05);
}

namespace {

// The q-th and (1-q)-th quantiles of v (q in [0, 0.5)).
std::pair<double, double> quantileRange(std::vector<double> v, double q) {
  const size_t a = size_t(q * double(v.size() - 1)), b = v.size() - 1 - a;
  std::nth_element(v.begin(), v.begin() + long(a), v.end());
  const double lo = v[a];
  std::nth_element(v.begin(), v.begin() + long(b), v.end());
  return {lo, v[b]};
}

// Photos around an object: every camera looks at the points' centre (within 20 degrees), from
// directions that differ by more than 60 degrees (an arc of a ring can be as open as a drive). Then
// *up is the normal of the cameras' plane, on the side the cameras are (photographers look down onto
// an object; in the plane of its centre, the side of `up`): the cameras' own up axes say nothing when
// the photos were taken rotated, as the Middlebury ring's are.
bool photosAround(const std::vector<Eigen::Vector3f>& points, const std::vector<SE3>& cameras, const Vector3d& up,
                  Vector3d* around_up) {
  if (cameras.size() < 3) return false;
  Vector3d centre;
  for (int k = 0; k < 3; ++k) {
    std::vector<double> v;
    for (const auto& p : points) v.push_back(double(p[k]));
    const auto [lo, hi] = quantileRange(v, 0.02);
    centre[k] = 0.5 * (lo + hi);
  }
  Vector3d mean_to = Vector3d::Zero(), mean_c = Vector3d::Zero();
  for (const auto& T : cameras) {
    const Vector3d to = centre - T.translation();
    if (to.norm() < 1e-12 || T.rotationMatrix().col(2).dot(to.normalized()) < std::cos(20.0 * M_PI / 180.0))
      return false;
    mean_to += to.normalized() / double(cameras.size());
    mean_c += T.translation() / double(cameras.size());
  }
  if (mean_to.norm() >= 0.87) return false;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& T : cameras) cov += (T.translation() - mean_c) * (T.translation() - mean_c).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
  Vector3d n = es.eigenvectors().col(0);  // smallest eigenvalue: the normal of the cameras' plane
  const double above = (mean_c - centre).dot(n);
  if (std::abs(above) > 1e-3 * (mean_c - centre).norm() ? above < 0 : n.dot(up) < 0) n = -n;
  *around_up = n.normalized();
  return true;
}

}  // namespace

Overview overviewViewpoint(const std::vector<Eigen::Vector3f>& points, const std::vector<SE3>& cameras,
                           const PreviewOptions& opts) {
  if (points.empty() || cameras.empty()) fail("overview viewpoint: needs points and cameras");
  if (!opts.up.allFinite() || opts.up.norm() < 1e-9) fail("preview up direction must be finite and non-zero");
  Overview ov;
  Vector3d up = opts.up.normalized();
  const bool around = photosAround(points, cameras, up, &up);
  ov.up = up;
  // A horizontal basis (a, b) perpendicular to up; the main horizontal direction of the camera path.
  Vector3d a = up.cross(std::abs(up.x()) < 0.9 ? Vector3d::UnitX() : Vector3d::UnitY()).normalized();
  Vector3d b = up.cross(a);
  Vector3d mean_c = Vector3d::Zero(), mean_fwd = Vector3d::Zero();
  for (const auto& T : cameras) {
    mean_c += T.translation() / double(cameras.size());
    mean_fwd += T.rotationMatrix().col(2) / double(cameras.size());
  }
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const auto& T : cameras) {
    const Vector3d d = T.translation() - mean_c;
    const Eigen::Vector2d h(d.dot(a), d.dot(b));
    cov += h * h.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
  Vector3d dir = es.eigenvectors()(0, 1) * a + es.eigenvectors()(1, 1) * b;  // largest eigenvalue
  const Vector3d start = cameras.front().translation(), end = cameras.back().translation();
  if ((end - start).dot(dir) < 0) dir = -dir;
  double plo = 1e300, phi = -1e300;
  for (const auto& T : cameras) {
    plo = std::min(plo, T.translation().dot(dir));
    phi = std::max(phi, T.translation().dot(dir));
  }
  const double path = phi - plo;
  // Robust bounds of the points in the (a, b, up) frame.
  std::vector<double> pa, pb, pu;
  for (const auto& p : points) {
    const Vector3d q = p.cast<double>();
    pa.push_back(q.dot(a)), pb.push_back(q.dot(b)), pu.push_back(q.dot(up));
  }
  const auto [alo, ahi] = quantileRange(pa, 0.02);
  const auto [blo, bhi] = quantileRange(pb, 0.02);
  const auto [ulo, uhi] = quantileRange(pu, 0.02);
  const double scene = std::max(ahi - alo, bhi - blo);
  const double half_fov = 0.5 * opts.fov_deg * M_PI / 180.0;
  // An open path, long against the scene, or shorter but with the cameras looking where they go.
  const bool open = (end - start).dot(dir) > 0.5 * path;
  const bool looking_ahead = mean_fwd.dot(dir) > 0.7;
  ov.traversal = !around && open && (path > 0.4 * scene || (looking_ahead && path > 0.2 * scene));
  if (ov.traversal) {
    // Looking 30 degrees down at a point ahead of the start, from behind and above it.
    ov.target = start + 0.45 * path * dir;
    ov.eye = ov.target - 0.8 * path * (std::cos(0.52) * dir - std::sin(0.52) * up);
    return ov;
  }
  const double ca = mean_c.dot(a), cb = mean_c.dot(b), cu = mean_c.dot(up);
  const bool inside = ca > alo && ca < ahi && cb > blo && cb < bhi && cu > ulo && cu < uhi;
  double top = uhi;
  if (inside) {
    double highest = -1e300;
    for (const auto& T : cameras) highest = std::max(highest, T.translation().dot(up));
    ov.max_height = std::min(uhi, highest + 0.25 * (uhi - ulo));
    top = *ov.max_height;
  }
  const Vector3d centre = 0.5 * (alo + ahi) * a + 0.5 * (blo + bhi) * b + 0.5 * (ulo + top) * up;
  double radius = std::max(0.05, 0.5 * Vector3d(ahi - alo, bhi - blo, top - ulo).norm());
  // An object seen from around it: the cameras are in the picture too (the trajectory would otherwise
  // be cut away, the legend naming a line nobody can see).
  if (!inside)
    for (const auto& T : cameras) radius = std::max(radius, (T.translation() - centre).norm());
  // From behind the cameras' mean viewing direction, else from the side the cameras are on.
  Vector3d side = -(mean_fwd - mean_fwd.dot(up) * up);
  if (side.norm() < 0.3) side = mean_c - centre - (mean_c - centre).dot(up) * up;
  if (side.norm() < 0.2 * radius) side = -0.8 * b + 0.6 * a;
  side.normalize();
  const double elevation = inside ? 0.52 : 0.61;  // 30 degrees into a room, 35 onto an object
  ov.target = centre;
  // The bounding sphere fits the view with room to spare: a little closer; with the cameras, a little
  // farther, so that none of them is at the edge.
  const double fit = inside ? 0.85 : 1.05;
  ov.eye = centre + (std::cos(elevation) * side + std::sin(elevation) * up) * (radius / std::sin(half_fov) * fit);
  return ov;
}

cv::Mat renderPreview(const PreviewScene& scene, const PreviewOptions& opts) {
  if (opts.width < 16 || opts.height < 16 || opts.width > 8192 || opts.height > 8192)
    fail("preview size {}x{} invalid: width and height must be in 16..8192", opts.width, opts.height);
  if (!(opts.fov_deg > 1 && opts.fov_deg < 170)) fail("preview fov {} must be in (1, 170) degrees", opts.fov_deg);
  if (!opts.up.allFinite() || opts.up.norm() < 1e-9) fail("preview up direction must be finite and non-zero");
  if (!(opts.point_size > 0 && opts.point_size <= 64))
    fail("preview point size {} must be in (0, 64]", opts.point_size);
  if (!(opts.line_width > 0 && opts.line_width <= 64))
    fail("preview line width {} must be in (0, 64]", opts.line_width);
  if (!(opts.frustum_size >= 0 && std::isfinite(opts.frustum_size)))
    fail("preview frustum size {} must be finite and >= 0 (0: automatic)", opts.frustum_size);
  if ((opts.eye && !opts.eye->allFinite()) || (opts.target && !opts.target->allFinite()))
    fail("preview eye and target must be finite");
  if (opts.max_height && !std::isfinite(*opts.max_height)) fail("preview max height must be finite");
  Vector3d eye, target;
  autoView(scene, opts, &eye, &target);  // also checks there is something to draw
  if (opts.eye && opts.target) {
    eye = *opts.eye;
    target = *opts.target;
  }
  const Vector3d up = opts.up.normalized();
  double frustum = opts.frustum_size;
  if (frustum <= 0) {
    Vector3d e2, t2;
    autoView(scene, opts, &e2, &t2);
    frustum = 0.03 * 2.0 * (e2 - t2).norm() * std::sin(0.5 * opts.fov_deg * M_PI / 180.0);
  }

  Renderer r;
  for (const auto& c : scene.clouds) {
    if (c.points.empty()) continue;
    Mesh m;
    m.primitive = Primitive::kPoints;
    double zlo = 1e300, zhi = -1e300;
    if (c.colors.empty())
      for (const auto& p : c.points) {
        const double h = p.cast<double>().dot(up);
        zlo = std::min(zlo, h), zhi = std::max(zhi, h);
      }
    m.vertices.reserve(c.points.size());
    for (size_t i = 0; i < c.points.size(); ++i) {
      if (opts.max_height && c.points[i].cast<double>().dot(up) > *opts.max_height) continue;
      cv::Vec3b col;
      if (!c.colors.empty()) {
        col = c.colors[i];
      } else {  // height colour map
        const double s = (c.points[i].cast<double>().dot(up) - zlo) / std::max(1e-9, zhi - zlo);
        cv::Mat1b in(1, 1, static_cast<uchar>(std::clamp(s, 0.0, 1.0) * 255));
        cv::Mat out;
        cv::applyColorMap(in, out, cv::COLORMAP_TURBO);
        col = out.at<cv::Vec3b>(0, 0);
      }
      m.vertices.push_back(vtx(c.points[i].cast<double>(), col));
    }
    if (!m.vertices.empty()) r.addMesh(m);
  }
  Mesh lines;
  lines.primitive = Primitive::kLines;
  auto seg = [&](const Vector3d& a, const Vector3d& b, const cv::Vec3b& c) {
    lines.vertices.push_back(vtx(a, c));
    lines.vertices.push_back(vtx(b, c));
  };
  for (const auto& t : scene.trajectories)
    for (size_t i = 1; i < t.poses.size(); ++i) seg(t.poses[i - 1].translation(), t.poses[i].translation(), t.color);
  for (const auto& T : scene.keyframes) {
    const Vector3d c = T.translation();
    const double s = frustum, w = 0.5 * s * 4.0 / 3.0 * 0.9, h = 0.5 * s * 0.9;
    const Vector3d corners[4] = {T * Vector3d(-w, -h, s), T * Vector3d(w, -h, s), T * Vector3d(w, h, s),
                                 T * Vector3d(-w, h, s)};
    for (int k = 0; k < 4; ++k) {
      seg(c, corners[k], scene.keyframe_color);
      seg(corners[k], corners[(k + 1) % 4], scene.keyframe_color);
    }
    seg(corners[0] + (corners[1] - corners[0]) * 0.3, T * Vector3d(0, -h * 1.6, s), scene.keyframe_color);  // "up" tick
    seg(corners[1] + (corners[0] - corners[1]) * 0.3, T * Vector3d(0, -h * 1.6, s), scene.keyframe_color);
  }
  if (!lines.vertices.empty()) r.addMesh(lines);

  const double f = 0.5 * std::min(opts.width, opts.height) / std::tan(0.5 * opts.fov_deg * M_PI / 180.0);
  const Camera cam = Camera::pinhole(opts.width, opts.height, f, f, 0.5 * (opts.width - 1), 0.5 * (opts.height - 1));
  RasterOptions ro;
  const double dist = (eye - target).norm();
  ro.near = std::max(1e-4, dist * 1e-3);
  ro.far = std::max(ro.near * 10, dist * 100);
  ro.background = cv::Vec3f(opts.background[0] / 255.f, opts.background[1] / 255.f, opts.background[2] / 255.f);
  ro.point_size = opts.point_size;
  ro.line_width = opts.line_width;
  cv::Mat img;
  r.render(cam, lookAt(eye, target, up), &img, nullptr, ro);
  if (opts.legend) {
    int y = 24;
    for (const auto& t : scene.trajectories) {
      if (t.label.empty()) continue;
      cv::rectangle(img, {12, y - 12}, {30, y + 2}, cv::Scalar(t.color[0], t.color[1], t.color[2]), cv::FILLED);
      cv::putText(img, t.label, {38, y}, cv::FONT_HERSHEY_SIMPLEX, 0.55, cv::Scalar(235, 235, 235), 1, cv::LINE_AA);
      y += 22;
    }
    if (!scene.keyframes.empty()) {
      cv::rectangle(img, {12, y - 12}, {30, y + 2},
                    cv::Scalar(scene.keyframe_color[0], scene.keyframe_color[1], scene.keyframe_color[2]), 1);
      cv::putText(img, fmt::format("keyframes ({})", scene.keyframes.size()), {38, y}, cv::FONT_HERSHEY_SIMPLEX, 0.55,
                  cv::Scalar(235, 235, 235), 1, cv::LINE_AA);
    }
  }
  return img;
}

}  // namespace nerfslam
