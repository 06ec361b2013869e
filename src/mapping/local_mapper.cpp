#include "nerfslam/mapping/local_mapper.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <map>
#include <set>
#include <unordered_map>
#include <unordered_set>

#include <spdlog/spdlog.h>

namespace nerfslam {
namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

double levelScale(const Frame& f, int idx) {
  const int oct = std::max(0, f.keypoints[idx].octave);
  return oct < static_cast<int>(f.level_scale.size()) ? f.level_scale[oct] : std::pow(1.2, oct);
}

double medianDepth(const Map& map, const Keyframe& kf) {
  std::vector<PointId> ids;
  for (PointId p : kf.points)
    if (p != kNoPoint) ids.push_back(p);
  const auto pts = map.points(ids);
  std::vector<double> z;
  const SE3 T_cw = kf.T_world_cam.inverse();
  for (const auto& p : pts) z.push_back((T_cw * p.position).z());
  if (z.empty()) return 0;
  std::nth_element(z.begin(), z.begin() + z.size() / 2, z.end());
  return z[z.size() / 2];
}

}  // namespace

LocalMapper::LocalMapper(Map& map, MappingOptions options) : map_(map), opt_(std::move(options)) {}

void LocalMapper::addRecentPoints(const std::vector<PointId>& ids, KeyframeId created_at) {
  for (PointId p : ids) recent_.emplace_back(p, created_at);
}

int LocalMapper::cullRecentPoints(KeyframeId current) {
  int culled = 0;
  std::deque<std::pair<PointId, KeyframeId>> keep;
  for (const auto& [pid, created] : recent_) {
    const auto p = map_.point(pid);
    if (!p) continue;
    const KeyframeId age = current - created;
    if (p->foundRatio() < opt_.point_min_found_ratio ||
        (age >= 2 && p->observations.size() <= 2 && age >= opt_.point_probation_keyframes - 1)) {
      map_.erasePoint(pid);
      ++culled;
    } else if (age < opt_.point_probation_keyframes) {
      keep.emplace_back(pid, created);
    }
  }
  recent_.swap(keep);
  return culled;
}

