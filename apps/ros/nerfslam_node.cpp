// nerfslam_node: the monocular SLAM system (nerfslam::SlamSystem) with its NeRF dense map as a ROS 1 node.
//
// Input: `image` + `camera_info` through image_transport's CameraSubscriber (remap them, e.g.
// image:=/camera/image_raw camera_info:=/camera/camera_info). With ~camera_yaml set, the calibration
// comes from that file instead (our camera YAML or a ROS camera_info YAML, nerfslam::loadCameraYaml)
// and only `image` is subscribed. Until a calibration arrives the node warns (throttled) and waits.
// Callbacks only check and enqueue: frames go into a bounded queue (the oldest are dropped and
// counted when tracking falls behind) and a worker thread feeds the system (colour images as BGR
// when the NeRF is on, so that it trains on colour; grey otherwise).
//
// Threads: ros::spin (image callbacks, ~reset, diagnostics), the tracking worker, the system's own
// mapping and NeRF training threads, and the "NeRF publisher" thread (niceness ~nerf_render_nice):
// renders ~nerf_view/~nerf_depth/~nerf_cloud and serves ~save_map. Rendering and saving never run
// on the image callbacks or the tracking worker; they read the model under NerfMapping::withModel,
// which pauses NeRF training (not tracking) for the render's duration.
//
// Published (private namespace unless noted):
//   tf                 ~map_frame -> ~camera_frame (T_map_camera at tracking time), per tracked frame
//   ~pose              geometry_msgs/PoseStamped, the same pose
//   ~path              nav_msgs/Path, every tracked frame resolved through its reference keyframe's
//                      bundle-adjusted pose (SlamSystem::trajectory()), frame ~map_frame
//   ~map_points        sensor_msgs/PointCloud2 x y z intensity (float32; intensity = number of
//                      keyframes observing the point), every ~map_points_period s, frame ~map_frame
//   ~keyframes         visualization_msgs/MarkerArray, one LINE_LIST of keyframe frustums
//   ~tracking_state    std_msgs/String: initializing | good | weak | lost (latched)
//   ~nerf_view         sensor_msgs/Image rgb8: the NeRF rendered from the last tracked pose at the
//                      NeRF's training resolution (camera NerfMapping::trainingCamera(), black
//                      background), frame ~camera_frame, stamp of that pose's image; every
//                      ~nerf_publish_period s while ~nerf_view or ~nerf_depth has a subscriber
//   ~nerf_depth        sensor_msgs/Image 32FC1: the same render's z-depth in map units (monocular:
//                      the map's arbitrary scale), NaN where the accumulated opacity is below 0.5
//   ~nerf_cloud        sensor_msgs/PointCloud2 x y z rgb, frame ~map_frame: depth renders of the
//                      ~nerf_cloud_views newest training views back-projected (nerf::depthPointCloud),
//                      or the density grid (nerf::densityPointCloud, ~nerf_cloud_source density);
//                      every ~nerf_cloud_period s while subscribed (latched)
//   /diagnostics       diagnostic_updater: frames received/tracked, dropped (queue), refused
//                      (encoding, size, timestamp), tracking ms, image callback ms, state, keyframes,
//                      map points; NeRF steps, samples/s, views, running PSNR, renders, map saves
// Services:
//   ~reset             std_srvs/Trigger: discards the map and starts a new system (reinitialises)
//   ~save_map          std_srvs/Trigger: saves the map folder (map_store.h saveMapFolder; with the
//                      NeRF model when there is one) to ~map_dir (re-read at each call); the reply's
//                      message is the folder's absolute path, or the error with success = false
//   ~set_localization_only  std_srvs/SetBool: data = true stops adding to the map (frames are
//                      tracked and relocalised against it; no keyframes, no reset when lost), false
//                      resumes mapping; applied from the next frame and kept across ~reset
//
// Parameters (printed and validated at start-up; an invalid value exits with status 1):
//   ~map_frame          string  "map"                   fixed frame of poses, path, points, markers
//   ~camera_frame       string  "camera_optical_frame"  child frame of the tf (OpenCV optical axes)
//   ~camera_yaml        string  ""                      calibration file used instead of camera_info
//   ~queue_size         int     2      (>= 1)           frames buffered before the oldest is dropped
//   ~wait_for_mapping   bool    false                   after each frame the worker waits until mapping
//                                                       is idle (offline-like accuracy; frames queue up
//                                                       and are dropped when the input is faster)
//   ~map_points_period  double  1.0    (>= 0)           s between ~map_points/~keyframes (0: every frame)
//   ~weak_inliers       int     60     (>= 0)           tracked with fewer map inliers -> "weak"
//   ~frustum_scale      double  0.5    (> 0)            depth (map units) of the keyframe frustums
//   ~max_features       int     2000   (>= 50)          FAST features per frame (tracking.features)
//   ~nerf               bool    true                    run the NeRF mapping thread (nerf.enabled)
//   ~nerf_threads       int     1      (1..64)          NeRF training threads (nerf.threads)
//   ~nerf_nice          int     19     (0..19)          niceness added to the NeRF training threads
//                                                       (nerf.nice_increment; 19: tracking always wins)
//   ~nerf_publish_period double 2.0    (> 0)            s between ~nerf_view/~nerf_depth renders
//   ~nerf_cloud_period  double  10.0   (> 0)            s between ~nerf_cloud exports
//   ~nerf_cloud_source  string  "depth"                 depth | density
//   ~nerf_cloud_views   int     4      (1..64)          newest training views in the depth cloud
//   ~nerf_cloud_stride  int     2      (1..16)          depth cloud: views rendered at 1/stride of the
//                                                       training resolution, a point per pixel
//   ~nerf_render_threads int    1      (1..64)          threads of each render / cloud export
//   ~nerf_render_nice   int     10     (0..19)          niceness of the NeRF publisher thread (10: views
//                                                       go before training, after tracking; 19: never
//                                                       take CPU from training)
//   ~map_dir            string  "nerfslam_map"          folder ~save_map writes (relative: to the
//                                                       node's working directory, ROS_HOME under roslaunch)
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <type_traits>
#include <vector>

#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseStamped.h>
#include <image_transport/image_transport.h>
#include <nav_msgs/Path.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <std_msgs/String.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/transform_broadcaster.h>
#include <visualization_msgs/MarkerArray.h>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/mapping/bounded_queue.h"
#include "nerfslam/nerf/export.h"
#include "nerfslam/nerf/field.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/nerf_options.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/nerf_mapping.h"
#include "nerfslam/system/slam_system.h"
#include "nerfslam_ros/conversions.h"

