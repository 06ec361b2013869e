#include "nerfslam/mapping/map.h"

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <mutex>
#include <optional>
#include <set>
#include <unordered_set>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

// Per-thread lock acquisition statistics (Map::threadLockWait). The uncontended path is one
// try_lock; only a contended acquisition is timed.
thread_local MapLockWait t_lock_wait;

void recordWait(std::chrono::steady_clock::time_point t0) {
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  ++t_lock_wait.contended;
  t_lock_wait.total_ms += ms;
  t_lock_wait.max_ms = std::max(t_lock_wait.max_ms, ms);
}

std::unique_lock<std::shared_mutex> lockExclusive(std::shared_mutex& m) {
  ++t_lock_wait.acquisitions;
  std::unique_lock<std::shared_mutex> lock(m, std::try_to_lock);
  if (!lock.owns_lock()) {
    const auto t0 = std::chrono::steady_clock::now();
    lock.lock();
    recordWait(t0);
  }
  return lock;
}

std::shared_lock<std::shared_mutex> lockShared(std::shared_mutex& m) {
  ++t_lock_wait.acquisitions;
  std::shared_lock<std::shared_mutex> lock(m, std::try_to_lock);
  if (!lock.owns_lock()) {
    const auto t0 = std::chrono::steady_clock::now();
    lock.lock();
    recordWait(t0);
  }
  return lock;
}

}  // namespace

MapLockWait Map::threadLockWait() { return t_lock_wait; }
void Map::resetThreadLockWait() { t_lock_wait = {}; }

int Keyframe::numTrackedPoints() const {
  int n = 0;
  for (PointId p : points) n += p != kNoPoint;
  return n;
}

Map::Map(Camera camera) : camera_(std::move(camera)) {}

KeyframeId Map::addKeyframe(Keyframe kf) {
  if (!kf.frame) fail("Map::addKeyframe: keyframe without a frame");
  const size_t n = kf.frame->keypoints.size();
  if (kf.points.empty()) kf.points.assign(n, kNoPoint);
  if (kf.points.size() != n) fail("Map::addKeyframe: {} point slots for {} keypoints", kf.points.size(), n);
  auto lock = lockExclusive(mutex_);
  kf.id = next_kf_++;
  if (keyframes_.empty()) kf.fixed = true;
  for (size_t i = 0; i < n; ++i) {
    const PointId pid = kf.points[i];
    if (pid == kNoPoint) continue;
    auto it = points_.find(pid);
    if (it == points_.end() || it->second.observations.count(kf.id)) {
      kf.points[i] = kNoPoint;
      continue;
    }
    it->second.observations[kf.id] = static_cast<int>(i);
  }
  const KeyframeId id = kf.id;
  auto& stored = keyframes_.emplace(id, std::move(kf)).first->second;
  for (PointId pid : stored.points)
    if (pid != kNoPoint) updateAppearanceLocked(points_.at(pid));
  bumpStructure();
  return id;
}

PointId Map::addPoint(const Eigen::Vector3d& position, const std::map<KeyframeId, int>& observations) {
  if (!position.allFinite()) return kNoPoint;
  auto lock = lockExclusive(mutex_);
  MapPoint p;
  p.position = position;
  for (const auto& [kid, idx] : observations) {
    auto it = keyframes_.find(kid);
    if (it == keyframes_.end()) continue;
    if (idx < 0 || idx >= static_cast<int>(it->second.points.size())) continue;
    if (it->second.points[idx] != kNoPoint) continue;
    p.observations[kid] = idx;
  }
  if (p.observations.size() < 2) return kNoPoint;
  p.id = next_point_++;
  p.first_keyframe = p.observations.begin()->first;
  for (const auto& [kid, idx] : p.observations) keyframes_.at(kid).points[idx] = p.id;
  auto& stored = points_.emplace(p.id, std::move(p)).first->second;
  updateAppearanceLocked(stored);
  bumpStructure();
  return stored.id;
}