int LocalMapper::createNewPoints(KeyframeId id) {
  const auto kf1o = map_.keyframe(id);
  if (!kf1o) return 0;
  const Keyframe& kf1 = *kf1o;
  const Frame& f1 = *kf1.frame;
  std::vector<KeyframeId> neighbours;
  for (const auto& [k, w] : map_.covisibleKeyframes(id)) {
    if (static_cast<int>(neighbours.size()) >= opt_.matching_neighbours) break;
    neighbours.push_back(k);
  }
  if (static_cast<int>(neighbours.size()) < opt_.matching_neighbours) {
    const auto ids = map_.keyframeIds();
    for (auto it = ids.rbegin(); it != ids.rend() && static_cast<int>(neighbours.size()) < opt_.matching_neighbours;
         ++it)
      if (*it != id && std::find(neighbours.begin(), neighbours.end(), *it) == neighbours.end())
        neighbours.push_back(*it);
  }
  const Eigen::Matrix3d K = f1.camera.K();
  TriangulationChecks checks;
  checks.min_parallax_deg = opt_.min_parallax_deg;
  checks.max_error_sigma = opt_.max_error_sigma;
  std::vector<char> used1(f1.size(), 0);
  for (size_t i = 0; i < f1.size(); ++i) used1[i] = kf1.points[i] != kNoPoint;
  int created = 0;
  std::vector<PointId> new_ids;
  for (KeyframeId nid : neighbours) {
    const auto kf2o = map_.keyframe(nid);
    if (!kf2o) continue;
    const Keyframe& kf2 = *kf2o;
    const Frame& f2 = *kf2.frame;
    const double baseline = (kf2.centre() - kf1.centre()).norm();
    const double depth = medianDepth(map_, kf2);
    if (depth <= 0 || baseline / depth < opt_.min_baseline_ratio) continue;
    const Eigen::Matrix3d F12 = fundamentalFromPoses(kf1.T_world_cam, kf2.T_world_cam, K);  // x2^T F x1 = 0
    // Epipole of camera 1 in image 2 (points near it triangulate badly).
    const Eigen::Vector3d c1_in_2 = kf2.T_world_cam.inverse() * kf1.centre();
    const bool has_epipole = c1_in_2.z() > 1e-9;
    const Eigen::Vector2d epipole = has_epipole ? Eigen::Vector2d((K * c1_in_2).hnormalized()) : Eigen::Vector2d(0, 0);

    // The free keypoints of kf2 in index order, which is by pyramid level (extractFrame appends
    // level after level), with what the inner loop reads: position, level, epipolar bound.
    struct Candidate {
      int j, octave;
      double x, y, max_e2, s2;
    };
    std::vector<Candidate> free2;
    for (size_t j = 0; j < f2.size(); ++j)
      if (kf2.points[j] == kNoPoint) {
        const double s2 = levelScale(f2, static_cast<int>(j));
        free2.push_back({static_cast<int>(j), f2.keypoints[j].octave, f2.undistorted[j].x(), f2.undistorted[j].y(),
                         opt_.epipolar_chi2 * s2 * s2, s2});
      }
    const bool by_level = std::is_sorted(free2.begin(), free2.end(),
                                         [](const Candidate& a, const Candidate& b) { return a.octave < b.octave; });
    std::vector<int> best_for_1(f1.size(), -1), best_dist_1(f1.size(), 256);
    std::unordered_map<int, std::pair<int, int>> best_for_2;  // j -> (i, dist)
    for (size_t i = 0; i < f1.size(); ++i) {
      if (used1[i]) continue;
      const Eigen::Vector3d l = F12 * f1.undistorted[i].homogeneous();
      const double ln = std::hypot(l.x(), l.y());
      if (!(ln > 0)) continue;
      const int oct1 = f1.keypoints[i].octave;
      const uint8_t* d1 = f1.descriptors.ptr<uint8_t>(static_cast<int>(i));
      // Candidates within one level of oct1: a contiguous run when sorted by level.
      auto first = free2.begin(), last = free2.end();
      if (by_level) {
        first = std::lower_bound(free2.begin(), free2.end(), oct1 - 1,
                                 [](const Candidate& c, int o) { return c.octave < o; });
        last = std::upper_bound(first, free2.end(), oct1 + 1, [](int o, const Candidate& c) { return o < c.octave; });
      }
      int best = opt_.max_descriptor_distance + 1, best_j = -1;
      for (auto c = first; c != last; ++c) {
        if (std::abs(c->octave - oct1) > 1) continue;
        const double e = (l.x() * c->x + l.y() * c->y + l.z()) / ln;
        if (e * e > c->max_e2) continue;
        const int d = descriptorDistance(d1, f2.descriptors.ptr<uint8_t>(c->j));
        if (d >= best) continue;
        if (has_epipole && (Eigen::Vector2d(c->x, c->y) - epipole).squaredNorm() < 100 * c->s2 * c->s2) continue;
        best = d;
        best_j = c->j;
      }
      if (best_j < 0) continue;
      best_for_1[i] = best_j;
      best_dist_1[i] = best;
      auto it = best_for_2.find(best_j);
      if (it == best_for_2.end() || best < it->second.second) best_for_2[best_j] = {static_cast<int>(i), best};
    }
    // Mutual best + rotation consistency (three dominant bins of the angle difference histogram).
    std::vector<std::pair<int, int>> matches;
    std::array<std::vector<int>, 30> hist;
    for (size_t i = 0; i < f1.size(); ++i) {
      const int j = best_for_1[i];
      if (j < 0 || best_for_2[j].first != static_cast<int>(i)) continue;
      float rot = f1.keypoints[i].angle - f2.keypoints[j].angle;
      if (rot < 0) rot += 360.f;
      int bin = static_cast<int>(std::lround(rot / 12.f)) % 30;
      hist[bin].push_back(static_cast<int>(matches.size()));
      matches.emplace_back(static_cast<int>(i), j);
    }
    std::vector<char> keep(matches.size(), 1);
    if (f1.keypoints.empty() || f1.keypoints[0].angle >= 0) {
      std::array<int, 30> order;
      for (int b = 0; b < 30; ++b) order[b] = b;
      std::sort(order.begin(), order.end(), [&](int a, int b) { return hist[a].size() > hist[b].size(); });
      std::fill(keep.begin(), keep.end(), 0);
      const size_t top = hist[order[0]].size();
      for (int r = 0; r < 3; ++r) {
        if (r > 0 && hist[order[r]].size() < 0.1 * top) break;
        for (int m : hist[order[r]]) keep[m] = 1;
      }
    }
    int n_kept = 0, n_tri = 0, n_scale = 0, n_added = 0;
    for (size_t m = 0; m < matches.size(); ++m) {
      if (!keep[m]) continue;
      ++n_kept;
      const auto [i, j] = matches[m];
      if (used1[i]) continue;
      const double s1 = levelScale(f1, i), s2 = levelScale(f2, j);
      const auto tp =
          triangulateChecked(kf1.T_world_cam, kf2.T_world_cam, K, f1.undistorted[i], f2.undistorted[j], s1, s2, checks);
      if (!tp) continue;
      ++n_tri;
      // Scale consistency: distance ratio vs pyramid scale ratio.
      const double d1 = (tp->position - kf1.centre()).norm(), d2 = (tp->position - kf2.centre()).norm();
      const double ratio_dist = d2 / d1, ratio_oct = s1 / s2;
      if (ratio_dist * 1.5 < ratio_oct || ratio_dist > ratio_oct * 1.5) continue;
      ++n_scale;
      const PointId pid = map_.addPoint(tp->position, {{id, i}, {nid, j}});
      if (pid == kNoPoint) continue;
      used1[i] = 1;
      new_ids.push_back(pid);
      ++created;
      ++n_added;
    }
    spdlog::debug(
        "new points kf {} x kf {}: {} mutual matches, {} rotation-consistent, {} triangulated, {} scale-consistent, {} "
        "added",
        id, nid, matches.size(), n_kept, n_tri, n_scale, n_added);
  }
  addRecentPoints(new_ids, id);
  return created;
}