namespace {

using nerfslam::Camera;
using nerfslam::SE3;
using nerfslam::SlamSystem;

struct Params {
  std::string map_frame = "map";
  std::string camera_frame = "camera_optical_frame";
  std::string camera_yaml;
  int queue_size = 2;
  bool wait_for_mapping = false;
  double map_points_period = 1.0;
  int weak_inliers = 60;
  double frustum_scale = 0.5;
  int max_features = 2000;
  bool nerf = true;
  int nerf_threads = 1;
  int nerf_nice = 19;
  double nerf_publish_period = 2.0;
  double nerf_cloud_period = 10.0;
  std::string nerf_cloud_source = "depth";
  int nerf_cloud_views = 4;
  int nerf_cloud_stride = 2;
  int nerf_render_threads = 1;
  int nerf_render_nice = 10;
  std::string map_dir = "nerfslam_map";
};

// A relative ~map_dir is taken relative to the working directory (ROS_HOME under roslaunch).
std::filesystem::path resolveMapDir(const std::string& dir) {
  std::error_code ec;
  const std::filesystem::path abs = std::filesystem::absolute(dir, ec);
  return ec ? std::filesystem::path(dir) : abs.lexically_normal();
}

bool isColourEncoding(const std::string& e) { return e == "bgr8" || e == "rgb8" || e == "bgra8" || e == "rgba8"; }

// Reads, prints and validates the parameters; returns an error message or "".
std::string loadParams(ros::NodeHandle& pnh, Params& p) {
  pnh.param("map_frame", p.map_frame, p.map_frame);
  pnh.param("camera_frame", p.camera_frame, p.camera_frame);
  pnh.param("camera_yaml", p.camera_yaml, p.camera_yaml);
  pnh.param("queue_size", p.queue_size, p.queue_size);
  pnh.param("wait_for_mapping", p.wait_for_mapping, p.wait_for_mapping);
  pnh.param("map_points_period", p.map_points_period, p.map_points_period);
  pnh.param("weak_inliers", p.weak_inliers, p.weak_inliers);
  pnh.param("frustum_scale", p.frustum_scale, p.frustum_scale);
  pnh.param("max_features", p.max_features, p.max_features);
  pnh.param("nerf", p.nerf, p.nerf);
  pnh.param("nerf_threads", p.nerf_threads, p.nerf_threads);
  pnh.param("nerf_nice", p.nerf_nice, p.nerf_nice);
  pnh.param("nerf_publish_period", p.nerf_publish_period, p.nerf_publish_period);
  pnh.param("nerf_cloud_period", p.nerf_cloud_period, p.nerf_cloud_period);
  pnh.param("nerf_cloud_source", p.nerf_cloud_source, p.nerf_cloud_source);
  pnh.param("nerf_cloud_views", p.nerf_cloud_views, p.nerf_cloud_views);
  pnh.param("nerf_cloud_stride", p.nerf_cloud_stride, p.nerf_cloud_stride);
  pnh.param("nerf_render_threads", p.nerf_render_threads, p.nerf_render_threads);
  pnh.param("nerf_render_nice", p.nerf_render_nice, p.nerf_render_nice);
  pnh.param("map_dir", p.map_dir, p.map_dir);
  ROS_INFO("nerfslam_node parameters:");
  ROS_INFO("  ~map_frame = %s", p.map_frame.c_str());
  ROS_INFO("  ~camera_frame = %s", p.camera_frame.c_str());
  ROS_INFO("  ~camera_yaml = %s", p.camera_yaml.empty() ? "(none: camera_info)" : p.camera_yaml.c_str());
  ROS_INFO("  ~queue_size = %d", p.queue_size);
  ROS_INFO("  ~wait_for_mapping = %s", p.wait_for_mapping ? "true" : "false");
  ROS_INFO("  ~map_points_period = %g s", p.map_points_period);
  ROS_INFO("  ~weak_inliers = %d", p.weak_inliers);
  ROS_INFO("  ~frustum_scale = %g", p.frustum_scale);
  ROS_INFO("  ~max_features = %d", p.max_features);
  ROS_INFO("  ~nerf = %s", p.nerf ? "true" : "false");
  ROS_INFO("  ~nerf_threads = %d", p.nerf_threads);
  ROS_INFO("  ~nerf_nice = %d", p.nerf_nice);
  ROS_INFO("  ~nerf_publish_period = %g s", p.nerf_publish_period);
  ROS_INFO("  ~nerf_cloud_period = %g s", p.nerf_cloud_period);
  ROS_INFO("  ~nerf_cloud_source = %s", p.nerf_cloud_source.c_str());
  ROS_INFO("  ~nerf_cloud_views = %d", p.nerf_cloud_views);
  ROS_INFO("  ~nerf_cloud_stride = %d", p.nerf_cloud_stride);
  ROS_INFO("  ~nerf_render_threads = %d", p.nerf_render_threads);
  ROS_INFO("  ~nerf_render_nice = %d", p.nerf_render_nice);
  ROS_INFO("  ~map_dir = %s (%s)", p.map_dir.c_str(), resolveMapDir(p.map_dir).c_str());
  if (p.map_frame.empty()) return "~map_frame must not be empty";
  if (p.camera_frame.empty()) return "~camera_frame must not be empty";
  if (p.map_frame == p.camera_frame) return "~map_frame and ~camera_frame must differ";
  if (p.queue_size < 1) return "~queue_size must be >= 1 (got " + std::to_string(p.queue_size) + ")";
  if (!(p.map_points_period >= 0) || !std::isfinite(p.map_points_period))
    return "~map_points_period must be >= 0 (got " + std::to_string(p.map_points_period) + ")";
  if (p.weak_inliers < 0) return "~weak_inliers must be >= 0 (got " + std::to_string(p.weak_inliers) + ")";
  if (!(p.frustum_scale > 0) || !std::isfinite(p.frustum_scale))
    return "~frustum_scale must be > 0 (got " + std::to_string(p.frustum_scale) + ")";
  if (p.max_features < 50) return "~max_features must be >= 50 (got " + std::to_string(p.max_features) + ")";
  if (p.nerf_threads < 1 || p.nerf_threads > 64)
    return "~nerf_threads must be in 1..64 (got " + std::to_string(p.nerf_threads) + ")";
  if (p.nerf_nice < 0 || p.nerf_nice > 19)
    return "~nerf_nice must be in 0..19 (got " + std::to_string(p.nerf_nice) + ")";
  if (!(p.nerf_publish_period > 0) || !std::isfinite(p.nerf_publish_period))
    return "~nerf_publish_period must be > 0 (got " + std::to_string(p.nerf_publish_period) + ")";
  if (!(p.nerf_cloud_period > 0) || !std::isfinite(p.nerf_cloud_period))
    return "~nerf_cloud_period must be > 0 (got " + std::to_string(p.nerf_cloud_period) + ")";
  if (p.nerf_cloud_source != "depth" && p.nerf_cloud_source != "density")
    return "~nerf_cloud_source must be depth or density (got '" + p.nerf_cloud_source + "')";
  if (p.nerf_cloud_views < 1 || p.nerf_cloud_views > 64)
    return "~nerf_cloud_views must be in 1..64 (got " + std::to_string(p.nerf_cloud_views) + ")";
  if (p.nerf_cloud_stride < 1 || p.nerf_cloud_stride > 16)
    return "~nerf_cloud_stride must be in 1..16 (got " + std::to_string(p.nerf_cloud_stride) + ")";
  if (p.nerf_render_threads < 1 || p.nerf_render_threads > 64)
    return "~nerf_render_threads must be in 1..64 (got " + std::to_string(p.nerf_render_threads) + ")";
  if (p.nerf_render_nice < 0 || p.nerf_render_nice > 19)
    return "~nerf_render_nice must be in 0..19 (got " + std::to_string(p.nerf_render_nice) + ")";
  if (p.map_dir.empty()) return "~map_dir must not be empty";
  if (p.nerf && p.nerf_render_nice > p.nerf_nice)
    ROS_WARN("~nerf_render_nice (%d) > ~nerf_nice (%d): NeRF training will starve the NeRF topics' renders",
             p.nerf_render_nice, p.nerf_nice);
  return "";
}

struct QueuedFrame {
  sensor_msgs::ImageConstPtr image;
  std::shared_ptr<const Camera> camera;
};

// What the NeRF publisher thread and the services need of the running system. The worker replaces it
// (under handle_mutex_) when it starts or resets the system; readers copy the shared_ptr and use the
// system without blocking tracking (NerfMapping, Map and saveMapFolder are thread-safe). The last
// holder destroys the system (after the worker's finish()).
struct SystemHandle {
  std::shared_ptr<SlamSystem> system;
  std::shared_ptr<const Camera> camera;
  nerfslam::SystemOptions options;
  uint64_t generation = 0;
};

// The last tracked pose (what ~nerf_view is rendered from).
struct TrackedPose {
  SE3 T_world_cam;
  ros::Time stamp;
  uint64_t generation = 0;
};

double wallSeconds() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

// Lowers the calling thread's priority (Linux: per-thread niceness; threads it starts inherit it).
void lowerThreadPriority(int increment) {
  if (increment <= 0) return;
  const pid_t tid = static_cast<pid_t>(syscall(SYS_gettid));
  if (setpriority(PRIO_PROCESS, static_cast<id_t>(tid), getpriority(PRIO_PROCESS, static_cast<id_t>(tid)) + increment) != 0)
    ROS_WARN("could not lower the NeRF publisher thread's priority");
}

// A copy of the NeRF model that the NeRF publisher thread renders, exports and saves from, so that
// NeRF training pauses only while the copy is taken (a memcpy of the parameters and the occupancy
// grid, under NerfMapping::withModel), not for a whole render. Costs one model's memory (the size of
// a saved model: ~70 MB with the default 2^19-entry hash tables); the buffers are reused.
class ModelCopy {
 public:
  // Copies the model; false when there is none yet. Returns the wait for the lock and the copy time.
  bool update(const nerfslam::NerfMapping& nerf, double* wait_ms, double* copy_ms) {
    const double t0 = now();
    double t1 = t0;
    const bool ok = nerf.withModel([&](nerfslam::nerf::NerfModel& src) {
      t1 = now();
      copyFrom(src);
    });
    if (!ok) return false;
    model_.field->parametersChanged();  // derived copies of the weights, outside the lock
    if (wait_ms) *wait_ms = 1e3 * (t1 - t0);
    if (copy_ms) *copy_ms = 1e3 * (now() - t1);
    return true;
  }
  nerfslam::nerf::NerfModel& model() { return model_; }