bool Map::addObservation(PointId pid, KeyframeId kid, int idx) {
  auto lock = lockExclusive(mutex_);
  auto pit = points_.find(pid);
  auto kit = keyframes_.find(kid);
  if (pit == points_.end() || kit == keyframes_.end()) return false;
  if (idx < 0 || idx >= static_cast<int>(kit->second.points.size())) return false;
  if (kit->second.points[idx] != kNoPoint || pit->second.observations.count(kid)) return false;
  kit->second.points[idx] = pid;
  pit->second.observations[kid] = idx;
  updateAppearanceLocked(pit->second);
  bumpStructure();
  return true;
}

void Map::eraseObservationLocked(PointId pid, KeyframeId kid) {
  auto pit = points_.find(pid);
  if (pit == points_.end()) return;
  auto oit = pit->second.observations.find(kid);
  if (oit == pit->second.observations.end()) return;
  auto kit = keyframes_.find(kid);
  if (kit != keyframes_.end() && kit->second.points[oit->second] == pid) kit->second.points[oit->second] = kNoPoint;
  pit->second.observations.erase(oit);
  if (pit->second.observations.size() < 2)
    erasePointLocked(pid);
  else
    updateAppearanceLocked(pit->second);
}

void Map::eraseObservation(PointId pid, KeyframeId kid) {
  auto lock = lockExclusive(mutex_);
  eraseObservationLocked(pid, kid);
  bumpStructure();
}

void Map::erasePointLocked(PointId pid) {
  auto pit = points_.find(pid);
  if (pit == points_.end()) return;
  for (const auto& [kid, idx] : pit->second.observations) {
    auto kit = keyframes_.find(kid);
    if (kit != keyframes_.end() && kit->second.points[idx] == pid) kit->second.points[idx] = kNoPoint;
  }
  points_.erase(pit);
}

void Map::erasePoint(PointId pid) {
  auto lock = lockExclusive(mutex_);
  erasePointLocked(pid);
  bumpStructure();
}

void Map::eraseKeyframe(KeyframeId kid, KeyframeId parent) {
  auto lock = lockExclusive(mutex_);
  auto kit = keyframes_.find(kid);
  if (kit == keyframes_.end()) return;
  auto pit = keyframes_.find(parent);
  if (pit != keyframes_.end() && parent != kid)
    retired_[kid] = {parent, pit->second.T_world_cam.inverse() * kit->second.T_world_cam};
  const std::vector<PointId> pts = kit->second.points;
  for (PointId pid : pts)
    if (pid != kNoPoint) eraseObservationLocked(pid, kid);
  keyframes_.erase(kid);
  bumpStructure();
}

void Map::fusePoints(PointId from, PointId to) {
  if (from == to) return;
  auto lock = lockExclusive(mutex_);
  auto fit = points_.find(from);
  auto tit = points_.find(to);
  if (fit == points_.end() || tit == points_.end()) return;
  for (const auto& [kid, idx] : fit->second.observations) {
    auto kit = keyframes_.find(kid);
    if (kit == keyframes_.end()) continue;
    kit->second.points[idx] = kNoPoint;
    if (!tit->second.observations.count(kid)) {
      tit->second.observations[kid] = idx;
      kit->second.points[idx] = to;
    }
  }
  tit->second.visible += fit->second.visible;
  tit->second.found += fit->second.found;
  points_.erase(fit);
  updateAppearanceLocked(points_.at(to));
  bumpStructure();
}

