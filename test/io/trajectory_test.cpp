#include "nerfslam/io/trajectory.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <random>
#include <sstream>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

std::string slurp(const fs::path& p) {
  std::ifstream is(p, std::ios::binary);
  std::stringstream ss;
  ss << is.rdbuf();
  return ss.str();
}

Trajectory randomTrajectory(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-5.0, 5.0);
  Trajectory t;
  for (int i = 0; i < n; ++i) {
    Vector6d xi;
    for (int k = 0; k < 6; ++k) xi(k) = u(rng);
    xi.tail<3>() *= 0.6;
    t.push_back({1305031102.160407 + 0.0333333 * i + 1e-7 * u(rng), SE3::exp(xi)});
  }
  return t;
}

// Expects `f` to throw an Error whose message contains every string in `parts`.
template <class F>
void expectError(F&& f, std::initializer_list<std::string> parts) {
  try {
    f();
    ADD_FAILURE() << "no error thrown";
  } catch (const Error& e) {
    const std::string msg = e.what();
    for (const auto& p : parts) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
  }
}

TEST(Trajectory, TumRoundTripIsExact) {
  test::TempDir tmp;
  const Trajectory t = randomTrajectory(50, 1);
  writeTumTrajectory(tmp / "t.txt", t);
  const Trajectory r = readTumTrajectory(tmp / "t.txt");
  ASSERT_EQ(r.size(), t.size());
  for (size_t i = 0; i < t.size(); ++i) {
    EXPECT_NEAR(r[i].timestamp, t[i].timestamp, 5e-10);
    EXPECT_EQ(r[i].pose.translation(), t[i].pose.translation());  // shortest round-trip formatting
    EXPECT_TRUE(r[i].pose.isApprox(t[i].pose, 1e-15));
  }
  EXPECT_EQ(detectTrajectoryFormat(tmp / "t.txt"), TrajectoryFormat::kTum);
  // Timestamps carry 9 decimals.
  const std::string text = slurp(tmp / "t.txt");
  EXPECT_NE(text.find(fmt::format("{:.9f} ", t[3].timestamp)), std::string::npos);
}

TEST(Trajectory, KittiRoundTripWithAndWithoutTimes) {
  test::TempDir tmp;
  const Trajectory t = randomTrajectory(20, 2);
  writeKittiTrajectory(tmp / "k.txt", t, tmp / "times.txt");
  const Trajectory with_times = readKittiTrajectory(tmp / "k.txt", tmp / "times.txt");
  const Trajectory indexed = readTrajectory(tmp / "k.txt");  // auto-detected, index timestamps
  EXPECT_EQ(detectTrajectoryFormat(tmp / "k.txt"), TrajectoryFormat::kKitti);
  ASSERT_EQ(with_times.size(), t.size());
  ASSERT_EQ(indexed.size(), t.size());
  for (size_t i = 0; i < t.size(); ++i) {
    EXPECT_NEAR(with_times[i].timestamp, t[i].timestamp, 5e-10);
    EXPECT_EQ(indexed[i].timestamp, static_cast<double>(i));
    EXPECT_TRUE(with_times[i].pose.isApprox(t[i].pose, 1e-14));
    EXPECT_EQ(with_times[i].pose.translation(), t[i].pose.translation());
  }
}

TEST(Trajectory, TolerantSeparatorsCommentsAndBlankLines) {
  test::TempDir tmp;
  test::writeText(tmp / "a.txt",
                  "# timestamp tx ty tz qx qy qz qw\r\n"
                  "\n"
                  "1.5 1 2 3 0 0 0 1\r\n"
                  "   # indented comment\n"
                  "2.5,\t4,5 ,6, 0,0,0.7071067811865476,0.7071067811865476\n"
                  "3.5\t7\t8\t9\t0\t0\t0\t-1\n");
  const Trajectory t = readTrajectory(tmp / "a.txt", TrajectoryFormat::kAuto);
  ASSERT_EQ(t.size(), 3u);
  EXPECT_EQ(t[0].timestamp, 1.5);
  EXPECT_EQ(t[1].pose.translation(), Eigen::Vector3d(4, 5, 6));
  EXPECT_TRUE((t[1].pose * Eigen::Vector3d(1, 0, 0) - Eigen::Vector3d(4, 6, 6)).norm() < 1e-15);
  EXPECT_TRUE(t[2].pose.isApprox(SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(7, 8, 9))));
}

TEST(Trajectory, SlightlyNonUnitQuaternionIsNormalised) {
  test::TempDir tmp;
  test::writeText(tmp / "a.txt", "0 0 0 0 0 0 0 1.0004\n");
  const Trajectory t = readTumTrajectory(tmp / "a.txt");
  EXPECT_NEAR(t[0].pose.rotation().norm(), 1.0, 1e-15);
}

