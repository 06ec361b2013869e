#include "nerfslam/tracking/tracking_policy.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include <Eigen/Geometry>

namespace nerfslam {
namespace {

TrackingResult tracked(TrackingQuality q, int inliers) {
  TrackingResult r;
  r.quality = q;
  r.num_inliers = inliers;
  return r;
}

// A camera at `centre` looking along world +Z turned by `yaw_deg` about the vertical (Y) axis.
SE3 cameraAt(const Eigen::Vector3d& centre, double yaw_deg = 0) {
  return SE3(Eigen::AngleAxisd(yaw_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix(), centre);
}

// Local map of keyframes `ids` at `poses`; point i is observed by observers[i].
TrackingLocalMap localMap(const std::vector<KeyframeId>& ids, const std::vector<SE3>& poses,
                          const std::vector<std::vector<KeyframeId>>& observers = {}) {
  TrackingLocalMap m;
  m.ref = ids.empty() ? -1 : ids.front();
  m.keyframes = ids;
  m.keyframe_poses = poses;
  m.keyframe_num_points.assign(ids.size(), 0);
  m.keyframe_num_established.assign(ids.size(), 0);
  m.observer_begin.assign(1, 0);
  for (size_t i = 0; i < observers.size(); ++i) {
    TrackingMapPoint p;
    p.id = 10 * (i + 1);
    p.p_world = Eigen::Vector3d(0, 0, 5);
    m.points.push_back(p);
    for (KeyframeId k : observers[i]) {
      m.observers.push_back(k);
      for (size_t s = 0; s < ids.size(); ++s) m.keyframe_num_points[s] += ids[s] == k;
    }
    m.observer_begin.push_back(static_cast<int>(m.observers.size()));
  }
  return m;
}

MapMatch matchOf(uint64_t point_id) {
  MapMatch m;
  m.point_id = point_id;
  return m;
}

TEST(RelocalizationPolicy, WeakTrackingIsRetriedBelowTheGoodCountOrAfterACollapse) {
  WeakTrackingPolicy p;
  p.min_inliers_good = 50;
  p.inlier_drop = 0.25;
  EXPECT_TRUE(relocalizeWeakTracking(tracked(TrackingQuality::kWeak, 49), 0, p));
  EXPECT_FALSE(relocalizeWeakTracking(tracked(TrackingQuality::kGood, 50), 0, p));
  // 60 of the previous frame's 300 inliers: fewer than a quarter of them.
  EXPECT_TRUE(relocalizeWeakTracking(tracked(TrackingQuality::kGood, 60), 300, p));
  EXPECT_FALSE(relocalizeWeakTracking(tracked(TrackingQuality::kGood, 75), 300, p));
  // A lost frame is relocalised anyway; this rule is only for the tracked ones.
  EXPECT_FALSE(relocalizeWeakTracking(tracked(TrackingQuality::kLost, 5), 300, p));
  p.relocalize_when_weak = false;
  EXPECT_FALSE(relocalizeWeakTracking(tracked(TrackingQuality::kWeak, 20), 300, p));
}

TEST(RelocalizationPolicy, DatabaseCandidatesOnlyWhereTheCameraMayBeAnywhere) {
  EXPECT_FALSE(relocalizeAnywhere(false, false, TrackingQuality::kWeak));
  EXPECT_TRUE(relocalizeAnywhere(false, false, TrackingQuality::kLost));
  EXPECT_TRUE(relocalizeAnywhere(true, false, TrackingQuality::kWeak));
  EXPECT_TRUE(relocalizeAnywhere(false, true, TrackingQuality::kGood));
}

TEST(RelocalizationPolicy, VotedKeyframesFirstThenTheNewestOthers) {
  // Voted 3 (best) and 7; then the newest not voted: 9, 8, 5, 2 ... of which `recent` = 2 count.
  const RelocalizationChoice c = chooseRelocalizationKeyframes({2, 3, 5, 7, 8, 9}, {3, 7}, 2);
  EXPECT_EQ(c.keyframes, (std::vector<KeyframeId>{3, 7, 9, 8, 5, 2}));
  EXPECT_EQ(c.max_candidates, 4u);
  // No vote: the `recent` newest (the order does not depend on the input's).
  const RelocalizationChoice r = chooseRelocalizationKeyframes({9, 2, 5}, {}, 5);
  EXPECT_EQ(r.keyframes, (std::vector<KeyframeId>{9, 5, 2}));
  EXPECT_EQ(r.max_candidates, 5u);
}

TEST(RelocalizationPolicy, RelocalisedPoseReplacesAWeakOneOnlyWithMoreInliers) {
  const TrackingResult weak = tracked(TrackingQuality::kWeak, 40);
  EXPECT_TRUE(relocalizedPoseWins(true, weak, tracked(TrackingQuality::kGood, 41)));
  EXPECT_FALSE(relocalizedPoseWins(true, weak, tracked(TrackingQuality::kGood, 40)));
  EXPECT_FALSE(relocalizedPoseWins(true, weak, tracked(TrackingQuality::kLost, 100)));
  // A lost frame takes whatever relocalisation gives.
  const TrackingResult lost = tracked(TrackingQuality::kLost, 0);
  EXPECT_TRUE(relocalizedPoseWins(false, lost, tracked(TrackingQuality::kLost, 0)));
  EXPECT_TRUE(relocalizedPoseWins(false, lost, tracked(TrackingQuality::kWeak, 25)));
}

TEST(WeakPose, RefusedAfterALossOrACollapseUnlessRelocalised) {
  WeakTrackingPolicy p;
  p.min_inliers_good = 50;
  const TrackingResult weak = tracked(TrackingQuality::kWeak, 30);
  const auto after_loss = refuseWeakPose(weak, false, true, 0, p);
  ASSERT_TRUE(after_loss);
  EXPECT_EQ(*after_loss,
            "lost: 30 inliers are too weak to recover from a loss (< 50); relocalisation found no better pose");
  const auto collapsed = refuseWeakPose(weak, false, false, 200, p);
  ASSERT_TRUE(collapsed);
  EXPECT_EQ(*collapsed, "lost: 30 inliers collapsed from (200); relocalisation found no better pose");
  EXPECT_FALSE(refuseWeakPose(weak, false, false, 100, p));  // 30 >= 0.25 x 100: it stands
  EXPECT_FALSE(refuseWeakPose(weak, true, true, 200, p));    // relocalised
  EXPECT_FALSE(refuseWeakPose(tracked(TrackingQuality::kGood, 30), false, true, 200, p));
  p.relocalize_when_weak = false;  // the collapse rule goes with it, the loss rule stays
  EXPECT_FALSE(refuseWeakPose(weak, false, false, 200, p));
  EXPECT_TRUE(refuseWeakPose(weak, false, true, 200, p));
}

TEST(ReferenceKeyframe, MostObservedMatchesWinTiesGoToTheNewer) {
  // Points 10, 20, 30 observed by {1, 2}, {2, 3}, {3}.
  const TrackingLocalMap m = localMap({1, 2, 3}, {SE3(), SE3(), SE3()}, {{1, 2}, {2, 3}, {3}});
  EXPECT_EQ(chooseReferenceKeyframe({matchOf(10), matchOf(20)}, m), 2);
  EXPECT_EQ(chooseReferenceKeyframe({matchOf(10), matchOf(20), matchOf(30)}, m), 3);  // 2 and 3 tie
  EXPECT_EQ(chooseReferenceKeyframe({matchOf(10)}, m), 2);                            // 1 and 2 tie
  EXPECT_EQ(chooseReferenceKeyframe({matchOf(99)}, m), -1);                           // not in the local map
  EXPECT_EQ(chooseReferenceKeyframe({}, m), -1);
}

TEST(VisiblePoints, OnlyPointsProjectingIntoTheImage) {
  TrackingLocalMap m = localMap({0}, {SE3()}, {{0}, {0}, {0}});
  m.points[0].p_world = Eigen::Vector3d(0, 0, 4);   // straight ahead
  m.points[1].p_world = Eigen::Vector3d(0, 0, -4);  // behind
  m.points[2].p_world = Eigen::Vector3d(40, 0, 4);  // far outside the image
  const Camera cam = Camera::pinhole(640, 480, 500, 500, 319.5, 239.5);
  EXPECT_EQ(visiblePoints(m, cam, SE3()), (std::vector<uint64_t>{10}));
  // Turned around, the point behind is the one in view.
  EXPECT_EQ(visiblePoints(m, cam, cameraAt(Eigen::Vector3d::Zero(), 180)), (std::vector<uint64_t>{20}));
}

TEST(KeyframeDecisionInput, DistancesToNearestSameViewAndSimilarOlderView) {
  KeyframePolicyOptions o;
  o.stopped_view_angle_deg = 2.0;
  o.covered_view_angle_deg = 10.0;
  // Keyframes 1..4: 1 at x = 1 looking the same way; 2 at x = 0.5 turned 5 deg; 3 (one of the newest
  // two) at x = 0.2 looking the same way; 4 (the newest) at x = 0.1 turned 90 deg.
  const TrackingLocalMap m = localMap(
      {3, 1, 2, 4}, {cameraAt({0.2, 0, 0}), cameraAt({1, 0, 0}), cameraAt({0.5, 0, 0}, 5), cameraAt({0.1, 0, 0}, 90)},
      {{3, 1}, {3, 2}, {4}});
  TrackingResult r = tracked(TrackingQuality::kGood, 120);
  r.T_world_cam = cameraAt(Eigen::Vector3d::Zero());
  r.median_depth = 4;
  r.matches = {matchOf(10), matchOf(20), matchOf(30)};
  const KeyframeDecisionInput in = keyframeDecisionInput(r, m, 3, std::nullopt, 7, false, o);
  EXPECT_EQ(in.quality, TrackingQuality::kGood);
  EXPECT_EQ(in.num_inliers, 120);
  EXPECT_EQ(in.frames_since_last_keyframe, 7);
  EXPECT_FALSE(in.mapping_idle);
  EXPECT_DOUBLE_EQ(in.median_scene_depth, 4);
  EXPECT_NEAR(in.distance_to_nearest_keyframe, 0.1, 1e-12);  // keyframe 4, whatever way it looks
  EXPECT_NEAR(in.distance_to_same_view, 0.2, 1e-12);         // keyframe 3 (the newest two count here)
  EXPECT_NEAR(in.distance_to_similar_view, 0.5, 1e-12);      // keyframe 2: 3 and 4 are the newest two
  EXPECT_EQ(in.reference_keyframe_points, 2);                // keyframe 3 observes points 10 and 20
  EXPECT_EQ(in.tracked_reference_points, 2);
  // The last keyframe made, not yet in the local map, counts for the same view.
  const KeyframeDecisionInput last = keyframeDecisionInput(r, m, 3, cameraAt({0.05, 0, 0}, 1), 7, true, o);
  EXPECT_NEAR(last.distance_to_same_view, 0.05, 1e-12);
  EXPECT_NEAR(last.distance_to_nearest_keyframe, 0.1, 1e-12);
  // Tracked reference points are counted only for the covered-view gate.
  o.covered_view_angle_deg = 0;
  EXPECT_EQ(keyframeDecisionInput(r, m, 3, std::nullopt, 7, true, o).tracked_reference_points, 0);
  // A reference outside the local map: no reference points; an unknown depth counts as 1.
  r.median_depth = 0;
  const KeyframeDecisionInput away = keyframeDecisionInput(r, m, 42, std::nullopt, 7, true, o);
  EXPECT_EQ(away.reference_keyframe_points, 0);
  EXPECT_DOUBLE_EQ(away.median_scene_depth, 1.0);
  // An empty local map: no keyframe near, none looking the same way.
  const KeyframeDecisionInput none = keyframeDecisionInput(r, TrackingLocalMap{}, 3, std::nullopt, 7, true, o);
  EXPECT_EQ(none.distance_to_nearest_keyframe, 0.0);
  EXPECT_EQ(none.distance_to_same_view, std::numeric_limits<double>::infinity());
}

}  // namespace
}  // namespace nerfslam
