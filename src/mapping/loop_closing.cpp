#include "nerfslam/mapping/loop_closing.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <unordered_set>

#include <spdlog/spdlog.h>

#include "nerfslam/core/error.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/mapping/mapping_thread.h"
#include "nerfslam/tracking/bow_matcher.h"

namespace nerfslam {

namespace {

double levelScaleOf(const Frame& f, int idx) {
  const int level = f.keypoints[idx].octave;
  return level >= 0 && level < static_cast<int>(f.level_scale.size()) ? f.level_scale[level] : 1.0;
}

Sim3 asSim3(const SE3& T) { return Sim3(1.0, T); }

double rotationDeg(const Eigen::Quaterniond& a, const Eigen::Quaterniond& b) {
  return a.angularDistance(b) * 180.0 / M_PI;
}

}  // namespace

std::string vocabularyPath(const std::string& given) {
  if (!given.empty()) return given;
#ifdef NERFSLAM_SOURCE_DIR
  return std::string(NERFSLAM_SOURCE_DIR) + "/config/vocabulary/brief_k12_L4.voc";
#else
  return "config/vocabulary/brief_k12_L4.voc";
#endif
}

std::vector<std::pair<int, PointId>> matchPointsByProjection(const Frame& f, const Sim3& S_world_cam,
                                                             const std::vector<MapPoint>& points, double radius_px,
                                                             int max_distance) {
  const Sim3 S_cam_world = S_world_cam.inverse();
  const Eigen::Matrix3d K = f.camera.K();
  const double max_scale = f.level_scale.empty() ? 1.0 : f.level_scale.back();
  // Per keypoint the best (distance, point).
  std::unordered_map<int, std::pair<int, PointId>> best;
  std::vector<int> cands;
  for (const MapPoint& p : points) {
    if (p.descriptor.empty()) continue;
    const Eigen::Vector3d pc = S_cam_world * p.position;
    Eigen::Vector2d uv;
    if (pc.z() <= 0 || !f.camera.projectInImage(pc, &uv)) continue;
    const Eigen::Vector2d ideal = (K * pc).hnormalized();
    f.featuresInArea(uv, radius_px * max_scale, &cands);
    int bd = max_distance + 1, bi = -1;
    for (int c : cands) {
      const double s = levelScaleOf(f, c);
      if ((f.undistorted[c] - ideal).norm() > radius_px * s) continue;
      const int d = descriptorDistance(p.descriptor.ptr<uint8_t>(), f.descriptors.ptr<uint8_t>(c));
      if (d < bd) {
        bd = d;
        bi = c;
      }
    }
    if (bi < 0) continue;
    auto it = best.find(bi);
    if (it == best.end() || bd < it->second.first) best[bi] = {bd, p.id};
  }
  std::vector<std::pair<int, PointId>> out;
  out.reserve(best.size());
  for (const auto& [idx, dp] : best) out.emplace_back(idx, dp.second);
  std::sort(out.begin(), out.end());
  return out;
}

LoopClosing::LoopClosing(Map& map, MappingThread* mapping, std::shared_ptr<const Vocabulary> vocabulary,
                         LoopClosingOptions options, std::shared_ptr<PlaceRecognition> places)
    : map_(map),
      mapping_(mapping),
      voc_(std::move(vocabulary)),
      opt_(std::move(options)),
      places_(std::move(places)),
      queue_(static_cast<std::size_t>(std::max(1, opt_.queue)), OverflowPolicy::kDropNewest) {
  if (!voc_ || voc_->empty()) fail("LoopClosing: no vocabulary");
  if (!places_) places_ = std::make_shared<PlaceRecognition>(voc_);
  if (!mapping_) own_mapper_ = std::make_unique<LocalMapper>(map_, MappingOptions{});
  if (places_->vocabularyPtr() != voc_ && places_->vocabulary().wordCount() != voc_->wordCount())
    fail("LoopClosing: the place database's vocabulary has {} words, the loop closer's {}",
         places_->vocabulary().wordCount(), voc_->wordCount());
}

LoopClosing::~LoopClosing() { stop(); }

void LoopClosing::start() {
  if (started_) return;
  started_ = true;
  thread_ = std::thread([this] {
    setThreadName("nerfslam-loop");
    run();
  });
}

void LoopClosing::stop() {
  queue_.close();
  if (thread_.joinable()) thread_.join();
  stopGlobalBa();
  idle_cv_.notify_all();
}

bool LoopClosing::submit(KeyframeId id) {
  pending_.fetch_add(1);
  const bool ok = queue_.tryPush(id);
  if (!ok) {
    pending_.fetch_sub(1);
    spdlog::debug("loop closing busy: keyframe {} dropped ({} so far)", id, queue_.dropped());
    idle_cv_.notify_all();
  }
  return ok;
}

void LoopClosing::waitIdle() const {
  std::unique_lock<std::mutex> lock(mutex_);
  while ((pending_.load() != 0 && thread_.joinable()) || gba_running_.load())
    idle_cv_.wait_for(lock, std::chrono::milliseconds(5));
}

void LoopClosing::run() {
  for (;;) {
    auto id = queue_.pop();
    if (!id) break;
    try {
      process(*id);
    } catch (const std::exception& e) {
      spdlog::error("loop closing: {}", e.what());
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      pending_.fetch_sub(1);
    }
    idle_cv_.notify_all();
  }
}

void LoopClosing::process(KeyframeId id) {
  const auto loop = detect(id);
  if (!loop) return;
  LoopClosureRecord rec;
  if (correct(*loop, &rec)) {
    if (opt_.global_ba) startGlobalBa();
    spdlog::info(
        "loop closed: keyframe {} (frame {}) with keyframe {} (frame {}): scale {:.4f}, {} Sim(3) inliers, {} matches "
        "by projection, {} points fused, the keyframe moved {:.3f} / {:.2f} deg; {:.0f} ms to find, {:.0f} ms to "
        "correct",
        rec.current, rec.frame, rec.loop, rec.loop_frame, rec.sim3_scale, rec.sim3_inliers, rec.projection_matches,
        rec.fused_points, rec.correction_m, rec.correction_deg, rec.detection_ms, rec.correction_ms);
  }
}

const LoopClosing::Bow* LoopClosing::bowOf(KeyframeId id, const Keyframe* kf) {
  auto it = bows_.find(id);
  if (it != bows_.end()) return &it->second;
  std::optional<Keyframe> copy;
  if (!kf) {
    copy = map_.keyframe(id);
    if (!copy) return nullptr;
    kf = &*copy;
  }
  Bow b;
  voc_->transform(kf->frame->descriptors, &b.bow, &b.direct, opt_.direct_index_level);
  return &bows_.emplace(id, std::move(b)).first->second;
}

std::optional<LoopCandidate> LoopClosing::detect(KeyframeId id) {
  Stopwatch sw;
  const auto kfo = map_.keyframe(id);
  if (!kfo) return std::nullopt;
  // Keyframes culled since they were added leave the database and the bag cache here: kept, each
  // held its bag and direct index (tens of KB) for the rest of the run (a 2-minute 60 Hz soak: 220
  // culled keyframes, RSS +14 MB).
  const std::vector<KeyframeId> alive = map_.keyframeIds();
  for (auto it = bows_.begin(); it != bows_.end();)
    it = std::binary_search(alive.begin(), alive.end(), it->first) ? std::next(it) : bows_.erase(it);
  places_->eraseMissing(alive);
  const Keyframe& kf = *kfo;
  const Bow* mine = bowOf(id, &kf);
  std::optional<LoopCandidate> found;
  const auto record_time = [&] {
    std::lock_guard<std::mutex> lock(mutex_);
    detection_ms_.push_back(sw.elapsedMs());
  };
  const bool too_early = static_cast<int>(map_.numKeyframes()) < opt_.min_keyframes ||
                         (last_loop_kf_ >= 0 && id - last_loop_kf_ < opt_.min_keyframe_gap);
  if (too_early) {
    places_->add(id, mine->bow);
    record_time();
    return std::nullopt;
  }
  // The covisible neighbours: the lowest score among the strong ones is the bar a candidate must pass.
  const auto covisible = map_.covisibleKeyframes(id, 1);
  std::unordered_set<KeyframeId> neighbours{id};
  double min_score = 1.0;
  bool any_strong = false;
  for (const auto& [n, w] : covisible) {
    neighbours.insert(n);
    if (w < opt_.min_shared_points) continue;
    const Bow* nb = bowOf(n, nullptr);
    if (!nb) continue;
    min_score = std::min(min_score, Vocabulary::score(mine->bow, nb->bow));
    any_strong = true;
  }
  std::vector<PlaceCandidate> cands;
  if (any_strong) {
    PlaceQuery q;
    q.min_score = min_score;
    q.max_results = static_cast<size_t>(opt_.max_candidates);
    q.exclude = [&](uint64_t k) { return neighbours.count(static_cast<KeyframeId>(k)) > 0; };
    cands = places_->query(mine->bow, q);
  }
  // Consistency: a candidate's group (it and its covisible keyframes) must meet a group of the
  // previous keyframe's candidates; the count of consecutive meetings is carried over.
  std::vector<std::pair<std::vector<KeyframeId>, int>> groups;
  std::vector<KeyframeId> accepted;
  for (const PlaceCandidate& c : cands) {
    const KeyframeId cid = static_cast<KeyframeId>(c.keyframe);
    if (!map_.keyframe(cid)) {  // culled since: out of the database
      places_->erase(cid);
      bows_.erase(cid);
      continue;
    }
    std::vector<KeyframeId> group{cid};
    for (const auto& [n, w] : map_.covisibleKeyframes(cid, opt_.min_shared_points)) group.push_back(n);
    std::sort(group.begin(), group.end());
    int count = 1;
    for (const auto& [g, n] : groups_) {
      std::vector<KeyframeId> common;
      std::set_intersection(g.begin(), g.end(), group.begin(), group.end(), std::back_inserter(common));
      if (!common.empty()) count = std::max(count, n + 1);
    }
    if (count >= opt_.consistency) accepted.push_back(cid);
    groups.emplace_back(std::move(group), count);
  }
  groups_ = std::move(groups);
  for (KeyframeId cid : accepted) {
    found = checkGeometry(kf, *mine, cid);
    if (found) break;
  }
  places_->add(id, mine->bow);
  if (found) {
    found->detection_ms = sw.elapsedMs();
    groups_.clear();
  }
  record_time();
  return found;
}

std::optional<LoopCandidate> LoopClosing::checkGeometry(const Keyframe& cur, const Bow& cur_bow, KeyframeId loop_id) {
  const auto lko = map_.keyframe(loop_id);
  if (!lko) return std::nullopt;
  const Keyframe& lk = *lko;
  const Bow* lb = bowOf(loop_id, &lk);
  BowMatchOptions bo;
  const auto pairs = matchByDirectIndex(cur_bow.direct, cur.frame->descriptors, lb->direct, lk.frame->descriptors, bo);
  // Pairs of map points: (current keypoint, loop keypoint), both with a point, the points distinct.
  std::vector<std::pair<int, int>> kp;
  std::vector<PointId> ids;
  std::unordered_set<PointId> used_loop;
  for (const auto& [a, b] : pairs) {
    const PointId pa = cur.points[a], pb = lk.points[b];
    if (pa == kNoPoint || pb == kNoPoint || pa == pb || !used_loop.insert(pb).second) continue;
    kp.emplace_back(a, b);
    ids.push_back(pa);
    ids.push_back(pb);
  }
  if (static_cast<int>(kp.size()) < opt_.min_bow_matches) {
    spdlog::debug("loop candidate {} for keyframe {}: {} point pairs", loop_id, cur.id, kp.size());
    return std::nullopt;
  }
  std::unordered_map<PointId, Eigen::Vector3d> pos;
  for (const MapPoint& p : map_.points(ids)) pos[p.id] = p.position;
  const SE3 T_cw1 = cur.T_world_cam.inverse(), T_cw2 = lk.T_world_cam.inverse();
  std::vector<Sim3Match> matches;
  for (const auto& [a, b] : kp) {
    const auto ia = pos.find(cur.points[a]), ib = pos.find(lk.points[b]);
    if (ia == pos.end() || ib == pos.end()) continue;
    Sim3Match m;
    m.p1 = T_cw1 * ia->second;
    m.p2 = T_cw2 * ib->second;
    m.uv1 = cur.frame->undistorted[a];
    m.uv2 = lk.frame->undistorted[b];
    m.sigma1 = levelScaleOf(*cur.frame, a);
    m.sigma2 = levelScaleOf(*lk.frame, b);
    matches.push_back(m);
  }
  {
    std::vector<double> ratios;
    for (const auto& m : matches) ratios.push_back(m.p1.norm() / m.p2.norm());
    std::sort(ratios.begin(), ratios.end());
    if (!ratios.empty())
      spdlog::debug("loop candidate {} for keyframe {}: {} pairs, depth ratio median {:.3f} q25 {:.3f} q75 {:.3f}",
                    loop_id, cur.id, ratios.size(), ratios[ratios.size() / 2], ratios[ratios.size() / 4],
                    ratios[3 * ratios.size() / 4]);
  }
  Sim3SolverOptions so;
  so.min_inliers = opt_.min_sim3_inliers;
  const Sim3Result r = solveSim3(matches, map_.camera(), map_.camera(), so);
  if (!r.ok) {
    spdlog::debug("loop candidate {} for keyframe {}: no Sim(3) from {} pairs", loop_id, cur.id, matches.size());
    return std::nullopt;
  }
  LoopCandidate out;
  out.current = cur.id;
  out.loop = loop_id;
  out.S_cur_loop = r.S12;
  out.sim3_inliers = r.inliers;
  out.S_world_cur = asSim3(lk.T_world_cam) * r.S12.inverse();
  // The loop side (the loop keyframe and its best covisibles) projected into the current keyframe.
  std::vector<KeyframeId> group{loop_id};
  for (const auto& [n, w] : map_.covisibleKeyframes(loop_id, 1)) {
    if (static_cast<int>(group.size()) >= opt_.loop_group_keyframes) break;
    group.push_back(n);
  }
  const std::vector<MapPoint> loop_points = map_.points(map_.pointsSeenBy(group));
  out.matches = matchPointsByProjection(*cur.frame, out.S_world_cur, loop_points, opt_.projection_radius_px,
                                        opt_.max_descriptor_distance);
  spdlog::debug("loop candidate {} for keyframe {}: Sim(3) scale {:.3f} with {} inliers, {} matches by projection",
                loop_id, cur.id, r.S12.scale(), r.inliers, out.matches.size());
  if (static_cast<int>(out.matches.size()) < opt_.min_projection_matches) return std::nullopt;
  return out;
}

bool LoopClosing::correct(const LoopCandidate& loop, LoopClosureRecord* record) {
  stopGlobalBa();  // a new closure: the running global BA's result is out of date
  Stopwatch sw;
  std::optional<MappingThread::Hold> hold;
  if (mapping_) hold.emplace(mapping_->hold());
  const auto [kfs, pts] = map_.snapshot();
  std::map<KeyframeId, const Keyframe*> by_id;
  std::map<KeyframeId, Sim3> before;
  for (const Keyframe& k : kfs) {
    by_id[k.id] = &k;
    before[k.id] = asSim3(k.T_world_cam);
  }
  if (!by_id.count(loop.current) || !by_id.count(loop.loop)) return false;
  // The loop side: its keyframes are never in the corrected neighbourhood.
  std::set<KeyframeId> loop_group{loop.loop};
  for (const auto& [n, w] : map_.covisibleKeyframes(loop.loop, 1)) {
    if (static_cast<int>(loop_group.size()) >= opt_.loop_group_keyframes) break;
    loop_group.insert(n);
  }
  // 1. The current keyframe's neighbourhood moved rigidly with it (its Sim(3) propagated).
  const Sim3 S_cur_before = before.at(loop.current);
  const Sim3 move = loop.S_world_cur * S_cur_before.inverse();
  std::map<KeyframeId, Sim3> initial = before;
  std::vector<KeyframeId> hood{loop.current};
  for (const auto& [n, w] : map_.covisibleKeyframes(loop.current, opt_.min_shared_points))
    if (!loop_group.count(n)) hood.push_back(n);
  for (KeyframeId k : hood) initial[k] = move * before.at(k);
  // 2. Fusion: the loop side's points projected into the neighbourhood at the corrected poses.
  std::vector<MapPoint> loop_points;
  {
    std::unordered_set<PointId> seen;
    for (KeyframeId g : loop_group) {
      const auto it = by_id.find(g);
      if (it == by_id.end()) continue;
      for (PointId p : it->second->points)
        if (p != kNoPoint) seen.insert(p);
    }
    for (const MapPoint& p : pts)
      if (seen.count(p.id)) loop_points.push_back(p);
  }
  struct Fuse {
    KeyframeId kf;
    int idx;
    PointId to;
  };
  std::vector<Fuse> fusions;
  std::map<KeyframeId, std::map<KeyframeId, int>> links;  // hood kf -> loop kf -> shared after fusion
  std::unordered_map<PointId, const MapPoint*> point_by_id;
  for (const MapPoint& p : pts) point_by_id[p.id] = &p;
  for (KeyframeId k : hood) {
    const Keyframe& kf = *by_id.at(k);
    auto m = k == loop.current ? loop.matches
                               : matchPointsByProjection(*kf.frame, initial.at(k), loop_points,
                                                         opt_.projection_radius_px, opt_.max_descriptor_distance);
    for (const auto& [idx, to] : m) {
      if (idx < 0 || idx >= static_cast<int>(kf.points.size())) continue;
      if (kf.points[idx] == to) continue;
      fusions.push_back({k, idx, to});
      const auto pit = point_by_id.find(to);
      if (pit == point_by_id.end()) continue;
      for (const auto& [ok, oi] : pit->second->observations)
        if (loop_group.count(ok)) ++links[k][ok];
    }
  }
  // 3. The essential graph: consecutive keyframes and strong covisibility measured before the
  // correction, loop edges measured with the neighbourhood corrected.
  std::vector<PoseGraphEdge> edges;
  std::set<std::pair<KeyframeId, KeyframeId>> have;
  const auto add = [&](KeyframeId i, KeyframeId j, const Sim3& Si, const Sim3& Sj, PoseGraphEdgeKind kind) {
    if (i == j || !have.insert({std::min(i, j), std::max(i, j)}).second) return;
    edges.push_back(measuredEdge(i, j, Si, Sj, 1.0, kind));
  };
  for (size_t a = 1; a < kfs.size(); ++a)
    add(kfs[a - 1].id, kfs[a].id, before.at(kfs[a - 1].id), before.at(kfs[a].id), PoseGraphEdgeKind::kSpanningTree);
  // Covisibility from the snapshot's observations.
  {
    std::map<std::pair<KeyframeId, KeyframeId>, int> shared;
    for (const MapPoint& p : pts) {
      std::vector<KeyframeId> obs;
      for (const auto& [k, i] : p.observations) obs.push_back(k);
      for (size_t a = 0; a < obs.size(); ++a)
        for (size_t b = a + 1; b < obs.size(); ++b) ++shared[{obs[a], obs[b]}];
    }
    for (const auto& [ij, n] : shared)
      if (n >= opt_.essential_min_shared && before.count(ij.first) && before.count(ij.second))
        add(ij.first, ij.second, before.at(ij.first), before.at(ij.second), PoseGraphEdgeKind::kCovisibility);
  }
  add(loop.loop, loop.current, before.at(loop.loop), loop.S_world_cur, PoseGraphEdgeKind::kLoop);
  for (const auto& [k, m] : links)
    for (const auto& [l, n] : m)
      if (n >= opt_.min_shared_points && before.count(l))
        add(l, k, before.at(l), initial.at(k), PoseGraphEdgeKind::kLoop);
  PoseGraphOptions po;
  po.max_iterations = opt_.pose_graph_iterations;
  std::map<uint64_t, Sim3> vertices;
  for (const auto& [k, S] : initial) vertices[uint64_t(k)] = S;
  const PoseGraphResult pg = optimizeEssentialGraph(vertices, edges, uint64_t(loop.loop), po);
  std::map<KeyframeId, Sim3> after = initial;
  if (pg.usable)
    for (const auto& [k, S] : pg.S_world_kf) after[static_cast<KeyframeId>(k)] = S;
  // 4. Everything moves: keyframes to their corrected poses, points with their first keyframe.
  MapUpdate up;
  std::map<KeyframeId, Sim3> delta;
  for (const auto& [k, S] : after) {
    up.keyframe_poses.emplace_back(k, correctedPose(S));
    delta[k] = S * before.at(k).inverse();
  }
  for (const MapPoint& p : pts) {
    if (p.observations.empty()) continue;
    const KeyframeId ref = p.observations.begin()->first;
    const auto d = delta.find(ref);
    if (d == delta.end()) continue;
    up.point_positions.emplace_back(p.id, d->second * p.position);
  }
  const uint64_t version_before = map_.version();
  map_.applyUpdate(up);
  // 5. The duplicates: the loop side's point replaces the neighbourhood's.
  int fused = 0;
  for (const Fuse& f : fusions) {
    const auto kf = map_.keyframe(f.kf);
    if (!kf || f.idx >= static_cast<int>(kf->points.size())) continue;
    const PointId existing = kf->points[f.idx];
    if (existing == f.to) continue;
    if (existing == kNoPoint) {
      fused += map_.addObservation(f.to, f.kf, f.idx);
    } else {
      map_.fusePoints(existing, f.to);
      ++fused;
    }
  }
  last_loop_kf_ = loop.current;
  const double correction_ms = sw.elapsedMs();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    deltas_.push_back({std::move(delta), version_before});
    LoopClosureRecord rec;
    rec.current = loop.current;
    rec.loop = loop.loop;
    rec.frame = by_id.at(loop.current)->frameId();
    rec.loop_frame = by_id.at(loop.loop)->frameId();
    rec.sim3_scale = loop.S_cur_loop.scale();
    const SE3 T_after = correctedPose(after.at(loop.current));
    rec.correction_m = (T_after.translation() - S_cur_before.translation()).norm();
    rec.correction_deg = rotationDeg(T_after.rotation(), S_cur_before.rotation());
    rec.sim3_inliers = loop.sim3_inliers;
    rec.projection_matches = static_cast<int>(loop.matches.size());
    rec.fused_points = fused;
    rec.corrected_keyframes = static_cast<int>(after.size());
    rec.detection_ms = loop.detection_ms;
    rec.correction_ms = correction_ms;
    closures_.push_back(rec);
    if (record) *record = rec;
  }
  corrections_.fetch_add(1, std::memory_order_acq_rel);
  return true;
}