void Map::updateAppearanceLocked(MapPoint& p) {
  std::vector<cv::Mat> descs;
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  for (const auto& [kid, idx] : p.observations) {
    auto kit = keyframes_.find(kid);
    if (kit == keyframes_.end()) continue;
    const Keyframe& kf = kit->second;
    if (!kf.frame->descriptors.empty() && idx < kf.frame->descriptors.rows)
      descs.push_back(kf.frame->descriptors.row(idx));
    const Eigen::Vector3d d = p.position - kf.centre();
    if (d.norm() > 0) normal += d.normalized();
  }
  if (normal.norm() > 0) p.normal = normal.normalized();
  if (descs.empty()) return;
  // Medoid: the descriptor with the least median distance to the others (ORB-SLAM). This runs under
  // the exclusive lock for every point a new keyframe observes, so binary descriptors use a direct
  // popcount over a symmetric distance table instead of cv::norm per pair.
  const size_t n = descs.size();
  std::vector<int> dist(n * n, 0);
  const bool binary = descs[0].depth() == CV_8U && descs[0].cols % 8 == 0 &&
                      std::all_of(descs.begin(), descs.end(), [&](const cv::Mat& m) {
                        return m.depth() == CV_8U && m.cols == descs[0].cols && m.isContinuous();
                      });
  for (size_t i = 0; i < n; ++i)
    for (size_t j = i + 1; j < n; ++j) {
      int d = 0;
      if (binary) {
        const uint8_t* a = descs[i].ptr<uint8_t>();
        const uint8_t* b = descs[j].ptr<uint8_t>();
        for (int k = 0; k < descs[0].cols; k += 8) {
          uint64_t wa, wb;
          std::memcpy(&wa, a + k, 8);
          std::memcpy(&wb, b + k, 8);
          d += __builtin_popcountll(wa ^ wb);
        }
      } else {
        d = static_cast<int>(cv::norm(descs[i], descs[j], descs[i].depth() == CV_8U ? cv::NORM_HAMMING : cv::NORM_L2));
      }
      dist[i * n + j] = dist[j * n + i] = d;
    }
  size_t best = 0;
  int best_median = std::numeric_limits<int>::max();
  std::vector<int> d(n);
  for (size_t i = 0; i < n; ++i) {
    std::copy(dist.begin() + i * n, dist.begin() + (i + 1) * n, d.begin());
    std::nth_element(d.begin(), d.begin() + n / 2, d.end());
    if (d[n / 2] < best_median) {
      best_median = d[n / 2];
      best = i;
    }
  }
  p.descriptor = descs[best].clone();
}

void Map::updatePointAppearance(PointId pid) {
  auto lock = lockExclusive(mutex_);
  auto pit = points_.find(pid);
  if (pit == points_.end()) return;
  updateAppearanceLocked(pit->second);
  bumpStructure();
}

void Map::setKeyframePose(KeyframeId id, const SE3& T) {
  auto lock = lockExclusive(mutex_);
  auto kit = keyframes_.find(id);
  if (kit == keyframes_.end()) return;
  kit->second.T_world_cam = T;
  bump();
}

void Map::applyUpdate(const MapUpdate& u) {
  auto lock = lockExclusive(mutex_);
  for (const auto& [kid, T] : u.keyframe_poses) {
    auto kit = keyframes_.find(kid);
    if (kit != keyframes_.end() && !kit->second.fixed) kit->second.T_world_cam = T;
  }
  for (const auto& [pid, X] : u.point_positions) {
    auto pit = points_.find(pid);
    if (pit != points_.end() && X.allFinite()) pit->second.position = X;
  }
  for (const auto& [pid, kid] : u.erase_observations) eraseObservationLocked(pid, kid);
  for (PointId pid : u.erase_points) erasePointLocked(pid);
  // Normals follow the new geometry.
  for (const auto& [pid, X] : u.point_positions) {
    auto pit = points_.find(pid);
    if (pit == points_.end()) continue;
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    for (const auto& [kid, idx] : pit->second.observations) {
      auto kit = keyframes_.find(kid);
      if (kit != keyframes_.end()) n += (pit->second.position - kit->second.centre()).normalized();
    }
    if (n.norm() > 0) pit->second.normal = n.normalized();
  }
  if (u.erase_observations.empty() && u.erase_points.empty())
    bump();
  else
    bumpStructure();
}