 private:
  static double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }
  // The field's structure, from its configuration's scalar options.
  struct KeyVisitor {
    std::string key;
    template <class T, class... Rest>
    void operator()(const char* name, T& value, Rest&&...) {
      if constexpr (std::is_arithmetic_v<T>) key += std::string(name) + "=" + std::to_string(value) + ";";
    }
  };
  static std::string configKey(nerfslam::nerf::FieldConfig config) {
    KeyVisitor v;
    config.visit(v);
    return v.key;
  }
  void copyFrom(nerfslam::nerf::NerfModel& src) {
    const std::string key = configKey(src.field->config());
    auto src_params = src.field->parameters();
    bool same = model_.field && key == key_;
    std::vector<nerfslam::nerf::FloatArray> dst_params;
    if (same) {
      dst_params = model_.field->parameters();
      same = dst_params.size() == src_params.size();
      for (size_t i = 0; same && i < src_params.size(); ++i)
        same = dst_params[i].name == src_params[i].name && dst_params[i].size == src_params[i].size;
    }
    if (!same) {  // first copy, or another field structure (rare: allocated under the lock)
      model_.field = std::make_unique<nerfslam::nerf::RadianceField>(src.field->config(), 0);
      key_ = key;
      dst_params = model_.field->parameters();
    }
    for (size_t i = 0; i < src_params.size(); ++i)
      std::memcpy(dst_params[i].data, src_params[i].data, src_params[i].size * sizeof(float));
    model_.field_config = src.field_config;
    model_.scene = src.scene;
    model_.training_steps = src.training_steps;
    if (model_.grid)
      *model_.grid = *src.grid;
    else
      model_.grid = std::make_unique<nerfslam::nerf::OccupancyGrid>(*src.grid);
  }

  nerfslam::nerf::NerfModel model_;
  std::string key_;
};

// Times a callback into running statistics (mean and max, ms).
class CallbackTimer {
 public:
  CallbackTimer(std::atomic<double>& sum, std::atomic<double>& max, std::atomic<uint64_t>& count)
      : sum_(sum), max_(max), count_(count), t0_(std::chrono::steady_clock::now()) {}
  ~CallbackTimer() {
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0_).count();
    sum_.store(sum_.load() + ms);
    if (ms > max_.load()) max_.store(ms);
    ++count_;
  }

 private:
  std::atomic<double>& sum_;
  std::atomic<double>& max_;
  std::atomic<uint64_t>& count_;
  std::chrono::steady_clock::time_point t0_;
};