void LoopClosing::startGlobalBa() {
  stopGlobalBa();
  gba_running_.store(true);
  gba_thread_ = std::thread([this] {
    setThreadName("nerfslam-gba");
    try {
      runGlobalBa();
    } catch (const std::exception& e) {
      spdlog::error("loop closing: global BA: {}", e.what());
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      gba_running_.store(false);
    }
    idle_cv_.notify_all();
  });
}

void LoopClosing::stopGlobalBa() {
  gba_stop_.store(true);
  if (gba_thread_.joinable()) gba_thread_.join();
  gba_stop_.store(false);
}

bool LoopClosing::runGlobalBa(GlobalBaRecord* record) {
  GlobalBaRecord rec;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    rec.closure = static_cast<int>(closures_.size()) - 1;
  }
  LocalMapper& mapper = mapping_ ? mapping_->mapper() : *own_mapper_;
  Stopwatch sw;
  MapUpdate solution;
  const BaResult r = mapper.solveGlobalBundleAdjustment(
      opt_.global_ba_iterations, [this] { return gba_stop_.load(); }, &solution);
  rec.solve_ms = sw.elapsedMs();
  rec.keyframes = static_cast<int>(solution.keyframe_poses.size());
  rec.points = static_cast<int>(solution.point_positions.size());
  rec.iterations = r.iterations;
  rec.outliers = r.outliers;
  rec.rmse_before_px = r.initial_rmse_px;
  rec.rmse_after_px = r.final_rmse_px;
  rec.stopped = gba_stop_.load();
  if (!rec.stopped && !solution.keyframe_poses.empty()) writeGlobalBa(solution, &rec);
  spdlog::info(
      "loop closing: global BA after closure {}: {} keyframes, {} points, rmse {:.2f} -> {:.2f} px, {} iterations, "
      "{:.0f} ms{}",
      rec.closure + 1, rec.keyframes, rec.points, rec.rmse_before_px, rec.rmse_after_px, rec.iterations, rec.solve_ms,
      rec.stopped ? ", stopped (nothing written)"
                  : fmt::format("; written in {:.0f} ms ({} keyframes and {} points made meanwhile moved with it)",
                                rec.write_ms, rec.propagated_keyframes, rec.propagated_points));
  {
    std::lock_guard<std::mutex> lock(mutex_);
    gbas_.push_back(rec);
  }
  if (record) *record = rec;
  return !rec.stopped;
}

