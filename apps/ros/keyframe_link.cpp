#include "nerfslam_ros/keyframe_link.h"

#include <chrono>

#include <opencv2/imgproc.hpp>

#include "nerfslam_ros/conversions.h"

namespace nerfslam::rosnode {
namespace {

double wallNow() { return ros::WallTime::now().toSec(); }

std::vector<geometry_msgs::Point32> pointPositions(const Map& map) {
  std::vector<geometry_msgs::Point32> out;
  const auto points = map.points();
  out.reserve(points.size());
  for (const auto& p : points) {
    geometry_msgs::Point32 q;
    q.x = static_cast<float>(p.position.x());
    q.y = static_cast<float>(p.position.y());
    q.z = static_cast<float>(p.position.z());
    out.push_back(q);
  }
  return out;
}

}  // namespace

// ---- KeyframeSender ----

struct KeyframeSender::Session {
  std::shared_ptr<SlamSystem> system;
  std::shared_ptr<KeyframeBus::Queue> queue;
  uint32_t id = 0;
  uint64_t seq = 0;
  std::set<KeyframeId> sent;      // keyframes published on keyframes_out
  std::set<KeyframeId> removed;   // of those, the ones the map cannot place any more
  uint64_t sent_version = ~0ull;  // Map::version() of the last pose update
  double last_poses = -1e9;       // wall time of the last pose update
};

KeyframeSender::KeyframeSender(ros::NodeHandle pnh, std::string map_frame, double poses_period)
    : pnh_(pnh), map_frame_(std::move(map_frame)), poses_period_(poses_period) {
  // Every keyframe matters to the receiver: a deep queue (a keyframe is one image).
  keyframes_pub_ = pnh_.advertise<MapKeyframe>("keyframes_out", 100);
  poses_pub_ = pnh_.advertise<KeyframePoses>("keyframe_poses", 10, true);
  session_base_ = static_cast<uint32_t>(
      std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
          .count());
}

KeyframeSender::~KeyframeSender() { stop(); }

void KeyframeSender::attach(std::shared_ptr<SlamSystem> system) {
  std::shared_ptr<Session> s;
  if (system) {
    s = std::make_shared<Session>();
    s->system = std::move(system);
    // Never blocks the mapping thread: a sender that falls this far behind loses the oldest.
    s->queue = s->system->keyframeBus().subscribe(1000, OverflowPolicy::kDropOldest);
    // A system started from a saved map (~map): its keyframes are in the map before any is inserted;
    // they go out first, as if inserted (empty for a new map).
    const Map& map = s->system->map();
    for (const KeyframeId id : map.keyframeIds())
      if (const std::optional<Keyframe> kf = map.keyframe(id))
        s->queue->tryPush(KeyframeEvent{kf->id, kf->T_world_cam, kf->frame});
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (s) {
    s->id = session_base_ + ++attaches_;
    if (s->id == 0) s->id = session_base_ + ++attaches_;  // 0: "no session" for receivers
    session_id_ = s->id;
  }
  session_ = std::move(s);
}

void KeyframeSender::start() {
  if (!thread_.joinable()) thread_ = std::thread([this] { run(); });
}

void KeyframeSender::stop() {
  stopping_ = true;
  if (thread_.joinable()) thread_.join();
}

void KeyframeSender::run() {
  while (!stopping_ && ros::ok()) {
    std::shared_ptr<Session> s;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      s = session_;
    }
    if (!s || s->queue->closed()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      continue;
    }
    bool sent_keyframe = false;
    if (auto ev = s->queue->popFor(std::chrono::milliseconds(50))) {
      sendKeyframe(*s, *ev);
      sent_keyframe = true;
      dropped_ = s->queue->dropped();
    }
    // After each keyframe (the receiver gets every pose), and when the map changed.
    const uint64_t v = s->system->map().version();
    if (!s->sent.empty() && (sent_keyframe || (v != s->sent_version && wallNow() - s->last_poses >= poses_period_)))
      sendPoses(*s, v);
  }
}

void KeyframeSender::sendKeyframe(Session& s, const KeyframeEvent& ev) {
  if (!ev.frame) return;
  const Frame& f = *ev.frame;
  const Map& map = s.system->map();
  MapKeyframe m;
  m.header.stamp = ros::Time(f.timestamp);
  m.header.frame_id = map_frame_;
  m.session = s.id;
  m.seq = ++s.seq;
  m.id = static_cast<uint64_t>(ev.id);
  m.frame_id = f.id;
  const cv::Mat& image = !f.colour.empty() ? f.colour : f.pyramid.at(0);
  m.image = *rosbridge::toImageMsg(image, m.header);
  m.camera_info = rosbridge::toCameraInfo(f.camera, m.header);
  m.T_world_cam = rosbridge::toPose(map.resolvePose(ev.id).value_or(ev.T_world_cam));
  m.points = pointPositions(map);
  keyframes_pub_.publish(m);
  s.sent.insert(ev.id);
  ++keyframes_sent_;
}

void KeyframeSender::sendPoses(Session& s, uint64_t map_version) {
  const Map& map = s.system->map();
  KeyframePoses m;
  m.header.stamp = ros::Time::now();
  m.header.frame_id = map_frame_;
  m.session = s.id;
  m.seq = ++s.seq;
  const std::vector<KeyframeId> present = map.keyframeIds();
  const std::set<KeyframeId> in_map(present.begin(), present.end());
  for (const KeyframeId id : s.sent) {
    if (s.removed.count(id)) continue;
    const std::optional<SE3> pose = map.resolvePose(id);
    if (!pose) {
      s.removed.insert(id);
      continue;
    }
    m.ids.push_back(static_cast<uint64_t>(id));
    m.poses.push_back(rosbridge::toPose(*pose));
    if (!in_map.count(id)) m.culled_ids.push_back(static_cast<uint64_t>(id));
  }
  for (const KeyframeId id : s.removed) m.removed_ids.push_back(static_cast<uint64_t>(id));
  m.points = pointPositions(map);
  poses_pub_.publish(m);
  s.sent_version = map_version;
  s.last_poses = wallNow();
  ++poses_sent_;
}

// ---- MapReplica ----

MapReplica::MapReplica() = default;

bool MapReplica::enterSession(uint32_t session) {
  if (session == session_) return true;
  if (left_sessions_.count(session)) {
    ++stale_;
    return false;
  }
  if (session_ != 0) {
    left_sessions_.insert(session_);
    ROS_WARN("the tracking node started a new map (session %u after %u): the replica and the NeRF start again", session,
             session_.load());
  }
  session_ = session;
  ++sessions_;
  entries_.clear();
  pending_.clear();
  removed_.clear();
  points_.clear();
  points_seq_ = 0;
  poses_seq_ = 0;
  return true;
}

void MapReplica::setPoints(const std::vector<geometry_msgs::Point32>& points, uint64_t seq) {
  if (seq <= points_seq_) return;
  points_seq_ = seq;
  points_.clear();
  points_.reserve(points.size());
  for (const auto& p : points) points_.emplace_back(p.x, p.y, p.z);
}

std::optional<KeyframeEvent> MapReplica::apply(const MapKeyframe& m) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!enterSession(m.session)) return std::nullopt;
  ++keyframes_received_;
  const auto id = static_cast<KeyframeId>(m.id);
  const SE3 pose = rosbridge::fromPose(m.T_world_cam);
  if (auto it = entries_.find(id); it != entries_.end()) {  // a repeat: at most a newer pose
    if (m.seq > it->second.seq) {
      it->second.pose = pose;
      it->second.seq = m.seq;
      setPoints(m.points, m.seq);
      rebuild();
    }
    return std::nullopt;
  }
  if (auto it = removed_.find(id); it != removed_.end() && it->second >= m.seq) {
    ++stale_;
    return std::nullopt;  // an update sent after this message already removed it
  }
  auto frame = std::make_shared<Frame>();
  frame->id = m.frame_id;
  frame->timestamp = m.header.stamp.toSec();
  frame->camera = rosbridge::fromCameraInfo(m.camera_info, "keyframe camera_info");  // throws
  const bool colour = m.image.encoding != "mono8" && m.image.encoding != "mono16";
  cv::Mat grey;
  if (colour) {
    frame->colour = rosbridge::fromImageMsg(m.image, rosbridge::ImageTarget::kBgr8);  // throws
    cv::cvtColor(frame->colour, grey, cv::COLOR_BGR2GRAY);
  } else {
    grey = rosbridge::fromImageMsg(m.image, rosbridge::ImageTarget::kGray8);
  }
  if (grey.cols != frame->camera.width || grey.rows != frame->camera.height)
    throw std::runtime_error("keyframe " + std::to_string(id) + ": image " + std::to_string(grey.cols) + "x" +
                             std::to_string(grey.rows) + " for a " + std::to_string(frame->camera.width) + "x" +
                             std::to_string(frame->camera.height) + " camera_info");
  frame->pyramid = {grey};
  frame->level_scale = {1.0};
  Entry e;
  e.frame = frame;
  e.pose = pose;
  e.seq = m.seq;
  if (auto it = pending_.find(id); it != pending_.end()) {
    if (it->second.seq > e.seq) {
      e.pose = it->second.pose;
      e.seq = it->second.seq;
      e.culled = it->second.culled;
    }
    pending_.erase(it);
  }
  entries_[id] = e;
  camera_ = std::make_shared<const Camera>(frame->camera);
  setPoints(m.points, m.seq);
  rebuild();
  // As MappingThread publishes it: the pose at insertion (NerfMapping reads the current one from the map).
  return KeyframeEvent{id, pose, frame};
}

