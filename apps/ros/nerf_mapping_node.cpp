// nerf_mapping_node: the NeRF half of the off-board mapping split (docs/ros.md, "Off-board mapping",
// "nerf_mapping_node": topics, services, parameters). tracking_node sends its keyframes and their
// bundle-adjusted poses over ROS topics; this node keeps a replica of the sparse map from them
// (keyframe_link.h, MapReplica) and trains an unchanged NerfMapping on it, fed through a KeyframeBus
// of its own exactly as SlamSystem feeds it in nerfslam_node.
#include <cstdio>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseStamped.h>
#include <ros/ros.h>

#include "nerfslam/core/timing.h"
#include "nerfslam/mapping/mapping_thread.h"
#include "nerfslam/system/nerf_mapping.h"
#include "nerfslam_ros/conversions.h"
#include "nerfslam_ros/keyframe_link.h"
#include "nerfslam_ros/master_watch.h"
#include "nerfslam_ros/nerf_publisher.h"
#include "nerfslam_ros/node_params.h"

namespace {

using nerfslam::rosnode::MapSource;
using nerfslam::rosnode::ViewPose;

using Params = nerfslam::rosnode::NerfMappingNodeParams;

class NerfMappingNode {
 public:
  NerfMappingNode(ros::NodeHandle nh, ros::NodeHandle pnh, Params p)
      : nh_(nh), pnh_(pnh), p_(std::move(p)), updater_(nh, pnh) {
    nerf_ = std::make_unique<nerfslam::NerfMapping>(replica_.map(), bus_, p_.slam.nerf);
    nerf_->start();
    nerf_pub_ = std::make_unique<nerfslam::rosnode::NerfPublisher>(
        pnh_, p_.topics, true, [this] { return source(); }, [this] { return viewPose(); });
    updater_.setHardwareID("nerfslam");
    updater_.add("nerf_mapping_node", this, &NerfMappingNode::diagnose);
    diag_timer_ =
        nh_.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) { updater_.force_update(); });
    keyframes_sub_ = nh_.subscribe("keyframes", 100, &NerfMappingNode::onKeyframe, this);
    poses_sub_ = nh_.subscribe("keyframe_poses", 10, &NerfMappingNode::onPoses, this);
    pose_sub_ = nh_.subscribe("pose", 1, &NerfMappingNode::onPose, this);
    wait_timer_ = nh_.createWallTimer(ros::WallDuration(2.0), [this](const ros::WallTimerEvent&) {
      if (replica_.keyframesReceived() == 0)
        ROS_WARN_THROTTLE(10.0, "waiting for keyframes on %s (remap `keyframes` to the tracking node's ~keyframes_out)",
                          keyframes_sub_.getTopic().c_str());
    });
    nerf_pub_->start();
    ROS_INFO("nerf_mapping_node: keyframes from %s, poses from %s, view pose from %s",
             keyframes_sub_.getTopic().c_str(), poses_sub_.getTopic().c_str(), pose_sub_.getTopic().c_str());
  }

  ~NerfMappingNode() {
    nerf_pub_->stop();
    nerf_->stop();
    const nerfslam::NerfMappingStats st = nerf_->stats();
    std::printf(
        "nerf_mapping_node: %lu keyframes received (%lu refused), %lu pose updates applied, %lu stale "
        "messages, %lu sessions; replica %zu keyframes, %zu points; NeRF %ld steps, %d views; %s\n",
        static_cast<unsigned long>(replica_.keyframesReceived()), static_cast<unsigned long>(refused_),
        static_cast<unsigned long>(replica_.poseUpdatesApplied()), static_cast<unsigned long>(replica_.staleMessages()),
        static_cast<unsigned long>(replica_.sessions()), replica_.map().numKeyframes(), replica_.map().numPoints(),
        static_cast<long>(st.steps), st.views, nerf_pub_->summary().c_str());
    std::fflush(stdout);
  }

 private:
  void onKeyframe(const nerfslam::MapKeyframeConstPtr& m) {
    std::optional<nerfslam::KeyframeEvent> ev;
    try {
      ev = replica_.apply(*m);
    } catch (const std::exception& e) {
      ++refused_;
      ROS_ERROR_THROTTLE(5.0, "refusing keyframe %lu: %s", static_cast<unsigned long>(m->id), e.what());
      return;
    }
    if (!ev) return;
    {
      std::lock_guard<std::mutex> lock(pose_mutex_);
      newest_keyframe_ = ViewPose{ev->T_world_cam, m->header.stamp, m->session};
    }
    bus_.publish(*ev);
  }

  void onPoses(const nerfslam::KeyframePosesConstPtr& m) { replica_.apply(*m); }

  void onPose(const geometry_msgs::PoseStampedConstPtr& m) {
    std::lock_guard<std::mutex> lock(pose_mutex_);
    last_pose_ = ViewPose{nerfslam::rosbridge::fromPose(m->pose), m->header.stamp, 0};
  }

  std::shared_ptr<const MapSource> source() const {
    auto cam = replica_.camera();
    if (!cam) return nullptr;
    auto s = std::make_shared<MapSource>();
    s->map = &replica_.map();
    s->nerf = nerf_.get();
    s->camera = std::move(cam);
    s->options = p_.slam;
    s->generation = replica_.session();
    s->map_to_save = [this] { return replica_.keyframesOnly(); };
    return s;
  }

  // The tracked pose when the tracking node's ~pose arrives, else the newest keyframe's.
  std::optional<ViewPose> viewPose() const {
    std::lock_guard<std::mutex> lock(pose_mutex_);
    std::optional<ViewPose> v = last_pose_ ? last_pose_ : newest_keyframe_;
    if (v) v->generation = replica_.session();
    return v;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) {
    const bool connected = keyframes_sub_.getNumPublishers() > 0 && poses_sub_.getNumPublishers() > 0;
    if (!connected)
      s.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no tracking node publishing keyframes and poses");
    else if (refused_ > 0)
      s.summary(diagnostic_msgs::DiagnosticStatus::WARN, "keyframes refused");
    else
      s.summary(diagnostic_msgs::DiagnosticStatus::OK, "mapping");
    s.add("tracking node connected", connected ? "yes" : "no");
    s.add("keyframes received", replica_.keyframesReceived());
    s.add("keyframes refused", static_cast<uint64_t>(refused_));
    s.add("pose updates applied", replica_.poseUpdatesApplied());
    s.add("last pose update seq", replica_.posesSeq());
    s.add("stale messages", replica_.staleMessages());
    s.add("sessions", replica_.sessions());
    s.add("session", static_cast<uint64_t>(replica_.session()));
    s.add("keyframes", replica_.map().numKeyframes());
    s.add("map points", replica_.map().numPoints());
    s.addf("resident memory (MB)", "%.1f", nerfslam::currentRssMb());
    master_watch_.diagnose(s);
    nerf_pub_->diagnose(s);
  }

  ros::NodeHandle nh_, pnh_;
  Params p_;
  diagnostic_updater::Updater updater_;
  nerfslam::rosnode::MapReplica replica_;
  nerfslam::KeyframeBus bus_;  // before nerf_, which unsubscribes from it
  std::unique_ptr<nerfslam::NerfMapping> nerf_;
  std::unique_ptr<nerfslam::rosnode::NerfPublisher> nerf_pub_;
  ros::Subscriber keyframes_sub_, poses_sub_, pose_sub_;
  ros::WallTimer diag_timer_, wait_timer_;
  mutable std::mutex pose_mutex_;
  std::optional<ViewPose> last_pose_, newest_keyframe_;
  std::atomic<uint64_t> refused_{0};
  nerfslam::rosnode::MasterWatch master_watch_;  // re-registers with a restarted master
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "nerf_mapping_node");
  Params p;
  return nerfslam::rosnode::spinNode<NerfMappingNode>(p, nerfslam::rosnode::loadNerfMappingNodeParams);
}
