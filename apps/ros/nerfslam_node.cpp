// nerfslam_node and tracking_node (one implementation, SlamNodeMode, slam_node.h): the SLAM system
// (nerfslam::SlamSystem) on an image + camera_info stream. Topics, services, parameters, threads and
// the handling of faulty input: docs/ros.md ("nerfslam_node", "tracking_node"). Here: the input
// callbacks (they check and enqueue), the tracking worker, the diagnostics; the parameters are
// node_params.h, what is published per frame slam_publishers.h, the NeRF topics nerf_publisher.h.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include <diagnostic_updater/diagnostic_updater.h>
#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>

#include "nerfslam/core/bounded_queue.h"
#include "nerfslam/core/camera.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/slam_system.h"
#include "nerfslam_ros/conversions.h"
#include "nerfslam_ros/keyframe_link.h"
#include "nerfslam_ros/map_to_odom.h"
#include "nerfslam_ros/master_watch.h"
#include "nerfslam_ros/nerf_publisher.h"
#include "nerfslam_ros/node_params.h"
#include "nerfslam_ros/slam_node.h"
#include "nerfslam_ros/slam_publishers.h"

namespace {

using nerfslam::Camera;
using nerfslam::SE3;
using nerfslam::SlamSystem;
using nerfslam::rosnode::SlamNodeMode;

using Params = nerfslam::rosnode::SlamNodeParams;

bool isColourEncoding(const std::string& e) { return e == "bgr8" || e == "rgb8" || e == "bgra8" || e == "rgba8"; }

// "fx 262.5 -> 288.75": the first calibration field that differs (calibrationDifference), for warnings.
std::string calibrationChange(const Camera& from, const Camera& to) {
  const auto d = nerfslam::calibrationDifference(from, to);
  return d ? d->field + " " + d->a + " -> " + d->b : "no change";
}

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
        queue_(p_.node.queue_size, nerfslam::OverflowPolicy::kDropOldest),
        map_mode_(nerfslam::rosnode::mapModeOf(p_.node)),
        localization_only_(map_mode_ == nerfslam::MapMode::kLocalize) {
    if (!p_.node.camera_yaml.empty()) {
      yaml_camera_ = std::make_shared<const Camera>(nerfslam::loadCameraYaml(p_.node.camera_yaml));  // throws
      ROS_INFO("calibration from %s: %dx%d fx=%.3f fy=%.3f cx=%.3f cy=%.3f", p_.node.camera_yaml.c_str(),
               yaml_camera_->width, yaml_camera_->height, yaml_camera_->fx, yaml_camera_->fy, yaml_camera_->cx,
               yaml_camera_->cy);
    }
    if (map_mode_ != nerfslam::MapMode::kSlam) loadStartMap();  // throws: ROS_FATAL, exit status 1 (spinNode)
    pub_ = std::make_unique<nerfslam::rosnode::SlamPublishers>(pnh_, p_);
    if (tracking())
      sender_ = std::make_unique<nerfslam::rosnode::KeyframeSender>(pnh_, mapFrame(), p_.node.keyframe_poses_period);
    reset_srv_ = pnh_.advertiseService("reset", &NerfslamNode::onReset, this);
    localization_srv_ = pnh_.advertiseService("set_localization_only", &NerfslamNode::onSetLocalizationOnly, this);
    // The NeRF topics and ~save_map, on the NeRF publisher thread.
    nerf_pub_ = std::make_unique<nerfslam::rosnode::NerfPublisher>(
        pnh_, p_.topics, p_.slam.nerf.enabled, [this] { return handle(); },
        [this]() -> std::optional<TrackedPose> {
          std::lock_guard<std::mutex> lock(pose_mutex_);
          return last_pose_;
        });
    pub_->publishState("initializing");

    updater_.setHardwareID("nerfslam");
    updater_.add(tracking() ? "tracking_node" : "nerfslam_node", this, &NerfslamNode::diagnose);
    diag_timer_ =
        nh_.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) { updater_.force_update(); });

    // roscpp's subscriber queue only fills while this thread's callbacks are starved (they just
    // enqueue); at least ~queue_size deep, so that frames the node's own queue would keep are not
    // dropped before it (what it drops is counted as seq gaps).
    const uint32_t ros_queue = static_cast<uint32_t>(std::max(5, p_.node.queue_size));
    if (yaml_camera_) {
      image_sub_ = it_.subscribe("image", ros_queue, &NerfslamNode::onImage, this);
    } else {
      camera_sub_ = it_.subscribeCamera("image", ros_queue, &NerfslamNode::onCamera, this);
    }
    wait_timer_ = nh_.createWallTimer(ros::WallDuration(2.0), [this](const ros::WallTimerEvent&) { checkInput(); });
    publishers_timer_ =
        nh_.createWallTimer(ros::WallDuration(0.1), [this](const ros::WallTimerEvent&) { watchPublishers(); });
    worker_ = std::thread([this] { work(); });
    nerf_pub_->start();
    if (sender_) sender_->start();
  }

  ~NerfslamNode() {
    // ~save_on_shutdown: the whole shutdown (the worker's last frame, mapping's queued keyframes, the
    // save) is bounded by ~save_on_shutdown_timeout.
    std::optional<ShutdownWatchdog> watchdog;
    if (p_.node.save_on_shutdown) watchdog.emplace(p_.node.save_on_shutdown_timeout, saveOnShutdownDir());
    stopping_ = true;
    queue_.close();
    if (worker_.joinable()) worker_.join();
    std::string odom_summary = pub_->stopMapToOdom();
    if (!odom_summary.empty()) odom_summary = "; " + odom_summary;
    nerf_pub_->stop();
    if (sender_) {
      sender_->stop();
      sender_->attach(nullptr);
    }
    if (p_.node.save_on_shutdown) saveOnShutdown(*watchdog);
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
  const std::string& mapFrame() const { return p_.topics.map_frame; }
  const std::string& cameraFrame() const { return p_.topics.camera_frame; }

  // ---- ~map: the saved map the node starts from ----
  // At start: the folder loaded and verified (with ~camera_yaml's calibration when set; otherwise the
  // first frame's camera_info is checked against it, prepareSystem). Throws an Error naming ~map.
  void loadStartMap() {
    map_dir_ = nerfslam::rosnode::resolveMapDir(p_.node.map);
    const std::string what = "~map " + map_dir_.string() + " (~map_mode " + p_.node.map_mode + ")";
    try {
      start_map_ = std::make_unique<nerfslam::LoadedMap>(nerfslam::loadMapFolder(
          map_dir_, yaml_camera_ ? std::optional<Camera>(*yaml_camera_) : std::optional<Camera>()));
    } catch (const std::exception& e) {
      throw nerfslam::Error(what + ": cannot load the map: " + e.what());
    }
    if (!start_map_->map || start_map_->map->numKeyframes() == 0)
      throw nerfslam::Error(what + ": the map has no keyframes");
    map_keyframes_ = start_map_->map->numKeyframes();
    if (start_map_->nerf_model && !p_.slam.nerf.enabled)
      ROS_WARN(
          "%s has a NeRF model, which this node does not use (%s): a map it saves (~save_map, "
          "~save_on_shutdown) has none; do not save it over this folder to keep the model",
          what.c_str(), tracking() ? "tracking_node trains no NeRF" : "~nerf false");
    ROS_INFO("%s: generation %lu, %zu keyframes, %zu points, %s, camera %s, loaded in %.2f s; %s", what.c_str(),
             static_cast<unsigned long>(start_map_->generation), start_map_->map->numKeyframes(),
             start_map_->map->numPoints(),
             !start_map_->nerf_model                   ? "no NeRF model"
             : !p_.slam.nerf.enabled                   ? "a NeRF model (not used: no NeRF in this node)"
             : map_mode_ == nerfslam::MapMode::kExtend ? "a NeRF model (trains on)"
                                                       : "a NeRF model (frozen)",
             start_map_->camera.describe().c_str(), start_map_->seconds,
             map_mode_ == nerfslam::MapMode::kExtend
                 ? "the node relocalises in it, then maps on (new keyframes and points)"
                 : "the node relocalises in it, then tracks against it without changing it (no keyframes added)");
  }

  // A fatal error found while running (e.g. a ~map of another camera): said, and the node exits with
  // status 1 instead of going on without the map.
  void fatal(const std::string& message) {
    ROS_FATAL("%s", message.c_str());
    std::fprintf(stderr, "FATAL: %s\n", message.c_str());
    nerfslam::rosnode::nodeExitCode() = 1;
    fatal_ = true;
    ros::requestShutdown();
  }

  std::filesystem::path saveOnShutdownDir() const {
    return nerfslam::rosnode::resolveMapDir(p_.node.save_on_shutdown_dir.empty() ? p_.topics.map_dir
                                                                                 : p_.node.save_on_shutdown_dir);
  }

  // Exits the process (status 1) when the shutdown takes longer than `seconds`: a map folder's save
  // is atomic, so the folder keeps its previous map. The deadline counts from construction; the save
  // itself checks it before it starts (expired()), so a watchdog thread the scheduler has not yet run
  // cannot let an overdue shutdown save anyway.
  class ShutdownWatchdog {
   public:
    ShutdownWatchdog(double seconds, const std::filesystem::path& dir)
        : seconds_(seconds),
          dir_(dir),
          deadline_(std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                                           std::chrono::duration<double>(seconds))) {
      std::printf("shutdown: saving the map into %s (~save_on_shutdown; at most %.1f s)\n", dir.c_str(), seconds);
      std::fflush(stdout);
      thread_ = std::thread([this] {
        std::unique_lock<std::mutex> lock(mutex_);
        if (cv_.wait_until(lock, deadline_, [this] { return done_; })) return;
        fire();
      });
    }
    ~ShutdownWatchdog() {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        done_ = true;
      }
      cv_.notify_all();
      thread_.join();
    }
    bool expired() const { return std::chrono::steady_clock::now() >= deadline_; }
    [[noreturn]] void fire() const {
      std::fprintf(stderr,
                   "shutdown: ~save_on_shutdown_timeout (%.1f s) reached before the map was saved into %s; exiting "
                   "with status 1 (the folder keeps its previous map)\n",
                   seconds_, dir_.c_str());
      std::fflush(stderr);
      std::_Exit(1);
    }

   private:
    const double seconds_;
    const std::filesystem::path dir_;
    const std::chrono::steady_clock::time_point deadline_;
    std::mutex mutex_;
    std::condition_variable cv_;
    bool done_ = false;
    std::thread thread_;
  };

  // ~save_on_shutdown, after the worker and the NeRF publisher stopped: mapping finishes the keyframes
  // it was given (no global BA), then the map folder is written as by ~save_map. stdout: rosconsole no
  // longer prints once ros::shutdown() has run.
  void saveOnShutdown(const ShutdownWatchdog& watchdog) {
    const std::filesystem::path dir = saveOnShutdownDir();
    std::error_code ec;
    if (map_mode_ == nerfslam::MapMode::kLocalize && localization_only_ &&
        std::filesystem::equivalent(dir, map_dir_, ec)) {
      std::printf("shutdown: the map in %s is not saved again: ~map_mode localize left it as it was\n", dir.c_str());
      std::fflush(stdout);
      return;
    }
    {
      std::lock_guard<std::mutex> lock(system_mutex_);
      if (system_) system_->finish(false);
    }
    if (watchdog.expired()) watchdog.fire();
    const auto t0 = std::chrono::steady_clock::now();
    std::string message;
    const auto outcome = nerf_pub_->saveMap(dir, &message);
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (outcome == nerfslam::rosnode::NerfPublisher::SaveOutcome::kSaved) {
      std::printf("shutdown: map saved: %s; %.2f s\n", message.c_str(), s);
    } else {
      std::fprintf(stderr, "shutdown: the map was not saved (~save_on_shutdown): %s\n", message.c_str());
      if (outcome == nerfslam::rosnode::NerfPublisher::SaveOutcome::kFailed) nerfslam::rosnode::nodeExitCode() = 1;
    }
    std::fflush(stdout);
    std::fflush(stderr);
  }

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
    if (nerfslam::calibrationDifference(*system_camera_, *cam)) {
      // The map (its points, keyframes and NeRF) was built with system_camera_: frames of another
      // calibration would be tracked with wrong intrinsics.
      const std::string change = calibrationChange(*system_camera_, *cam);
      if (p_.node.calibration_change == "reset") {
        ROS_WARN("camera_info changed from [%s] to [%s] (%s): starting a new map with it (~calibration_change reset)",
                 system_camera_->describe().c_str(), cam->describe().c_str(), change.c_str());
        system_camera_ = cam;  // the worker restarts the system on the new calibration
      } else {
        ++refused_calibration_change_;
        ROS_WARN_THROTTLE(5.0,
                          "refusing frame: camera_info changed from [%s] (the calibration the map was built with) "
                          "to [%s] (%s); call ~reset to start a new map with it (or set ~calibration_change reset); "
                          "%lu refused so far",
                          system_camera_->describe().c_str(), cam->describe().c_str(), change.c_str(),
                          static_cast<unsigned long>(refused_calibration_change_));
        return;
      }
    }
    if (have_last_stamp_ && (image->header.stamp - last_stamp_).toSec() > p_.node.stream_gap) {
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
    if (!have_last_stamp_ || silence < p_.node.stream_gap) return;
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
    while (!stopping_) {
      // While no frame comes, ~path catches up with the map (bundle adjustment after the last frame).
      auto item = queue_.popFor(std::chrono::milliseconds(250));
      if (stopping_ || (!item && queue_.closed())) break;
      std::unique_lock<std::mutex> lock(system_mutex_);
      if (!item) {
        if (system_) pub_->idle(*system_);
        continue;
      }
      if (prepareSystem(item->camera)) track(*item->image, index);
    }
  }

  // Discards the system on ~reset or a new calibration and starts one when there is none; false
  // when it cannot start. system_mutex_ held.
  bool prepareSystem(const std::shared_ptr<const Camera>& camera) {
    const bool new_calibration = system_ && nerfslam::calibrationDifference(*worker_camera_, *camera);
    if (new_calibration)
      ROS_WARN("new calibration [%s] (was [%s]; %s): the map is discarded and a new one started",
               camera->describe().c_str(), worker_camera_->describe().c_str(),
               calibrationChange(*worker_camera_, *camera).c_str());
    if ((reset_requested_.exchange(false) || new_calibration) && system_) {
      setHandle(nullptr);  // the NeRF publisher and the services stop using it
      if (sender_) sender_->attach(nullptr);
      system_->finish(false);
      system_.reset();  // destroyed here, or by the last reader still holding it
      ++resets_;
      pub_->newSystem();
    }
    if (system_) return true;
    if (fatal_) return false;
    nerfslam::SystemOptions opt = p_.slam;
    opt.lockstep = false;  // `nerfslam run`'s reader; recorded so in a saved map's options
    if (map_mode_ != nerfslam::MapMode::kSlam) {
      // From ~map (after a ~reset or a new calibration: loaded again), with the same code as `nerfslam
      // run --map`; a map of another camera is fatal (the node never maps from scratch instead).
      const std::string what = "~map " + map_dir_.string() + " (~map_mode " + p_.node.map_mode + ")";
      try {
        if (start_map_)
          nerfslam::checkSameCamera(start_map_->camera, *camera, "the images' camera_info");
        else
          start_map_ = std::make_unique<nerfslam::LoadedMap>(nerfslam::loadMapFolder(map_dir_, *camera));
      } catch (const std::exception& e) {
        start_map_.reset();
        fatal(what + ": " + e.what());
        return false;
      }
      try {
        system_ = nerfslam::startSlamSystem(*camera, opt, *start_map_, map_mode_);
        worker_camera_ = camera;
      } catch (const std::exception& e) {
        start_map_.reset();
        fatal(what + ": cannot start the SLAM system from it: " + e.what());
        return false;
      }
      start_map_.reset();
      ROS_INFO("SLAM system started from %s: lost until it relocalises in the map", what.c_str());
    } else {
      try {
        system_ = std::make_shared<SlamSystem>(*camera, opt);
        worker_camera_ = camera;
      } catch (const std::exception& e) {
        ++tracking_errors_;
        ROS_ERROR_THROTTLE(5.0, "cannot start the SLAM system: %s", e.what());
        return false;
      }
    }
    system_index0_ = -1;
    relocalized_frame_ = -1;
    relocalized_after_s_ = -1.0;
    pub_->newSystem();
    // Before the first frame: every keyframe the mapping inserts reaches ~keyframes_out.
    if (sender_) sender_->attach(system_);
    auto h = std::make_shared<SystemHandle>();
    h->owner = system_;
    h->map = &system_->map();
    h->nerf = system_->nerf();
    h->camera = camera;
    h->options = opt;
    h->generation = ++generation_;
    setHandle(std::move(h));
    ROS_INFO("SLAM system started on %dx%d images%s", camera->width, camera->height,
             opt.nerf.enabled ? " with the NeRF mapping thread"
             : tracking()     ? " (sparse only; keyframes go out on ~keyframes_out)"
                              : " (sparse only: nerf.enabled is false)");
    return true;
  }

  // Converts and tracks one frame (the index of the frames given to the system: `index`, counted up),
  // then publishes what it gave. system_mutex_ held.
  void track(const sensor_msgs::Image& msg, uint64_t& index) {
    // The NeRF trains on colour: colour encodings go in as BGR (tracking converts to grey itself);
    // the tracking node keeps them for the keyframes it sends to nerf_mapping_node.
    const bool wants_colour = p_.slam.nerf.enabled || tracking();
    const bool colour = wants_colour && isColourEncoding(msg.encoding);
    if (wants_colour && !colour && !warned_grey_input_) {
      warned_grey_input_ = true;
      ROS_WARN("images are '%s': the NeRF trains on grey (publish bgr8/rgb8 for a colour NeRF)", msg.encoding.c_str());
    }
    if (pub_->mapToOdom() && !msg.header.frame_id.empty() && msg.header.frame_id != cameraFrame() &&
        !warned_frame_id_) {
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
      return;
    }
    nerfslam::FrameRecord rec;
    try {
      system_->setLocalizationOnly(localization_only_);
      rec = system_->trackFrame(image, msg.header.stamp.toSec(), index++);
    } catch (const std::exception& e) {
      ++tracking_errors_;
      ROS_ERROR_THROTTLE(5.0, "tracking failed on the frame stamped %.6f: %s", msg.header.stamp.toSec(), e.what());
      return;
    }
    if (p_.node.wait_for_mapping) system_->waitMappingIdle();
    noteRelocalization(rec, msg.header.stamp);
    ++processed_;
    tracking_ms_last_ = rec.tracking_ms;
    tracking_ms_sum_.store(tracking_ms_sum_.load() + rec.tracking_ms);
    if (rec.tracked) {
      ++tracked_;
      std::lock_guard<std::mutex> pose_lock(pose_mutex_);
      last_pose_ = TrackedPose{rec.T_world_cam, msg.header.stamp, generation_};
    }
    noteLatency(msg.header.stamp);
    pub_->publishFrame(msg.header.stamp, rec, *system_, *worker_camera_);
  }

  // ~map: the first frame of the system, and the frame at which it relocalised in the map (its index
  // among the system's frames and its time after the first frame's stamp). Worker only.
  void noteRelocalization(const nerfslam::FrameRecord& rec, const ros::Time& stamp) {
    if (system_index0_ < 0) {
      system_index0_ = static_cast<int64_t>(rec.index);
      system_stamp0_ = stamp;
    }
    if (map_mode_ == nerfslam::MapMode::kSlam || relocalized_frame_ >= 0) return;
    const int64_t at = system_->relocalizedAtFrame();
    if (at < 0) return;
    relocalized_after_s_ = (stamp - system_stamp0_).toSec();
    relocalized_frame_ = at - system_index0_;
    ROS_INFO("relocalised in the map %s at frame %ld, %.3f s after the first frame (stamps)", map_dir_.c_str(),
             static_cast<long>(relocalized_frame_.load()), relocalized_after_s_.load());
  }

  // Latency from the image's stamp to its pose (queue + conversion + tracking), for live stamps only
  // (a recorded sequence's stamps are in the past).
  void noteLatency(const ros::Time& stamp) {
    const double age = (ros::Time::now() - stamp).toSec();
    if (age < 0 || age >= 10.0) return;
    const double ms = 1e3 * age;
    latency_ms_sum_.store(latency_ms_sum_.load() + ms);
    if (ms > latency_ms_max_.load()) latency_ms_max_.store(ms);
    ++latency_count_;
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
    const std::string state = pub_->state();
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
    s.add("map mode", nerfslam::toString(map_mode_));
    if (map_mode_ != nerfslam::MapMode::kSlam) {
      s.add("map", map_dir_.string());
      s.add("map keyframes loaded", static_cast<uint64_t>(map_keyframes_));
      const int64_t at = relocalized_frame_;
      s.add("relocalised", at >= 0 ? "yes" : "not yet");
      s.add("relocalised at frame", at);
      s.addf("relocalised after s", "%.3f", at >= 0 ? relocalized_after_s_.load() : -1.0);
    }
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
    if (auto* odom = pub_->mapToOdom()) odom->diagnose(s);
  }

  ros::NodeHandle nh_, pnh_;
  Params p_;
  image_transport::ImageTransport it_;
  diagnostic_updater::Updater updater_;
  image_transport::CameraSubscriber camera_sub_;
  image_transport::Subscriber image_sub_;
  std::unique_ptr<nerfslam::rosnode::SlamPublishers> pub_;  // tf, ~pose, ~path, ~map_points, ...
  ros::ServiceServer reset_srv_, localization_srv_;
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
  // ~map (map_mode_ kSlam without it): the folder, the map loaded at start until the first system takes
  // it, and where the system relocalised in it.
  nerfslam::MapMode map_mode_ = nerfslam::MapMode::kSlam;
  std::atomic<bool> reset_requested_{false}, stopping_{false}, localization_only_{false}, fatal_{false};
  std::filesystem::path map_dir_;
  std::unique_ptr<nerfslam::LoadedMap> start_map_;
  size_t map_keyframes_ = 0;
  int64_t system_index0_ = -1;
  ros::Time system_stamp0_;
  std::atomic<int64_t> relocalized_frame_{-1};
  std::atomic<double> relocalized_after_s_{-1.0};
  std::shared_ptr<const Camera> worker_camera_;
  std::thread worker_;

  // Shared with the NeRF publisher thread and the services.
  mutable std::mutex handle_mutex_;
  std::shared_ptr<const SystemHandle> handle_;
  std::mutex pose_mutex_;
  std::optional<TrackedPose> last_pose_;
  std::unique_ptr<nerfslam::rosnode::NerfPublisher> nerf_pub_;  // ~nerf_*, ~save_map
  std::unique_ptr<nerfslam::rosnode::KeyframeSender> sender_;   // tracking_node: ~keyframes_out, ~keyframe_poses

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
  nerfslam::rosnode::MasterWatch master_watch_;  // re-registers with a restarted master
};

}  // namespace

namespace nerfslam::rosnode {

int runSlamNode(int argc, char** argv, SlamNodeMode mode) {
  ros::init(argc, argv, mode == SlamNodeMode::kTracking ? "tracking_node" : "nerfslam_node");
  Params p;
  p.mode = mode;
  return spinNode<NerfslamNode>(p, loadSlamNodeParams);
}

}  // namespace nerfslam::rosnode
