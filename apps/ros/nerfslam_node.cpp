// nerfslam_node: the monocular SLAM system (nerfslam::SlamSystem) with its NeRF dense map as a ROS 1 node.
// tracking_node (same code, SlamNodeMode::kTracking, slam_node.h): the same without the NeRF, which it
// leaves to nerf_mapping_node: it publishes ~keyframes_out (nerfslam/MapKeyframe, every keyframe the
// mapping inserts, with its colour image) and ~keyframe_poses (nerfslam/KeyframePoses, the sent
// keyframes' poses after bundle adjustment, at most every ~keyframe_poses_period s, default 0.5) from
// a sender thread (keyframe_link.h); ~nerf is not read and the ~nerf_* topics are not advertised.
//
// Input: `image` + `camera_info` through image_transport's CameraSubscriber (remap them, e.g.
// image:=/camera/image_raw camera_info:=/camera/camera_info). With ~camera_yaml set, the calibration
// comes from that file instead (our camera YAML or a ROS camera_info YAML, nerfslam::loadCameraYaml)
// and only `image` is subscribed. Until a calibration arrives the node warns (throttled) and waits.
// Callbacks only check and enqueue: frames go into a bounded queue (the oldest are dropped and
// counted when tracking falls behind) and a worker thread feeds the system (colour images as BGR
// when the NeRF is on, so that it trains on colour; grey otherwise).
// Input faults (docs/ros.md, "Faults"): the first frame fixes the calibration; a camera_info with other
// intrinsics or size is refused and counted (~calibration_change refuse) or starts a new map (reset);
// ~reset takes the next frame's calibration. A stamp not after the previous one is refused, except
// after >= ~stream_gap s without images with one publisher connected (a restarted publisher or
// recording: a new stream); a longer gap is logged and counted. The master going away and coming
// back is detected and everything registered again (MasterWatch, master_watch.h).
//
// Threads: ros::spin (image callbacks, ~reset, diagnostics), the tracking worker, the system's own
// mapping and NeRF training threads, and the "NeRF publisher" thread (niceness ~nerf_render_nice):
// renders ~nerf_view/~nerf_depth/~nerf_cloud and serves ~save_map. Rendering and saving never run
// on the image callbacks or the tracking worker; they read the model under NerfMapping::withModel,
// which pauses NeRF training (not tracking) for the render's duration.
//
// Published (private namespace unless noted):
//   tf                 ~map_frame -> ~camera_frame (T_map_camera at tracking time), per tracked frame;
//                      with ~publish_map_to_odom instead ~map_frame -> ~odom_frame, the REP-105
//                      correction T_map_cam * T_base_cam^-1 * T_odom_base^-1 (map_to_odom.h), and
//                      while tracking is lost the last correction again at each image's stamp
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
//   /diagnostics       diagnostic_updater: frames received/tracked, lost before the node (header.seq
//                      gaps), dropped (queue), refused
//                      (encoding, size, timestamp, calibration changed), tracking ms, image callback ms,
//                      state, keyframes, map points, image publishers, stream restarts and gaps,
//                      resident memory, master losses and re-registrations; NeRF steps, samples/s,
//                      views, running PSNR, renders, map saves
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
//   ~keyframe_poses_period double 0.5 (> 0)             tracking_node: s between ~keyframe_poses updates
//   ~calibration_change string  "refuse"                refuse | reset: frames whose camera_info differs
//                                                       from the map's calibration are refused (counted,
//                                                       warned with both), or start a new map
//   ~stream_gap         double  1.0    (> 0)            s without images after which stamps may go back
//                                                       (a new stream); longer gaps are logged
//   ~publish_map_to_odom bool   false                   publish map -> ~odom_frame, not map -> ~camera_frame
//   ~odom_frame         string  "odom"                  the robot's odometry frame (odom -> ~base_frame on tf)
//   ~base_frame         string  "base_link"             the robot's base (static ~base_frame -> ~camera_frame)
//   ~tf_timeout         double  0.1    (0..10)          s the map -> odom lookups wait for the robot's tf
// The NeRF topics, ~save_map and the parameters from ~map_frame on are shared with nerf_mapping_node
// (nerf_publisher.h).
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseStamped.h>
#include <image_transport/image_transport.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <std_msgs/String.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/transform_broadcaster.h>
#include <visualization_msgs/MarkerArray.h>

