// The fly-through: poses spread in time along the trajectory, a video that reads back with every
// frame, and a PNG sequence when no codec is available.
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>
#include <vector>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/occupancy.h"
#include "nerfslam/system/flythrough.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

Trajectory line(int n, double dt) {
  Trajectory t;
  for (int i = 0; i < n; ++i)
    t.push_back({10.0 + i * dt, SE3(Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitY())),
                                    Eigen::Vector3d(0.5 * i, 0.0, 0.0))});
  return t;
}

TEST(Flythrough, PosesAreSpreadEvenlyInTimeAlongTheTrajectory) {
  const Trajectory t = line(5, 0.1);  // 0.4 s, 2 m
  const auto p = flythroughPoses(t, 9);
  ASSERT_EQ(p.size(), 9u);
  EXPECT_TRUE(p.front().isApprox(t.front().pose, 1e-9));
  EXPECT_TRUE(p.back().isApprox(t.back().pose, 1e-9));
  for (size_t k = 0; k < p.size(); ++k) EXPECT_NEAR(p[k].translation().x(), 0.25 * double(k), 1e-9) << k;
  EXPECT_TRUE(p[3].isApprox(SE3::interpolate(t[1].pose, t[2].pose, 0.5), 1e-9));
  EXPECT_TRUE(flythroughPoses({}, 5).empty());
  EXPECT_TRUE(flythroughPoses(t, 0).empty());
  EXPECT_EQ(flythroughPoses({t[0]}, 3).size(), 3u);
}

long entries(const fs::path& dir) { return std::distance(fs::directory_iterator(dir), fs::directory_iterator{}); }

nerf::NerfModel smallModel() {
  nerf::FieldConfig c;
  c.n_levels = 8;
  c.log2_hashmap_size = 14;
  c.finest_resolution = 64;
  c.hidden = 32;
  nerf::NerfModel m = nerf::NerfModel::create(c, nerf::SceneTransform{}, 3);
  // Occupied only in a ball at the cube's centre, as after training on an object: the frames render
  // the field there, and the other rays skip the empty cells instead of sampling an untrained grid
  // where every cell is still a candidate (what made these tests take over a minute under ASan).
  constexpr int kRes = nerf::OccupancyGrid::kRes;
  std::vector<float> values(size_t(m.grid->cascades()) * nerf::OccupancyGrid::kCells, 0.f);
  for (int z = 0; z < kRes; ++z)
    for (int y = 0; y < kRes; ++y)
      for (int x = 0; x < kRes; ++x)
        if ((Eigen::Vector3d(x, y, z) - Eigen::Vector3d::Constant(0.5 * (kRes - 1))).norm() < kRes / 8.0)
          values[nerf::OccupancyGrid::cellIndex(x, y, z)] = 1.f;
  m.grid->setValues(std::move(values), 0.5f);
  return m;
}

TEST(Flythrough, VideoReadsBackWithEveryFrameAtTheEvenSize) {
  test::TempDir dir;
  const nerf::NerfModel model = smallModel();
  const Camera cam = Camera::pinhole(81, 61, 70, 70, 40, 30);  // odd: the video is 80x60
  FlythroughOptions o;
  o.frames = 12;
  const FlythroughResult r = writeFlythrough(model, cam, line(5, 0.1), o, dir.path());
  EXPECT_EQ(r.path, dir / "flythrough.mp4");
  EXPECT_TRUE(r.codec == "avc1" || r.codec == "mp4v") << r.codec;
  EXPECT_EQ(r.frames, 12);
  EXPECT_EQ(r.frames_requested, 12);
  EXPECT_EQ(r.size, cv::Size(80, 60));
  cv::VideoCapture cap((dir / "flythrough.mp4").string());
  ASSERT_TRUE(cap.isOpened());
  int n = 0;
  cv::Mat f;
  while (cap.read(f)) {
    EXPECT_EQ(f.size(), cv::Size(80, 60));
    ++n;
  }
  EXPECT_EQ(n, 12);
  // Nothing else is left in the folder (no temporary files).
  EXPECT_EQ(entries(dir.path()), 1);
}

TEST(Flythrough, WithoutACodecItIsAPngSequence) {
  test::TempDir dir;
  const nerf::NerfModel model = smallModel();
  const Camera cam = Camera::pinhole(64, 48, 60, 60, 32, 24);
  FlythroughOptions o;
  o.frames = 7;
  o.codecs.clear();
  const FlythroughResult r = writeFlythrough(model, cam, line(3, 0.5), o, dir.path());
  EXPECT_EQ(r.codec, "png");
  EXPECT_EQ(r.path, dir / "flythrough");
  for (int i = 0; i < 7; ++i) {
    const cv::Mat img = cv::imread((dir / "flythrough" / fmt::format("{:06d}.png", i)).string());
    ASSERT_FALSE(img.empty()) << i;
    EXPECT_EQ(img.size(), cv::Size(64, 48));
  }
  EXPECT_FALSE(fs::exists(dir / "flythrough" / "000007.png"));
  // A second run replaces the folder.
  o.frames = 3;
  writeFlythrough(model, cam, line(3, 0.5), o, dir.path());
  EXPECT_FALSE(fs::exists(dir / "flythrough" / "000003.png"));
  EXPECT_TRUE(fs::exists(dir / "flythrough" / "000002.png"));
  EXPECT_EQ(entries(dir.path()), 1) << "no temporary or old folder left";
  EXPECT_THROW(writeFlythrough(model, cam, {}, o, dir.path()), Error);
  o.codecs = {"mp4"};
  EXPECT_THROW(writeFlythrough(model, cam, line(3, 0.5), o, dir.path()), Error);
}

// A budget far below the cost of the frames: fewer frames, at least 2, over the whole trajectory.
TEST(Flythrough, ATimeBudgetCutsTheFrameCount) {
  test::TempDir dir;
  const nerf::NerfModel model = smallModel();
  FlythroughOptions o;
  o.frames = 500;
  o.max_seconds = 1e-6;
  o.codecs.clear();
  const FlythroughResult r =
      writeFlythrough(model, Camera::pinhole(32, 24, 30, 30, 16, 12), line(4, 0.1), o, dir.path());
  EXPECT_EQ(r.frames_requested, 500);
  EXPECT_EQ(r.frames, 2);
  EXPECT_TRUE(fs::exists(dir / "flythrough" / "000001.png"));
  EXPECT_FALSE(fs::exists(dir / "flythrough" / "000002.png"));
  EXPECT_LT(r.seconds, 30.0);
}

}  // namespace
}  // namespace nerfslam
