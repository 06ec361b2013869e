#include "nerfslam_ros/map_to_odom.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "nerfslam_ros/conversions.h"

namespace nerfslam::rosnode {

namespace {
// tf history kept for the lookups: an image tracked more than this after its stamp (a long queue,
// ~wait_for_mapping behind a slow mapping) finds no odometry at its stamp.
constexpr double kTfCacheSeconds = 60.0;
// Images waiting for their lookups; when the lookups fall behind the oldest are dropped (counted).
constexpr size_t kQueue = 8;
}  // namespace

std::string checkMapToOdomParams(const MapToOdomParams& p, const std::string& map_frame,
                                 const std::string& camera_frame) {
  if (!p.enabled) return "";
  for (const auto& [name, value] : {std::pair{"~odom_frame", p.odom_frame}, std::pair{"~base_frame", p.base_frame}}) {
    if (value.empty()) return std::string(name) + " must not be empty (~publish_map_to_odom is true)";
    if (value == map_frame) return std::string(name) + " must differ from ~map_frame (both '" + value + "')";
    if (value == camera_frame)
      return std::string(name) + " must differ from ~camera_frame (both '" + value +
             "'; a camera that is the robot's base needs an identity static transform)";
  }
  if (p.odom_frame == p.base_frame) return "~odom_frame and ~base_frame must differ (both '" + p.odom_frame + "')";
  return "";
}

MapToOdomPublisher::MapToOdomPublisher(const MapToOdomParams& p, std::string map_frame, std::string camera_frame)
    : p_(p),
      map_frame_(std::move(map_frame)),
      camera_frame_(std::move(camera_frame)),
      buffer_(ros::Duration(kTfCacheSeconds)),
      listener_(buffer_),
      queue_(kQueue, OverflowPolicy::kDropOldest) {
  thread_ = std::thread([this] { run(); });
}

MapToOdomPublisher::~MapToOdomPublisher() {
  queue_.close();
  if (thread_.joinable()) thread_.join();
}

void MapToOdomPublisher::push(const ros::Time& stamp, const SE3& T_map_cam) {
  enqueue(Item{stamp, T_map_cam, map_generation_, false});
}

void MapToOdomPublisher::pushLost(const ros::Time& stamp) { enqueue(Item{stamp, SE3(), map_generation_, true}); }

void MapToOdomPublisher::enqueue(Item item) {
  const uint64_t before = queue_.dropped();
  queue_.tryPush(std::move(item));
  if (queue_.dropped() > before)
    ROS_WARN_THROTTLE(5.0,
                      "map -> odom: images waiting for their tf lookups dropped (each waits up to ~tf_timeout = %g s "
                      "for the robot's transforms); %lu dropped without it so far",
                      p_.tf_timeout, static_cast<unsigned long>(queue_.dropped()));
}

bool MapToOdomPublisher::lookup(const std::string& target, const std::string& source, const ros::Time& stamp,
                                const ros::Time& deadline, SE3* T, std::string* error) {
  const ros::Duration wait = std::max(ros::Duration(0), deadline - ros::Time::now());
  if (!buffer_.canTransform(target, source, stamp, wait, error)) return false;
  try {
    *T = rosbridge::fromTransform(buffer_.lookupTransform(target, source, stamp).transform);
  } catch (const tf2::TransformException& e) {
    *error = e.what();
    return false;
  }
  return true;
}

void MapToOdomPublisher::skip(std::atomic<uint64_t>& counter, const Item& item, const std::string& what,
                              const std::string& error) {
  ++counter;
  const std::string message = "no tf " + what + " at " + std::to_string(item.stamp.toSec()) + ": " + error;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    last_error_ = message;
  }
  ROS_WARN_THROTTLE(
      5.0, "map -> odom not published for the image stamped %.6f: missing tf %s (%s); %lu images without it so far",
      item.stamp.toSec(), what.c_str(), error.c_str(),
      static_cast<unsigned long>(no_odom_ + no_mount_ + queue_.dropped()));
}

void MapToOdomPublisher::run() {
  const std::string odom_base = p_.odom_frame + " -> " + p_.base_frame;
  const std::string base_cam = p_.base_frame + " -> " + camera_frame_;
  while (auto item = queue_.pop()) {
    if (item->lost) {
      repeat(*item);
      continue;
    }
    const ros::Time deadline = ros::Time::now() + ros::Duration(p_.tf_timeout);
    SE3 T_odom_base, T_base_cam;
    std::string error;
    if (!lookup(p_.odom_frame, p_.base_frame, item->stamp, deadline, &T_odom_base, &error)) {
      skip(no_odom_, *item, odom_base, error);
      continue;
    }
    if (!lookup(p_.base_frame, camera_frame_, item->stamp, deadline, &T_base_cam, &error)) {
      skip(no_mount_, *item, base_cam, error);
      continue;
    }
    const SE3 T_map_odom = item->T_map_cam * T_base_cam.inverse() * T_odom_base.inverse();
    broadcaster_.sendTransform(rosbridge::toTransformStamped(T_map_odom, map_frame_, p_.odom_frame, item->stamp));
    ++published_;
    have_last_ = true;
    last_T_map_odom_ = T_map_odom;
    last_generation_ = item->map_generation;
    std::lock_guard<std::mutex> lock(mutex_);
    last_error_.clear();
  }
}

void MapToOdomPublisher::repeat(const Item& item) {
  if (!have_last_ || last_generation_ != item.map_generation) {
    ++lost_without_correction_;  // nothing published for this map yet
    return;
  }
  broadcaster_.sendTransform(rosbridge::toTransformStamped(last_T_map_odom_, map_frame_, p_.odom_frame, item.stamp));
  ++repeated_;
}

void MapToOdomPublisher::diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) const {
  std::string last;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    last = last_error_;
  }
  if (!last.empty()) s.mergeSummary(diagnostic_msgs::DiagnosticStatus::WARN, "map -> odom missing");
  s.add("map -> odom published", static_cast<uint64_t>(published_));
  s.add("map -> odom skipped (no " + p_.odom_frame + " -> " + p_.base_frame + ")", static_cast<uint64_t>(no_odom_));
  s.add("map -> odom skipped (no " + p_.base_frame + " -> " + camera_frame_ + ")", static_cast<uint64_t>(no_mount_));
  s.add("map -> odom skipped (lookups behind)", static_cast<uint64_t>(queue_.dropped()));
  s.add("map -> odom repeated (tracking lost)", static_cast<uint64_t>(repeated_));
  s.add("map -> odom not repeated (lost, none for this map)", static_cast<uint64_t>(lost_without_correction_));
  s.add("map -> odom last error", last.empty() ? "none" : last);
}

std::string MapToOdomPublisher::summary() const {
  return "map -> odom " + std::to_string(published_) + " published, " + std::to_string(no_odom_) + " without " +
         p_.odom_frame + " -> " + p_.base_frame + ", " + std::to_string(no_mount_) + " without " + p_.base_frame +
         " -> " + camera_frame_ + ", " + std::to_string(queue_.dropped()) + " dropped (lookups behind), " +
         std::to_string(repeated_) + " repeated while lost";
}

}  // namespace nerfslam::rosnode
