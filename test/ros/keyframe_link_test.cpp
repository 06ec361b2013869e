// MapReplica (apps/ros/keyframe_link.h), the nerf_mapping_node side of the off-board mapping link,
// driven by hand-made messages (no ROS master): it must agree with the tracking map after every
// update whatever order the two topics deliver in.
#include <gtest/gtest.h>

#include <cmath>

#include "nerfslam_ros/conversions.h"
#include "nerfslam_ros/keyframe_link.h"

namespace {

using nerfslam::SE3;
using nerfslam::rosnode::MapReplica;

nerfslam::Camera testCamera() {
  nerfslam::Camera c;
  c.width = 64;
  c.height = 48;
  c.fx = c.fy = 50;
  c.cx = 31.5;
  c.cy = 23.5;
  return c;
}

SE3 poseAt(double x, double yaw = 0) {
  return SE3(Eigen::Quaterniond(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY())), Eigen::Vector3d(x, 0.1 * x, 0));
}

nerfslam::MapKeyframe keyframeMsg(uint32_t session, uint64_t seq, uint64_t id, const SE3& pose, int points = 30) {
  nerfslam::MapKeyframe m;
  m.header.stamp = ros::Time(10.0 + double(id));
  m.header.frame_id = "map";
  m.session = session;
  m.seq = seq;
  m.id = id;
  m.frame_id = 100 + id;
  cv::Mat bgr(48, 64, CV_8UC3, cv::Scalar(10, 20, 30 + double(id)));
  m.image = *nerfslam::rosbridge::toImageMsg(bgr, m.header);
  m.camera_info = nerfslam::rosbridge::toCameraInfo(testCamera(), m.header);
  m.T_world_cam = nerfslam::rosbridge::toPose(pose);
  for (int i = 0; i < points; ++i) {
    geometry_msgs::Point32 p;
    p.x = float(i);
    p.y = 1;
    p.z = 2;
    m.points.push_back(p);
  }
  return m;
}

nerfslam::KeyframePoses posesMsg(uint32_t session, uint64_t seq, const std::vector<std::pair<uint64_t, SE3>>& poses,
                                 std::vector<uint64_t> culled = {}, std::vector<uint64_t> removed = {},
                                 int points = 40) {
  nerfslam::KeyframePoses m;
  m.session = session;
  m.seq = seq;
  for (const auto& [id, T] : poses) {
    m.ids.push_back(id);
    m.poses.push_back(nerfslam::rosbridge::toPose(T));
  }
  m.culled_ids = std::move(culled);
  m.removed_ids = std::move(removed);
  m.points.resize(size_t(points));
  return m;
}

double poseError(const std::optional<SE3>& a, const SE3& b) {
  if (!a) return 1e9;
  return (a->translation() - b.translation()).norm() + a->rotation().angularDistance(b.rotation());
}

TEST(RosKeyframeLink, ReplicaFollowsKeyframesPosesCullingAndRemovals) {
  MapReplica r;
  // A keyframe: a new event for the NeRF bus, with the image as the frame's colour and grey level 0.
  auto ev = r.apply(keyframeMsg(7, 1, 0, poseAt(0)));
  ASSERT_TRUE(ev);
  EXPECT_EQ(ev->id, 0);
  ASSERT_TRUE(ev->frame);
  EXPECT_EQ(ev->frame->id, 100u);
  EXPECT_EQ(ev->frame->colour.type(), CV_8UC3);
  EXPECT_EQ(ev->frame->pyramid.at(0).type(), CV_8UC1);
  EXPECT_EQ(ev->frame->camera.fx, 50);
  EXPECT_EQ(r.map().numPoints(), 30u);
  ASSERT_TRUE(r.apply(keyframeMsg(7, 2, 1, poseAt(1))));
  ASSERT_TRUE(r.apply(keyframeMsg(7, 3, 2, poseAt(2))));
  EXPECT_FALSE(r.apply(keyframeMsg(7, 3, 2, poseAt(2)))) << "a repeat is not a new keyframe";

  // Bundle adjustment moved them; keyframe 1 was culled (its pose follows its parent).
  EXPECT_TRUE(r.apply(posesMsg(7, 4, {{0, poseAt(0)}, {1, poseAt(1.1, 0.1)}, {2, poseAt(2.2, 0.2)}}, {1})));
  EXPECT_LT(poseError(r.map().resolvePose(1), poseAt(1.1, 0.1)), 1e-12);
  EXPECT_LT(poseError(r.map().resolvePose(2), poseAt(2.2, 0.2)), 1e-12);
  EXPECT_EQ(r.map().keyframeIds(), (std::vector<nerfslam::KeyframeId>{0, 2}));
  EXPECT_EQ(r.map().numPoints(), 40u);
  // The next update moves the culled keyframe with the map.
  EXPECT_TRUE(r.apply(posesMsg(7, 5, {{0, poseAt(0)}, {1, poseAt(1.5, 0.1)}, {2, poseAt(2.5, 0.2)}}, {1})));
  EXPECT_LT(poseError(r.map().resolvePose(1), poseAt(1.5, 0.1)), 1e-12);

  // Out of order: an older update is ignored.
  EXPECT_FALSE(r.apply(posesMsg(7, 4, {{0, poseAt(9)}, {2, poseAt(9)}})));
  EXPECT_LT(poseError(r.map().resolvePose(2), poseAt(2.5, 0.2)), 1e-12);
  EXPECT_EQ(r.staleMessages(), 1u);

  // An update that arrives before its keyframe: the keyframe takes the newer pose.
  EXPECT_TRUE(r.apply(posesMsg(7, 7, {{0, poseAt(0)}, {1, poseAt(1.5)}, {2, poseAt(2.5)}, {3, poseAt(3.3)}}, {1})));
  ASSERT_TRUE(r.apply(keyframeMsg(7, 6, 3, poseAt(3))));
  EXPECT_LT(poseError(r.map().resolvePose(3), poseAt(3.3)), 1e-12);

  // A removal: the keyframe leaves the replica; its late keyframe message would not bring it back.
  EXPECT_TRUE(r.apply(posesMsg(7, 9, {{0, poseAt(0)}, {1, poseAt(1.5)}, {2, poseAt(2.5)}}, {1}, {3})));
  EXPECT_FALSE(r.map().resolvePose(3).has_value());
  EXPECT_FALSE(r.apply(keyframeMsg(7, 8, 3, poseAt(3))));
  EXPECT_EQ(r.posesSeq(), 9u);
  EXPECT_EQ(r.keyframesOnly()->numKeyframes(), 2u);
  EXPECT_EQ(r.keyframesOnly()->numPoints(), 0u);

  // A new session (the tracking node's ~reset): the replica starts again; the old one's messages are stale.
  ASSERT_TRUE(r.apply(keyframeMsg(8, 1, 10, poseAt(0))));
  EXPECT_EQ(r.map().keyframeIds(), (std::vector<nerfslam::KeyframeId>{10}));
  EXPECT_FALSE(r.map().resolvePose(2).has_value());
  EXPECT_FALSE(r.apply(keyframeMsg(7, 10, 4, poseAt(4))));
  EXPECT_EQ(r.sessions(), 2u);
}

TEST(RosKeyframeLink, RefusesAnImageThatDoesNotMatchItsCameraInfo) {
  MapReplica r;
  nerfslam::MapKeyframe m = keyframeMsg(1, 1, 0, poseAt(0));
  m.camera_info.width = 320;
  EXPECT_THROW(r.apply(m), std::exception);
  EXPECT_EQ(r.map().numKeyframes(), 0u);
}

}  // namespace