class NerfslamNode {
 public:
  NerfslamNode(ros::NodeHandle nh, ros::NodeHandle pnh, Params p)
      : nh_(nh),
        pnh_(pnh),
        p_(std::move(p)),
        it_(nh),
        updater_(nh, pnh),
        queue_(p_.queue_size, nerfslam::OverflowPolicy::kDropOldest) {
    if (!p_.camera_yaml.empty()) {
      yaml_camera_ = std::make_shared<const Camera>(nerfslam::loadCameraYaml(p_.camera_yaml));  // throws
      ROS_INFO("calibration from %s: %dx%d fx=%.3f fy=%.3f cx=%.3f cy=%.3f", p_.camera_yaml.c_str(),
               yaml_camera_->width, yaml_camera_->height, yaml_camera_->fx, yaml_camera_->fy, yaml_camera_->cx,
               yaml_camera_->cy);
    }
    pose_pub_ = pnh_.advertise<geometry_msgs::PoseStamped>("pose", 10);
    path_pub_ = pnh_.advertise<nav_msgs::Path>("path", 2, true);
    points_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("map_points", 2, true);
    keyframes_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("keyframes", 2, true);
    state_pub_ = pnh_.advertise<std_msgs::String>("tracking_state", 10, true);
    reset_srv_ = pnh_.advertiseService("reset", &NerfslamNode::onReset, this);
    localization_srv_ = pnh_.advertiseService("set_localization_only", &NerfslamNode::onSetLocalizationOnly, this);
    // The NeRF publisher thread's queue: the NeRF topics' renders and the map services (slow work
    // that must not delay image callbacks or tracking).
    slow_nh_ = pnh_;
    slow_nh_.setCallbackQueue(&slow_queue_);
    save_srv_ = slow_nh_.advertiseService("save_map", &NerfslamNode::onSaveMap, this);
    if (p_.nerf) {
      nerf_view_pub_ = pnh_.advertise<sensor_msgs::Image>("nerf_view", 1);
      nerf_depth_pub_ = pnh_.advertise<sensor_msgs::Image>("nerf_depth", 1);
      nerf_cloud_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("nerf_cloud", 1, true);
    }
    publishState("initializing");

    updater_.setHardwareID("nerfslam");
    updater_.add("nerfslam_node", this, &NerfslamNode::diagnose);
    diag_timer_ =
        nh_.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) { updater_.force_update(); });

    if (yaml_camera_) {
      image_sub_ = it_.subscribe("image", 5, &NerfslamNode::onImage, this);
    } else {
      camera_sub_ = it_.subscribeCamera("image", 5, &NerfslamNode::onCamera, this);
    }
    wait_timer_ = nh_.createWallTimer(ros::WallDuration(2.0), [this](const ros::WallTimerEvent&) { checkInput(); });
    worker_ = std::thread([this] { work(); });
    slow_thread_ = std::thread([this] { slowWork(); });
  }

  ~NerfslamNode() {
    stopping_ = true;
    queue_.close();
    if (worker_.joinable()) worker_.join();
    if (slow_thread_.joinable()) slow_thread_.join();
    setHandle(nullptr);
    std::lock_guard<std::mutex> lock(system_mutex_);
    if (system_) system_->finish(false);
    // stdout: rosconsole no longer prints once ros::shutdown() has run.
    std::printf(
        "nerfslam_node: %lu frames received, %lu processed, %lu tracked, %lu dropped (queue full), refused: "
        "%lu encoding, %lu size, %lu timestamp; mean tracking %.1f ms; image callback mean %.3f ms, max %.3f ms; "
        "frame latency (stamp to pose, live stamps) mean %.1f ms, max %.1f ms; "
        "%lu NeRF renders (mean %.0f ms), %lu NeRF clouds, %lu map saves (%lu failed)\n",
        static_cast<unsigned long>(received_), static_cast<unsigned long>(processed_),
        static_cast<unsigned long>(tracked_), static_cast<unsigned long>(queue_.dropped()),
        static_cast<unsigned long>(refused_encoding_), static_cast<unsigned long>(refused_size_),
        static_cast<unsigned long>(refused_stamp_), processed_ > 0 ? tracking_ms_sum_.load() / processed_ : 0.0,
        callbacks_ > 0 ? callback_ms_sum_.load() / callbacks_ : 0.0, callback_ms_max_.load(),
        latency_count_ > 0 ? latency_ms_sum_.load() / latency_count_ : 0.0, latency_ms_max_.load(),
        static_cast<unsigned long>(nerf_renders_), nerf_renders_ > 0 ? nerf_render_ms_sum_.load() / nerf_renders_ : 0.0,
        static_cast<unsigned long>(nerf_clouds_), static_cast<unsigned long>(map_saves_),
        static_cast<unsigned long>(map_save_failures_));
    std::fflush(stdout);
  }

 private:
  // ---- Callbacks: checks and enqueueing only ----
  void onCamera(const sensor_msgs::ImageConstPtr& image, const sensor_msgs::CameraInfoConstPtr& info) {
    const CallbackTimer timer(callback_ms_sum_, callback_ms_max_, callbacks_);
    std::shared_ptr<const Camera> cam;
    {
      std::lock_guard<std::mutex> lock(input_mutex_);
      if (!last_info_ || last_info_->K != info->K || last_info_->D != info->D || last_info_->width != info->width ||
          last_info_->height != info->height || last_info_->distortion_model != info->distortion_model) {
        try {
          info_camera_ = std::make_shared<const Camera>(nerfslam::rosbridge::fromCameraInfo(*info, "camera_info"));
        } catch (const std::exception& e) {
          ++refused_calibration_;
          ROS_ERROR_THROTTLE(5.0, "refusing camera_info: %s", e.what());
          return;
        }
        last_info_ = info;
      }
      cam = info_camera_;
    }
    enqueue(image, cam);
  }
  void onImage(const sensor_msgs::ImageConstPtr& image) {
    const CallbackTimer timer(callback_ms_sum_, callback_ms_max_, callbacks_);
    enqueue(image, yaml_camera_);
  }

  void enqueue(const sensor_msgs::ImageConstPtr& image, const std::shared_ptr<const Camera>& cam) {
    ++received_;
    last_input_ = ros::WallTime::now().toSec();
    if (!nerfslam::rosbridge::isAcceptedEncoding(image->encoding)) {
      ++refused_encoding_;
      std::string accepted;
      for (const auto& e : nerfslam::rosbridge::acceptedEncodings()) accepted += (accepted.empty() ? "" : ", ") + e;
      ROS_ERROR_THROTTLE(5.0, "refusing image with encoding '%s' (accepted: %s); %lu refused so far",
                         image->encoding.c_str(), accepted.c_str(), static_cast<unsigned long>(refused_encoding_));
      return;
    }
    std::lock_guard<std::mutex> lock(input_mutex_);
    if (!system_camera_) {
      system_camera_ = cam;  // the first frame fixes the calibration and image size
    } else if (static_cast<int>(image->width) != system_camera_->width ||
               static_cast<int>(image->height) != system_camera_->height) {
      ++refused_size_;
      ROS_ERROR_THROTTLE(5.0, "refusing %ux%u image: the system was started on %dx%d images; %lu refused so far",
                         image->width, image->height, system_camera_->width, system_camera_->height,
                         static_cast<unsigned long>(refused_size_));
      return;
    }
    if (static_cast<int>(image->width) != cam->width || static_cast<int>(image->height) != cam->height) {
      ++refused_size_;
      ROS_ERROR_THROTTLE(5.0, "refusing %ux%u image: the calibration is for %dx%d", image->width, image->height,
                         cam->width, cam->height);
      return;
    }
    if (have_last_stamp_ && image->header.stamp <= last_stamp_) {
      ++refused_stamp_;
      ROS_WARN_THROTTLE(5.0, "dropping frame stamped %.6f: not after the previous frame (%.6f); %lu dropped so far",
                        image->header.stamp.toSec(), last_stamp_.toSec(), static_cast<unsigned long>(refused_stamp_));
      return;
    }
    last_stamp_ = image->header.stamp;
    have_last_stamp_ = true;
    const uint64_t dropped_before = queue_.dropped();
    queue_.tryPush(QueuedFrame{image, system_camera_});
    if (queue_.dropped() > dropped_before)
      ROS_WARN_THROTTLE(5.0, "tracking falls behind: oldest queued frame dropped (%lu dropped so far)",
                        static_cast<unsigned long>(queue_.dropped()));
  }

  void checkInput() {
    if (received_ > 0 && ros::WallTime::now().toSec() - last_input_ < 5.0) return;
    if (yaml_camera_)
      ROS_WARN_THROTTLE(10.0, "waiting for images on %s", image_sub_.getTopic().c_str());
    else
      ROS_WARN_THROTTLE(10.0,
                        "waiting for images on %s with camera_info on %s (both needed, with equal stamps; or set "
                        "~camera_yaml to use a calibration file without camera_info)",
                        camera_sub_.getTopic().c_str(), camera_sub_.getInfoTopic().c_str());
  }

  bool onReset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    reset_requested_ = true;
    res.success = true;
    res.message = "the map is discarded before the next frame; the system reinitialises";
    ROS_INFO("reset requested");
    return true;
  }

  bool onSetLocalizationOnly(std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
    const bool was = localization_only_.exchange(req.data);
    res.success = true;
    res.message = req.data ? (was ? "already localisation only" : "localisation only: the map is no longer extended")
                           : (was ? "mapping resumed" : "already mapping");
    ROS_INFO("~set_localization_only %s: %s", req.data ? "true" : "false", res.message.c_str());
    return true;
  }

  // ---- Worker ----
  void work() {
    uint64_t index = 0;
    while (auto item = queue_.pop()) {
      if (stopping_) break;
      std::unique_lock<std::mutex> lock(system_mutex_);
      if (reset_requested_.exchange(false) && system_) {
        setHandle(nullptr);  // the NeRF publisher and the services stop using it
        system_->finish(false);
        system_.reset();  // destroyed here, or by the last reader still holding it
        ++resets_;
      }
      if (!system_) {
        nerfslam::SystemOptions opt;
        opt.tracking.features.max_features = p_.max_features;
        opt.lockstep = false;
        opt.nerf.enabled = p_.nerf;
        opt.nerf.threads = p_.nerf_threads;
        opt.nerf.nice_increment = p_.nerf_nice;
        try {
          system_ = std::make_shared<SlamSystem>(*item->camera, opt);
          worker_camera_ = item->camera;
        } catch (const std::exception& e) {
          ROS_ERROR_THROTTLE(5.0, "cannot start the SLAM system: %s", e.what());
          continue;
        }
        auto h = std::make_shared<SystemHandle>();
        h->system = system_;
        h->camera = item->camera;
        h->options = opt;
        h->generation = ++generation_;
        setHandle(std::move(h));
        ROS_INFO("SLAM system started on %dx%d images%s", item->camera->width, item->camera->height,
                 p_.nerf ? " with the NeRF mapping thread" : " (sparse only: ~nerf is false)");
      }
      const auto& msg = *item->image;
      // The NeRF trains on colour: colour encodings go in as BGR (tracking converts to grey itself).
      const bool colour = p_.nerf && isColourEncoding(msg.encoding);
      if (p_.nerf && !colour && !warned_grey_input_) {
        warned_grey_input_ = true;
        ROS_WARN("images are '%s': the NeRF trains on grey (publish bgr8/rgb8 for a colour NeRF)", msg.encoding.c_str());
      }
      cv::Mat image;
      try {
        image = nerfslam::rosbridge::fromImageMsg(
            msg, colour ? nerfslam::rosbridge::ImageTarget::kBgr8 : nerfslam::rosbridge::ImageTarget::kGray8);
      } catch (const std::exception& e) {
        ++refused_encoding_;
        ROS_ERROR_THROTTLE(5.0, "refusing image: %s", e.what());
        continue;
      }
      nerfslam::FrameRecord rec;
      try {
        system_->setLocalizationOnly(localization_only_);
        rec = system_->trackFrame(image, msg.header.stamp.toSec(), index++);
      } catch (const std::exception& e) {
        ++tracking_errors_;
        ROS_ERROR_THROTTLE(5.0, "tracking failed on the frame stamped %.6f: %s", msg.header.stamp.toSec(), e.what());
        continue;
      }
      if (p_.wait_for_mapping) system_->waitMappingIdle();
      ++processed_;
      tracking_ms_last_ = rec.tracking_ms;
      tracking_ms_sum_.store(tracking_ms_sum_.load() + rec.tracking_ms);
      if (rec.tracked) {
        ++tracked_;
        std::lock_guard<std::mutex> pose_lock(pose_mutex_);
        last_pose_ = TrackedPose{rec.T_world_cam, msg.header.stamp, generation_};
      }
      publishFrame(msg.header.stamp, rec);
    }
  }

  std::string stateName(const nerfslam::FrameRecord& rec) const {
    switch (rec.state) {
      case nerfslam::TrackingState::kNotInitialized:
        return "initializing";
      case nerfslam::TrackingState::kLost:
        return "lost";
      case nerfslam::TrackingState::kTracking:
        return rec.num_inliers < p_.weak_inliers ? "weak" : "good";
    }
    return "lost";
  }

  void publishState(const std::string& s) {
    {
      std::lock_guard<std::mutex> lock(diag_mutex_);
      if (s == state_) return;
      state_ = s;
    }
    std_msgs::String m;
    m.data = s;
    state_pub_.publish(m);
  }

  void publishFrame(const ros::Time& stamp, const nerfslam::FrameRecord& rec) {
    // Latency from the image's stamp to here (queue + conversion + tracking), for live stamps only
    // (a recorded sequence's stamps are in the past).
    const double age = (ros::Time::now() - stamp).toSec();
    if (age >= 0 && age < 10.0) {
      const double ms = 1e3 * age;
      latency_ms_sum_.store(latency_ms_sum_.load() + ms);
      if (ms > latency_ms_max_.load()) latency_ms_max_.store(ms);
      ++latency_count_;
    }
    publishState(stateName(rec));
    if (rec.tracked) {
      tf_.sendTransform(nerfslam::rosbridge::toTransformStamped(rec.T_world_cam, p_.map_frame, p_.camera_frame, stamp));
      geometry_msgs::PoseStamped ps;
      ps.header.stamp = stamp;
      ps.header.frame_id = p_.map_frame;
      ps.pose = nerfslam::rosbridge::toPose(rec.T_world_cam);
      pose_pub_.publish(ps);
    }
    if (system_->initialized()) {
      nav_msgs::Path path;
      path.header.stamp = stamp;
      path.header.frame_id = p_.map_frame;
      for (const auto& e : system_->trajectory()) {
        geometry_msgs::PoseStamped ps;
        ps.header.stamp = ros::Time(e.timestamp);
        ps.header.frame_id = p_.map_frame;
        ps.pose = nerfslam::rosbridge::toPose(e.pose);
        path.poses.push_back(ps);
      }
      path_pub_.publish(path);
    }
    const ros::WallTime now = ros::WallTime::now();
    if (system_->initialized() && (now - last_map_publish_).toSec() >= p_.map_points_period) {
      last_map_publish_ = now;
      publishMap(stamp);
    }
  }

  void publishMap(const ros::Time& stamp) {
    const auto points = system_->map().points();
    const auto keyframes = system_->map().keyframes();
    {
      std::lock_guard<std::mutex> lock(diag_mutex_);
      map_points_ = points.size();
      keyframes_ = keyframes.size();
    }
    sensor_msgs::PointCloud2 cloud;
    cloud.header.stamp = stamp;
    cloud.header.frame_id = p_.map_frame;
    sensor_msgs::PointCloud2Modifier mod(cloud);
    mod.setPointCloud2Fields(4, "x", 1, sensor_msgs::PointField::FLOAT32, "y", 1, sensor_msgs::PointField::FLOAT32, "z",
                             1, sensor_msgs::PointField::FLOAT32, "intensity", 1, sensor_msgs::PointField::FLOAT32);
    mod.resize(points.size());
    sensor_msgs::PointCloud2Iterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z"), in(cloud, "intensity");
    for (const auto& pt : points) {
      *x = static_cast<float>(pt.position.x());
      *y = static_cast<float>(pt.position.y());
      *z = static_cast<float>(pt.position.z());
      *in = static_cast<float>(pt.observations.size());
      ++x, ++y, ++z, ++in;
    }
    points_pub_.publish(cloud);

    // Keyframe frustums: apex at the centre, the image corners at depth frustum_scale.
    visualization_msgs::MarkerArray arr;
    visualization_msgs::Marker m;
    m.header.stamp = stamp;
    m.header.frame_id = p_.map_frame;
    m.ns = "keyframes";
    m.id = 0;
    m.type = visualization_msgs::Marker::LINE_LIST;
    m.action = visualization_msgs::Marker::ADD;
    m.pose.orientation.w = 1.0;
    m.scale.x = 0.02 * p_.frustum_scale;
    m.color.r = 0.1f;
    m.color.g = 0.8f;
    m.color.b = 0.2f;
    m.color.a = 1.0f;
    const Camera& cam = *worker_camera_;
    const double d = p_.frustum_scale;
    const std::array<Eigen::Vector3d, 4> corners = {
        Eigen::Vector3d((0 - cam.cx) / cam.fx * d, (0 - cam.cy) / cam.fy * d, d),
        Eigen::Vector3d((cam.width - cam.cx) / cam.fx * d, (0 - cam.cy) / cam.fy * d, d),
        Eigen::Vector3d((cam.width - cam.cx) / cam.fx * d, (cam.height - cam.cy) / cam.fy * d, d),
        Eigen::Vector3d((0 - cam.cx) / cam.fx * d, (cam.height - cam.cy) / cam.fy * d, d)};
    auto pt = [](const Eigen::Vector3d& v) {
      geometry_msgs::Point p;
      p.x = v.x();
      p.y = v.y();
      p.z = v.z();
      return p;
    };
    for (const auto& kf : keyframes) {
      const Eigen::Vector3d c = kf.T_world_cam.translation();
      std::array<Eigen::Vector3d, 4> w;
      for (int i = 0; i < 4; ++i) w[i] = kf.T_world_cam * corners[i];
      for (int i = 0; i < 4; ++i) {
        m.points.push_back(pt(c));
        m.points.push_back(pt(w[i]));
        m.points.push_back(pt(w[i]));
        m.points.push_back(pt(w[(i + 1) % 4]));
      }
    }
    if (m.points.empty()) m.action = visualization_msgs::Marker::DELETE;
    arr.markers.push_back(m);
    keyframes_pub_.publish(arr);
  }

  // ---- The running system, shared with the NeRF publisher thread and the services ----
  void setHandle(std::shared_ptr<const SystemHandle> h) {
    std::shared_ptr<const SystemHandle> old;
    {
      std::lock_guard<std::mutex> lock(handle_mutex_);
      old = std::move(handle_);
      handle_ = std::move(h);
    }
  }
  std::shared_ptr<const SystemHandle> handle() const {
    std::lock_guard<std::mutex> lock(handle_mutex_);
    return handle_;
  }

  // ---- NeRF publisher thread: renders and services (never the image callbacks or the worker) ----
  void slowWork() {
    lowerThreadPriority(p_.nerf_render_nice);
    double next_view = wallSeconds() + p_.nerf_publish_period;
    double next_cloud = wallSeconds() + p_.nerf_cloud_period;
    while (!stopping_ && ros::ok()) {
      slow_queue_.callAvailable(ros::WallDuration(0.05));
      if (!p_.nerf || stopping_) continue;
      // A render longer than its period is followed by half a period of rest, so the thread never
      // renders back to back.
      double now = wallSeconds();
      if (now >= next_view) {
        publishNerfView();
        const double end = wallSeconds();
        next_view = std::max(now + p_.nerf_publish_period, end + 0.5 * p_.nerf_publish_period);
      }
      now = wallSeconds();
      if (now >= next_cloud) {
        publishNerfCloud();
        const double end = wallSeconds();
        next_cloud = std::max(now + p_.nerf_cloud_period, end + 0.5 * p_.nerf_cloud_period);
      }
    }
  }

  // A new model is rendered only after its occupancy grid's second update (TrainOptions::
  // grid_update_interval steps, the interval NerfMapping trains with): before it nearly every cell is
  // still marked occupied and a render costs ~5x more samples (measured at 160x120: 4.2 M samples,
  // 218 per ray, at step 3; 0.6 M, 30 per ray, at step 17).
  static bool modelReady(const nerfslam::NerfMapping& nerf) {
    return nerf.stats().steps > nerfslam::nerf::TrainOptions{}.grid_update_interval && nerf.hasModel();
  }

  void publishNerfView() {
    if (nerf_view_pub_.getNumSubscribers() == 0 && nerf_depth_pub_.getNumSubscribers() == 0) return;
    const auto h = handle();
    if (!h || !h->system->nerf()) return;
    nerfslam::NerfMapping& nerf = *h->system->nerf();
    if (!modelReady(nerf)) return;
    TrackedPose pose;
    {
      std::lock_guard<std::mutex> lock(pose_mutex_);
      if (!last_pose_ || last_pose_->generation != h->generation) return;
      pose = *last_pose_;
    }
    const Camera cam = nerf.trainingCamera();
    nerfslam::nerf::RenderOptions ro;
    ro.threads = p_.nerf_render_threads;
    ro.normals = false;
    ro.background = {0.0, 0.0, 0.0};
    nerfslam::nerf::RenderResult r;
    double t0 = 0;
    try {
      if (!updateModelCopy(nerf)) return;
      t0 = wallSeconds();
      r = nerfslam::nerf::renderView(model_copy_.model(), cam, pose.T_world_cam, ro);
    } catch (const std::exception& e) {
      ++nerf_render_errors_;
      ROS_ERROR_THROTTLE(10.0, "NeRF render failed: %s", e.what());
      return;
    }
    const double ms = 1e3 * (wallSeconds() - t0);
    nerf_samples_per_ray_last_ = double(r.samples) / std::max(1, cam.width * cam.height);
    nerf_occupied_last_ = model_copy_.model().grid->occupiedFraction();
    std_msgs::Header header;
    header.stamp = pose.stamp;
    header.frame_id = p_.camera_frame;
    if (nerf_view_pub_.getNumSubscribers() > 0) {
      cv::Mat rgb8;
      r.rgb.convertTo(rgb8, CV_8UC3, 255.0);  // saturating: [0,1] -> 0..255, RGB order
      nerf_view_pub_.publish(cv_bridge::CvImage(header, "rgb8", rgb8).toImageMsg());
    }
    if (nerf_depth_pub_.getNumSubscribers() > 0) {
      cv::Mat depth = r.depth.clone();
      depth.setTo(std::numeric_limits<float>::quiet_NaN(), depth <= 0.0f);  // REP 118: NaN = no depth
      nerf_depth_pub_.publish(nerfslam::rosbridge::toImageMsg(depth, header));
    }
    ++nerf_renders_;
    nerf_render_ms_last_ = ms;
    nerf_render_ms_sum_.store(nerf_render_ms_sum_.load() + ms);
  }

  void publishNerfCloud() {
    if (nerf_cloud_pub_.getNumSubscribers() == 0) return;
    const auto h = handle();
    if (!h || !h->system->nerf()) return;
    nerfslam::NerfMapping& nerf = *h->system->nerf();
    if (!modelReady(nerf)) return;
    nerfslam::nerf::ExportOptions xo;
    xo.threads = p_.nerf_render_threads;
    std::vector<nerfslam::nerf::PosedCamera> views;
    if (p_.nerf_cloud_source == "depth") {
      // Rendered at 1/stride of the training resolution with a point per pixel: the points
      // depthPointCloud would keep with pixel_stride, for 1/stride^2 of the rays.
      const Camera train = nerf.trainingCamera();
      const int w = std::max(1, static_cast<int>(std::lround(double(train.width) / p_.nerf_cloud_stride)));
      const int hgt = std::max(1, static_cast<int>(std::lround(double(train.height) / p_.nerf_cloud_stride)));
      Camera cam = train.scaled(double(w) / train.width);
      cam.width = w;
      cam.height = hgt;
      xo.pixel_stride = 1;
      const std::vector<SE3> poses = nerf.viewPoses();
      const size_t n = std::min(poses.size(), static_cast<size_t>(p_.nerf_cloud_views));
      for (size_t i = poses.size() - n; i < poses.size(); ++i) views.push_back({cam, poses[i]});
      if (views.empty()) return;
    }
    pcl::PointCloud<pcl::PointXYZRGB> pc;
    double t0 = 0;
    try {
      if (!updateModelCopy(nerf)) return;
      t0 = wallSeconds();
      const nerfslam::nerf::NerfModel& m = model_copy_.model();
      pc = views.empty() ? nerfslam::nerf::densityPointCloud(m, xo) : nerfslam::nerf::depthPointCloud(m, views, xo);
    } catch (const std::exception& e) {
      ++nerf_render_errors_;
      ROS_ERROR_THROTTLE(10.0, "NeRF cloud export failed: %s", e.what());
      return;
    }
    const double ms = 1e3 * (wallSeconds() - t0);
    sensor_msgs::PointCloud2 cloud;
    {
      std::lock_guard<std::mutex> lock(pose_mutex_);
      cloud.header.stamp = last_pose_ ? last_pose_->stamp : ros::Time::now();
    }
    cloud.header.frame_id = p_.map_frame;
    sensor_msgs::PointCloud2Modifier mod(cloud);
    mod.setPointCloud2FieldsByString(2, "xyz", "rgb");  // x y z float32, rgb packed (rviz RGB8)
    mod.resize(pc.size());
    sensor_msgs::PointCloud2Iterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
    sensor_msgs::PointCloud2Iterator<uint8_t> cr(cloud, "r"), cg(cloud, "g"), cb(cloud, "b");
    for (const auto& pt : pc.points) {
      *x = pt.x;
      *y = pt.y;
      *z = pt.z;
      *cr = pt.r;
      *cg = pt.g;
      *cb = pt.b;
      ++x, ++y, ++z, ++cr, ++cg, ++cb;
    }
    nerf_cloud_pub_.publish(cloud);
    ++nerf_clouds_;
    nerf_cloud_points_last_ = pc.size();
    nerf_cloud_ms_last_ = ms;
  }

  // Refreshes model_copy_ from the running NeRF (NeRF publisher thread only); false without a model.
  bool updateModelCopy(const nerfslam::NerfMapping& nerf) {
    double wait_ms = 0, copy_ms = 0;
    if (!model_copy_.update(nerf, &wait_ms, &copy_ms)) return false;
    nerf_lock_wait_ms_last_ = wait_ms;
    nerf_copy_ms_last_ = copy_ms;
    return true;
  }

  // ---- Services on the NeRF publisher thread ----
  bool onSaveMap(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    std::string dir_param = p_.map_dir;
    pnh_.getParam("map_dir", dir_param);  // re-read: `rosparam set` before the call changes the folder
    const std::filesystem::path dir = resolveMapDir(dir_param);
    auto refuse = [&](const std::string& why) {
      ++map_save_failures_;
      res.success = false;
      res.message = why;
      ROS_ERROR("~save_map: %s", why.c_str());
      return true;
    };
    if (dir_param.empty()) return refuse("~map_dir is empty");
    const auto h = handle();
    if (!h) return refuse("no map to save: the SLAM system has not started (no images received yet)");
    if (h->system->map().numKeyframes() == 0)
      return refuse("no map to save: the SLAM system has not initialised yet (no keyframes)");
    nerfslam::NerfModelWriter write_nerf;
    // The model is written from a copy (training pauses only for the copy, not for the disk write).
    if (nerfslam::NerfMapping* n = h->system->nerf(); n && n->hasModel())
      write_nerf = [this, n](const std::filesystem::path& path) {
        if (!updateModelCopy(*n)) throw std::runtime_error("the NeRF model disappeared (reset)");
        nerfslam::nerf::saveModel(model_copy_.model(), path);
      };
    try {
      const nerfslam::MapSaveResult r = nerfslam::saveMapFolder(dir, h->system->map(), *h->camera, h->options, write_nerf);
      ++map_saves_;
      {
        std::lock_guard<std::mutex> lock(diag_mutex_);
        last_map_saved_ = dir.string();
      }
      res.success = true;
      res.message = dir.string();
      ROS_INFO("~save_map: %s (generation %lu: %zu keyframes, %zu points, %s, %.1f MB, %zu images written, %zu "
               "reused, %.2f s)",
               dir.c_str(), static_cast<unsigned long>(r.generation), r.keyframes, r.points,
               r.has_nerf ? "with the NeRF model" : "no NeRF model", r.bytes / 1e6, r.images_written, r.images_reused,
               r.seconds);
    } catch (const std::exception& e) {
      const std::string what = e.what();
      return refuse(what.find(dir.string()) != std::string::npos
                        ? "cannot save the map: " + what
                        : "cannot save the map to " + dir.string() + ": " + what);
    }
    return true;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) {
    std::string state;
    size_t points = 0, kfs = 0;
    {
      std::lock_guard<std::mutex> lock(diag_mutex_);
      state = state_;
      points = map_points_;
      kfs = keyframes_;
    }
    const uint64_t dropped = queue_.dropped();
    if (state == "lost")
      s.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "tracking lost");
    else if (state == "weak" || dropped > 0 || refused_encoding_ > 0 || refused_size_ > 0 || refused_stamp_ > 0)
      s.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                "tracking " + state + (dropped > 0 ? ", frames dropped" : "") +
                    (refused_encoding_ + refused_size_ + refused_stamp_ > 0 ? ", frames refused" : ""));
    else
      s.summary(diagnostic_msgs::DiagnosticStatus::OK, "tracking " + state);
    const uint64_t processed = processed_;
    s.add("state", state);
    s.add("frames received", static_cast<uint64_t>(received_));
    s.add("frames processed", processed);
    s.add("frames tracked", static_cast<uint64_t>(tracked_));
    s.add("frames dropped (queue full)", dropped);
    s.add("frames refused (encoding)", static_cast<uint64_t>(refused_encoding_));
    s.add("frames refused (size)", static_cast<uint64_t>(refused_size_));
    s.add("frames refused (timestamp)", static_cast<uint64_t>(refused_stamp_));
    s.add("camera_info refused", static_cast<uint64_t>(refused_calibration_));
    s.add("tracking errors", static_cast<uint64_t>(tracking_errors_));
    s.add("queue", std::to_string(queue_.size()) + "/" + std::to_string(queue_.capacity()));
    s.addf("tracking ms (last)", "%.1f", tracking_ms_last_.load());
    s.addf("tracking ms (mean)", "%.1f", processed > 0 ? tracking_ms_sum_.load() / processed : 0.0);
    s.add("keyframes", kfs);
    s.add("map points", points);
    s.add("resets", static_cast<uint64_t>(resets_));
    const uint64_t callbacks = callbacks_;
    s.addf("image callback ms (mean)", "%.3f", callbacks > 0 ? callback_ms_sum_.load() / callbacks : 0.0);
    s.addf("image callback ms (max)", "%.3f", callback_ms_max_.load());
    const uint64_t lat = latency_count_;
    s.addf("frame latency ms (mean)", "%.1f", lat > 0 ? latency_ms_sum_.load() / lat : 0.0);
    s.addf("frame latency ms (max)", "%.1f", latency_ms_max_.load());
    s.add("nerf", p_.nerf ? "on" : "off");
    if (p_.nerf) {
      // Only stats() here (a short lock of its own): hasModel(), trainingCamera() and viewPoses() take
      // the model lock, held across whole training steps and renders, and would stall this (the image
      // callbacks') thread.
      const auto h = handle();
      const nerfslam::NerfMapping* nerf = h ? h->system->nerf() : nullptr;
      const nerfslam::NerfMappingStats st = nerf ? nerf->stats() : nerfslam::NerfMappingStats{};
      s.add("nerf model", st.views > 0 ? "yes" : "no");
      s.add("nerf steps", static_cast<int64_t>(st.steps));
      s.addf("nerf samples/s", "%.0f", st.samples_per_second);
      s.add("nerf views", st.views);
      s.addf("nerf psnr recent (dB)", "%.2f", st.psnr_recent);
      s.add("nerf keyframes dropped", static_cast<uint64_t>(st.keyframes_dropped));
      s.add("nerf refits", static_cast<int64_t>(st.refits));
      const uint64_t renders = nerf_renders_;
      s.add("nerf renders", renders);
      s.addf("nerf render ms (last)", "%.1f", nerf_render_ms_last_.load());
      s.addf("nerf render ms (mean)", "%.1f", renders > 0 ? nerf_render_ms_sum_.load() / renders : 0.0);
      s.addf("nerf model lock wait ms (last)", "%.1f", nerf_lock_wait_ms_last_.load());
      s.addf("nerf model copy ms (last)", "%.1f", nerf_copy_ms_last_.load());
      s.addf("nerf render samples per ray (last)", "%.1f", nerf_samples_per_ray_last_.load());
      s.addf("nerf occupied fraction (last render)", "%.4f", nerf_occupied_last_.load());
      s.add("nerf clouds", static_cast<uint64_t>(nerf_clouds_));
      s.add("nerf cloud points (last)", static_cast<uint64_t>(nerf_cloud_points_last_));
      s.addf("nerf cloud ms (last)", "%.1f", nerf_cloud_ms_last_.load());
      s.add("nerf render errors", static_cast<uint64_t>(nerf_render_errors_));
    }
    s.add("map saves", static_cast<uint64_t>(map_saves_));
    s.add("map save failures", static_cast<uint64_t>(map_save_failures_));
    {
      std::lock_guard<std::mutex> lock(diag_mutex_);
      s.add("map saved to", last_map_saved_);
    }
  }

  ros::NodeHandle nh_, pnh_;
  Params p_;
  // Before everything registered on it (destroyed after them).
  ros::CallbackQueue slow_queue_;
  ros::NodeHandle slow_nh_;
  image_transport::ImageTransport it_;
  diagnostic_updater::Updater updater_;
  image_transport::CameraSubscriber camera_sub_;
  image_transport::Subscriber image_sub_;
  ros::Publisher pose_pub_, path_pub_, points_pub_, keyframes_pub_, state_pub_;
  ros::Publisher nerf_view_pub_, nerf_depth_pub_, nerf_cloud_pub_;
  ros::ServiceServer reset_srv_, save_srv_, localization_srv_;
  tf2_ros::TransformBroadcaster tf_;
  ros::WallTimer diag_timer_, wait_timer_;

  std::shared_ptr<const Camera> yaml_camera_;
  // Input side (callbacks).
  std::mutex input_mutex_;
  sensor_msgs::CameraInfoConstPtr last_info_;
  std::shared_ptr<const Camera> info_camera_;
  std::shared_ptr<const Camera> system_camera_;
  ros::Time last_stamp_;
  bool have_last_stamp_ = false;
  std::atomic<double> last_input_{0.0};  // wall seconds
  nerfslam::BoundedQueue<QueuedFrame> queue_;

  // Worker side.
  std::mutex system_mutex_;
  std::shared_ptr<SlamSystem> system_;
  uint64_t generation_ = 0;  // of system_ (worker only)
  bool warned_grey_input_ = false;
  std::atomic<bool> reset_requested_{false}, stopping_{false}, localization_only_{false};
  std::shared_ptr<const Camera> worker_camera_;
  ros::WallTime last_map_publish_;
  std::thread worker_;

  // Shared with the NeRF publisher thread and the services.
  mutable std::mutex handle_mutex_;
  std::shared_ptr<const SystemHandle> handle_;
  std::mutex pose_mutex_;
  std::optional<TrackedPose> last_pose_;
  ModelCopy model_copy_;  // NeRF publisher thread only
  std::thread slow_thread_;

  // Statistics.
  std::atomic<uint64_t> received_{0}, processed_{0}, tracked_{0}, refused_encoding_{0}, refused_size_{0},
      refused_stamp_{0}, refused_calibration_{0}, tracking_errors_{0}, resets_{0};
  std::atomic<double> tracking_ms_last_{0}, tracking_ms_sum_{0};
  std::atomic<uint64_t> callbacks_{0}, latency_count_{0};
  std::atomic<double> latency_ms_sum_{0}, latency_ms_max_{0};
  std::atomic<double> callback_ms_sum_{0}, callback_ms_max_{0};
  std::atomic<uint64_t> nerf_renders_{0}, nerf_clouds_{0}, nerf_cloud_points_last_{0}, nerf_render_errors_{0},
      map_saves_{0}, map_save_failures_{0};
  std::atomic<double> nerf_render_ms_last_{0}, nerf_render_ms_sum_{0}, nerf_cloud_ms_last_{0},
      nerf_lock_wait_ms_last_{0}, nerf_copy_ms_last_{0}, nerf_samples_per_ray_last_{0}, nerf_occupied_last_{0};
  std::mutex diag_mutex_;
  std::string state_;
  std::string last_map_saved_;
  size_t map_points_ = 0, keyframes_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "nerfslam_node");
  ros::NodeHandle nh, pnh("~");
  Params p;
  const std::string err = loadParams(pnh, p);
  if (!err.empty()) {
    ROS_FATAL("%s", err.c_str());
    return 1;
  }
  try {
    NerfslamNode node(nh, pnh, p);
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("%s", e.what());
    return 1;
  }
  return 0;
}
