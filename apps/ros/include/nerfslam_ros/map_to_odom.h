#pragma once
// REP-105 map -> odom correction of the SLAM nodes (nerfslam_node, tracking_node), with
// ~publish_map_to_odom. The robot publishes odom -> ~base_frame (its odometry) and a static
// ~base_frame -> ~camera_frame (where the camera is mounted, optical axes); the node then publishes
// no map -> ~camera_frame (a tf frame has one parent) but, for each tracked image,
//   T_map_odom = T_map_cam * T_base_cam^-1 * T_odom_base^-1
// stamped with the image's stamp, T_odom_base and T_base_cam looked up at that stamp.
//
// The lookups run on a thread of their own (never on the image callbacks or the tracking worker),
// each waiting at most ~tf_timeout s for the robot's transforms to reach the stamp. The tracking
// worker hands over (stamp, T_map_cam) without blocking; when the lookups fall behind, the oldest
// waiting frames are dropped (counted). A frame whose transforms are missing (no odometry yet, a
// stamp outside what tf holds, no camera mount) gets no correction: counted, a throttled warning
// names the missing transform, diagnostics report it.
//
// Monocular SLAM: the map's scale is arbitrary, the odometry's metric. The correction places the
// odom frame so that map -> odom -> base -> camera is exactly the tracked camera pose; it is
// constant over time only when the map is metric. Otherwise its rotation is still constant (the
// map's orientation relative to odom), but its translation moves with the camera by (s - 1) times
// the camera-to-odom-origin vector (s: map units per metre). Nothing here estimates s.
#include <atomic>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>

#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/ros.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include "nerfslam/core/pose.h"
#include "nerfslam/mapping/bounded_queue.h"

namespace nerfslam::rosnode {

struct MapToOdomParams {
  bool enabled = false;  // ~publish_map_to_odom
  std::string odom_frame = "odom";
  std::string base_frame = "base_link";
  double tf_timeout = 0.1;  // s: the longest wait for the robot's transforms at an image's stamp
};

// Reads, prints and validates ~publish_map_to_odom, ~odom_frame, ~base_frame, ~tf_timeout (the frames
// only when enabled: non-empty, distinct from each other and from ~map_frame and ~camera_frame);
// returns an error message naming the parameter, or "".
std::string loadMapToOdomParams(ros::NodeHandle& pnh, MapToOdomParams& p, const std::string& map_frame,
                                const std::string& camera_frame);

class MapToOdomPublisher {
 public:
  MapToOdomPublisher(const MapToOdomParams& p, std::string map_frame, std::string camera_frame);
  ~MapToOdomPublisher();  // stops the thread
  MapToOdomPublisher(const MapToOdomPublisher&) = delete;
  MapToOdomPublisher& operator=(const MapToOdomPublisher&) = delete;

  // From the tracking worker: never blocks.
  void push(const ros::Time& stamp, const SE3& T_map_cam);

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) const;
  std::string summary() const;  // for the node's shutdown line

 private:
  struct Item {
    ros::Time stamp;
    SE3 T_map_cam;
  };
  void run();
  // T_target_source at `stamp`, waiting until `deadline` (ROS time); false with tf's message.
  bool lookup(const std::string& target, const std::string& source, const ros::Time& stamp, const ros::Time& deadline,
              SE3* T, std::string* error);
  void skip(std::atomic<uint64_t>& counter, const Item& item, const std::string& what, const std::string& error);

  MapToOdomParams p_;
  std::string map_frame_, camera_frame_;
  tf2_ros::Buffer buffer_;
  tf2_ros::TransformListener listener_;  // its own spinner thread
  tf2_ros::TransformBroadcaster broadcaster_;
  BoundedQueue<Item> queue_;
  std::thread thread_;

  std::atomic<uint64_t> published_{0}, no_odom_{0}, no_mount_{0};
  mutable std::mutex mutex_;
  std::string last_error_;  // of the last frame, "" when it was published
};

}  // namespace nerfslam::rosnode
