#include "nerfslam/tracking/tracker.h"

#include <limits>

#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/tracking/relocalizer.h"
#include "nerfslam/tracking/two_view_geometry.h"
#include "test_support.h"

namespace nerfslam {
namespace {

struct Kitti {
  Camera cam = Camera::pinhole(1226, 370, 707.0912, 707.0912, 601.8873, 183.1104);
  std::vector<SE3> gt;
  std::filesystem::path dir;
  Frame frame(int i) const {
    char name[32];
    std::snprintf(name, sizeof(name), "image_l/%06d.png", i);
    const cv::Mat img = cv::imread((dir / name).string(), cv::IMREAD_GRAYSCALE);
    EXPECT_FALSE(img.empty()) << name;
    FeatureOptions fo;
    fo.max_features = 1500;
    return extractFrame(img, cam, fo, static_cast<uint64_t>(i));
  }
};

Kitti loadKitti(const std::filesystem::path& dir) {
  Kitti k;
  k.dir = dir;
  std::ifstream in(dir / "poses.txt");
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream is(line);
    Eigen::Matrix<double, 3, 4> T;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) is >> T(r, c);
    if (is) k.gt.push_back(SE3::fromMatrix3x4(T));
  }
  return k;
}

// Map points from two ground-truth-posed frames: descriptor matches (ratio test) that satisfy the
// known epipolar geometry, triangulated with the known relative pose. Descriptors from frame a.
std::vector<TrackingMapPoint> triangulateWithGroundTruth(const Frame& a, const Frame& b, const SE3& T_w_a,
                                                         const SE3& T_w_b) {
  const SE3 T_b_a = T_w_b.inverse() * T_w_a;
  const RelativePose rel{T_b_a.rotationMatrix(), T_b_a.translation()};
  const Eigen::Matrix3d K = a.camera.K(), Ki = K.inverse();
  std::vector<TrackingMapPoint> map;
  for (size_t i = 0; i < a.size(); ++i) {
    int best = 256, second = 256, bj = -1;
    for (size_t j = 0; j < b.size(); ++j) {
      const int d = descriptorDistance(a.descriptors.ptr<uint8_t>(int(i)), b.descriptors.ptr<uint8_t>(int(j)));
      if (d < best) {
        second = best;
        best = d;
        bj = int(j);
      } else if (d < second) {
        second = d;
      }
    }
    if (bj < 0 || best > 50 || best > 0.8 * second) continue;
    const Eigen::Vector2d& u1 = a.undistorted[i];
    const Eigen::Vector2d& u2 = b.undistorted[size_t(bj)];
    const Eigen::Vector3d X =
        triangulate(rel, (Ki * u1.homogeneous()).hnormalized(), (Ki * u2.homogeneous()).hnormalized());
    const Eigen::Vector3d X2 = rel.R * X + rel.t;
    if (!X.allFinite() || X.z() < 1 || X.z() > 80 || X2.z() < 1) continue;
    const double tol1 = 2.0 * a.level_scale[size_t(a.keypoints[i].octave)];
    const double tol2 = 2.0 * b.level_scale[size_t(b.keypoints[size_t(bj)].octave)];
    if (((K * X).hnormalized() - u1).norm() > tol1 || ((K * X2).hnormalized() - u2).norm() > tol2) continue;
    TrackingMapPoint p;
    p.id = 1000 + i;
    p.p_world = T_w_a * X;
    p.descriptor = a.descriptors.row(int(i)).clone();
    p.angle = a.keypoints[i].angle;
    map.push_back(p);
  }
  return map;
}

double rotDeg(const SE3& a, const SE3& b) {
  return Eigen::AngleAxisd(a.rotationMatrix().transpose() * b.rotationMatrix()).angle() * 180 / M_PI;
}