bool MapReplica::apply(const KeyframePoses& m) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!enterSession(m.session)) return false;
  if (m.seq <= poses_seq_ || m.ids.size() != m.poses.size()) {
    ++stale_;
    return false;
  }
  const std::set<uint64_t> culled(m.culled_ids.begin(), m.culled_ids.end());
  for (size_t i = 0; i < m.ids.size(); ++i) {
    const auto id = static_cast<KeyframeId>(m.ids[i]);
    const SE3 pose = rosbridge::fromPose(m.poses[i]);
    auto it = entries_.find(id);
    if (it == entries_.end()) {
      pending_[id] = PendingPose{pose, m.seq, culled.count(m.ids[i]) > 0};
      continue;
    }
    if (m.seq <= it->second.seq) continue;
    it->second.pose = pose;
    it->second.seq = m.seq;
    it->second.culled = culled.count(m.ids[i]) > 0;
  }
  for (const uint64_t rid : m.removed_ids) {
    const auto id = static_cast<KeyframeId>(rid);
    auto it = entries_.find(id);
    if (it != entries_.end() && it->second.seq < m.seq) entries_.erase(it);
    pending_.erase(id);
    removed_[id] = std::max(removed_[id], m.seq);
  }
  setPoints(m.points, m.seq);
  poses_seq_ = m.seq;
  rebuild();
  ++poses_applied_;
  return true;
}