TEST(Trajectory, ErrorsNameFileAndLine) {
  test::TempDir tmp;
  const std::string good = "1 0 0 0 0 0 0 1\n";
  struct Case {
    std::string text;
    std::vector<std::string> parts;
  };
  const std::vector<Case> cases = {
      {good + "2 0 0 0 0 0 1\n", {":2:", "expected 8 columns", "found 7"}},
      {good + good + "3 0 0 x 0 0 0 1\n", {":3:", "column 4", "'x' is not a number"}},
      {"# c\n1 0 0 nan 0 0 0 1\n", {":2:", "not finite"}},
      {"1 0 0 0 0 0 0 0\n", {":1:", "quaternion is zero"}},
      {"1 0 0 0 0 0 0 2\n", {":1:", "not a unit quaternion"}},
      {"1 0 0 0 0 0 0 1e400\n", {":1:", "not finite"}},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const fs::path p = tmp / ("bad" + std::to_string(i) + ".txt");
    test::writeText(p, cases[i].text);
    std::vector<std::string> parts = cases[i].parts;
    parts.push_back(p.string());
    try {
      readTumTrajectory(p);
      ADD_FAILURE() << "case " << i << ": no error";
    } catch (const Error& e) {
      for (const auto& s : parts) EXPECT_NE(std::string(e.what()).find(s), std::string::npos) << e.what();
    }
  }
  const fs::path missing = tmp / "missing.txt";
  expectError([&] { readTrajectory(missing); }, {missing.string(), "trajectory file not found"});
  test::writeText(tmp / "empty.txt", "# only a comment\n\n");
  expectError([&] { readTumTrajectory(tmp / "empty.txt"); }, {"empty.txt", "no poses"});
  expectError([&] { readTrajectory(tmp / "empty.txt"); }, {"empty.txt", "no poses"});
  test::writeText(tmp / "five.txt", "1 2 3 4 5\n");
  expectError([&] { readTrajectory(tmp / "five.txt"); }, {"five.txt:1:", "cannot detect"});
  expectError([&] { parseTrajectoryFormat("csv"); }, {"csv", "tum", "kitti"});
}

TEST(Trajectory, KittiErrors) {
  test::TempDir tmp;
  test::writeText(tmp / "k.txt",
                  "1 0 0 0 0 1 0 0 0 0 1 0\n"
                  "2 0 0 0 0 1 0 0 0 0 1 0\n");
  expectError([&] { readKittiTrajectory(tmp / "k.txt"); }, {"k.txt:2:", "not a rotation matrix"});
  test::writeText(tmp / "m.txt",
                  "1 0 0 0 0 1 0 0 0 0 -1 0\n");  // det -1: a reflection
  expectError([&] { readKittiTrajectory(tmp / "m.txt"); }, {"m.txt:1:", "not a rotation matrix"});
  test::writeText(tmp / "ok.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n");
  test::writeText(tmp / "times.txt", "0.0\n");
  expectError([&] { readKittiTrajectory(tmp / "ok.txt", tmp / "times.txt"); },
              {"times.txt", "1 timestamps", "2 poses"});
  test::writeText(tmp / "short.txt", "1 0 0 0 0 1 0 0 0 0 1\n");
  expectError([&] { readKittiTrajectory(tmp / "short.txt"); }, {"short.txt:1:", "expected 12 columns", "found 11"});
}

TEST(Trajectory, WriterIsAtomicAndReportsUnwritableDirectory) {
  test::TempDir tmp;
  const Trajectory t = randomTrajectory(3, 5);
  const fs::path bad = tmp / "no_such_dir" / "t.txt";
  EXPECT_THROW(writeTumTrajectory(bad, t), Error);
  EXPECT_FALSE(fs::exists(bad));
  writeTumTrajectory(tmp / "t.txt", t);
  size_t files = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(tmp.path())) ++files;
  EXPECT_EQ(files, 1u);  // no temporary left behind
}

TEST(Trajectory, ReadsEvoReferenceFiles) {
  NERFSLAM_REQUIRE_DATA(dir, "evo_reference");
  const Trajectory kitti =
      readTrajectory(dir / "KITTI_00_gt.txt", TrajectoryFormat::kAuto, dir / "KITTI_00_gt_times.txt");
  ASSERT_EQ(kitti.size(), 4541u);
  EXPECT_NEAR(kitti[1].timestamp, 1.037359e-01, 1e-12);
  // Line 2 of KITTI_00_gt.txt: translation (-4.690294e-02, -2.839928e-02, 8.586941e-01).
  EXPECT_TRUE(kitti[1].pose.translation().isApprox(Eigen::Vector3d(-4.690294e-02, -2.839928e-02, 8.586941e-01), 1e-15));

  const Trajectory tum = readTrajectory(dir / "freiburg1_xyz-groundtruth.txt");
  EXPECT_EQ(tum.size(), 3000u);
  EXPECT_EQ(detectTrajectoryFormat(dir / "freiburg1_xyz-rgbdslam.txt"), TrajectoryFormat::kTum);

  EXPECT_EQ(detectTrajectoryFormat(dir / "V102_groundtruth.csv"), TrajectoryFormat::kEuroc);
  const Trajectory euroc = readTrajectory(dir / "V102_groundtruth.csv");
  ASSERT_EQ(euroc.size(), 16702u);
  // First row: 1403715524907143168 ns, p = (0.515356, 1.996773, 0.971104), q_wxyz = (0.161996,
  // 0.789985, -0.205376, 0.554528).
  EXPECT_NEAR(euroc[0].timestamp, 1403715524.907143168, 1e-6);
  EXPECT_TRUE(euroc[0].pose.translation().isApprox(Eigen::Vector3d(0.515356, 1.996773, 0.971104), 1e-15));
  EXPECT_NEAR(std::abs(euroc[0].pose.rotation().coeffs().normalized().dot(
                  Eigen::Quaterniond(0.161996, 0.789985, -0.205376, 0.554528).coeffs().normalized())),
              1.0, 1e-12);
}

}  // namespace
}  // namespace nerfslam