void Map::applyStatisticsLocked(const std::vector<PointId>& visible, const std::vector<PointId>& found) {
  for (PointId pid : visible) {
    auto it = points_.find(pid);
    if (it != points_.end()) ++it->second.visible;
  }
  for (PointId pid : found) {
    auto it = points_.find(pid);
    if (it != points_.end()) ++it->second.found;
  }
}

void Map::updateStatistics(const std::vector<PointId>& visible, const std::vector<PointId>& found, bool wait) {
  std::unique_lock<std::shared_mutex> lock(mutex_, std::try_to_lock);
  if (!lock.owns_lock()) {
    if (!wait) {  // a writer holds the map: queue, count at a later call
      std::lock_guard<std::mutex> q(pending_mutex_);
      pending_visible_.insert(pending_visible_.end(), visible.begin(), visible.end());
      pending_found_.insert(pending_found_.end(), found.begin(), found.end());
      return;
    }
    lock = lockExclusive(mutex_);
  } else {
    ++t_lock_wait.acquisitions;
  }
  std::vector<PointId> queued_visible, queued_found;
  {
    std::lock_guard<std::mutex> q(pending_mutex_);
    queued_visible.swap(pending_visible_);
    queued_found.swap(pending_found_);
  }
  applyStatisticsLocked(queued_visible, queued_found);
  applyStatisticsLocked(visible, found);
}

void Map::increaseVisible(const std::vector<PointId>& pids) { updateStatistics(pids, {}, false); }
void Map::increaseFound(const std::vector<PointId>& pids) { updateStatistics({}, pids, false); }
void Map::flushTrackingStatistics() { updateStatistics({}, {}, true); }

void Map::transform(const Sim3& T) {
  auto lock = lockExclusive(mutex_);
  for (auto& [id, kf] : keyframes_) kf.T_world_cam = T.transformPose(kf.T_world_cam);
  for (auto& [id, r] : retired_) r.second = SE3(r.second.rotation(), T.scale() * r.second.translation());
  for (auto& [id, p] : points_) p.position = T * p.position;
  bump();
}

void Map::clear() {
  auto lock = lockExclusive(mutex_);
  keyframes_.clear();
  points_.clear();
  retired_.clear();
  bumpStructure();
}

std::pair<std::vector<Keyframe>, std::vector<MapPoint>> Map::snapshot() const {
  auto lock = lockShared(mutex_);
  std::pair<std::vector<Keyframe>, std::vector<MapPoint>> out;
  out.first.reserve(keyframes_.size());
  for (const auto& [id, kf] : keyframes_) out.first.push_back(kf);
  out.second.reserve(points_.size());
  for (const auto& [id, p] : points_) out.second.push_back(p);
  std::sort(out.second.begin(), out.second.end(), [](const MapPoint& a, const MapPoint& b) { return a.id < b.id; });
  return out;
}

