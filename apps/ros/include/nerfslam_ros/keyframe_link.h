#pragma once
// The off-board mapping link (docs/ros.md, "Off-board mapping"): tracking_node sends its sparse map's
// keyframes (nerfslam/MapKeyframe on ~keyframes_out) and their bundle-adjusted poses
// (nerfslam/KeyframePoses on ~keyframe_poses); nerf_mapping_node keeps a replica of the map from them
// and trains an unchanged NerfMapping on it.
//
//   KeyframeSender  tracking side: subscribes to the SlamSystem's KeyframeBus (the same feed the NeRF
//                   mapping thread reads in nerfslam_node) and publishes, from a thread of its own,
//                   every keyframe the mapping inserts, then the poses of every keyframe it sent
//                   (after each keyframe, and whenever Map::version() changed, at most every
//                   `poses_period` s).
//   MapReplica      mapping side: a Map holding the sent keyframes (image, calibration, pose; no
//                   features) with the tracking map's ids and the tracking map's point positions.
//                   Messages are ordered by their `seq` (the two topics are separate connections):
//                   older data never overwrites newer. Culled keyframes leave the replica as they
//                   left the tracking map (Map::eraseKeyframe with a parent), so resolvePose() and
//                   keyframes() agree with the tracking map after each update. A new session (the
//                   tracking node's ~reset or restart) empties it, which resets the NeRF as a map
//                   reset does in nerfslam_node.
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <ros/ros.h>

#include "nerfslam/KeyframePoses.h"
#include "nerfslam/MapKeyframe.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/mapping/mapping_thread.h"
#include "nerfslam/system/slam_system.h"

namespace nerfslam::rosnode {

class KeyframeSender {
 public:
  // Advertises `keyframes_out` and `keyframe_poses` on `pnh`.
  KeyframeSender(ros::NodeHandle pnh, std::string map_frame, double poses_period);
  ~KeyframeSender();
  KeyframeSender(const KeyframeSender&) = delete;
  KeyframeSender& operator=(const KeyframeSender&) = delete;

  // Follows `system` from now on (call it before the system's first frame, so that no keyframe is
  // missed); a new session, replacing the previous system. nullptr: follow nothing.
  void attach(std::shared_ptr<SlamSystem> system);
  void start();
  void stop();  // sends the last pose update, joins; idempotent

  uint64_t keyframesSent() const { return keyframes_sent_; }
  uint64_t poseUpdatesSent() const { return poses_sent_; }
  uint64_t keyframesDropped() const { return dropped_; }  // by the bus queue (the sender fell behind)
  uint32_t session() const { return session_id_; }

 private:
  struct Session;
  void run();
  void sendKeyframe(Session& s, const KeyframeEvent& ev);
  void sendPoses(Session& s, uint64_t map_version);

  ros::NodeHandle pnh_;
  std::string map_frame_;
  double poses_period_;
  ros::Publisher keyframes_pub_, poses_pub_;
  std::mutex mutex_;
  std::shared_ptr<Session> session_;  // under mutex_
  uint32_t session_base_;             // session ids differ across resets and node restarts
  uint32_t attaches_ = 0;             // under mutex_
  std::atomic<uint32_t> session_id_{0};
  std::thread thread_;
  std::atomic<bool> stopping_{false};
  std::atomic<uint64_t> keyframes_sent_{0}, poses_sent_{0}, dropped_{0};
};

class MapReplica {
 public:
  MapReplica();
  Map& map() { return map_; }
  const Map& map() const { return map_; }

  // A keyframe message: returns the event for the NeRF's KeyframeBus when the keyframe is new to the
  // replica (nullopt: a repeat, a stale message, or an image the conversions refuse, which throws).
  std::optional<KeyframeEvent> apply(const MapKeyframe& m);
  // A pose update: false when it is older than one already applied (ignored).
  bool apply(const KeyframePoses& m);

  // The replica's keyframes alone (images and poses; no points: a map folder point needs two
  // observations), what nerf_mapping_node's ~save_map writes.
  std::shared_ptr<const Map> keyframesOnly() const;
  // Calibration of the newest keyframe (null before the first).
  std::shared_ptr<const Camera> camera() const;
  uint32_t session() const { return session_; }
  uint64_t keyframesReceived() const { return keyframes_received_; }
  uint64_t poseUpdatesApplied() const { return poses_applied_; }
  uint64_t staleMessages() const { return stale_; }
  uint64_t sessions() const { return sessions_; }
  // The seq of the newest pose update applied (0: none).
  uint64_t posesSeq() const { return poses_seq_; }

 private:
  struct Entry {
    std::shared_ptr<const Frame> frame;
    SE3 pose;
    uint64_t seq = 0;  // of the data in `pose`
    bool culled = false;
  };
  struct PendingPose {
    SE3 pose;
    uint64_t seq = 0;
    bool culled = false;
  };
  // False (message ignored) for a session left before; another new one empties the replica.
  bool enterSession(uint32_t session);
  void setPoints(const std::vector<geometry_msgs::Point32>& points, uint64_t seq);
  void rebuild();

  Map map_;
  mutable std::mutex mutex_;  // the bookkeeping below (callbacks run on one thread; diagnostics read)
  std::map<KeyframeId, Entry> entries_;
  std::map<KeyframeId, PendingPose> pending_;  // poses of keyframes whose message has not arrived
  std::map<KeyframeId, uint64_t> removed_;     // id -> seq of the update that removed it
  std::set<uint32_t> left_sessions_;
  std::vector<Eigen::Vector3d> points_;
  uint64_t points_seq_ = 0;
  std::shared_ptr<const Camera> camera_;
  std::atomic<uint32_t> session_{0};
  std::atomic<uint64_t> poses_seq_{0};
  std::atomic<uint64_t> keyframes_received_{0}, poses_applied_{0}, stale_{0}, sessions_{0};
};

}  // namespace nerfslam::rosnode
