// Wheel odometry (mapping/odometry.h): the extrinsic's check, interpolation, the file's checks and
// the scale estimate from keyframe pairs against exact truth.
#include "nerfslam/mapping/odometry.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {

SE3 basePose(double t) {  // a base driving a gentle S-curve in the plane at about 0.5 m/s
  const double yaw = 0.6 * std::sin(0.4 * t);
  return SE3(Eigen::Quaterniond(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ())),
             Eigen::Vector3d(0.5 * t, 0.8 * std::sin(0.3 * t), 0.0));
}

OdometryOptions withExtrinsic() {
  OdometryOptions o;
  o.T_base_cam = {0, 0, 1, 0.1, -1, 0, 0, 0, 0, -1, 0, 0.5, 0, 0, 0, 1};
  return o;
}

TEST(Odometry, RigidTransformCheckNamesWhatIsWrong) {
  EXPECT_EQ(checkRigidTransform(withExtrinsic().T_base_cam), "");
  EXPECT_NE(checkRigidTransform({1, 0, 0}).find("16 numbers"), std::string::npos);
  std::vector<double> scaled = withExtrinsic().T_base_cam;
  for (int k : {0, 1, 2, 4, 5, 6, 8, 9, 10}) scaled[k] *= 1.1;
  EXPECT_NE(checkRigidTransform(scaled).find("not orthonormal"), std::string::npos);
  std::vector<double> mirror = {-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  EXPECT_NE(checkRigidTransform(mirror).find("reflection"), std::string::npos);
  std::vector<double> row = withExtrinsic().T_base_cam;
  row[14] = 1;
  EXPECT_NE(checkRigidTransform(row).find("last row"), std::string::npos);
  row = withExtrinsic().T_base_cam;
  row[3] = std::nan("");
  EXPECT_NE(checkRigidTransform(row).find("finite"), std::string::npos);
  const SE3 T = rigidTransformFromRowMajor(withExtrinsic().T_base_cam);
  EXPECT_NEAR((T * Eigen::Vector3d(0, 0, 1) - Eigen::Vector3d(1.1, 0, 0.5)).norm(), 0, 1e-12);
}

TEST(Odometry, InterpolatesWithinSamplesAndNotAcrossGaps) {
  Trajectory tr;
  for (int i = 0; i <= 20; ++i) tr.push_back({0.1 * i, basePose(0.1 * i)});
  tr.push_back({5.0, basePose(5.0)});  // a 3 s gap
  const OdometryOptions o = withExtrinsic();
  const OdometryTrack odo(tr, rigidTransformFromRowMajor(o.T_base_cam), "test", o);
  ASSERT_TRUE(odo.baseAt(0.55).has_value());
  EXPECT_NEAR((odo.baseAt(0.55)->translation() - basePose(0.55).translation()).norm(), 0, 2e-3);
  EXPECT_TRUE(odo.baseAt(1.0)->isApprox(basePose(1.0), 1e-12));
  EXPECT_FALSE(odo.baseAt(3.0).has_value()) << "across a gap";
  EXPECT_TRUE(odo.baseAt(-0.05).has_value()) << "within max_stamp_offset_s of the first sample";
  EXPECT_FALSE(odo.baseAt(-1.0).has_value());
  EXPECT_FALSE(odo.baseAt(6.0).has_value());
  // The camera's motion: the base's, seen through the extrinsic.
  const SE3 Tbc = rigidTransformFromRowMajor(o.T_base_cam);
  const auto m = odo.cameraMotion(0.2, 1.7);
  ASSERT_TRUE(m.has_value());
  EXPECT_TRUE(m->isApprox(Tbc.inverse() * basePose(0.2).inverse() * basePose(1.7) * Tbc, 1e-9));
  EXPECT_FALSE(odo.cameraMotion(0.2, 3.0).has_value());

  Trajectory back = tr;
  back[5].timestamp = back[3].timestamp;
  const std::string e = test::errorOf([&] { OdometryTrack(back, SE3(), "odo.txt", o); });
  EXPECT_NE(e.find("odo.txt: field 'timestamp' of odometry sample 6"), std::string::npos) << e;
  EXPECT_NE(e.find("stamps going back"), std::string::npos) << e;
  EXPECT_NE(test::errorOf([&] { OdometryTrack({tr[0]}, SE3(), "one.txt", o); }).find("at least 2"), std::string::npos);
}

TEST(Odometry, FileWithNanOrStampsGoingBackIsRefusedNamingFileAndLine) {
  test::TempDir tmp;
  const OdometryOptions o = withExtrinsic();
  test::writeText(tmp / "nan.txt", "# t x y z qx qy qz qw\n0 0 0 0 0 0 0 1\n0.1 nan 0 0 0 0 0 1\n");
  std::string e = test::errorOf([&] { OdometryTrack::load(tmp / "nan.txt", o); });
  EXPECT_NE(e.find("nan.txt"), std::string::npos) << e;
  EXPECT_NE(e.find("nan.txt:3: column 2"), std::string::npos) << e;
  test::writeText(tmp / "back.txt", "0 0 0 0 0 0 0 1\n0.2 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0 1\n");
  e = test::errorOf([&] { OdometryTrack::load(tmp / "back.txt", o); });
  EXPECT_NE(e.find("back.txt: field 'timestamp' of odometry sample 3"), std::string::npos) << e;
  EXPECT_NE(e.find("going back"), std::string::npos) << e;
  test::writeText(tmp / "ok.txt", "0 0 0 0 0 0 0 1\n0.1 0.05 0 0 0 0 0 1\n");
  EXPECT_EQ(OdometryTrack::load(tmp / "ok.txt", o).size(), 2u);
}

// The map is the truth shrunk to 1/3 with tracking noise; the odometry has 2 % noise and a slip
// episode (0.6 s reporting 1.5x): the estimate is the truth's 3 within 1 %, and only after enough motion.
TEST(Odometry, ScaleFromKeyframePairsIsRobustToSlip) {
  const OdometryOptions o = withExtrinsic();
  const SE3 Tbc = rigidTransformFromRowMajor(o.T_base_cam);
  std::mt19937 rng(5);
  std::normal_distribution<double> g(0, 1);
  Trajectory odo{{0.0, SE3()}};
  for (int i = 1; i <= 300; ++i) {  // 30 s at 10 Hz
    const double t = 0.1 * i;
    const SE3 D = basePose(t - 0.1).inverse() * basePose(t);
    Eigen::Vector3d d = D.translation();
    if (t > 8.0 && t <= 8.6) d *= 1.5;  // slip
    d += 0.02 / std::sqrt(3.0) * D.translation().norm() * Eigen::Vector3d(g(rng), g(rng), g(rng));
    odo.push_back({t, odo.back().pose * SE3(D.rotation(), d)});
  }
  const OdometryTrack track(odo, Tbc, "sim", o);
  std::vector<TimedPose> kfs;
  for (int k = 0; k <= 60; ++k) {  // a keyframe every 0.5 s
    const double t = 0.5 * k;
    SE3 cam = basePose(t) * Tbc;
    const Eigen::Vector3d c = cam.translation() / 3.0 + 0.002 * Eigen::Vector3d(g(rng), g(rng), g(rng));
    kfs.push_back({t, SE3(cam.rotation(), c)});
  }
  const std::vector<TimedPose> early(kfs.begin(), kfs.begin() + 4);
  const ScaleEstimate e0 = estimateScale(early, track);
  EXPECT_FALSE(e0.valid) << "3 pairs, 0.75 m: not enough motion yet";
  const ScaleEstimate e = estimateScale(kfs, track);
  ASSERT_TRUE(e.valid);
  EXPECT_EQ(e.pairs, 60);
  EXPECT_LT(e.inliers, 60) << "the slipping pairs are left out";
  EXPECT_NEAR(e.scale / 3.0, 1.0, 0.01) << e.scale;
  // Only the last 20 pairs, shuffled keyframes (sorted by time inside).
  std::vector<TimedPose> shuffled = kfs;
  std::shuffle(shuffled.begin(), shuffled.end(), rng);
  const ScaleEstimate recent = estimateScale(shuffled, track, 20);
  EXPECT_EQ(recent.pairs, 20);
  EXPECT_NEAR(recent.scale / 3.0, 1.0, 0.02);
  // A 4x map: the estimate follows it.
  for (auto& k : kfs) k.T_world_cam = SE3(k.T_world_cam.rotation(), 4.0 * k.T_world_cam.translation());
  EXPECT_NEAR(estimateScale(kfs, track).scale / 0.75, 1.0, 0.01);
}

}  // namespace
}  // namespace nerfslam