void Map::restore(std::vector<Keyframe> keyframes, std::vector<MapPoint> points) {
  std::map<KeyframeId, Keyframe> kfs;
  std::unordered_map<PointId, MapPoint> pts;
  KeyframeId next_kf = 0;
  PointId next_point = 0;
  for (Keyframe& kf : keyframes) {
    if (!kf.frame) fail("Map::restore: keyframe {} without a frame", kf.id);
    if (kf.id < 0) fail("Map::restore: keyframe id {} < 0", kf.id);
    if (kf.points.size() != kf.frame->keypoints.size())
      fail("Map::restore: keyframe {}: {} point slots for {} keypoints", kf.id, kf.points.size(),
           kf.frame->keypoints.size());
    next_kf = std::max(next_kf, kf.id + 1);
    const KeyframeId id = kf.id;
    if (!kfs.emplace(id, std::move(kf)).second) fail("Map::restore: keyframe id {} twice", id);
  }
  for (MapPoint& p : points) {
    if (p.id < 0) fail("Map::restore: point id {} < 0", p.id);
    for (const auto& [kid, idx] : p.observations) {
      auto it = kfs.find(kid);
      if (it == kfs.end()) fail("Map::restore: point {} observed by unknown keyframe {}", p.id, kid);
      if (idx < 0 || idx >= static_cast<int>(it->second.points.size()) || it->second.points[idx] != p.id)
        fail("Map::restore: point {}: keyframe {} keypoint {} does not name it", p.id, kid, idx);
    }
    next_point = std::max(next_point, p.id + 1);
    const PointId id = p.id;
    if (!pts.emplace(id, std::move(p)).second) fail("Map::restore: point id {} twice", id);
  }
  for (const auto& [kid, kf] : kfs)
    for (size_t i = 0; i < kf.points.size(); ++i) {
      const PointId pid = kf.points[i];
      if (pid == kNoPoint) continue;
      auto it = pts.find(pid);
      if (it == pts.end()) fail("Map::restore: keyframe {} keypoint {} names unknown point {}", kid, i, pid);
      auto oit = it->second.observations.find(kid);
      if (oit == it->second.observations.end() || oit->second != static_cast<int>(i))
        fail("Map::restore: keyframe {} keypoint {} names point {}, which does not list it", kid, i, pid);
    }
  auto lock = lockExclusive(mutex_);
  keyframes_ = std::move(kfs);
  points_ = std::move(pts);
  retired_.clear();
  next_kf_ = std::max(next_kf_, next_kf);
  next_point_ = std::max(next_point_, next_point);
  bumpStructure();
}

std::optional<SE3> Map::resolvePose(KeyframeId id) const {
  auto lock = lockShared(mutex_);
  SE3 T_chain;  // T_parent_..._id accumulated
  for (int hops = 0; hops < 100000; ++hops) {
    auto kit = keyframes_.find(id);
    if (kit != keyframes_.end()) return kit->second.T_world_cam * T_chain;
    auto rit = retired_.find(id);
    if (rit == retired_.end()) return std::nullopt;
    T_chain = rit->second.second * T_chain;
    id = rit->second.first;
  }
  return std::nullopt;
}

std::optional<Keyframe> Map::keyframe(KeyframeId id) const {
  auto lock = lockShared(mutex_);
  auto it = keyframes_.find(id);
  if (it == keyframes_.end()) return std::nullopt;
  return it->second;
}

std::optional<MapPoint> Map::point(PointId id) const {
  auto lock = lockShared(mutex_);
  auto it = points_.find(id);
  if (it == points_.end()) return std::nullopt;
  return it->second;
}

std::vector<Keyframe> Map::keyframes() const {
  auto lock = lockShared(mutex_);
  std::vector<Keyframe> out;
  out.reserve(keyframes_.size());
  for (const auto& [id, kf] : keyframes_) out.push_back(kf);
  return out;
}

std::vector<KeyframeId> Map::keyframeIds() const {
  auto lock = lockShared(mutex_);
  std::vector<KeyframeId> out;
  for (const auto& [id, kf] : keyframes_) out.push_back(id);
  return out;
}

std::vector<TimedPose> Map::keyframePoses() const {
  auto lock = lockShared(mutex_);
  std::vector<TimedPose> out;
  out.reserve(keyframes_.size());
  for (const auto& [id, kf] : keyframes_) out.push_back({kf.timestamp(), kf.T_world_cam});
  return out;
}

std::vector<MapPoint> Map::points() const {
  auto lock = lockShared(mutex_);
  std::vector<MapPoint> out;
  out.reserve(points_.size());
  for (const auto& [id, p] : points_) out.push_back(p);
  std::sort(out.begin(), out.end(), [](const MapPoint& a, const MapPoint& b) { return a.id < b.id; });
  return out;
}

std::vector<MapPoint> Map::points(const std::vector<PointId>& ids) const {
  auto lock = lockShared(mutex_);
  std::vector<MapPoint> out;
  out.reserve(ids.size());
  for (PointId id : ids) {
    auto it = points_.find(id);
    if (it != points_.end()) out.push_back(it->second);
  }
  return out;
}

