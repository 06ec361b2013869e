#include "nerfslam/tracking/initializer.h"

#include <algorithm>
#include <cmath>
#include <optional>

#include <spdlog/spdlog.h>
#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <opencv2/video/tracking.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/core/statistics.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/tracking/two_view_geometry.h"

namespace nerfslam {
namespace {

InitializationResult refuse(InitializationResult r, const std::string& why) {
  r.success = false;
  r.reason = why;
  spdlog::info("initialisation refused (frames {} -> {}): {}", r.ref_frame_id, r.cur_frame_id, why);
  return r;
}

// Pure rotation: the calibrated homography K^-1 H K is (a multiple of) a rotation, and the parallax
// of H's inliers once that rotation is undone is below `min_parallax_deg`. Returns why (and that
// parallax in `parallax_deg`) when it is one.
std::optional<std::string> pureRotation(const ModelEstimate& H, const Eigen::Matrix3d& K, const Points2d& x1,
                                        const Points2d& x2, double min_parallax_deg, double* parallax_deg) {
  const Eigen::Matrix3d Hn = K.inverse() * H.M * K;
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(Hn, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Vector3d singular = svd.singularValues();
  const Eigen::Vector3d sv = singular / singular(1);
  Eigen::Matrix3d R = svd.matrixU() * svd.matrixV().transpose();
  if (R.determinant() < 0) R = -R;
  const Eigen::Matrix3d Ki = K.inverse();
  std::vector<double> ang;
  for (size_t i = 0; i < x1.size(); ++i) {
    if (!H.inliers[i]) continue;
    const Eigen::Vector3d a = (R * (Ki * x1[i].homogeneous())).normalized();
    const Eigen::Vector3d b = (Ki * x2[i].homogeneous()).normalized();
    ang.push_back(std::acos(std::clamp(a.dot(b), -1.0, 1.0)) * 180.0 / M_PI);
  }
  const double rot_parallax = median(ang);
  if (!(sv(0) - 1.0 < 0.01 && 1.0 - sv(2) < 0.01 && rot_parallax < min_parallax_deg)) return std::nullopt;
  *parallax_deg = rot_parallax;
  return fmt::format(
      "pure rotation: homography is a rotation (singular values {:.3f} {:.3f} "
      "{:.3f}), parallax {:.2f}° < {:.1f}°",
      sv(0), sv(1), sv(2), rot_parallax, min_parallax_deg);
}

// Why the reconstruction from model `M` (named `model`, fitted to `num_tracks` tracks) is not good
// enough to start a map from, or nothing.
std::optional<std::string> weakReconstruction(const Reconstruction& rec, const ModelEstimate& M,
                                              const std::string& model, size_t num_tracks,
                                              const InitializerOptions& opt) {
  if (rec.num_good < opt.min_inliers)
    return fmt::format("inliers {} < {} ({} model, {} RANSAC inliers of {} tracks)", rec.num_good, opt.min_inliers,
                       model, M.num_inliers, num_tracks);
  if (rec.parallax_deg < opt.min_parallax_deg)
    return fmt::format("parallax {:.2f}° < {:.1f}° ({} model)", rec.parallax_deg, opt.min_parallax_deg, model);
  if (rec.num_good < opt.min_good_fraction * M.num_inliers)
    return fmt::format("only {} of {} {} inliers triangulate in front of both cameras", rec.num_good, M.num_inliers,
                       model);
  if (rec.second_best_good > 0.7 * rec.num_good)
    return fmt::format("ambiguous pose: runner-up candidate explains {} of {} points", rec.second_best_good,
                       rec.num_good);
  return std::nullopt;
}

}  // namespace

Initializer::Initializer(InitializerOptions options) : opt_(options) {}

void Initializer::reset() {
  has_ref_ = false;
  ref_ = Frame();
  prev_pyr_.clear();
  prev_pts_.clear();
  track_ref_index_.clear();
}

InitializationResult Initializer::addFrame(const Frame& frame) {
  InitializationResult r;
  r.cur_frame_id = frame.id;
  if (frame.pyramid.empty()) fail("Initializer: frame {} has no image", frame.id);
  if (!has_ref_ || frame.camera.width != ref_.camera.width || frame.camera.height != ref_.camera.height)
    return setReference(frame, r);
  r.ref_frame_id = ref_.id;

  const double t_klt = threadCpuMs();
  trackCorners(frame);
  r.num_tracked = static_cast<int>(prev_pts_.size());
  r.klt_cpu_ms = threadCpuMs() - t_klt;
  if (r.num_tracked < opt_.min_tracked) {
    const std::string why =
        fmt::format("tracks {} < {}: reference reset to frame {}", r.num_tracked, opt_.min_tracked, frame.id);
    reset();
    InitializationResult again = addFrame(frame);  // becomes the new reference
    again.cur_frame_id = frame.id;
    again.num_tracked = r.num_tracked;
    return refuse(again, why);
  }

  // Ideal-pixel correspondences.
  const bool distorted = frame.camera.hasDistortion();
  Points2d x1(prev_pts_.size()), x2(prev_pts_.size());
  std::vector<double> flow(prev_pts_.size());
  for (size_t i = 0; i < prev_pts_.size(); ++i) {
    x1[i] = ref_.undistorted[static_cast<size_t>(track_ref_index_[i])];
    const Eigen::Vector2d uv(prev_pts_[i].x, prev_pts_[i].y);
    x2[i] = distorted ? frame.camera.undistortPoint(uv) : uv;
    flow[i] = (x2[i] - x1[i]).norm();
  }
  r.median_flow_px = median(flow);
  if (r.median_flow_px < opt_.min_median_flow_px)
    return refuse(
        r, fmt::format("median flow {:.2f} px < {:.1f} px (static camera)", r.median_flow_px, opt_.min_median_flow_px));

  const double t_models = threadCpuMs();
  const std::optional<std::string> why = reconstruct(frame, x1, x2, r);
  r.models_cpu_ms = threadCpuMs() - t_models;
  if (why) return refuse(r, *why);
  spdlog::info("initialised from frames {} -> {}: {} model (R_H {:.2f}), {} points, parallax {:.2f}°", r.ref_frame_id,
               r.cur_frame_id, r.model, r.homography_ratio, r.points.size(), r.parallax_deg);
  return r;
}

InitializationResult Initializer::setReference(const Frame& frame, InitializationResult r) {
  reset();
  r.ref_frame_id = frame.id;
  if (static_cast<int>(frame.size()) < opt_.min_tracked)
    return refuse(r, fmt::format("reference frame has {} features < {}", frame.size(), opt_.min_tracked));
  ref_ = frame;
  has_ref_ = true;
  cv::buildOpticalFlowPyramid(frame.pyramid[0], prev_pyr_, cv::Size(opt_.klt_window, opt_.klt_window), opt_.klt_levels,
                              true);
  prev_pts_.clear();
  track_ref_index_.clear();
  // KLT costs the same per corner: track at most max_tracks, every n-th, which keeps the
  // keypoints' spread over the image and over the pyramid levels (they are stored level by level,
  // bucketed in a grid).
  const size_t n = frame.keypoints.size();
  const size_t cap = static_cast<size_t>(std::max(opt_.max_tracks, opt_.min_tracked));
  const size_t m = opt_.max_tracks > 0 ? std::min(n, cap) : n;
  for (size_t k = 0; k < m; ++k) {
    const size_t i = k * n / m;
    prev_pts_.push_back(frame.keypoints[i].pt);
    track_ref_index_.push_back(static_cast<int>(i));
  }
  r.reason = fmt::format("reference frame set ({} corners, {} tracked)", n, m);
  r.num_tracked = static_cast<int>(m);
  return r;
}

void Initializer::trackCorners(const Frame& frame) {
  // Frame-to-frame pyramidal KLT with a forward-backward check.
  std::vector<cv::Point2f> fwd, bwd;
  std::vector<uchar> st_f, st_b;
  std::vector<float> err;
  const cv::Size win(opt_.klt_window, opt_.klt_window);
  const cv::TermCriteria crit(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 0.01);
  std::vector<cv::Mat> cur_pyr;
  cv::buildOpticalFlowPyramid(frame.pyramid[0], cur_pyr, win, opt_.klt_levels, true);
  if (!prev_pts_.empty()) {
    cv::calcOpticalFlowPyrLK(prev_pyr_, cur_pyr, prev_pts_, fwd, st_f, err, win, opt_.klt_levels, crit);
    // The backward pass starts at the answer it should find (the previous position), so the finest
    // level alone decides whether it stays there: the coarse levels would only repeat the forward
    // pass's work (measured on New Tsukuba: the same tracks pass, the pass costs 0.3x).
    bwd = prev_pts_;
    cv::calcOpticalFlowPyrLK(cur_pyr, prev_pyr_, fwd, bwd, st_b, err, win, 0, crit, cv::OPTFLOW_USE_INITIAL_FLOW);
  }
  std::vector<cv::Point2f> kept;
  std::vector<int> kept_idx;
  const double fb2 = opt_.fb_threshold_px * opt_.fb_threshold_px;
  for (size_t i = 0; i < prev_pts_.size(); ++i) {
    if (!st_f[i] || !st_b[i]) continue;
    const cv::Point2f d = bwd[i] - prev_pts_[i];
    if (d.dot(d) > fb2) continue;
    const cv::Point2f p = fwd[i];
    if (p.x < 0 || p.y < 0 || p.x > frame.camera.width - 1 || p.y > frame.camera.height - 1) continue;
    kept.push_back(p);
    kept_idx.push_back(track_ref_index_[i]);
  }
  prev_pts_ = kept;
  track_ref_index_ = kept_idx;
  prev_pyr_ = std::move(cur_pyr);
}

std::optional<std::string> Initializer::reconstruct(const Frame& frame, const Points2d& x1, const Points2d& x2,
                                                    InitializationResult& r) const {
  RansacOptions ro;
  ro.threshold_px = opt_.ransac_threshold_px;
  ro.seed = frame.id * 7919 + 17;
  ro.max_iterations = opt_.ransac_iterations;
  const ModelEstimate F = findFundamentalRansac(x1, x2, ro);
  const ModelEstimate H = findHomographyRansac(x1, x2, ro);
  if (!F.valid && !H.valid) return "no fundamental or homography model found";
  r.homography_ratio = H.score / std::max(1e-12, H.score + F.score);
  const bool use_h = r.homography_ratio > opt_.homography_ratio;
  r.model = use_h ? "homography" : "fundamental";
  const Eigen::Matrix3d K = frame.camera.K();
  if (use_h)
    if (auto why = pureRotation(H, K, x1, x2, opt_.min_parallax_deg, &r.parallax_deg)) return why;

  const ModelEstimate& M = use_h ? H : F;
  const double reproj_th = 2.0 * opt_.ransac_threshold_px;
  const Reconstruction rec = use_h ? reconstructFromHomography(M.M, K, x1, x2, M.inliers, reproj_th)
                                   : reconstructFromFundamental(M.M, K, x1, x2, M.inliers, reproj_th);
  r.num_inliers = rec.num_good;
  r.parallax_deg = rec.parallax_deg;
  if (auto why = weakReconstruction(rec, M, r.model, x1.size(), opt_)) return why;

  // Scale the map to median depth 1 in the reference camera.
  std::vector<double> depths;
  for (size_t i = 0; i < x1.size(); ++i)
    if (rec.good[i]) depths.push_back(rec.points[i].z());
  const double med_depth = median(depths);
  if (!(med_depth > 0)) return "degenerate depth of the triangulated points";
  const double s = 1.0 / med_depth;
  r.points = initialPoints(frame, rec, s);
  // X_cur = R X_ref + t  ->  T_cur_ref = (R, t),  T_world_cur = T_cur_ref^-1 (world = reference).
  r.T_world_ref = SE3();
  r.T_world_cur = SE3(rec.pose.R, rec.pose.t * s).inverse();
  r.success = true;
  return std::nullopt;
}

std::vector<InitialPoint> Initializer::initialPoints(const Frame& frame, const Reconstruction& rec,
                                                     double scale) const {
  std::vector<InitialPoint> out;
  for (size_t i = 0; i < rec.good.size(); ++i) {
    if (!rec.good[i]) continue;
    InitialPoint p;
    p.p_world = rec.points[i] * scale;
    p.ref_feature = track_ref_index_[i];
    const cv::KeyPoint& ref_kp = ref_.keypoints[static_cast<size_t>(p.ref_feature)];
    p.uv_ref = Eigen::Vector2d(ref_kp.pt.x, ref_kp.pt.y);
    p.uv_cur = Eigen::Vector2d(prev_pts_[i].x, prev_pts_[i].y);
    // Nearest current keypoint of a similar level and descriptor.
    const int ref_level = ref_kp.octave;
    double best = 2.0 * 2.0;
    for (int j : frame.featuresInArea(p.uv_cur, 2.0, std::max(0, ref_level - 1), ref_level + 1)) {
      const cv::KeyPoint& k = frame.keypoints[static_cast<size_t>(j)];
      const double d2 = (Eigen::Vector2d(k.pt.x, k.pt.y) - p.uv_cur).squaredNorm();
      if (d2 <= best &&
          descriptorDistance(frame.descriptors.ptr<uint8_t>(j), ref_.descriptors.ptr<uint8_t>(p.ref_feature)) <= 80) {
        best = d2;
        p.cur_feature = j;
      }
    }
    out.push_back(p);
  }
  return out;
}

}  // namespace nerfslam