void LoopClosing::writeGlobalBa(const MapUpdate& solution, GlobalBaRecord* record) {
  Stopwatch sw;
  std::optional<MappingThread::Hold> hold;
  if (mapping_) hold.emplace(mapping_->hold());
  const auto [kfs, pts] = map_.snapshot();
  std::unordered_map<KeyframeId, SE3> solved(solution.keyframe_poses.begin(), solution.keyframe_poses.end());
  std::map<KeyframeId, SE3> now, after;
  std::set<KeyframeId> adjusted;  // in the global BA (fixed ones included)
  for (const Keyframe& k : kfs) {
    now[k.id] = k.T_world_cam;
    const auto it = solved.find(k.id);
    if (k.fixed || it != solved.end()) {
      after[k.id] = k.fixed ? k.T_world_cam : it->second;
      adjusted.insert(k.id);
    }
  }
  // Keyframes made meanwhile (oldest first) keep their pose relative to their parent.
  int propagated_kfs = 0;
  for (const Keyframe& k : kfs) {
    if (adjusted.count(k.id)) continue;
    KeyframeId parent = -1;
    for (const auto& [n, w] : map_.covisibleKeyframes(k.id, 1))
      if (adjusted.count(n)) {
        parent = n;
        break;
      }
    if (parent < 0) {
      const auto it = after.lower_bound(k.id);
      if (it != after.begin()) parent = std::prev(it)->first;
    }
    if (parent < 0) continue;
    after[k.id] = after.at(parent) * now.at(parent).inverse() * k.T_world_cam;
    ++propagated_kfs;
  }
  MapUpdate up;
  for (const auto& [k, T] : after) up.keyframe_poses.emplace_back(k, T);
  std::unordered_map<PointId, Eigen::Vector3d> solved_points(solution.point_positions.begin(),
                                                             solution.point_positions.end());
  int propagated_pts = 0;
  for (const MapPoint& p : pts) {
    const auto it = solved_points.find(p.id);
    if (it != solved_points.end()) {
      up.point_positions.emplace_back(p.id, it->second);
      continue;
    }
    if (p.observations.empty()) continue;
    const KeyframeId ref = p.observations.begin()->first;
    const auto a = after.find(ref);
    if (a == after.end()) continue;
    up.point_positions.emplace_back(p.id, a->second * (now.at(ref).inverse() * p.position));
    ++propagated_pts;
  }
  up.erase_observations = solution.erase_observations;
  map_.applyUpdate(up);
  if (record) {
    record->propagated_keyframes = propagated_kfs;
    record->propagated_points = propagated_pts;
    record->write_ms = sw.elapsedMs();
  }
}

