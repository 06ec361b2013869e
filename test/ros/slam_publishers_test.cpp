// ~path built incrementally (apps/ros/slam_publishers.h, PathBuilder), no ROS master: the rule for
// rebuilding, and on a real SLAM run that the path the node publishes ends as SlamSystem::trajectory()
// while being rebuilt only about once per refresh period.
#include <gtest/gtest.h>

#include <cstdio>

#include "nerfslam/render/synth.h"
#include "nerfslam_ros/conversions.h"
#include "nerfslam_ros/slam_publishers.h"

namespace {

using nerfslam::SE3;
using nerfslam::rosnode::PathBuilder;

SE3 poseAt(double x) { return SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(x, 0, 0)); }

TEST(PathBuilder, RebuildsWhenTheMapChangedAndThePeriodPassedOrIdle) {
  PathBuilder b("map", 1.0);
  EXPECT_TRUE(b.wantsRebuild(0, 0.0, false));  // nothing built yet
  b.rebuild({{1.0, poseAt(1)}, {2.0, poseAt(2)}}, 5, 10.0, ros::Time(2.0));
  EXPECT_EQ(b.rebuilds(), 1u);
  ASSERT_EQ(b.path().poses.size(), 2u);
  EXPECT_EQ(b.path().header.frame_id, "map");
  EXPECT_EQ(b.path().poses[1].header.frame_id, "map");
  EXPECT_EQ(b.path().poses[1].header.stamp, ros::Time(2.0));
  EXPECT_EQ(b.path().poses[1].pose.position.x, 2.0);

  EXPECT_FALSE(b.wantsRebuild(5, 100.0, true));  // the map did not change
  EXPECT_FALSE(b.wantsRebuild(6, 10.5, false));  // changed, within the period: append
  EXPECT_TRUE(b.wantsRebuild(6, 11.0, false));   // the period passed
  EXPECT_TRUE(b.wantsRebuild(6, 10.1, true));    // idle: at once

  b.append(3.0, poseAt(3), ros::Time(3.0));
  ASSERT_EQ(b.path().poses.size(), 3u);
  EXPECT_EQ(b.path().header.stamp, ros::Time(3.0));
  EXPECT_EQ(b.path().poses[2].pose.position.x, 3.0);

  b.clear();
  EXPECT_TRUE(b.path().poses.empty());
  EXPECT_TRUE(b.wantsRebuild(5, 10.2, false));

  PathBuilder every_frame("map", 0.0);  // ~path_refresh_period 0: rebuilt at every change
  every_frame.rebuild({}, 1, 0.0, ros::Time(1.0));
  EXPECT_TRUE(every_frame.wantsRebuild(2, 0.0, false));
}

void expectSamePose(const geometry_msgs::PoseStamped& a, const nerfslam::TrajectoryEntry& e, size_t i) {
  const geometry_msgs::Pose b = nerfslam::rosbridge::toPose(e.pose);
  EXPECT_EQ(a.header.stamp, ros::Time(e.timestamp)) << i;
  EXPECT_EQ(a.pose.position.x, b.position.x) << i;
  EXPECT_EQ(a.pose.position.y, b.position.y) << i;
  EXPECT_EQ(a.pose.position.z, b.position.z) << i;
  EXPECT_EQ(a.pose.orientation.w, b.orientation.w) << i;
  EXPECT_EQ(a.pose.orientation.x, b.orientation.x) << i;
  EXPECT_EQ(a.pose.orientation.y, b.orientation.y) << i;
  EXPECT_EQ(a.pose.orientation.z, b.orientation.z) << i;
}

// A live-like run (the tracking never waits for mapping) of the synthetic room at 30 frames/s of
// simulated time, the path updated after every frame as the node does.
TEST(PathBuilder, EndsAsTheSystemsTrajectoryWithFewRebuilds) {
  nerfslam::SynthOptions so;
  so.scene = "room";
  so.trajectory = "handheld";
  so.frames = 120;
  so.width = 320;
  so.height = 240;
  so.textures = "procedural";
  nerfslam::SequenceRenderer seq(so);
  nerfslam::SystemOptions opt;
  opt.nerf.enabled = false;
  nerfslam::SlamSystem sys(seq.camera(), opt);
  PathBuilder path("map", 1.0);
  size_t updates = 0, tracked = 0;
  double now = 0;
  ros::Time stamp;
  for (int i = 0; i < so.frames; ++i) {
    const nerfslam::SynthFrame f = seq.render(i);
    const nerfslam::FrameRecord rec = sys.trackFrame(f.bgr, f.timestamp, static_cast<uint64_t>(i));
    now = i / 30.0;
    stamp = ros::Time(1.0 + f.timestamp);
    tracked += rec.tracked;
    if (!path.update(sys, &rec, now, stamp)) continue;
    ++updates;
    if (rec.tracked) {  // the frame is on the path, last
      ASSERT_FALSE(path.path().poses.empty());
      EXPECT_EQ(path.path().poses.back().header.stamp, ros::Time(rec.timestamp)) << i;
    }
  }
  sys.waitMappingIdle();
  // Idle (no frame waiting): once the map changed, the whole path is rebuilt.
  path.update(sys, nullptr, now + 0.25, stamp);
  const nerfslam::Trajectory t = sys.trajectory();
  std::printf("%d frames, %zu tracked, %zu path updates, %lu rebuilds, %zu poses\n", so.frames, tracked, updates,
              static_cast<unsigned long>(path.rebuilds()), t.size());
  ASSERT_GT(tracked, 90u);
  ASSERT_GT(t.size(), tracked);  // with the frames before and between the initialisation pair
  ASSERT_EQ(path.path().poses.size(), t.size());
  for (size_t i = 0; i < t.size(); ++i) expectSamePose(path.path().poses[i], t[i], i);
  EXPECT_EQ(path.path().header.stamp, stamp);
  // 4 s of simulated time at one rebuild per second (and the first, and the idle one).
  EXPECT_LE(path.rebuilds(), 8u);
  EXPECT_GE(updates, tracked);
  // Nothing changes once the map is still.
  EXPECT_FALSE(path.update(sys, nullptr, now + 0.5, stamp));
  sys.finish(false);
}

}  // namespace
