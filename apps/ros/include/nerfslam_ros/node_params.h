#pragma once
// The parameters of nerfslam_node, tracking_node and nerf_mapping_node (docs/ros.md, "Parameters"):
// the library's options (SystemOptions, from ~config and by path, ros_params.h), each node's ROS-only
// options, and the aliases kept from before ~config (~max_features, ~nerf_threads, ...), all in one
// struct per node whose visit() lists them at the root of the private namespace.
#include <string>
#include <vector>

#include <ros/ros.h>

#include "nerfslam/core/options.h"
#include "nerfslam/system/slam_system.h"
#include "nerfslam_ros/map_to_odom.h"
#include "nerfslam_ros/nerf_publisher.h"
#include "nerfslam_ros/ros_params.h"
#include "nerfslam_ros/slam_node.h"

namespace nerfslam::rosnode {

enum class NodeKind { kSlam, kNerfMapping };  // nerfslam_node and tracking_node; nerf_mapping_node

// The aliases of a node: one table for all of them (node_params.cpp).
const std::vector<OptionAlias>& optionAliases(NodeKind node);

// The ROS-only options of nerfslam_node and tracking_node (besides NerfTopicsOptions and
// MapToOdomParams).
struct SlamNodeOptions {
  std::string camera_yaml;
  int queue_size = 2;
  bool wait_for_mapping = false;
  double map_points_period = 1.0;
  double path_refresh_period = 1.0;
  int weak_inliers = 60;
  double frustum_scale = 0.5;
  double keyframe_poses_period = 0.5;
  std::string calibration_change = "refuse";
  double stream_gap = 1.0;
  std::string map;  // a saved map folder to start from (system/map_store.h)
  std::string map_mode = "localize";
  bool save_on_shutdown = false;
  std::string save_on_shutdown_dir;
  double save_on_shutdown_timeout = 10.0;

  template <class V>
  void visit(V& v) {
    v("camera_yaml", camera_yaml,
      "Calibration file used instead of camera_info (our camera YAML or a ROS camera_info YAML; \"\": camera_info)");
    v("queue_size", queue_size, "Frames buffered before the oldest is dropped", check::positive<int>());
    v("wait_for_mapping", wait_for_mapping,
      "After each frame the worker waits until mapping is idle (offline-like accuracy; faster input is dropped)");
    v("map_points_period", map_points_period, "Seconds between ~map_points / ~keyframes (0: every frame)",
      check::nonNegative<double>());
    v("path_refresh_period", path_refresh_period,
      "Seconds between rebuilds of the whole ~path while the map changes; new frames are appended in between "
      "(0: rebuilt at every frame)",
      check::nonNegative<double>());
    v("weak_inliers", weak_inliers, "A frame tracked with fewer map inliers is 'weak' on ~tracking_state",
      check::nonNegative<int>());
    v("frustum_scale", frustum_scale, "Depth (map units) of the keyframe frustums on ~keyframes",
      check::positive<double>());
    v("keyframe_poses_period", keyframe_poses_period, "tracking_node: seconds between ~keyframe_poses updates",
      check::positive<double>());
    v("calibration_change", calibration_change,
      "refuse: frames whose camera_info differs from the map's calibration are refused; reset: they start a new map",
      check::oneOf({"refuse", "reset"}));
    v("stream_gap", stream_gap,
      "Seconds without images after which a frame stamped earlier starts a new stream; longer gaps are logged",
      check::positive<double>());
    v("map", map,
      "Saved map folder to start from (`nerfslam run --save-map`, ~save_map; relative: as ~map_dir): loaded at start, "
      "the node starts lost and relocalises in it (\"\": a new map)");
    v("map_mode", map_mode,
      "With ~map: localize (track against the map, never change it) or extend (keep mapping; the map's NeRF model "
      "trains on)");
    v("save_on_shutdown", save_on_shutdown,
      "At shutdown (SIGINT, rosnode kill, roslaunch's end) save the map folder (as ~save_map) before exiting");
    v("save_on_shutdown_dir", save_on_shutdown_dir, "Folder ~save_on_shutdown writes (\"\": ~map_dir)");
    v("save_on_shutdown_timeout", save_on_shutdown_timeout,
      "Seconds the shutdown with ~save_on_shutdown may take (stopping mapping and the save); after them the node "
      "exits with status 1, the folder keeping its previous map (roslaunch sends SIGTERM after 15 s)",
      check::positive<double>());
  }
};

// ~map_mode as the library's MapMode (kSlam without ~map).
MapMode mapModeOf(const SlamNodeOptions& o);

struct SlamNodeParams {
  SlamNodeMode mode = SlamNodeMode::kFull;  // not a parameter: the executable
  SystemOptions slam;                       // ~config, ~<option path>, the aliases
  SlamNodeOptions node;
  NerfTopicsOptions topics;
  MapToOdomParams odom;

  template <class V>
  void visit(V& v) {
    slam.visit(v);
    node.visit(v);
    topics.visit(v);
    odom.visit(v);
  }
};

struct NerfMappingNodeParams {
  SystemOptions slam;  // the same file as the tracking node's; nerf.* is what this node uses
  NerfTopicsOptions topics;

  template <class V>
  void visit(V& v) {
    slam.visit(v);
    topics.visit(v);
  }
};

// Read from the private namespace, printed and checked; "" or the errors, one a line (spinNode()
// makes them a ROS_FATAL and exit status 1). tracking_node trains no NeRF (nerf.enabled is false),
// nerf_mapping_node always does.
std::string loadSlamNodeParams(ros::NodeHandle& pnh, SlamNodeParams& p);
std::string loadNerfMappingNodeParams(ros::NodeHandle& pnh, NerfMappingNodeParams& p);

// The same from a parameter tree and without printing (tests): the report, with the checks between
// parameters that visit() cannot express among its errors.
ParamReport readSlamNodeParams(const XmlRpc::XmlRpcValue& tree, SlamNodeParams& p);
ParamReport readNerfMappingNodeParams(const XmlRpc::XmlRpcValue& tree, NerfMappingNodeParams& p);

}  // namespace nerfslam::rosnode