int LocalMapper::fuseWithNeighbours(KeyframeId id) {
  std::vector<KeyframeId> neighbours;
  for (const auto& [k, w] : map_.covisibleKeyframes(id)) {
    if (static_cast<int>(neighbours.size()) >= opt_.matching_neighbours) break;
    neighbours.push_back(k);
  }
  int fused = 0;
  // Projects `pids` into keyframe `target` and associates or fuses.
  auto fuseInto = [&](KeyframeId target, const std::vector<PointId>& pids) {
    const auto kfo = map_.keyframe(target);
    if (!kfo) return;
    const Keyframe& kf = *kfo;
    const Frame& f = *kf.frame;
    const SE3 T_cw = kf.T_world_cam.inverse();
    const Eigen::Matrix3d K = f.camera.K();
    for (const MapPoint& p : map_.points(pids)) {
      if (p.observations.count(target) || p.descriptor.empty()) continue;
      const Eigen::Vector3d pc = T_cw * p.position;
      Eigen::Vector2d uv;
      if (!f.camera.projectInImage(pc, &uv)) continue;
      // Viewing angle within 60 degrees of the mean.
      const Eigen::Vector3d view = (p.position - kf.centre()).normalized();
      if (view.dot(p.normal) < 0.5) continue;
      const Eigen::Vector2d ideal = (K * pc).hnormalized();
      const auto cands =
          f.featuresInArea(uv, opt_.fuse_radius_px * (f.level_scale.empty() ? 1.0 : f.level_scale.back()));
      int best = opt_.fuse_descriptor_distance + 1, best_idx = -1;
      for (int c : cands) {
        const double s = levelScale(f, c);
        if ((f.undistorted[c] - ideal).squaredNorm() > 5.99 * s * s) continue;
        const int d = descriptorDistance(p.descriptor.ptr<uint8_t>(), f.descriptors.ptr<uint8_t>(c));
        if (d < best) {
          best = d;
          best_idx = c;
        }
      }
      if (best_idx < 0) continue;
      const PointId existing = kf.points[best_idx];
      if (existing == kNoPoint) {
        if (map_.addObservation(p.id, target, best_idx)) ++fused;
      } else if (existing != p.id) {
        const auto q = map_.point(existing);
        if (!q) continue;
        if (q->observations.size() >= p.observations.size())
          map_.fusePoints(p.id, existing);
        else
          map_.fusePoints(existing, p.id);
        ++fused;
      }
    }
  };
  {
    const auto kfo = map_.keyframe(id);
    if (!kfo) return 0;
    std::vector<PointId> own;
    for (PointId p : kfo->points)
      if (p != kNoPoint) own.push_back(p);
    for (KeyframeId n : neighbours) fuseInto(n, own);
  }
  fuseInto(id, map_.pointsSeenBy(neighbours));
  return fused;
}