TEST(Tracker, TracksKittiFramesAgainstGroundTruthMap) {
  NERFSLAM_REQUIRE_DATA(dir, "kitti06_first51");
  const Kitti k = loadKitti(dir);
  // Keyframes 2 and 4 (2.4 m apart) give the map; frames 5-7 are tracked with the motion model.
  const std::vector<TrackingMapPoint> map = triangulateWithGroundTruth(k.frame(4), k.frame(2), k.gt[4], k.gt[2]);
  ASSERT_GT(map.size(), 100u);
  Tracker tracker;
  tracker.setPose(k.gt[4], &k.gt[3]);
  for (int i = 5; i <= 7; ++i) {
    const Frame f = k.frame(i);
    const TrackingResult r = tracker.track(f, map);
    const double terr = (r.T_world_cam.translation() - k.gt[size_t(i)].translation()).norm();
    const double rerr = rotDeg(r.T_world_cam, k.gt[size_t(i)]);
    std::printf("frame %d: %s, t err %.3f m, R err %.3f deg, %.2f ms match + %.2f ms opt\n", i, r.message.c_str(), terr,
                rerr, r.timings.matching_ms, r.timings.optimization_ms);
    // The map inherits ground-truth noise (KITTI's GPS/INS poses), so the pose is judged with
    // tolerances that allow for it, and the optimiser must fit the images at least as well as GT.
    double sq = 0;
    const SE3 Tcw = k.gt[size_t(i)].inverse();
    for (const MapMatch& m : r.matches)
      sq +=
          ((f.camera.K() * (Tcw * map[size_t(m.point_index)].p_world)).hnormalized() - f.undistorted[size_t(m.feature)])
              .squaredNorm();
    const double rms_gt = std::sqrt(sq / std::max<size_t>(1, r.matches.size()));
    std::printf("  reprojection rms at the ground-truth pose: %.2f px\n", rms_gt);
    EXPECT_LE(r.rms_px, rms_gt + 1e-6);
    EXPECT_NE(r.quality, TrackingQuality::kLost) << r.message;
    if (i == 5) {
      EXPECT_EQ(r.quality, TrackingQuality::kGood) << r.message;
    }
    EXPECT_LT(terr, 0.2);
    EXPECT_LT(rerr, 1.0);
    EXPECT_EQ(static_cast<int>(r.matches.size()), r.num_inliers);
    for (const MapMatch& m : r.matches) {
      ASSERT_GE(m.point_index, 0);
      EXPECT_EQ(map[size_t(m.point_index)].id, m.point_id);
    }
    EXPECT_GT(r.median_depth, 1.0);
  }
}

TEST(Tracker, LostOnUnrelatedImageKeepsMotionModel) {
  NERFSLAM_REQUIRE_DATA(dir, "kitti06_first51");
  const Kitti k = loadKitti(dir);
  const std::vector<TrackingMapPoint> map = triangulateWithGroundTruth(k.frame(0), k.frame(2), k.gt[0], k.gt[2]);
  Tracker tracker;
  tracker.setPose(k.gt[2], &k.gt[1]);
  const SE3 before = tracker.predictedPose();
  cv::Mat noise(370, 1226, CV_8U);
  cv::randu(noise, 0, 255);
  const TrackingResult r = tracker.track(extractFrame(noise, k.cam, {}), map);
  EXPECT_EQ(r.quality, TrackingQuality::kLost);
  EXPECT_NE(r.message.find("lost"), std::string::npos) << r.message;
  EXPECT_TRUE(tracker.predictedPose().isApprox(before));
  Tracker fresh;
  EXPECT_EQ(fresh.track(k.frame(3), map).quality, TrackingQuality::kLost);  // no pose yet
}

TEST(Relocalizer, RecoversKittiPoseFromKeyframeDescriptors) {
  NERFSLAM_REQUIRE_DATA(dir, "kitti06_first51");
  const Kitti k = loadKitti(dir);
  RelocalizationCandidate real;
  real.keyframe_id = 2;
  real.T_world_cam = k.gt[2];
  real.points = triangulateWithGroundTruth(k.frame(2), k.frame(4), k.gt[2], k.gt[4]);
  ASSERT_GT(real.points.size(), 100u);
  RelocalizationCandidate decoy = real;  // same geometry, scrambled descriptors
  decoy.keyframe_id = 99;
  cv::RNG rng(5);
  for (auto& p : decoy.points) {
    p.descriptor = p.descriptor.clone();  // cv::Mat copies share data
    rng.fill(p.descriptor, cv::RNG::UNIFORM, 0, 256);
  }
  const Frame f = k.frame(6);
  const RelocalizationResult r = relocalize(f, {decoy, real});
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_EQ(r.keyframe_id, 2u);
  const double terr = (r.T_world_cam.translation() - k.gt[6].translation()).norm();
  std::printf("relocalised frame 6 (4.8 m from the keyframe): %d inliers, t err %.3f m, R err %.3f deg\n",
              r.num_inliers, terr, rotDeg(r.T_world_cam, k.gt[6]));
  EXPECT_LT(terr, 0.2);
  EXPECT_LT(rotDeg(r.T_world_cam, k.gt[6]), 1.0);
  EXPECT_EQ(static_cast<int>(r.matches.size()), r.num_inliers);

  cv::Mat noise(370, 1226, CV_8U);
  cv::randu(noise, 0, 255);
  const RelocalizationResult bad = relocalize(extractFrame(noise, k.cam, {}), {real});
  EXPECT_FALSE(bad.success);
  EXPECT_FALSE(bad.reason.empty());
  EXPECT_FALSE(relocalize(f, {}).success);
}