std::vector<Map::PointSummary> Map::pointSummaries(const std::vector<PointId>& ids) const {
  auto lock = lockShared(mutex_);
  std::vector<PointSummary> out(ids.size());
  for (size_t i = 0; i < ids.size(); ++i) {
    auto it = points_.find(ids[i]);
    if (it == points_.end()) continue;
    out[i].position = it->second.position;
    out[i].observations = int(it->second.observations.size());
    out[i].found_ratio = it->second.foundRatio();
  }
  return out;
}

std::optional<KeyframeId> Map::lastKeyframeId() const {
  auto lock = lockShared(mutex_);
  if (keyframes_.empty()) return std::nullopt;
  return keyframes_.rbegin()->first;
}

size_t Map::numKeyframes() const {
  auto lock = lockShared(mutex_);
  return keyframes_.size();
}

size_t Map::numPoints() const {
  auto lock = lockShared(mutex_);
  return points_.size();
}

std::vector<std::pair<KeyframeId, int>> Map::covisibleLocked(KeyframeId id, int min_shared) const {
  auto kit = keyframes_.find(id);
  if (kit == keyframes_.end()) return {};
  std::unordered_map<KeyframeId, int> counts;
  for (PointId pid : kit->second.points) {
    if (pid == kNoPoint) continue;
    auto pit = points_.find(pid);
    if (pit == points_.end()) continue;
    for (const auto& [other, idx] : pit->second.observations)
      if (other != id) ++counts[other];
  }
  std::vector<std::pair<KeyframeId, int>> out;
  for (const auto& [k, c] : counts)
    if (c >= min_shared) out.emplace_back(k, c);
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) {
    return a.second != b.second ? a.second > b.second : a.first > b.first;
  });
  return out;
}

std::vector<std::pair<KeyframeId, int>> Map::covisibleKeyframes(KeyframeId id, int min_shared) const {
  auto lock = lockShared(mutex_);
  return covisibleLocked(id, min_shared);
}

std::vector<PointId> Map::pointsSeenBy(const std::vector<KeyframeId>& kfs) const {
  auto lock = lockShared(mutex_);
  std::set<PointId> ids;
  for (KeyframeId k : kfs) {
    auto kit = keyframes_.find(k);
    if (kit == keyframes_.end()) continue;
    for (PointId pid : kit->second.points)
      if (pid != kNoPoint && points_.count(pid)) ids.insert(pid);
  }
  return {ids.begin(), ids.end()};
}

bool Map::localMapForTracking(KeyframeId ref, int max_keyframes, TrackingLocalMap* out, bool wait) const {
  std::shared_lock<std::shared_mutex> lock(mutex_, std::try_to_lock);
  if (!lock.owns_lock()) {
    if (!wait) return false;
    lock = lockShared(mutex_);
  } else {
    ++t_lock_wait.acquisitions;
  }
  auto rit = keyframes_.find(ref);
  if (rit == keyframes_.end()) return false;
  TrackingLocalMap& m = *out;
  m.ref = ref;
  m.structure_version = structureVersion();
  m.version = version();
  m.keyframes.assign(1, ref);
  // Covisible keyframes of ref by shared points (ties: newer first).
  const auto cov = covisibleLocked(ref, 1);
  for (const auto& [k, c] : cov) {
    if (static_cast<int>(m.keyframes.size()) >= max_keyframes) break;
    m.keyframes.push_back(k);
  }
  if (!keyframes_.empty()) {
    const KeyframeId last = keyframes_.rbegin()->first;
    if (std::find(m.keyframes.begin(), m.keyframes.end(), last) == m.keyframes.end()) m.keyframes.push_back(last);
  }
  m.keyframe_poses.clear();
  m.keyframe_num_points.clear();
  m.keyframe_num_established.clear();
  const size_t established = keyframes_.size() > 2 ? 3 : 2;
  std::vector<PointId> ids;
  for (KeyframeId k : m.keyframes) {
    const Keyframe& kf = keyframes_.at(k);
    m.keyframe_poses.push_back(kf.T_world_cam);
    const size_t before = ids.size();
    int n_established = 0;
    for (PointId pid : kf.points) {
      if (pid == kNoPoint) continue;
      ids.push_back(pid);
      auto pit = points_.find(pid);
      n_established += pit != points_.end() && pit->second.observations.size() >= established;
    }
    m.keyframe_num_points.push_back(static_cast<int>(ids.size() - before));
    m.keyframe_num_established.push_back(n_established);
  }
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  m.points.clear();
  m.points.reserve(ids.size());
  m.observer_begin.assign(1, 0);
  m.observer_begin.reserve(ids.size() + 1);
  m.observers.clear();
  for (PointId pid : ids) {
    auto pit = points_.find(pid);
    if (pit == points_.end() || pit->second.descriptor.empty()) continue;
    const MapPoint& p = pit->second;
    TrackingMapPoint t;
    t.id = static_cast<uint64_t>(p.id);
    t.p_world = p.position;
    t.descriptor = p.descriptor;  // shares the buffer: descriptors are replaced, never written in place
    m.points.push_back(std::move(t));
    for (const auto& [k, idx] : p.observations) m.observers.push_back(k);
    m.observer_begin.push_back(static_cast<int>(m.observers.size()));
  }
  return true;
}