BaResult LocalMapper::runBa(const std::vector<KeyframeId>& free_kfs, const std::vector<KeyframeId>& fixed_kfs,
                            const std::vector<PointId>& point_ids, const BundleAdjustmentOptions& ba,
                            MapUpdate* solution) {
  BaProblem pb;
  std::unordered_map<KeyframeId, int> cam_index;
  std::vector<Keyframe> kfs;
  auto addCam = [&](KeyframeId k, bool fixed) {
    if (cam_index.count(k)) return;
    auto kf = map_.keyframe(k);
    if (!kf) return;
    cam_index[k] = static_cast<int>(pb.cameras.size());
    pb.cameras.push_back({kf->T_world_cam, fixed || kf->fixed});
    kfs.push_back(std::move(*kf));
  };
  for (KeyframeId k : free_kfs) addCam(k, false);
  for (KeyframeId k : fixed_kfs) addCam(k, true);
  if (kfs.empty()) return {};
  const Eigen::Matrix3d K = kfs[0].frame->camera.K();
  pb.fx = K(0, 0);
  pb.fy = K(1, 1);
  pb.cx = K(0, 2);
  pb.cy = K(1, 2);
  const auto points = map_.points(point_ids);
  std::vector<std::pair<PointId, KeyframeId>> obs_ids;
  for (const MapPoint& p : points) {
    const int pi = static_cast<int>(pb.points.size());
    pb.points.push_back({p.position, false});
    for (const auto& [k, idx] : p.observations) {
      auto it = cam_index.find(k);
      if (it == cam_index.end()) continue;
      const Frame& f = *kfs[it->second].frame;
      if (idx >= static_cast<int>(f.undistorted.size())) continue;
      pb.observations.push_back({it->second, pi, f.undistorted[idx], levelScale(f, idx)});
      obs_ids.emplace_back(p.id, k);
    }
  }
  int64_t gated = 0;
  if (odometry_ && odometryActive() && odometry_->options().constrain_ba) {
    const OdometryOptions& oo = odometry_->options();
    std::vector<int> order(kfs.size());
    for (size_t i = 0; i < kfs.size(); ++i) order[i] = static_cast<int>(i);
    std::sort(order.begin(), order.end(), [&](int a, int b) { return kfs[a].timestamp() < kfs[b].timestamp(); });
    for (size_t k = 1; k < order.size(); ++k) {
      const int i = order[k - 1], j = order[k];
      if (pb.cameras[i].fixed && pb.cameras[j].fixed) continue;
      const double ti = kfs[i].timestamp(), tj = kfs[j].timestamp();
      if (tj - ti > oo.max_pair_gap_s) continue;
      const auto m = odometry_->cameraMotion(ti, tj);
      if (!m) continue;
      // A pair whose odometry disagrees with the (metric) map by more than the gate is left out: wheel
      // slip. Coherent slips would otherwise pull a global BA's free scale however robust the loss.
      const double d_odom = m->translation().norm();
      const double d_map = (kfs[j].T_world_cam.translation() - kfs[i].T_world_cam.translation()).norm();
      if (std::abs(d_odom - d_map) > std::max(oo.gate_ratio * d_odom, 3.0 * oo.min_sigma_m)) {
        ++gated;
        continue;
      }
      const double sigma = oo.translation_noise * d_odom + oo.min_sigma_m;
      pb.relative_translations.push_back({i, j, m->translation(), sigma, oo.huber_sigma});
    }
  }
  if (!solution) {  // statistics of the mapping thread's own adjustments
    last_odometry_constraints_ = static_cast<int>(pb.relative_translations.size());
    odometry_gated_ += gated;
  }
  BaResult r = bundleAdjust(pb, ba);
  MapUpdate u;
  for (const auto& [k, ci] : cam_index)
    if (!pb.cameras[ci].fixed) u.keyframe_poses.emplace_back(k, pb.cameras[ci].T_world_cam);
  for (size_t i = 0; i < points.size(); ++i) u.point_positions.emplace_back(points[i].id, pb.points[i].position);
  for (size_t o = 0; o < obs_ids.size(); ++o)
    if (!r.inlier[o]) u.erase_observations.push_back(obs_ids[o]);
  if (solution)
    *solution = std::move(u);
  else
    map_.applyUpdate(u);
  return r;
}

BaResult LocalMapper::localBundleAdjustment(KeyframeId id, int* n_keyframes, int* n_points) {
  std::vector<KeyframeId> window{id};
  for (const auto& [k, w] : map_.covisibleKeyframes(id)) {
    if (static_cast<int>(window.size()) >= opt_.local_window) break;
    window.push_back(k);
  }
  const auto pts = map_.pointsSeenBy(window);
  // Keyframes outside the window that see the points anchor it (most shared points first).
  std::map<KeyframeId, int> others;
  const std::set<KeyframeId> in_window(window.begin(), window.end());
  for (const MapPoint& p : map_.points(pts))
    for (const auto& [k, idx] : p.observations)
      if (!in_window.count(k)) ++others[k];
  std::vector<std::pair<KeyframeId, int>> ranked(others.begin(), others.end());
  std::sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  std::vector<KeyframeId> fixed;
  for (const auto& [k, c] : ranked) {
    if (static_cast<int>(fixed.size()) >= opt_.max_fixed_keyframes) break;
    fixed.push_back(k);
  }
  if (n_keyframes) *n_keyframes = static_cast<int>(window.size());
  if (n_points) *n_points = static_cast<int>(pts.size());
  return runBa(window, fixed, pts, opt_.ba);
}

