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
// While tracking is lost (REP-105: map -> odom stays available, odometry carries the robot meanwhile)
// each image the tracking worker processes republishes the last correction published for the current
// map, unchanged, stamped with that image's stamp (no lookups; counted). Not while initialising
// (after a reset, or the system's own reinitialisation, the last correction belongs to a discarded
// map: forget()), and not before a correction was published for this map.
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

#include "nerfslam/core/bounded_queue.h"
#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"

namespace nerfslam::rosnode {

struct MapToOdomParams {
  bool enabled = false;  // ~publish_map_to_odom
  std::string odom_frame = "odom";
  std::string base_frame = "base_link";
  double tf_timeout = 0.1;  // s: the longest wait for the robot's transforms at an image's stamp

  template <class V>
  void visit(V& v) {
    v("publish_map_to_odom", enabled,
      "Publish the REP-105 correction map_frame -> odom_frame instead of map_frame -> camera_frame");
    v("odom_frame", odom_frame, "The robot's odometry frame (odom_frame -> base_frame on tf, from the robot)");
    v("base_frame", base_frame, "The robot's base (a static base_frame -> camera_frame on tf, from the robot)");
    v("tf_timeout", tf_timeout, "Seconds each image's map -> odom lookups may wait for the robot's transforms",
      check::range(0.0, 10.0));
  }
};

// The checks visit() cannot express, when enabled: the frames are not empty, distinct from each
// other and from ~map_frame and ~camera_frame. Returns an error message naming the parameter, or "".
std::string checkMapToOdomParams(const MapToOdomParams& p, const std::string& map_frame,
                                 const std::string& camera_frame);

class MapToOdomPublisher {
 public:
  MapToOdomPublisher(const MapToOdomParams& p, std::string map_frame, std::string camera_frame);
  ~MapToOdomPublisher();  // stops the thread
  MapToOdomPublisher(const MapToOdomPublisher&) = delete;
  MapToOdomPublisher& operator=(const MapToOdomPublisher&) = delete;

  // From the tracking worker, in the order of the images; none blocks.
  // A tracked image: its correction, after the lookups.
  void push(const ros::Time& stamp, const SE3& T_map_cam);
  // An image on which tracking is lost: the last correction of the current map again, at `stamp`.
  void pushLost(const ros::Time& stamp);
  // The map was discarded (a reset, reinitialising): the last correction is not repeated any more.
  void forget() { ++map_generation_; }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) const;
  std::string summary() const;  // for the node's shutdown line

 private:
  struct Item {
    ros::Time stamp;
    SE3 T_map_cam;
    uint64_t map_generation = 0;  // forget() calls before it was pushed
    bool lost = false;            // pushLost(): repeat the last correction
  };
  void enqueue(Item item);
  void repeat(const Item& item);
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

  std::atomic<uint64_t> map_generation_{0};  // the tracking worker's (forget())
  // The lookup thread's last correction and the map it belongs to (repeated while lost).
  bool have_last_ = false;
  SE3 last_T_map_odom_;
  uint64_t last_generation_ = 0;

  std::atomic<uint64_t> published_{0}, no_odom_{0}, no_mount_{0}, repeated_{0}, lost_without_correction_{0};
  mutable std::mutex mutex_;
  std::string last_error_;  // of the last frame, "" when it was published
};

}  // namespace nerfslam::rosnode