#include "nerfslam/core/bounded_queue.h"
#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/nerf_mapping.h"
#include "nerfslam/system/slam_system.h"
#include "nerfslam_ros/conversions.h"
#include "nerfslam_ros/keyframe_link.h"
#include "nerfslam_ros/map_to_odom.h"
#include "nerfslam_ros/master_watch.h"
#include "nerfslam_ros/nerf_publisher.h"
#include "nerfslam_ros/slam_node.h"

namespace {

using nerfslam::Camera;
using nerfslam::SE3;
using nerfslam::SlamSystem;
using nerfslam::rosnode::SlamNodeMode;

struct Params {
  SlamNodeMode mode = SlamNodeMode::kFull;
  nerfslam::rosnode::NerfParams nerf;  // ~map_frame, ~camera_frame, ~nerf*, ~map_dir (nerf_publisher.h)
  std::string camera_yaml;
  int queue_size = 2;
  bool wait_for_mapping = false;
  double map_points_period = 1.0;
  int weak_inliers = 60;
  double frustum_scale = 0.5;
  int max_features = 2000;
  double keyframe_poses_period = 0.5;  // tracking_node only
  std::string calibration_change = "refuse";
  double stream_gap = 1.0;
  nerfslam::rosnode::MapToOdomParams odom;  // ~publish_map_to_odom, ~odom_frame, ~base_frame, ~tf_timeout
};

bool isColourEncoding(const std::string& e) { return e == "bgr8" || e == "rgb8" || e == "bgra8" || e == "rgba8"; }

// Reads, prints and validates the parameters; returns an error message or "".
std::string loadParams(ros::NodeHandle& pnh, Params& p) {
  const bool tracking = p.mode == SlamNodeMode::kTracking;
  pnh.param("camera_yaml", p.camera_yaml, p.camera_yaml);
  pnh.param("queue_size", p.queue_size, p.queue_size);
  pnh.param("wait_for_mapping", p.wait_for_mapping, p.wait_for_mapping);
  pnh.param("map_points_period", p.map_points_period, p.map_points_period);
  pnh.param("weak_inliers", p.weak_inliers, p.weak_inliers);
  pnh.param("frustum_scale", p.frustum_scale, p.frustum_scale);
  pnh.param("max_features", p.max_features, p.max_features);
  if (tracking) pnh.param("keyframe_poses_period", p.keyframe_poses_period, p.keyframe_poses_period);
  pnh.param("calibration_change", p.calibration_change, p.calibration_change);
  pnh.param("stream_gap", p.stream_gap, p.stream_gap);
  ROS_INFO("%s parameters:", tracking ? "tracking_node" : "nerfslam_node");
  ROS_INFO("  ~camera_yaml = %s", p.camera_yaml.empty() ? "(none: camera_info)" : p.camera_yaml.c_str());
  ROS_INFO("  ~queue_size = %d", p.queue_size);
  ROS_INFO("  ~wait_for_mapping = %s", p.wait_for_mapping ? "true" : "false");
  ROS_INFO("  ~map_points_period = %g s", p.map_points_period);
  ROS_INFO("  ~weak_inliers = %d", p.weak_inliers);
  ROS_INFO("  ~frustum_scale = %g", p.frustum_scale);
  ROS_INFO("  ~max_features = %d", p.max_features);
  if (tracking) ROS_INFO("  ~keyframe_poses_period = %g s", p.keyframe_poses_period);
  ROS_INFO("  ~calibration_change = %s", p.calibration_change.c_str());
  ROS_INFO("  ~stream_gap = %g s", p.stream_gap);
  // tracking_node: the NeRF runs in nerf_mapping_node (~nerf is not read).
  if (tracking) p.nerf.nerf = false;
  if (std::string err = nerfslam::rosnode::loadNerfParams(pnh, p.nerf, !tracking); !err.empty()) return err;
  if (std::string err = nerfslam::rosnode::loadMapToOdomParams(pnh, p.odom, p.nerf.map_frame, p.nerf.camera_frame);
      !err.empty())
    return err;
  if (p.queue_size < 1) return "~queue_size must be >= 1 (got " + std::to_string(p.queue_size) + ")";
  if (!(p.map_points_period >= 0) || !std::isfinite(p.map_points_period))
    return "~map_points_period must be >= 0 (got " + std::to_string(p.map_points_period) + ")";
  if (p.weak_inliers < 0) return "~weak_inliers must be >= 0 (got " + std::to_string(p.weak_inliers) + ")";
  if (!(p.frustum_scale > 0) || !std::isfinite(p.frustum_scale))
    return "~frustum_scale must be > 0 (got " + std::to_string(p.frustum_scale) + ")";
  if (p.max_features < 50) return "~max_features must be >= 50 (got " + std::to_string(p.max_features) + ")";
  if (!(p.keyframe_poses_period > 0) || !std::isfinite(p.keyframe_poses_period))
    return "~keyframe_poses_period must be > 0 (got " + std::to_string(p.keyframe_poses_period) + ")";
  if (p.calibration_change != "refuse" && p.calibration_change != "reset")
    return "~calibration_change must be refuse or reset (got " + p.calibration_change + ")";
  if (!(p.stream_gap > 0) || !std::isfinite(p.stream_gap))
    return "~stream_gap must be > 0 (got " + std::to_string(p.stream_gap) + ")";
  return "";
}

// Same calibration (size, intrinsics, distortion), up to rounding: the library's comparison.
bool sameCamera(const Camera& a, const Camera& b) { return !calibrationDifference(a, b); }

struct QueuedFrame {
  sensor_msgs::ImageConstPtr image;
  std::shared_ptr<const Camera> camera;
};

// The last tracked pose (what ~nerf_view is rendered from).
using TrackedPose = nerfslam::rosnode::ViewPose;
// What the NeRF publisher thread and the services need of the running system. The worker replaces it
// (under handle_mutex_) when it starts or resets the system; readers copy the shared_ptr and use the
// system without blocking tracking (NerfMapping, Map and saveMapFolder are thread-safe). The last
// holder destroys the system (after the worker's finish()).
using SystemHandle = nerfslam::rosnode::MapSource;

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
    if (tracking())
      sender_ = std::make_unique<nerfslam::rosnode::KeyframeSender>(pnh_, mapFrame(), p_.keyframe_poses_period);
    path_pub_ = pnh_.advertise<nav_msgs::Path>("path", 2, true);
    points_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("map_points", 2, true);
    keyframes_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("keyframes", 2, true);
    state_pub_ = pnh_.advertise<std_msgs::String>("tracking_state", 10, true);
    reset_srv_ = pnh_.advertiseService("reset", &NerfslamNode::onReset, this);
    localization_srv_ = pnh_.advertiseService("set_localization_only", &NerfslamNode::onSetLocalizationOnly, this);
    // The NeRF topics and ~save_map, on the NeRF publisher thread.
    nerf_pub_ = std::make_unique<nerfslam::rosnode::NerfPublisher>(
        pnh_, p_.nerf, [this] { return handle(); },
        [this]() -> std::optional<TrackedPose> {
          std::lock_guard<std::mutex> lock(pose_mutex_);
          return last_pose_;
        });
    publishState("initializing");