int LocalMapper::cullRedundantKeyframes(KeyframeId id) {
  if (!opt_.cull_keyframes) return 0;
  int culled = 0;
  std::unordered_map<KeyframeId, std::shared_ptr<const Frame>> frames;
  for (const auto& [k, w] : map_.covisibleKeyframes(id)) {
    const auto kf = map_.keyframe(k);
    if (!kf || kf->fixed || k == id) continue;
    // Keep the two most recent keyframes (tracking references them).
    const auto last = map_.lastKeyframeId();
    if (last && k >= *last - 1) continue;
    std::vector<PointId> ids;
    for (PointId p : kf->points)
      if (p != kNoPoint) ids.push_back(p);
    if (ids.empty()) continue;
    int redundant = 0;
    for (const MapPoint& p : map_.points(ids)) {
      const int oct = kf->frame->keypoints[p.observations.at(k)].octave;
      int seen = 0;
      for (const auto& [ok, oidx] : p.observations) {
        if (ok == k) continue;
        // One Map::keyframe() copy per keyframe, not per observation (each copy holds the
        // keyframe's point-id vector and takes the Map lock).
        auto cit = frames.find(ok);
        if (cit == frames.end()) {
          const auto okf = map_.keyframe(ok);
          cit = frames.emplace(ok, okf ? okf->frame : nullptr).first;
        }
        if (cit->second && cit->second->keypoints[oidx].octave <= oct + 1) ++seen;
        if (seen >= 3) break;
      }
      redundant += seen >= 3;
    }
    if (redundant > opt_.redundant_ratio * ids.size()) {
      const auto cov = map_.covisibleKeyframes(k);
      KeyframeId parent = -1;
      for (const auto& [c, cw] : cov)
        if (c != k) {
          parent = c;
          break;
        }
      map_.eraseKeyframe(k, parent);
      ++culled;
    }
  }
  return culled;
}

MappingStats LocalMapper::processKeyframe(KeyframeId id) {
  const auto t0 = Clock::now();
  MappingStats s;
  s.culled_points = cullRecentPoints(id);
  s.new_points = createNewPoints(id);
  s.fused_points = fuseWithNeighbours(id);
  const auto tb = Clock::now();
  const BaResult r = localBundleAdjustment(id, &s.ba_keyframes, &s.ba_points);
  s.ba_ms = msSince(tb);
  s.ba_outliers = r.outliers;
  s.ba_rmse_px = r.final_rmse_px;
  s.culled_keyframes = cullRedundantKeyframes(id);
  s.total_ms = msSince(t0);
  spdlog::debug(
      "mapping kf {}: +{} points, {} fused, {} culled, BA {} kf / {} pts {:.1f} ms rmse {:.2f} px, {} kf culled", id,
      s.new_points, s.fused_points, s.culled_points, s.ba_keyframes, s.ba_points, s.ba_ms, s.ba_rmse_px,
      s.culled_keyframes);
  return s;
}

BaResult LocalMapper::globalBundleAdjustment(int iterations, const std::function<bool()>& should_stop) {
  return solveGlobalBundleAdjustment(iterations, should_stop, nullptr);
}

BaResult LocalMapper::solveGlobalBundleAdjustment(int iterations, const std::function<bool()>& should_stop,
                                                  MapUpdate* solution) {
  const auto ids = map_.keyframeIds();
  if (ids.size() < 2 || iterations <= 0) return {};
  std::vector<KeyframeId> free;
  std::vector<KeyframeId> fixed;
  for (KeyframeId k : ids) {
    const auto kf = map_.keyframe(k);
    if (kf && kf->fixed)
      fixed.push_back(k);
    else
      free.push_back(k);
  }
  BundleAdjustmentOptions ba = opt_.ba;
  ba.max_iterations = iterations;
  ba.refine_iterations = iterations / 2;
  ba.max_solver_time_s = std::max(ba.max_solver_time_s, 30.0);
  ba.function_tolerance = std::min(ba.function_tolerance, 1e-6);  // the final map: converge fully
  ba.should_stop = should_stop;
  std::vector<PointId> pts;
  for (const auto& p : map_.points()) pts.push_back(p.id);
  return runBa(free, fixed, pts, ba, solution);
}

}  // namespace nerfslam