std::vector<GlobalBaRecord> LoopClosing::globalBas() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return gbas_;
}

void LoopClosing::clear() {
  stopGlobalBa();
  places_->clear();
  bows_.clear();
  groups_.clear();
  last_loop_kf_ = -1;
}

bool LoopClosing::correctionsSince(uint64_t* seen, std::map<KeyframeId, Sim3>* delta) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const uint64_t n = deltas_.size();
  if (*seen >= n) return false;
  delta->clear();
  for (uint64_t c = *seen; c < n; ++c)
    for (const auto& [k, d] : deltas_[c].delta) {
      auto it = delta->find(k);
      if (it == delta->end())
        (*delta)[k] = d;
      else
        it->second = d * it->second;
    }
  *seen = n;
  return true;
}

bool LoopClosing::correctionsSince(uint64_t* seen, std::vector<LoopCorrection>* corrections) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const uint64_t n = deltas_.size();
  if (*seen >= n) return false;
  corrections->assign(deltas_.begin() + static_cast<std::ptrdiff_t>(*seen), deltas_.end());
  *seen = n;
  return true;
}

std::vector<LoopClosureRecord> LoopClosing::closures() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return closures_;
}

std::vector<double> LoopClosing::detectionTimes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return detection_ms_;
}

}  // namespace nerfslam