std::shared_ptr<const Map> MapReplica::keyframesOnly() const {
  auto out = std::make_shared<Map>(map_.camera());
  out->restore(map_.snapshot().first, {});
  return out;
}

std::shared_ptr<const Camera> MapReplica::camera() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return camera_;
}

void MapReplica::rebuild() {
  // The whole replica in one Map::restore (ids as the tracking map's; keyframes without features,
  // points without observations: what NerfMapping reads is poses, images and point positions).
  std::vector<Keyframe> kfs;
  kfs.reserve(entries_.size());
  for (const auto& [id, e] : entries_) {
    Keyframe kf;
    kf.id = id;
    kf.T_world_cam = e.pose;
    kf.frame = e.frame;
    kf.fixed = kfs.empty();
    kfs.push_back(std::move(kf));
  }
  std::vector<MapPoint> pts(points_.size());
  for (size_t i = 0; i < points_.size(); ++i) {
    pts[i].id = static_cast<PointId>(i);
    pts[i].position = points_[i];
  }
  map_.restore(std::move(kfs), std::move(pts));
  // Culled keyframes leave the map with a parent that stays, as in the tracking map: resolvePose()
  // gives the pose they were sent with until the next update.
  KeyframeId parent = -1;
  for (const auto& [id, e] : entries_)
    if (!e.culled) parent = id;
  for (const auto& [id, e] : entries_)
    if (e.culled) map_.eraseKeyframe(id, parent);
}

}  // namespace nerfslam::rosnode
