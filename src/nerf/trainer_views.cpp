// The trainer's views: validation, the compact images it keeps, poses, sampling weights, surface
// points and per-view appearance (the training step itself is in trainer.cpp).
#include <algorithm>
#include <cmath>
#include <cstring>

#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/trainer.h"

namespace nerfslam::nerf {

namespace {

// The same points, each moved by less than a tenth of its distance from `centre` (bundle
// adjustment's corrections), in the same order.
bool samePointsMoved(const std::vector<SurfacePoint>& a, const std::vector<SurfacePoint>& b,
                     const Eigen::Vector3f& centre) {
  if (a.size() != b.size()) return false;
  for (size_t k = 0; k < a.size(); ++k)
    if (!((a[k].position - b[k].position).norm() <= 0.1f * (a[k].position - centre).norm())) return false;
  return true;
}

}  // namespace

void validateView(const TrainingView& view, const std::string& source) {
  view.camera.validate(source);
  const cv::Mat& im = view.image;
  if (im.empty()) throw fieldError(source, "image", "is empty");
  const int depth = im.depth(), ch = im.channels();
  if (!((depth == CV_8U || depth == CV_32F) && (ch == 3 || ch == 4)))
    throw fieldError(source, "image", "must be 8-bit or float RGB/RGBA");
  if (im.cols != view.camera.width || im.rows != view.camera.height)
    throw fieldError(
        source, "image",
        fmt::format("is {}x{} but the camera is {}x{}", im.cols, im.rows, view.camera.width, view.camera.height));
  if (!view.T_world_cam.matrix().allFinite()) throw fieldError(source, "T_world_cam", "is not finite");
}

std::vector<SurfacePoint> surfacePointsFromDepth(const cv::Mat& depth, const Camera& camera, const SE3& T_world_cam,
                                                 size_t max_points, const std::string& source) {
  if (depth.type() != CV_32FC1) throw fieldError(source, "depth", "must be a single-channel float image");
  if (depth.cols != camera.width || depth.rows != camera.height)
    throw fieldError(
        source, "depth",
        fmt::format("is {}x{} but the camera is {}x{}", depth.cols, depth.rows, camera.width, camera.height));
  std::vector<SurfacePoint> out;
  if (max_points == 0) return out;
  // The smallest grid stride that keeps at most max_points of the image's pixels.
  const double pixels = double(depth.cols) * depth.rows;
  const int stride = std::max(1, int(std::ceil(std::sqrt(pixels / double(max_points)))));
  for (int y = stride / 2; y < depth.rows; y += stride) {
    const float* row = depth.ptr<float>(y);
    for (int x = stride / 2; x < depth.cols; x += stride) {
      const float z = row[x];
      if (!(z > 0.f) || !std::isfinite(z)) continue;
      const Eigen::Vector3d ray = camera.unproject(Eigen::Vector2d(x, y));  // (x, y, 1)
      if (!ray.allFinite()) continue;
      SurfacePoint p;
      p.position = (T_world_cam * (ray * double(z))).cast<float>();
      out.push_back(p);
      if (out.size() >= max_points) return out;
    }
  }
  return out;
}

TrainingView makeTrainingView(const cv::Mat& image, const Camera& camera, const SE3& T_world_cam, double downscale,
                              const std::string& source) {
  if (image.empty()) throw fieldError(source, "image", "is empty");
  if (image.depth() != CV_8U || (image.channels() != 3 && image.channels() != 4))
    throw fieldError(source, "image", "must be 8-bit BGR or BGRA");
  if (!(downscale >= 1.0) || !std::isfinite(downscale)) throw fieldError(source, "downscale", "must be >= 1");
  if (image.cols != camera.width || image.rows != camera.height)
    throw fieldError(
        source, "image",
        fmt::format("is {}x{} but the camera is {}x{}", image.cols, image.rows, camera.width, camera.height));
  TrainingView v;
  v.T_world_cam = T_world_cam;
  cv::Mat rgb;
  cv::cvtColor(image, rgb, image.channels() == 4 ? cv::COLOR_BGRA2RGBA : cv::COLOR_BGR2RGB);
  if (downscale == 1.0) {
    v.image = rgb;
    v.camera = camera;
  } else {
    const int w = std::max(1, int(std::lround(camera.width / downscale)));
    const int h = std::max(1, int(std::lround(camera.height / downscale)));
    v.camera = camera.scaled(double(w) / camera.width);
    v.camera.width = w;
    v.camera.height = h;
    cv::Mat f;
    rgb.convertTo(f, CV_32F, 1.0 / 255.0);
    if (f.channels() == 4) {
      std::vector<cv::Mat> ch;
      cv::split(f, ch);
      for (int c = 0; c < 3; ++c) ch[size_t(c)] = ch[size_t(c)].mul(ch[3]);
      cv::merge(ch, f);
    }
    cv::Mat small;
    cv::resize(f, small, cv::Size(w, h), 0, 0, cv::INTER_AREA);
    if (small.channels() == 4) {
      std::vector<cv::Mat> ch;
      cv::split(small, ch);
      cv::Mat inv;
      cv::divide(1.0, cv::max(ch[3], 1e-6), inv);
      for (int c = 0; c < 3; ++c) ch[size_t(c)] = cv::min(ch[size_t(c)].mul(inv), 1.0);
      cv::merge(ch, small);
    }
    // Back to 8 bits (rounded): the trainer keeps 8-bit pixels anyway, and a float copy per view
    // would be 4x the memory (lego at 400x400: 2.6 MB instead of 0.64 MB per view).
    small.convertTo(v.image, CV_8U, 255.0);
  }
  validateView(v, source);
  return v;
}

cv::Mat compositeOver(const TrainingView& view, const float bg[3]) {
  cv::Mat f;
  view.image.convertTo(f, CV_32F, view.image.depth() == CV_8U ? 1.0 / 255.0 : 1.0);
  cv::Mat out(f.size(), CV_32FC3);
  const int ch = f.channels();
  for (int y = 0; y < f.rows; ++y) {
    const float* s = f.ptr<float>(y);
    auto* d = out.ptr<cv::Vec3f>(y);
    for (int x = 0; x < f.cols; ++x) {
      const float a = ch == 4 ? s[4 * x + 3] : 1.f;
      for (int c = 0; c < 3; ++c) d[x][c] = s[ch * x + c] * a + bg[c] * (1.f - a);
    }
  }
  return out;
}

Trainer::ImageData Trainer::toImageData(const cv::Mat& im) {
  ImageData d;
  d.width = im.cols;
  d.height = im.rows;
  cv::Mat u8;
  if (im.depth() == CV_32F)
    im.convertTo(u8, CV_8U, 255.0);
  else
    u8 = im;
  if (u8.channels() == 3) {
    cv::Mat a(u8.size(), CV_8UC1, cv::Scalar(255));
    cv::Mat out;
    cv::merge(std::vector<cv::Mat>{u8, a}, out);
    u8 = out;
  }
  d.rgba.resize(size_t(d.width) * d.height * 4);
  for (int y = 0; y < d.height; ++y)
    std::memcpy(d.rgba.data() + size_t(y) * d.width * 4, u8.ptr(y), size_t(d.width) * 4);
  // Alpha that is 255 everywhere (e.g. a view rebuilt by view()) is no alpha: an opaque image.
  d.has_alpha = false;
  for (size_t i = 3; i < d.rgba.size() && !d.has_alpha; i += 4) d.has_alpha = d.rgba[i] != 255;
  return d;
}

size_t Trainer::addView(TrainingView view) {
  validateView(view, fmt::format("training view {}", views_.size()));
  images_.push_back(toImageData(view.image));
  view.image.release();  // keep only the compact copy
  appearance_.emplace_back();
  pose_corr_.emplace_back();
  std::vector<SurfacePoint> points = std::move(view.points);
  if (opt_.learned_background && !images_.back().has_alpha && !model_.background) {
    model_.background =
        std::make_unique<Background>(opt_.background_rows, view.T_world_cam.rotationMatrix().cast<float>());
    snap_background_.clear();  // the next snapshot takes it
  }
  views_.push_back(std::move(view));
  triangles_.emplace_back();
  view_loss_.push_back(-1.0);
  if (!view_weights_.empty()) view_weights_.push_back(1.0);
  setViewPoints(views_.size() - 1, std::move(points));
  return views_.size() - 1;
}

void Trainer::setViewPoints(size_t i, std::vector<SurfacePoint> points) {
  if (i >= views_.size()) fail("NeRF training: no view {} (have {})", i, views_.size());
  points.erase(std::remove_if(points.begin(), points.end(),
                              [](const SurfacePoint& p) {
                                return !p.position.allFinite() || !(p.weight > 0.f && p.weight <= 1.f);
                              }),
               points.end());
  // The triangles' corners are indices into the points. The same points moved a little by bundle
  // adjustment keep them (they are drawn where the corners project at each step, on the plane
  // through where they are now); any other change of the points makes them anew.
  const bool same = samePointsMoved(views_[i].points, points, views_[i].T_world_cam.translation().cast<float>());
  views_[i].points = std::move(points);
  if (opt_.depth_triangle_share <= 0)
    triangles_[i] = {};
  else if (!same || triangles_[i].empty())
    triangles_[i] = triangulateSurfacePoints(views_[i].points, views_[i].camera, views_[i].T_world_cam);
  else
    for (DepthTriangle& t : triangles_[i].triangles) {  // the corners' weights may have changed
      float w = 1.f;
      for (const uint32_t c : t.corner) w = std::min(w, views_[i].points[c].weight);
      t.weight = kTriangleWeight * w;
    }
}

void Trainer::setViewAppearance(size_t i, const Appearance& a) {
  if (i >= views_.size()) fail("NeRF training: no view {} (have {})", i, views_.size());
  if (!a.finite()) throw fieldError(fmt::format("training view {}", i), "appearance", "is not finite");
  if (learnsAppearance(i)) appearance_[i] = a;
}

Appearance Trainer::appearanceNear(const SE3& pose) const {
  std::vector<SE3> poses;
  for (const auto& v : views_) poses.push_back(v.T_world_cam);
  return nerf::appearanceNear(poses, appearance_, pose);
}

bool Trainer::learnsAppearance(size_t view) const { return opt_.appearance && !images_[view].has_alpha; }

TrainingView Trainer::view(size_t i) const {
  if (i >= views_.size()) fail("NeRF training: no view {} (have {})", i, views_.size());
  TrainingView v = views_[i];
  const ImageData& d = images_[i];
  v.image = cv::Mat(d.height, d.width, CV_8UC4, const_cast<uint8_t*>(d.rgba.data())).clone();
  return v;
}

void Trainer::setViewPose(size_t i, const SE3& T_world_cam) {
  if (i >= views_.size()) fail("NeRF training: no view {} (have {})", i, views_.size());
  if (!T_world_cam.matrix().allFinite())
    throw fieldError(fmt::format("training view {}", i), "T_world_cam", "is not finite");
  views_[i].T_world_cam = T_world_cam;
}

void Trainer::setViewWeights(std::vector<double> w) {
  if (!w.empty()) {
    if (w.size() != views_.size()) fail("NeRF training: {} view weights for {} views", w.size(), views_.size());
    double sum = 0;
    for (double x : w) {
      if (!(x >= 0) || !std::isfinite(x)) fail("NeRF training: view weights must be finite and >= 0");
      sum += x;
    }
    if (!(sum > 0)) fail("NeRF training: view weights are all zero");
  }
  view_weights_ = std::move(w);
}

}  // namespace nerfslam::nerf
