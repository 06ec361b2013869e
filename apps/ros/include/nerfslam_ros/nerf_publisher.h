#pragma once
// The "NeRF publisher" of the ROS nodes that run a NerfMapping (nerfslam_node, nerf_mapping_node):
// a thread of its own (niceness ~nerf_render_nice) that renders ~nerf_view / ~nerf_depth /
// ~nerf_cloud and serves ~save_map, never on the image callbacks or a tracking worker. Renders and
// saves read a copy of the model taken under NerfMapping::withModel, which pauses NeRF training (not
// tracking) only for the copy. Also the ROS-only parameters of those topics (docs/ros.md).
#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <cmath>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/system/nerf_mapping.h"
#include "nerfslam/system/slam_system.h"
#include "nerfslam_ros/ros_params.h"

namespace nerfslam::rosnode {

// The ROS-only parameters of the nodes with a NerfPublisher (nerfslam_node, tracking_node for
// ~save_map, nerf_mapping_node): the frames, the NeRF topics and ~save_map. The NeRF itself is the
// library's (SystemOptions::nerf); docs/ros.md has the table.
struct NerfTopicsOptions {
  std::string map_frame = "map";
  std::string camera_frame = "camera_optical_frame";
  double nerf_publish_period = 2.0;
  double nerf_cloud_period = 10.0;
  std::string nerf_cloud_source = "depth";
  int nerf_cloud_views = 4;
  int nerf_cloud_stride = 2;
  int nerf_render_threads = 1;
  int nerf_render_nice = 10;
  std::string map_dir = "nerfslam_map";
  double occupancy_period = 5.0;
  double occupancy_resolution = 0.0;
  double occupancy_band_lo = 0.05, occupancy_band_hi = 0.9;
  double occupancy_budget = 1.0 / 16;
  int occupancy_pixel_stride = 8;
  std::string occupancy_dir = "nerfslam_occupancy";

  template <class V>
  void visit(V& v) {
    v("map_frame", map_frame, "Fixed frame of tf, poses, path, points, markers and the NeRF cloud", notEmpty());
    v("camera_frame", camera_frame, "Child frame of the tf (OpenCV optical axes); differs from map_frame", notEmpty());
    v("nerf_publish_period", nerf_publish_period, "Seconds between ~nerf_view / ~nerf_depth renders",
      check::positive<double>());
    v("nerf_cloud_period", nerf_cloud_period, "Seconds between ~nerf_cloud exports", check::positive<double>());
    v("nerf_cloud_source", nerf_cloud_source,
      "depth: depth renders of the newest training views; density: the density grid",
      check::oneOf({"depth", "density"}));
    v("nerf_cloud_views", nerf_cloud_views, "Newest training views in the depth cloud", check::range(1, 64));
    v("nerf_cloud_stride", nerf_cloud_stride,
      "Depth cloud: views rendered at 1/stride of the training resolution, a point per pixel", check::range(1, 16));
    v("nerf_render_threads", nerf_render_threads, "Threads of each render and cloud export", check::range(1, 64));
    v("nerf_render_nice", nerf_render_nice,
      "Niceness of the NeRF publisher thread (10: views before training, after tracking)", check::range(0, 19));
    v("map_dir", map_dir,
      "Folder ~save_map writes (re-read at each call; relative: to the working directory, ROS_HOME under "
      "roslaunch)",
      notEmpty());
    v("occupancy_period", occupancy_period, "Seconds between updates of ~occupancy and ~occupied_voxels (0: never)",
      check::range(0.0, 1e6));
    v("occupancy_resolution", occupancy_resolution,
      "Voxel and cell side of the occupancy maps, in map units (0: 1/160 of the mapped region's diagonal)",
      check::range(0.0, 1e3));
    v("occupancy_band_lo", occupancy_band_lo,
      "~occupancy: lowest height projected, as a fraction of the cameras' median height above the floor",
      check::range(-10.0, 10.0));
    const double lo = occupancy_band_lo;
    v("occupancy_band_hi", occupancy_band_hi,
      "~occupancy: highest height projected, as a fraction of the cameras' median height above the floor; > "
      "occupancy_band_lo",
      Check<double>([lo](const double& x) -> std::string {
        if (!std::isfinite(x) || x > 10) return "must be a finite number <= 10";
        return x > lo ? "" : "must be > occupancy_band_lo";
      }));
    v("occupancy_budget", occupancy_budget,
      "Share of the voxels whose density each update re-evaluates (the oldest first; the rays are re-cast every "
      "time); a new map region or a NeRF box re-fit rebuilds the whole map",
      check::range(1e-4, 1.0));
    v("occupancy_pixel_stride", occupancy_pixel_stride, "One keyframe ray per N x N training-view pixels",
      check::range(1, 256));
    v("occupancy_dir", occupancy_dir,
      "Folder ~save_occupancy writes occupancy.bt/.ot and map.yaml/.pgm to (relative: as map_dir)", notEmpty());
  }
};

// A relative ~map_dir is taken relative to the working directory (ROS_HOME under roslaunch).
std::filesystem::path resolveMapDir(const std::string& dir);
double wallSeconds();

// The exit status spinNode() returns once the node is destroyed (0 unless set: a fatal error found
// while running, e.g. a ~map of another camera, or a failed save at shutdown).
inline std::atomic<int>& nodeExitCode() {
  static std::atomic<int> code{0};
  return code;
}

// The nodes' main(): reads the parameters with `load` (an error is a ROS_FATAL and exit code 1), then
// runs a `Node(nh, pnh, params)` under ros::spin(); exceptions are fatal too. Call after ros::init.
template <class Node, class Params, class Load>
int spinNode(Params& params, Load load) {
  ros::NodeHandle nh, pnh("~");
  try {
    if (const std::string err = load(pnh, params); !err.empty()) {
      ROS_FATAL("%s", err.c_str());
      return 1;
    }
    Node node(nh, pnh, params);
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("%s", e.what());
    return 1;
  }
  return nodeExitCode().load();
}

// What the publisher renders and saves: the running map and NeRF, kept alive by `owner` while used.
struct MapSource {
  std::shared_ptr<const void> owner;
  const Map* map = nullptr;
  NerfMapping* nerf = nullptr;  // null: no NeRF (~save_map saves the sparse map alone)
  std::shared_ptr<const Camera> camera;
  SystemOptions options;
  uint64_t generation = 0;
  // What ~save_map saves when not `map` (e.g. a copy without what the map folder format refuses).
  std::function<std::shared_ptr<const Map>()> map_to_save;
};

// The pose ~nerf_view is rendered from, and the stamp of its image.
struct ViewPose {
  SE3 T_world_cam;
  ros::Time stamp;
  uint64_t generation = 0;
};

class NerfPublisher {
 public:
  using SourceFn = std::function<std::shared_ptr<const MapSource>()>;
  using PoseFn = std::function<std::optional<ViewPose>()>;
  // Advertises the NeRF topics (when `nerf`: the node trains a NeRF) and ~save_map on `pnh`. `source`
  // and `pose` are called from the publisher thread; a view is rendered only from a pose of the
  // source's generation.
  NerfPublisher(ros::NodeHandle pnh, NerfTopicsOptions p, bool nerf, SourceFn source, PoseFn pose);
  ~NerfPublisher();
  NerfPublisher(const NerfPublisher&) = delete;
  NerfPublisher& operator=(const NerfPublisher&) = delete;

