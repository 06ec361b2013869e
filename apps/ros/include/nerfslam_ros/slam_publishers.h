#pragma once
// What nerfslam_node and tracking_node publish about each processed frame (docs/ros.md,
// "nerfslam_node"): tf map -> camera (or the REP-105 map -> odom, map_to_odom.h), ~pose, ~path,
// ~map_points, ~keyframes and ~tracking_state. Everything but state() is called by the tracking
// worker only (SlamSystem::trajectory() must be called by the thread that tracks).
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>

#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <tf2_ros/transform_broadcaster.h>

#include "nerfslam/core/camera.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/system/slam_system.h"
#include "nerfslam_ros/map_to_odom.h"
#include "nerfslam_ros/node_params.h"

namespace nerfslam::rosnode {

// ~path without rebuilding the whole trajectory at every frame. A tracked frame's pose is appended
// (through its reference keyframe's current pose, as SlamSystem::trajectory() gives it); the whole
// path is rebuilt from trajectory() when the map changed since the last rebuild (Map::version():
// bundle adjustment, new or culled keyframes, also the tracking statistics) and `refresh_period` s
// have passed since it, and, once no frame is waiting, as soon as the map changed. So while the map
// changes the path follows it within `refresh_period` s, and once the map is still the last message
// is trajectory() (the poses exactly as it resolves them).
class PathBuilder {
 public:
  PathBuilder(std::string frame_id, double refresh_period);

  // After a frame of `system` (`rec`; null: no frame is waiting), from the thread that tracks it:
  // appends the frame's pose or rebuilds the path. `now`: seconds on a steady clock; `stamp`: the
  // message's. True when the path changed (publish it). Nothing before the system initialised.
  bool update(SlamSystem& system, const FrameRecord* rec, double now, const ros::Time& stamp);

  // A new system: the next update rebuilds.
  void clear();
  // Whether to rebuild now (`now`: seconds on a steady clock; `idle`: no frame waiting): never built
  // since clear(), or `map_version` differs from the last rebuild's and the period passed or idle.
  bool wantsRebuild(uint64_t map_version, double now, bool idle) const;
  void rebuild(const Trajectory& trajectory, uint64_t map_version, double now, const ros::Time& stamp);
  void append(double timestamp, const SE3& T_world_cam, const ros::Time& stamp);
  const nav_msgs::Path& path() const { return path_; }
  uint64_t rebuilds() const { return rebuilds_; }

 private:
  nav_msgs::Path path_;
  double refresh_period_;
  bool built_ = false;
  uint64_t built_version_ = 0;
  double built_at_ = 0;
  uint64_t rebuilds_ = 0;
};

class SlamPublishers {
 public:
  // Advertises on `pnh`; with p.odom.enabled, starts the map -> odom publisher.
  SlamPublishers(ros::NodeHandle pnh, const SlamNodeParams& p);

  // A processed frame (`system` tracked it on `camera`).
  void publishFrame(const ros::Time& stamp, const FrameRecord& rec, SlamSystem& system, const Camera& camera);
  // No frame came for a while: ~path catches up with the map's last changes.
  void idle(SlamSystem& system);
  // The system was replaced (reset, new calibration): a new path; map -> odom forgets its correction.
  void newSystem();
  void forgetMapToOdom();

  void publishState(const std::string& s);  // latched, on change
  std::string state() const;                // any thread
  MapToOdomPublisher* mapToOdom() { return map_to_odom_.get(); }
  // Stops the map -> odom thread; returns its summary for the node's shutdown line ("" without it).
  std::string stopMapToOdom();

 private:
  std::string stateName(const FrameRecord& rec) const;
  void updatePath(SlamSystem& system, const FrameRecord* rec);
  void publishMap(const ros::Time& stamp, const SlamSystem& system, const Camera& camera);

  std::string map_frame_, camera_frame_;
  double map_points_period_;
  int weak_inliers_;
  double frustum_scale_;
  ros::Publisher pose_pub_, path_pub_, points_pub_, keyframes_pub_, state_pub_;
  tf2_ros::TransformBroadcaster tf_;
  std::unique_ptr<MapToOdomPublisher> map_to_odom_;  // ~publish_map_to_odom
  PathBuilder path_;
  ros::Time last_stamp_;
  ros::WallTime last_map_publish_;
  mutable std::mutex state_mutex_;
  std::string state_;
};

}  // namespace nerfslam::rosnode