    updater_.setHardwareID("nerfslam");
    updater_.add(tracking() ? "tracking_node" : "nerfslam_node", this, &NerfslamNode::diagnose);
    diag_timer_ =
        nh_.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) { updater_.force_update(); });

    // roscpp's subscriber queue only fills while this thread's callbacks are starved (they just
    // enqueue); at least ~queue_size deep, so that frames the node's own queue would keep are not
    // dropped before it (what it drops is counted as seq gaps).
    const uint32_t ros_queue = static_cast<uint32_t>(std::max(5, p_.queue_size));
    if (yaml_camera_) {
      image_sub_ = it_.subscribe("image", ros_queue, &NerfslamNode::onImage, this);
    } else {
      camera_sub_ = it_.subscribeCamera("image", ros_queue, &NerfslamNode::onCamera, this);
    }
    wait_timer_ = nh_.createWallTimer(ros::WallDuration(2.0), [this](const ros::WallTimerEvent&) { checkInput(); });
    publishers_timer_ =
        nh_.createWallTimer(ros::WallDuration(0.1), [this](const ros::WallTimerEvent&) { watchPublishers(); });
    if (p_.odom.enabled)
      map_to_odom_ = std::make_unique<nerfslam::rosnode::MapToOdomPublisher>(p_.odom, mapFrame(), cameraFrame());
    worker_ = std::thread([this] { work(); });
    nerf_pub_->start();
    if (sender_) sender_->start();
  }

  ~NerfslamNode() {
    stopping_ = true;
    queue_.close();
    if (worker_.joinable()) worker_.join();
    const std::string odom_summary = map_to_odom_ ? "; " + map_to_odom_->summary() : "";
    map_to_odom_.reset();
    nerf_pub_->stop();
    if (sender_) {
      sender_->stop();
      sender_->attach(nullptr);
    }
    setHandle(nullptr);
    std::lock_guard<std::mutex> lock(system_mutex_);
    if (system_) system_->finish(false);
    // stdout: rosconsole no longer prints once ros::shutdown() has run.
    std::printf(
        "%s: %lu frames received, %lu processed, %lu tracked, %lu dropped (queue full), refused: "
        "%lu encoding, %lu size, %lu timestamp; mean tracking %.1f ms; image callback mean %.3f ms, max %.3f ms; "
        "frame latency (stamp to pose, live stamps) mean %.1f ms, max %.1f ms; %s%s%s\n",
        tracking() ? "tracking_node" : "nerfslam_node", static_cast<unsigned long>(received_),
        static_cast<unsigned long>(processed_), static_cast<unsigned long>(tracked_),
        static_cast<unsigned long>(queue_.dropped()), static_cast<unsigned long>(refused_encoding_),
        static_cast<unsigned long>(refused_size_), static_cast<unsigned long>(refused_stamp_),
        processed_ > 0 ? tracking_ms_sum_.load() / processed_ : 0.0,
        callbacks_ > 0 ? callback_ms_sum_.load() / callbacks_ : 0.0, callback_ms_max_.load(),
        latency_count_ > 0 ? latency_ms_sum_.load() / latency_count_ : 0.0, latency_ms_max_.load(),
        nerf_pub_->summary().c_str(),
        sender_ ? ("; " + std::to_string(sender_->keyframesSent()) + " keyframes and " +
                   std::to_string(sender_->poseUpdatesSent()) + " pose updates sent")
                      .c_str()
                : "",
        odom_summary.c_str());
    std::fflush(stdout);
  }

 private:
  bool tracking() const { return p_.mode == SlamNodeMode::kTracking; }
  const std::string& mapFrame() const { return p_.nerf.map_frame; }
  const std::string& cameraFrame() const { return p_.nerf.camera_frame; }

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
    countLost(image->header.seq);
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
      system_camera_ = cam;  // the first frame (after ~reset) fixes the calibration and image size
    } else if (static_cast<int>(image->width) != system_camera_->width ||
               static_cast<int>(image->height) != system_camera_->height) {
      ++refused_size_;
      ROS_ERROR_THROTTLE(5.0,
                         "refusing %ux%u image: the map was built on %dx%d images (call ~reset to start a new map "
                         "on the new size); %lu refused so far",
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
    noteStream(*image);
    if (have_last_stamp_ && image->header.stamp <= last_stamp_) {
      ++refused_stamp_;
      ROS_WARN_THROTTLE(5.0, "dropping frame stamped %.6f: not after the previous frame (%.6f); %lu dropped so far",
                        image->header.stamp.toSec(), last_stamp_.toSec(), static_cast<unsigned long>(refused_stamp_));
      return;
    }
    if (!sameCamera(*cam, *system_camera_)) {
      // The map (its points, keyframes and NeRF) was built with system_camera_: frames of another
      // calibration would be tracked with wrong intrinsics.
      if (p_.calibration_change == "reset") {
        ROS_WARN("camera_info changed from [%s] to [%s]: starting a new map with it (~calibration_change reset)",
                 system_camera_->describe().c_str(), cam->describe().c_str());
        system_camera_ = cam;  // the worker restarts the system on the new calibration
      } else {
        ++refused_calibration_change_;
        ROS_WARN_THROTTLE(5.0,
                          "refusing frame: camera_info changed from [%s] (the calibration the map was built with) "
                          "to [%s]; call ~reset to start a new map with it (or set ~calibration_change reset); "
                          "%lu refused so far",
                          system_camera_->describe().c_str(), cam->describe().c_str(),
                          static_cast<unsigned long>(refused_calibration_change_));
        return;
      }
    }
    if (have_last_stamp_ && (image->header.stamp - last_stamp_).toSec() > p_.stream_gap) {
      ++stream_gaps_;
      ROS_WARN(
          "gap of %.2f s in the image stream (publisher restarted or stalled?) (frames stamped %.6f then %.6f); "
          "%lu gaps so far",
          (image->header.stamp - last_stamp_).toSec(), last_stamp_.toSec(), image->header.stamp.toSec(),
          static_cast<unsigned long>(stream_gaps_));
    }
    last_stamp_ = image->header.stamp;
    have_last_stamp_ = true;
    const uint64_t dropped_before = queue_.dropped();
    queue_.tryPush(QueuedFrame{image, system_camera_});
    if (queue_.dropped() > dropped_before)
      ROS_WARN_THROTTLE(5.0, "tracking falls behind: oldest queued frame dropped (%lu dropped so far)",
                        static_cast<unsigned long>(queue_.dropped()));
  }

  // A restarted image publisher (a restarted driver, recording or dataset player): after at least
  // ~stream_gap s without images, with a single publisher connected, a frame stamped before the
  // previous one starts a new stream (the ordering check starts over) instead of being refused; a frame
  // stamped later is a gap. While images keep coming, or several publishers are connected, stamps must
  // keep increasing. input_mutex_ held.
  void noteStream(const sensor_msgs::Image& image) {
    const double now = ros::WallTime::now().toSec();
    const double silence = now - last_accepted_wall_;
    last_accepted_wall_ = now;
    if (!have_last_stamp_ || silence < p_.stream_gap) return;
    const double jump = (image.header.stamp - last_stamp_).toSec();
    if (jump > 0) return;  // a gap: counted by enqueue
    const uint32_t publishers = yaml_camera_ ? image_sub_.getNumPublishers() : camera_sub_.getNumPublishers();
    if (publishers > 1) return;
    ++stream_restarts_;
    ROS_WARN(
        "new image stream after %.2f s without images: stamps went back by %.3f s (a restarted publisher or "
        "recording); frames are taken from it, tracking relocalises against the map; %lu stream restarts so far",
        silence, -jump, static_cast<unsigned long>(stream_restarts_));
    have_last_stamp_ = false;
  }
  // Says when the image publishers are gone (sampled every 0.1 s; roscpp keeps the link of a killed
  // publisher, retrying it, until the master hears of its end or of its replacement).
  void watchPublishers() {
    const uint32_t publishers = yaml_camera_ ? image_sub_.getNumPublishers() : camera_sub_.getNumPublishers();
    const uint32_t before = publishers_.exchange(publishers);
    if (publishers == 0 && before > 0 && received_ > 0)
      ROS_WARN("the image publisher disconnected after %lu frames received; waiting for images",
               static_cast<unsigned long>(received_));
  }

  // Frames lost before they reached the node (roscpp's subscriber queue overflowing while the callbacks
  // were starved, an image without its camera_info): gaps in header.seq, when the publisher numbers its
  // frames (image_folder_publisher does; a seq that does not increase starts over; with several
  // publishers interleaving on the topic the count is meaningless).
  void countLost(uint32_t seq) {
    const uint32_t last = last_seq_.exchange(seq);
    if (have_seq_.exchange(true) && seq > last + 1 && seq - last < 100000) lost_ += seq - last - 1;
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
    {
      // The next frame fixes the calibration and image size again (a new camera is taken).
      std::lock_guard<std::mutex> lock(input_mutex_);
      system_camera_.reset();
      have_last_stamp_ = false;
    }
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
      const bool new_calibration = system_ && !sameCamera(*item->camera, *worker_camera_);
      if (new_calibration)
        ROS_WARN("new calibration [%s] (was [%s]): the map is discarded and a new one started",
                 item->camera->describe().c_str(), worker_camera_->describe().c_str());
      if ((reset_requested_.exchange(false) || new_calibration) && system_) {
        setHandle(nullptr);  // the NeRF publisher and the services stop using it
        if (sender_) sender_->attach(nullptr);
        system_->finish(false);
        system_.reset();  // destroyed here, or by the last reader still holding it
        ++resets_;
        if (map_to_odom_) map_to_odom_->forget();  // its corrections were for the discarded map
      }
      if (!system_) {
        nerfslam::SystemOptions opt;
        opt.tracking.features.max_features = p_.max_features;
        opt.lockstep = false;
        opt.nerf.enabled = p_.nerf.nerf;
        opt.nerf.threads = p_.nerf.nerf_threads;
        opt.nerf.nice_increment = p_.nerf.nerf_nice;
        try {
          system_ = std::make_shared<SlamSystem>(*item->camera, opt);
          worker_camera_ = item->camera;
        } catch (const std::exception& e) {
          ++tracking_errors_;
          ROS_ERROR_THROTTLE(5.0, "cannot start the SLAM system: %s", e.what());
          continue;
        }
        // Before the first frame: every keyframe the mapping inserts reaches ~keyframes_out.
        if (sender_) sender_->attach(system_);
        auto h = std::make_shared<SystemHandle>();
        h->owner = system_;
        h->map = &system_->map();
        h->nerf = system_->nerf();
        h->camera = item->camera;
        h->options = opt;
        h->generation = ++generation_;
        setHandle(std::move(h));
        ROS_INFO("SLAM system started on %dx%d images%s", item->camera->width, item->camera->height,
                 p_.nerf.nerf ? " with the NeRF mapping thread"
                 : tracking() ? " (sparse only; keyframes go out on ~keyframes_out)"
                              : " (sparse only: ~nerf is false)");
      }
      const auto& msg = *item->image;
      // The NeRF trains on colour: colour encodings go in as BGR (tracking converts to grey itself);
      // the tracking node keeps them for the keyframes it sends to nerf_mapping_node.
      const bool wants_colour = p_.nerf.nerf || tracking();
      const bool colour = wants_colour && isColourEncoding(msg.encoding);
      if (wants_colour && !colour && !warned_grey_input_) {
        warned_grey_input_ = true;
        ROS_WARN("images are '%s': the NeRF trains on grey (publish bgr8/rgb8 for a colour NeRF)",
                 msg.encoding.c_str());
      }
      if (map_to_odom_ && !msg.header.frame_id.empty() && msg.header.frame_id != cameraFrame() && !warned_frame_id_) {
        warned_frame_id_ = true;
        ROS_WARN(
            "images are in frame '%s' but ~camera_frame is '%s': map -> %s is computed through tf %s -> %s; "
            "set ~camera_frame to the camera's optical frame if that is not where it is mounted",
            msg.header.frame_id.c_str(), cameraFrame().c_str(), p_.odom.odom_frame.c_str(), p_.odom.base_frame.c_str(),
            cameraFrame().c_str());
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
      // A frame has one parent on tf: with the REP-105 correction the camera's is the robot's base.
      if (map_to_odom_)
        map_to_odom_->push(stamp, rec.T_world_cam);
      else
        tf_.sendTransform(nerfslam::rosbridge::toTransformStamped(rec.T_world_cam, mapFrame(), cameraFrame(), stamp));
      geometry_msgs::PoseStamped ps;
      ps.header.stamp = stamp;
      ps.header.frame_id = mapFrame();
      ps.pose = nerfslam::rosbridge::toPose(rec.T_world_cam);
      pose_pub_.publish(ps);
    } else if (map_to_odom_) {
      // REP-105: while lost, map -> odom stays available (the last correction, at this stamp); while
      // initialising there is no map it belongs to.
      if (rec.state == nerfslam::TrackingState::kLost)
        map_to_odom_->pushLost(stamp);
      else if (rec.state == nerfslam::TrackingState::kNotInitialized)
        map_to_odom_->forget();
    }
    if (system_->initialized()) {
      nav_msgs::Path path;
      path.header.stamp = stamp;
      path.header.frame_id = mapFrame();
      for (const auto& e : system_->trajectory()) {
        geometry_msgs::PoseStamped ps;
        ps.header.stamp = ros::Time(e.timestamp);
        ps.header.frame_id = mapFrame();
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
    sensor_msgs::PointCloud2 cloud;
    cloud.header.stamp = stamp;
    cloud.header.frame_id = mapFrame();
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
    m.header.frame_id = mapFrame();
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

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) {
    std::string state;
    {
      std::lock_guard<std::mutex> lock(diag_mutex_);
      state = state_;
    }
    // The map's own counts (0 while no system runs), not those of the last published cloud: that is
    // only refreshed when a frame arrives, so keyframes the mapping thread adds while no images come
    // would not show.
    size_t points = 0, kfs = 0;
    if (const auto h = handle(); h && h->map) {
      kfs = h->map->numKeyframes();
      points = h->map->numPoints();
    }
    const uint64_t dropped = queue_.dropped();
    if (state == "lost")
      s.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "tracking lost");
    else if (state == "weak" || dropped > 0 ||
             refused_encoding_ + refused_size_ + refused_stamp_ + refused_calibration_change_ > 0)
      s.summary(
          diagnostic_msgs::DiagnosticStatus::WARN,
          "tracking " + state + (dropped > 0 ? ", frames dropped" : "") +
              (refused_encoding_ + refused_size_ + refused_stamp_ + refused_calibration_change_ > 0 ? ", frames refused"
                                                                                                    : ""));
    else
      s.summary(diagnostic_msgs::DiagnosticStatus::OK, "tracking " + state);
    const uint64_t processed = processed_;
    s.add("state", state);
    s.add("frames received", static_cast<uint64_t>(received_));
    s.add("frames lost before the node (seq gaps)", static_cast<uint64_t>(lost_));
    s.add("frames processed", processed);
    s.add("frames tracked", static_cast<uint64_t>(tracked_));
    s.add("frames dropped (queue full)", dropped);
    s.add("frames refused (encoding)", static_cast<uint64_t>(refused_encoding_));
    s.add("frames refused (size)", static_cast<uint64_t>(refused_size_));
    s.add("frames refused (timestamp)", static_cast<uint64_t>(refused_stamp_));
    s.add("frames refused (calibration changed)", static_cast<uint64_t>(refused_calibration_change_));
    s.add("camera_info refused", static_cast<uint64_t>(refused_calibration_));
    s.add("tracking errors", static_cast<uint64_t>(tracking_errors_));
    s.add("queue", std::to_string(queue_.size()) + "/" + std::to_string(queue_.capacity()));
    s.addf("tracking ms (last)", "%.1f", tracking_ms_last_.load());
    s.addf("tracking ms (mean)", "%.1f", processed > 0 ? tracking_ms_sum_.load() / processed : 0.0);
    s.add("keyframes", kfs);
    s.add("map points", points);
    s.add("resets", static_cast<uint64_t>(resets_));
    s.add("image publishers", static_cast<uint64_t>(publishers_));
    s.add("image stream restarts", static_cast<uint64_t>(stream_restarts_));
    s.add("image stream gaps", static_cast<uint64_t>(stream_gaps_));
    s.addf("resident memory (MB)", "%.1f", nerfslam::currentRssMb());
    master_watch_.diagnose(s);
    const uint64_t callbacks = callbacks_;
    s.addf("image callback ms (mean)", "%.3f", callbacks > 0 ? callback_ms_sum_.load() / callbacks : 0.0);
    s.addf("image callback ms (max)", "%.3f", callback_ms_max_.load());
    const uint64_t lat = latency_count_;
    s.addf("frame latency ms (mean)", "%.1f", lat > 0 ? latency_ms_sum_.load() / lat : 0.0);
    s.addf("frame latency ms (max)", "%.1f", latency_ms_max_.load());
    if (sender_) {
      s.add("keyframes sent", sender_->keyframesSent());
      s.add("keyframe pose updates sent", sender_->poseUpdatesSent());
      s.add("keyframes dropped (sender behind)", sender_->keyframesDropped());
      s.add("keyframe session", static_cast<uint64_t>(sender_->session()));
    }
    nerf_pub_->diagnose(s);
    if (map_to_odom_) map_to_odom_->diagnose(s);
  }

  ros::NodeHandle nh_, pnh_;
  Params p_;
  image_transport::ImageTransport it_;
  diagnostic_updater::Updater updater_;
  image_transport::CameraSubscriber camera_sub_;
  image_transport::Subscriber image_sub_;
  ros::Publisher pose_pub_, path_pub_, points_pub_, keyframes_pub_, state_pub_;
  ros::ServiceServer reset_srv_, localization_srv_;
  tf2_ros::TransformBroadcaster tf_;
  ros::WallTimer diag_timer_, wait_timer_, publishers_timer_;

  std::shared_ptr<const Camera> yaml_camera_;
  // Input side (callbacks).
  std::mutex input_mutex_;
  sensor_msgs::CameraInfoConstPtr last_info_;
  std::shared_ptr<const Camera> info_camera_;
  std::shared_ptr<const Camera> system_camera_;
  ros::Time last_stamp_;
  bool have_last_stamp_ = false;
  std::atomic<uint32_t> publishers_{0};  // image publishers connected at the last watchPublishers()
  double last_accepted_wall_ = 0;        // wall s of the last frame of the right size (noteStream)
  std::atomic<double> last_input_{0.0};  // wall seconds
  nerfslam::BoundedQueue<QueuedFrame> queue_;

  // Worker side.
  std::mutex system_mutex_;
  std::shared_ptr<SlamSystem> system_;
  uint64_t generation_ = 0;  // of system_ (worker only)
  bool warned_grey_input_ = false;
  bool warned_frame_id_ = false;
  std::atomic<bool> reset_requested_{false}, stopping_{false}, localization_only_{false};
  std::shared_ptr<const Camera> worker_camera_;
  ros::WallTime last_map_publish_;
  std::thread worker_;

  // Shared with the NeRF publisher thread and the services.
  mutable std::mutex handle_mutex_;
  std::shared_ptr<const SystemHandle> handle_;
  std::mutex pose_mutex_;
  std::optional<TrackedPose> last_pose_;
  std::unique_ptr<nerfslam::rosnode::NerfPublisher> nerf_pub_;  // ~nerf_*, ~save_map
  std::unique_ptr<nerfslam::rosnode::KeyframeSender> sender_;   // tracking_node: ~keyframes_out, ~keyframe_poses
  std::unique_ptr<nerfslam::rosnode::MapToOdomPublisher> map_to_odom_;  // ~publish_map_to_odom

  // Statistics.
  std::atomic<uint64_t> received_{0}, processed_{0}, tracked_{0}, refused_encoding_{0}, refused_size_{0},
      refused_stamp_{0}, refused_calibration_{0}, refused_calibration_change_{0}, tracking_errors_{0}, resets_{0},
      stream_restarts_{0}, stream_gaps_{0}, lost_{0};
  std::atomic<uint32_t> last_seq_{0};
  std::atomic<bool> have_seq_{false};
  std::atomic<double> tracking_ms_last_{0}, tracking_ms_sum_{0};
  std::atomic<uint64_t> callbacks_{0}, latency_count_{0};
  std::atomic<double> latency_ms_sum_{0}, latency_ms_max_{0};
  std::atomic<double> callback_ms_sum_{0}, callback_ms_max_{0};
  std::mutex diag_mutex_;
  std::string state_;
  nerfslam::rosnode::MasterWatch master_watch_;  // re-registers with a restarted master
};

}  // namespace

namespace nerfslam::rosnode {

int runSlamNode(int argc, char** argv, SlamNodeMode mode) {
  ros::init(argc, argv, mode == SlamNodeMode::kTracking ? "tracking_node" : "nerfslam_node");
  Params p;
  p.mode = mode;
  return spinNode<NerfslamNode>(p, loadParams);
}

}  // namespace nerfslam::rosnode