bool Map::refreshLocalMap(TrackingLocalMap* m, bool wait) const {
  std::shared_lock<std::shared_mutex> lock(mutex_, std::try_to_lock);
  if (!lock.owns_lock()) {
    if (!wait) return false;
    lock = lockShared(mutex_);
  } else {
    ++t_lock_wait.acquisitions;
  }
  m->version = version();
  for (size_t i = 0; i < m->keyframes.size(); ++i) {
    auto kit = keyframes_.find(m->keyframes[i]);
    if (kit != keyframes_.end()) m->keyframe_poses[i] = kit->second.T_world_cam;
  }
  for (TrackingMapPoint& t : m->points) {
    auto pit = points_.find(static_cast<PointId>(t.id));
    if (pit != points_.end()) t.p_world = pit->second.position;
  }
  return true;
}

std::vector<RelocalizationCandidate> Map::relocalizationCandidates(const std::vector<KeyframeId>& order,
                                                                   size_t max_candidates,
                                                                   int neighbour_keyframes) const {
  auto lock = lockShared(mutex_);
  std::vector<RelocalizationCandidate> out;
  auto point = [this](PointId pid) -> std::optional<TrackingMapPoint> {
    if (pid == kNoPoint) return std::nullopt;
    const auto pit = points_.find(pid);
    if (pit == points_.end() || pit->second.descriptor.empty()) return std::nullopt;
    TrackingMapPoint t;
    t.id = static_cast<uint64_t>(pid);
    t.p_world = pit->second.position;
    t.descriptor = pit->second.descriptor;  // shares the buffer: descriptors are replaced, never written in place
    return t;
  };
  for (KeyframeId id : order) {
    if (out.size() >= max_candidates) break;
    const auto kit = keyframes_.find(id);
    if (kit == keyframes_.end()) continue;
    RelocalizationCandidate c;
    c.keyframe_id = static_cast<uint64_t>(id);
    c.T_world_cam = kit->second.T_world_cam;
    std::unordered_set<PointId> seen;
    for (PointId pid : kit->second.points)
      if (auto t = point(pid); t && seen.insert(pid).second) c.points.push_back(std::move(*t));
    const auto covisible = covisibleLocked(id, 1);
    const size_t n = std::min(covisible.size(), static_cast<size_t>(std::max(0, neighbour_keyframes)));
    for (size_t i = 0; i < n; ++i) {
      const auto nit = keyframes_.find(covisible[i].first);
      if (nit == keyframes_.end()) continue;
      for (PointId pid : nit->second.points)
        if (auto t = point(pid); t && seen.insert(pid).second) c.neighbours.push_back(std::move(*t));
    }
    out.push_back(std::move(c));
  }
  return out;
}

}  // namespace nerfslam