  void start();
  void stop();  // joins the thread; idempotent

  // NeRF fields (when `nerf`) and the map saves, for the node's diagnostics.
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) const;
  // "N NeRF renders (mean X ms), N NeRF clouds, N map saves (N failed)", for the shutdown summary.
  std::string summary() const;
  uint64_t renders() const { return renders_; }

  // Saves the map folder (the map and the NeRF model of the current source) into `dir`, as ~save_map
  // does; `message` says what was saved or why not. Any thread, but not while the publisher thread
  // runs (after stop(): the node's shutdown, ~save_on_shutdown). ~save_map calls it on that thread.
  enum class SaveOutcome { kSaved, kNothingToSave, kFailed };
  SaveOutcome saveMap(const std::filesystem::path& dir, std::string* message);

 private:
  class ModelCopy;
  void run();
  void publishView();
  void publishCloud();
  void updateOccupancy(bool force);
  bool onSaveOccupancy(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res);
  bool updateModelCopy(const NerfMapping& nerf);
  bool onSaveMap(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res);

  ros::NodeHandle pnh_;
  NerfTopicsOptions p_;
  bool nerf_ = true;
  SourceFn source_;
  PoseFn pose_;
  ros::CallbackQueue queue_;  // before everything registered on it
  ros::NodeHandle queue_nh_;
  ros::Publisher view_pub_, depth_pub_, cloud_pub_, occupancy_pub_, voxels_pub_;
  ros::ServiceServer save_srv_, save_occupancy_srv_;
  struct Occupancy;
  std::unique_ptr<Occupancy> occupancy_;   // publisher thread only
  std::unique_ptr<ModelCopy> model_copy_;  // publisher thread only
  std::thread thread_;
  std::atomic<bool> stopping_{false};

  std::atomic<uint64_t> renders_{0}, clouds_{0}, cloud_points_last_{0}, render_errors_{0}, saves_{0}, save_failures_{0};
  std::atomic<double> render_ms_last_{0}, render_ms_sum_{0}, cloud_ms_last_{0}, lock_wait_ms_last_{0}, copy_ms_last_{0},
      samples_per_ray_last_{0}, occupied_last_{0}, occupancy_ms_last_{0};
  std::atomic<uint64_t> occupancy_updates_{0}, occupancy_rebuilds_{0}, occupancy_errors_{0};
  mutable std::mutex saved_mutex_;
  std::string last_saved_;
};

}  // namespace nerfslam::rosnode
