#include "nerfslam/tracking/relocalizer.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

#include "nerfslam/tracking/pose_optimizer.h"

namespace nerfslam {
namespace {

// For every candidate point: best frame feature by Hamming distance, ratio-tested, one point
// per feature.
std::vector<MapMatch> matchDescriptors(const Frame& frame, const std::vector<TrackingMapPoint>& points,
                                       const RelocalizerOptions& opt) {
  std::vector<MapMatch> out;
  std::vector<int> owner(frame.size(), -1), owner_dist(frame.size(), 256);
  const int n = static_cast<int>(frame.size());
  for (size_t pi = 0; pi < points.size(); ++pi) {
    if (points[pi].descriptor.empty()) continue;
    const uint8_t* d = points[pi].descriptor.ptr<uint8_t>();
    int best = 256, second = 256, bi = -1;
    for (int j = 0; j < n; ++j) {
      const int dd = descriptorDistance(d, frame.descriptors.ptr<uint8_t>(j));
      if (dd < best) {
        second = best;
        best = dd;
        bi = j;
      } else if (dd < second) {
        second = dd;
      }
    }
    if (bi < 0 || best > opt.max_descriptor_distance || best > opt.ratio * second) continue;
    const size_t f = static_cast<size_t>(bi);
    if (owner[f] >= 0) {
      if (best < owner_dist[f]) {
        out[static_cast<size_t>(owner[f])] = {bi, points[pi].id, static_cast<int>(pi)};
        owner_dist[f] = best;
      }
      continue;
    }
    owner[f] = static_cast<int>(out.size());
    owner_dist[f] = best;
    out.push_back({bi, points[pi].id, static_cast<int>(pi)});
  }
  return out;
}

std::vector<PoseObservation> toObservations(const Frame& frame, const std::vector<TrackingMapPoint>& points,
                                            const std::vector<MapMatch>& m) {
  std::vector<PoseObservation> obs(m.size());
  for (size_t i = 0; i < m.size(); ++i) {
    const size_t f = static_cast<size_t>(m[i].feature);
    obs[i].p_world = points[static_cast<size_t>(m[i].point_index)].p_world;
    obs[i].uv = frame.undistorted[f];
    obs[i].sigma = frame.level_scale[static_cast<size_t>(frame.keypoints[f].octave)];
  }
  return obs;
}

}  // namespace

RelocalizationResult relocalize(const Frame& frame, const std::vector<RelocalizationCandidate>& candidates,
                                const RelocalizerOptions& opt, const PoseOptimizerOptions& optimizer) {
  RelocalizationResult best;
  best.reason = candidates.empty() ? "no candidate keyframes" : "no candidate gave enough inliers";
  if (frame.size() == 0) {
    best.reason = "frame has no features";
    return best;
  }
  const Eigen::Matrix3d K = frame.camera.K();
  const cv::Mat cvK = frame.camera.cvK();
  std::string details;
  std::vector<TrackingMapPoint> all;  // a candidate's points, then its neighbours'
  for (const RelocalizationCandidate& c : candidates) {
    std::vector<MapMatch> m = matchDescriptors(frame, c.points, opt);
    if (static_cast<int>(m.size()) < opt.min_matches) {
      details += fmt::format(" kf {}: {} matches;", c.keyframe_id, m.size());
      continue;
    }
    std::vector<cv::Point3f> obj;
    std::vector<cv::Point2f> img;
    for (const MapMatch& mm : m) {
      const Eigen::Vector3d& p = c.points[static_cast<size_t>(mm.point_index)].p_world;
      const Eigen::Vector2d& u = frame.undistorted[static_cast<size_t>(mm.feature)];
      obj.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
      img.emplace_back(static_cast<float>(u.x()), static_cast<float>(u.y()));
    }
    cv::Mat rvec, tvec;
    std::vector<int> inl;
    bool ok = false;
    try {
      ok = cv::solvePnPRansac(obj, img, cvK, cv::noArray(), rvec, tvec, false, opt.pnp_iterations,
                              static_cast<float>(opt.pnp_reprojection_px), 0.99, inl, cv::SOLVEPNP_EPNP);
    } catch (const cv::Exception& e) {
      ok = false;
    }
    if (!ok || static_cast<int>(inl.size()) < opt.min_matches / 2 + 3) {
      details += fmt::format(" kf {}: PnP {} inliers;", c.keyframe_id, inl.size());
      continue;
    }
    cv::Mat Rcv;
    cv::Rodrigues(rvec, Rcv);
    Eigen::Matrix3d R;
    Eigen::Vector3d t;
    cv::cv2eigen(Rcv, R);
    cv::cv2eigen(tvec, t);
    SE3 pose = SE3(R, t).inverse();
    all = c.points;
    all.insert(all.end(), c.neighbours.begin(), c.neighbours.end());
    PoseOptimizationResult o = optimizePose(K, toObservations(frame, all, m), pose, optimizer);
    if (!o.converged) {
      details += fmt::format(" kf {}: pose optimisation failed;", c.keyframe_id);
      continue;
    }
    const int pnp_inliers = o.num_inliers;
    // Guided search: project the candidate's and its neighbours' points with the pose for more
    // matches, and optimise again (a wide window first, then a narrow one when still short).
    TrackerOptions to;
    to.optimizer = optimizer;
    to.max_descriptor_distance = opt.guided_max_descriptor_distance;
    to.ratio = opt.ratio;
    auto extend = [&](double radius) {
      std::vector<MapMatch> m2 = matchByProjection(frame, all, o.T_world_cam, radius, to);
      if (static_cast<int>(m2.size()) <= o.num_inliers) return;
      PoseOptimizationResult o2 = optimizePose(K, toObservations(frame, all, m2), o.T_world_cam, optimizer);
      if (o2.converged && o2.num_inliers > o.num_inliers) {
        o = std::move(o2);
        m = std::move(m2);
      }
    };
    if (o.num_inliers < opt.guided_search_below) {
      extend(opt.guided_radius_px);
      if (o.num_inliers < opt.guided_search_below && o.num_inliers > opt.guided_search_below * 3 / 5)
        extend(opt.guided_fine_radius_px);
    }
    details += o.num_inliers == pnp_inliers ? fmt::format(" kf {}: {} inliers;", c.keyframe_id, o.num_inliers)
                                            : fmt::format(" kf {}: {} inliers ({} before the guided search);",
                                                          c.keyframe_id, o.num_inliers, pnp_inliers);
    if (o.num_inliers >= opt.min_inliers && o.num_inliers > best.num_inliers) {
      best.success = true;
      best.keyframe_id = c.keyframe_id;
      best.T_world_cam = o.T_world_cam;
      best.num_matches = static_cast<int>(m.size());
      best.num_inliers = o.num_inliers;
      best.matches.clear();
      for (size_t i = 0; i < m.size(); ++i)
        if (o.inlier[i]) best.matches.push_back(m[i]);
      best.reason.clear();
    }
  }
  if (!best.success && !candidates.empty()) best.reason += fmt::format(" ({} need {})", details, opt.min_inliers);
  spdlog::info("relocalisation of frame {}: {}", frame.id,
               best.success
                   ? fmt::format("ok against keyframe {} ({} inliers;{})", best.keyframe_id, best.num_inliers, details)
                   : best.reason);
  return best;
}

}  // namespace nerfslam
