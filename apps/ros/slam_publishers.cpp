#include "nerfslam_ros/slam_publishers.h"

#include <array>
#include <utility>

#include <geometry_msgs/PoseStamped.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <std_msgs/String.h>
#include <visualization_msgs/MarkerArray.h>

#include "nerfslam_ros/conversions.h"
#include "nerfslam_ros/nerf_publisher.h"

namespace nerfslam::rosnode {

PathBuilder::PathBuilder(std::string frame_id, double refresh_period) : refresh_period_(refresh_period) {
  path_.header.frame_id = std::move(frame_id);
}

void PathBuilder::clear() {
  path_.poses.clear();
  built_ = false;
}

bool PathBuilder::wantsRebuild(uint64_t map_version, double now, bool idle) const {
  if (!built_) return true;
  if (map_version == built_version_) return false;
  return idle || now - built_at_ >= refresh_period_;
}

namespace {
geometry_msgs::PoseStamped stampedPose(double timestamp, const SE3& T, const std::string& frame) {
  geometry_msgs::PoseStamped ps;
  ps.header.stamp = ros::Time(timestamp);
  ps.header.frame_id = frame;
  ps.pose = rosbridge::toPose(T);
  return ps;
}
}  // namespace

void PathBuilder::rebuild(const Trajectory& trajectory, uint64_t map_version, double now, const ros::Time& stamp) {
  path_.header.stamp = stamp;
  path_.poses.clear();
  path_.poses.reserve(trajectory.size());
  for (const auto& e : trajectory) path_.poses.push_back(stampedPose(e.timestamp, e.pose, path_.header.frame_id));
  built_ = true;
  built_version_ = map_version;
  built_at_ = now;
  ++rebuilds_;
}

bool PathBuilder::update(SlamSystem& system, const FrameRecord* rec, double now, const ros::Time& stamp) {
  if (!system.initialized()) return false;
  const uint64_t version = system.map().version();  // before trajectory(): a change meanwhile rebuilds again
  if (wantsRebuild(version, now, rec == nullptr)) {
    rebuild(system.trajectory(), version, now, stamp);
    return true;
  }
  if (!rec || !rec->tracked) return false;
  // As trajectory() resolves it: through the reference keyframe's current pose.
  const auto T_ref = system.map().resolvePose(rec->reference);
  append(rec->timestamp, T_ref ? *T_ref * rec->T_ref_cam : rec->T_world_cam, stamp);
  return true;
}

void PathBuilder::append(double timestamp, const SE3& T_world_cam, const ros::Time& stamp) {
  path_.header.stamp = stamp;
  path_.poses.push_back(stampedPose(timestamp, T_world_cam, path_.header.frame_id));
}

SlamPublishers::SlamPublishers(ros::NodeHandle pnh, const SlamNodeParams& p)
    : map_frame_(p.topics.map_frame),
      camera_frame_(p.topics.camera_frame),
      map_points_period_(p.node.map_points_period),
      weak_inliers_(p.node.weak_inliers),
      frustum_scale_(p.node.frustum_scale),
      path_(p.topics.map_frame, p.node.path_refresh_period) {
  pose_pub_ = pnh.advertise<geometry_msgs::PoseStamped>("pose", 10);
  path_pub_ = pnh.advertise<nav_msgs::Path>("path", 2, true);
  points_pub_ = pnh.advertise<sensor_msgs::PointCloud2>("map_points", 2, true);
  keyframes_pub_ = pnh.advertise<visualization_msgs::MarkerArray>("keyframes", 2, true);
  state_pub_ = pnh.advertise<std_msgs::String>("tracking_state", 10, true);
  if (p.odom.enabled) map_to_odom_ = std::make_unique<MapToOdomPublisher>(p.odom, map_frame_, camera_frame_);
}

std::string SlamPublishers::stopMapToOdom() {
  const std::string summary = map_to_odom_ ? map_to_odom_->summary() : "";
  map_to_odom_.reset();
  return summary;
}

void SlamPublishers::newSystem() {
  path_.clear();
  forgetMapToOdom();
}

void SlamPublishers::forgetMapToOdom() {
  if (map_to_odom_) map_to_odom_->forget();  // its corrections were for the discarded map
}

std::string SlamPublishers::stateName(const FrameRecord& rec) const {
  switch (rec.state) {
    case TrackingState::kNotInitialized:
      return "initializing";
    case TrackingState::kLost:
      return "lost";
    case TrackingState::kTracking:
      return rec.num_inliers < weak_inliers_ ? "weak" : "good";
  }
  return "lost";
}

void SlamPublishers::publishState(const std::string& s) {
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    if (s == state_) return;
    state_ = s;
  }
  std_msgs::String m;
  m.data = s;
  state_pub_.publish(m);
}

std::string SlamPublishers::state() const {
  std::lock_guard<std::mutex> lock(state_mutex_);
  return state_;
}

void SlamPublishers::publishFrame(const ros::Time& stamp, const FrameRecord& rec, SlamSystem& system,
                                  const Camera& camera) {
  last_stamp_ = stamp;
  publishState(stateName(rec));
  if (rec.tracked) {
    // A frame has one parent on tf: with the REP-105 correction the camera's is the robot's base.
    if (map_to_odom_)
      map_to_odom_->push(stamp, rec.T_world_cam);
    else
      tf_.sendTransform(rosbridge::toTransformStamped(rec.T_world_cam, map_frame_, camera_frame_, stamp));
    geometry_msgs::PoseStamped ps;
    ps.header.stamp = stamp;
    ps.header.frame_id = map_frame_;
    ps.pose = rosbridge::toPose(rec.T_world_cam);
    pose_pub_.publish(ps);
  } else if (map_to_odom_) {
    // REP-105: while lost, map -> odom stays available (the last correction, at this stamp); while
    // initialising there is no map it belongs to.
    if (rec.state == TrackingState::kLost)
      map_to_odom_->pushLost(stamp);
    else if (rec.state == TrackingState::kNotInitialized)
      map_to_odom_->forget();
  }
  updatePath(system, &rec);
  const ros::WallTime now = ros::WallTime::now();
  if (system.initialized() && (now - last_map_publish_).toSec() >= map_points_period_) {
    last_map_publish_ = now;
    publishMap(stamp, system, camera);
  }
}

void SlamPublishers::idle(SlamSystem& system) { updatePath(system, nullptr); }

void SlamPublishers::updatePath(SlamSystem& system, const FrameRecord* rec) {
  if (path_.update(system, rec, wallSeconds(), last_stamp_)) path_pub_.publish(path_.path());
}

void SlamPublishers::publishMap(const ros::Time& stamp, const SlamSystem& system, const Camera& cam) {
  const auto points = system.map().points();
  const auto keyframes = system.map().keyframes();
  sensor_msgs::PointCloud2 cloud;
  cloud.header.stamp = stamp;
  cloud.header.frame_id = map_frame_;
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
  m.header.frame_id = map_frame_;
  m.ns = "keyframes";
  m.id = 0;
  m.type = visualization_msgs::Marker::LINE_LIST;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.orientation.w = 1.0;
  m.scale.x = 0.02 * frustum_scale_;
  m.color.r = 0.1f;
  m.color.g = 0.8f;
  m.color.b = 0.2f;
  m.color.a = 1.0f;
  const double d = frustum_scale_;
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

}  // namespace nerfslam::rosnode
