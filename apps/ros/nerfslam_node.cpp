// nerfslam_node: the sparse monocular SLAM system (nerfslam::SlamSystem) as a ROS 1 node.
//
// Input: `image` + `camera_info` through image_transport's CameraSubscriber (remap them, e.g.
// image:=/camera/image_raw camera_info:=/camera/camera_info). With ~camera_yaml set, the calibration
// comes from that file instead (our camera YAML or a ROS camera_info YAML, nerfslam::loadCameraYaml)
// and only `image` is subscribed. Until a calibration arrives the node warns (throttled) and waits.
// Callbacks only check and enqueue: frames go into a bounded queue (the oldest are dropped and
// counted when tracking falls behind) and a worker thread feeds the system.
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
//   /diagnostics       diagnostic_updater: frames received/tracked, dropped (queue), refused
//                      (encoding, size, timestamp), tracking ms, state, keyframes, map points
// Services:
//   ~reset             std_srvs/Trigger: discards the map and starts a new system (reinitialises)
//   (no ~set_localization_only: SlamSystem has no localization-only mode)
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

#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseStamped.h>
#include <image_transport/image_transport.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/transform_broadcaster.h>
#include <visualization_msgs/MarkerArray.h>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/mapping/bounded_queue.h"
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
};

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
  return "";
}

struct QueuedFrame {
  sensor_msgs::ImageConstPtr image;
  std::shared_ptr<const Camera> camera;
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
  }

  ~NerfslamNode() {
    stopping_ = true;
    queue_.close();
    if (worker_.joinable()) worker_.join();
    std::lock_guard<std::mutex> lock(system_mutex_);
    if (system_) system_->finish(false);
    // stdout: rosconsole no longer prints once ros::shutdown() has run.
    std::printf(
        "nerfslam_node: %lu frames received, %lu processed, %lu tracked, %lu dropped (queue full), refused: "
        "%lu encoding, %lu size, %lu timestamp; mean tracking %.1f ms\n",
        static_cast<unsigned long>(received_), static_cast<unsigned long>(processed_),
        static_cast<unsigned long>(tracked_), static_cast<unsigned long>(queue_.dropped()),
        static_cast<unsigned long>(refused_encoding_), static_cast<unsigned long>(refused_size_),
        static_cast<unsigned long>(refused_stamp_), processed_ > 0 ? tracking_ms_sum_.load() / processed_ : 0.0);
    std::fflush(stdout);
  }

 private:
  // ---- Callbacks: checks and enqueueing only ----
  void onCamera(const sensor_msgs::ImageConstPtr& image, const sensor_msgs::CameraInfoConstPtr& info) {
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
  void onImage(const sensor_msgs::ImageConstPtr& image) { enqueue(image, yaml_camera_); }

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

  // ---- Worker ----
  void work() {
    uint64_t index = 0;
    while (auto item = queue_.pop()) {
      if (stopping_) break;
      std::unique_lock<std::mutex> lock(system_mutex_);
      if (reset_requested_.exchange(false) && system_) {
        system_->finish(false);
        system_.reset();
        ++resets_;
      }
      if (!system_) {
        nerfslam::SystemOptions opt;
        opt.tracking.features.max_features = p_.max_features;
        opt.lockstep = false;
        try {
          system_ = std::make_unique<SlamSystem>(*item->camera, opt);
          worker_camera_ = item->camera;
        } catch (const std::exception& e) {
          ROS_ERROR_THROTTLE(5.0, "cannot start the SLAM system: %s", e.what());
          continue;
        }
        ROS_INFO("SLAM system started on %dx%d images", item->camera->width, item->camera->height);
      }
      const auto& msg = *item->image;
      cv::Mat gray;
      try {
        gray = nerfslam::rosbridge::fromImageMsg(msg, nerfslam::rosbridge::ImageTarget::kGray8);
      } catch (const std::exception& e) {
        ++refused_encoding_;
        ROS_ERROR_THROTTLE(5.0, "refusing image: %s", e.what());
        continue;
      }
      nerfslam::FrameRecord rec;
      try {
        rec = system_->trackFrame(gray, msg.header.stamp.toSec(), index++);
      } catch (const std::exception& e) {
        ++tracking_errors_;
        ROS_ERROR_THROTTLE(5.0, "tracking failed on the frame stamped %.6f: %s", msg.header.stamp.toSec(), e.what());
        continue;
      }
      if (p_.wait_for_mapping) system_->waitMappingIdle();
      ++processed_;
      tracking_ms_last_ = rec.tracking_ms;
      tracking_ms_sum_.store(tracking_ms_sum_.load() + rec.tracking_ms);
      if (rec.tracked) ++tracked_;
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
  }

  ros::NodeHandle nh_, pnh_;
  Params p_;
  image_transport::ImageTransport it_;
  diagnostic_updater::Updater updater_;
  image_transport::CameraSubscriber camera_sub_;
  image_transport::Subscriber image_sub_;
  ros::Publisher pose_pub_, path_pub_, points_pub_, keyframes_pub_, state_pub_;
  ros::ServiceServer reset_srv_;
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
  std::unique_ptr<SlamSystem> system_;
  std::atomic<bool> reset_requested_{false}, stopping_{false};
  std::shared_ptr<const Camera> worker_camera_;
  ros::WallTime last_map_publish_;
  std::thread worker_;

  // Statistics.
  std::atomic<uint64_t> received_{0}, processed_{0}, tracked_{0}, refused_encoding_{0}, refused_size_{0},
      refused_stamp_{0}, refused_calibration_{0}, tracking_errors_{0}, resets_{0};
  std::atomic<double> tracking_ms_last_{0}, tracking_ms_sum_{0};
  std::mutex diag_mutex_;
  std::string state_;
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