// ORB-SLAM's verification: a candidate whose own points give too few inliers is accepted once the
// guided search has projected its covisible keyframes' points (`neighbours`), never below
// min_inliers, and of two accepted candidates the one with more inliers wins.
TEST(Relocalizer, GuidedSearchThroughTheNeighboursAndTheBestCandidateWins) {
  NERFSLAM_REQUIRE_DATA(dir, "kitti06_first51");
  const Kitti k = loadKitti(dir);
  const std::vector<TrackingMapPoint> all = triangulateWithGroundTruth(k.frame(2), k.frame(4), k.gt[2], k.gt[4]);
  ASSERT_GT(all.size(), 100u);
  RelocalizationCandidate few;  // half of the points as its own, the others as its neighbours'
  few.keyframe_id = 3;
  for (size_t i = 0; i < all.size(); ++i) (i % 2 == 0 ? few.points : few.neighbours).push_back(all[i]);
  const Frame f = k.frame(5);
  RelocalizerOptions no_guided;
  no_guided.guided_search_below = 0;
  const RelocalizationResult without = relocalize(f, {few}, no_guided);
  EXPECT_FALSE(without.success) << without.num_inliers;
  EXPECT_NE(without.reason.find("need 50"), std::string::npos) << without.reason;
  const RelocalizationResult guided = relocalize(f, {few});
  ASSERT_TRUE(guided.success) << guided.reason;
  EXPECT_GE(guided.num_inliers, 50);
  EXPECT_LT((guided.T_world_cam.translation() - k.gt[5].translation()).norm(), 0.2);
  EXPECT_LT(rotDeg(guided.T_world_cam, k.gt[5]), 1.0);
  int from_neighbours = 0;  // matches with point_index past the candidate's own points
  for (const MapMatch& m : guided.matches) {
    ASSERT_GE(m.point_index, 0);
    ASSERT_LT(size_t(m.point_index), few.points.size() + few.neighbours.size());
    from_neighbours += size_t(m.point_index) >= few.points.size() ? 1 : 0;
  }
  EXPECT_GT(from_neighbours, 10);
  // Two acceptable candidates: the one with more inliers, whatever the order.
  RelocalizationCandidate half;
  half.keyframe_id = 4;
  for (size_t i = 0; i < all.size(); i += 2) half.points.push_back(all[i]);
  RelocalizationCandidate full;
  full.keyframe_id = 2;
  full.points = all;
  const RelocalizationResult r = relocalize(f, {half, full});
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_EQ(r.keyframe_id, 2u);
  std::printf("guided search: %d inliers (none without it: %s); of two candidates, %d inliers\n", guided.num_inliers,
              without.reason.c_str(), r.num_inliers);
}

TEST(KeyframeDecision, PtamAndCovisibilityCriteria) {
  KeyframePolicyOptions o;
  KeyframeDecisionInput in;
  in.quality = TrackingQuality::kGood;
  in.num_inliers = 200;
  in.median_scene_depth = 10;
  in.frames_since_last_keyframe = 8;
  in.distance_to_nearest_keyframe = 0.5;  // 0.05 x depth
  in.reference_keyframe_points = 300;
  in.tracked_reference_points = 290;
  in.reference_keyframe_established_points = 210;  // 200 inliers >= 0.9 x 210
  EXPECT_FALSE(decideKeyframe(in, o).insert);
  in.distance_to_nearest_keyframe = 1.5;  // 0.15 x depth
  auto d = decideKeyframe(in, o);
  EXPECT_TRUE(d.insert);
  EXPECT_NE(d.reason.find("baseline"), std::string::npos);
  in.frames_since_last_keyframe = 2;  // too soon
  EXPECT_FALSE(decideKeyframe(in, o).insert);
  in.frames_since_last_keyframe = 8;
  in.distance_to_nearest_keyframe = 0.1;
  in.reference_keyframe_established_points = 250;  // 200 inliers < 0.9 x 250 (ORB-SLAM's rule)
  d = decideKeyframe(in, o);
  EXPECT_TRUE(d.insert);
  EXPECT_NE(d.reason.find("established points"), std::string::npos) << d.reason;
  in.mapping_idle = false;
  EXPECT_FALSE(decideKeyframe(in, o).insert);
  in.frames_since_last_keyframe = 40;
  EXPECT_TRUE(decideKeyframe(in, o).insert);
  in.quality = TrackingQuality::kLost;
  EXPECT_FALSE(decideKeyframe(in, o).insert);
}

// A stopped camera (a keyframe, the newest included, within stopped_distance_ratio x depth looking
// the same way) makes no keyframe whatever the other criteria say, weak tracking and the frame count
// included; moving off it, or the rule switched off, lets them decide again.
TEST(KeyframeDecision, StoppedCameraMakesNoSecondKeyframeInOnePlace) {
  KeyframePolicyOptions o;
  KeyframeDecisionInput in;
  in.quality = TrackingQuality::kWeak;
  in.num_inliers = 200;
  in.median_scene_depth = 10;
  in.frames_since_last_keyframe = 40;
  in.reference_keyframe_points = 300;
  in.tracked_reference_points = 100;
  in.distance_to_nearest_keyframe = 0.005;
  in.distance_to_same_view = 0.005;  // 0.0005 x depth
  auto d = decideKeyframe(in, o);
  EXPECT_FALSE(d.insert);
  EXPECT_NE(d.reason.find("stopped"), std::string::npos) << d.reason;
  in.distance_to_same_view = 0.02;  // 0.002 x depth: moving
  EXPECT_TRUE(decideKeyframe(in, o).insert);
  in.distance_to_same_view = std::numeric_limits<double>::infinity();  // turned away from every keyframe
  EXPECT_TRUE(decideKeyframe(in, o).insert);
  in.distance_to_same_view = 0.005;
  o.stopped_distance_ratio = 0;
  EXPECT_TRUE(decideKeyframe(in, o).insert);
}

// A camera back where a keyframe already looks the same way makes no keyframe while tracking is good,
// whatever the frame count or covisibility say; a new viewing direction, weak tracking or the gate
// switched off still make one.
TEST(KeyframeDecision, CoveredViewMakesNoKeyframeWhileTrackingIsGood) {
  KeyframePolicyOptions o;
  o.covered_view_angle_deg = 8;  // off by default
  KeyframeDecisionInput in;
  in.quality = TrackingQuality::kGood;
  in.num_inliers = 200;
  in.median_scene_depth = 10;
  in.frames_since_last_keyframe = 40;     // beyond max_frames_between
  in.distance_to_nearest_keyframe = 0.3;  // 0.03 x depth
  in.distance_to_similar_view = 0.3;      // and that keyframe looks the same way
  in.reference_keyframe_points = 300;
  in.tracked_reference_points = 200;  // covisibility 0.67: most of the reference keyframe is found
  auto d = decideKeyframe(in, o);
  EXPECT_FALSE(d.insert);
  EXPECT_NE(d.reason.find("view covered"), std::string::npos) << d.reason;
  in.tracked_reference_points = 100;  // 0.33: the view ahead is new (forward motion), not covered
  d = decideKeyframe(in, o);
  EXPECT_TRUE(d.insert);
  EXPECT_NE(d.reason.find("frames since"), std::string::npos) << d.reason;
  in.tracked_reference_points = 200;
  in.distance_to_similar_view = 5.0;  // the near keyframe looks elsewhere; a similar one is 0.5 x depth away
  d = decideKeyframe(in, o);
  EXPECT_TRUE(d.insert);
  EXPECT_NE(d.reason.find("frames since"), std::string::npos) << d.reason;
  in.frames_since_last_keyframe = 8;
  in.reference_keyframe_established_points = 250;  // 200 inliers < 0.9 x 250
  d = decideKeyframe(in, o);
  EXPECT_TRUE(d.insert);
  EXPECT_NE(d.reason.find("established points"), std::string::npos) << d.reason;
  in.distance_to_similar_view = 0.3;
  in.quality = TrackingQuality::kWeak;  // weak tracking still asks for a keyframe
  EXPECT_TRUE(decideKeyframe(in, o).insert);
  in.quality = TrackingQuality::kGood;
  o.covered_view_angle_deg = 0;  // off: the inlier criterion decides again
  EXPECT_TRUE(decideKeyframe(in, o).insert);
}

}  // namespace
}  // namespace nerfslam
