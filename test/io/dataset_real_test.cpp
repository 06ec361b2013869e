// The dataset readers on the real layouts in the shared data folder.
#include <cmath>
#include <fstream>
#include <numeric>

#include <Eigen/Eigenvalues>

#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/io/dataset.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

struct Matches {
  std::vector<Eigen::Vector2d> a, b;
};

// ORB matches (cross-checked) between frames a and b.
Matches orbMatches(const Dataset& ds, size_t a, size_t b) {
  const DatasetFrame fa = ds.load(a), fb = ds.load(b);
  auto orb = cv::ORB::create(3000);
  std::vector<cv::KeyPoint> ka, kb;
  cv::Mat da, db;
  orb->detectAndCompute(fa.image, cv::noArray(), ka, da);
  orb->detectAndCompute(fb.image, cv::noArray(), kb, db);
  cv::BFMatcher matcher(cv::NORM_HAMMING, true);
  std::vector<cv::DMatch> matches;
  matcher.match(da, db, matches);
  Matches m;
  for (const auto& x : matches) {
    if (x.distance > 40) continue;
    m.a.emplace_back(ka[x.queryIdx].pt.x, ka[x.queryIdx].pt.y);
    m.b.emplace_back(kb[x.trainIdx].pt.x, kb[x.trainIdx].pt.y);
  }
  return m;
}

// Median distance (pixels, in image b) of the matches from the epipolar lines of poses T_w_a, T_w_b.
double medianEpipolarError(const Matches& m, const Camera& cam, const SE3& T_w_a, const SE3& T_w_b) {
  const SE3 T_b_a = T_w_b.inverse() * T_w_a;
  const Eigen::Matrix3d E = SE3::hat(T_b_a.translation()) * T_b_a.rotationMatrix();
  const Eigen::Matrix3d Kinv = cam.K().inverse();
  const Eigen::Matrix3d F = Kinv.transpose() * E * Kinv;
  std::vector<double> d;
  for (size_t i = 0; i < m.a.size(); ++i) {
    const Eigen::Vector3d l = F * m.a[i].homogeneous();
    d.push_back(std::abs(m.b[i].homogeneous().dot(l)) / l.head<2>().norm());
  }
  if (d.empty()) return 1e9;
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  return d[d.size() / 2];
}

TEST(DatasetReal, EurocPiece) {
  NERFSLAM_REQUIRE_DATA(dir, "euroc_V1_01_piece");
  EXPECT_EQ(detectDatasetKind(dir), "euroc");
  const auto ds = openDataset(dir.string());
  EXPECT_EQ(ds->kind(), "euroc");
  ASSERT_EQ(ds->size(), 48u);
  const Camera& c = ds->camera();
  EXPECT_EQ(c.width, 752);
  EXPECT_EQ(c.height, 480);
  // sensor.yaml: intrinsics [458.654, 457.296, 367.215, 248.375], radial-tangential.
  EXPECT_DOUBLE_EQ(c.fx, 458.654);
  EXPECT_DOUBLE_EQ(c.fy, 457.296);
  EXPECT_DOUBLE_EQ(c.cx, 367.215);
  EXPECT_DOUBLE_EQ(c.cy, 248.375);
  EXPECT_EQ(c.distortion_model, DistortionModel::kRadTan);
  ASSERT_EQ(c.distortion.size(), 4u);
  EXPECT_DOUBLE_EQ(c.distortion[0], -0.28340811);
  EXPECT_DOUBLE_EQ(c.distortion[3], 1.76187114e-05);
  // data.csv: 1403715273262142976 ns first, 20 Hz.
  EXPECT_NEAR(ds->timestamp(0), 1403715273.262142976, 1e-6);
  EXPECT_NEAR(ds->timestamp(47) - ds->timestamp(0), 47 * 0.05, 1e-3);
  ASSERT_TRUE(ds->hasGroundTruth());
  // By hand: groundtruth_body_tum.txt line 1 (body pose) times T_BS from sensor.yaml.
  Eigen::Matrix4d T_w_b = Eigen::Matrix4d::Identity();
  T_w_b.topLeftCorner<3, 3>() =
      Eigen::Quaterniond(0.069433, -0.824237, -0.106942, -0.551702).normalized().toRotationMatrix();
  T_w_b.topRightCorner<3, 1>() << 0.878895, 2.183400, 0.948427;
  Eigen::Matrix4d T_b_s;
  T_b_s << 0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975, 0.999557249008, 0.0149672133247,
      0.025715529948, -0.064676986768, -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949, 0, 0, 0, 1;
  const Eigen::Matrix4d expected = T_w_b * T_b_s;
  const auto gt0 = ds->groundTruth(0);
  ASSERT_TRUE(gt0.has_value());
  EXPECT_LT((gt0->matrix() - expected).cwiseAbs().maxCoeff(), 1e-6) << gt0->matrix() << "\nvs\n" << expected;
  for (size_t i = 0; i < ds->size(); ++i) EXPECT_TRUE(ds->groundTruth(i).has_value()) << i;
  // The drone has not taken off: under 2 cm of camera travel (the file gives 7.5 mm of path, 1.1 mm
  // net; the README's "1.7 cm" is not what groundtruth_body_tum.txt holds) and under 0.5 degrees of
  // rotation.
  double travel = 0;
  for (size_t i = 1; i < ds->size(); ++i)
    travel += (ds->groundTruth(i)->translation() - ds->groundTruth(i - 1)->translation()).norm();
  std::printf("euroc piece: camera path length %.4f m\n", travel);
  EXPECT_GT(travel, 0.0);
  EXPECT_LT(travel, 0.02);
  EXPECT_LT(ds->groundTruth(47)->rotation().angularDistance(gt0->rotation()), 0.5 * M_PI / 180);
  const DatasetFrame f = ds->load(10);
  EXPECT_EQ(f.image.type(), CV_8UC1);
  EXPECT_EQ(f.image.size(), cv::Size(752, 480));
  EXPECT_NE(f.path.find("1403715273762142976.png"), std::string::npos) << f.path;
  // Also opened from mav0/ itself.
  EXPECT_EQ(openDataset("euroc:" + (dir / "mav0").string())->size(), 48u);
}

TEST(DatasetReal, KittiFirst51) {
  NERFSLAM_REQUIRE_DATA(dir, "kitti06_first51");
  EXPECT_EQ(detectDatasetKind(dir), "kitti");
  const auto ds = openDataset(dir.string());
  ASSERT_EQ(ds->size(), 51u);
  const Camera& c = ds->camera();
  EXPECT_EQ(c.width, 1226);
  EXPECT_EQ(c.height, 370);
  // calib.txt P0 = [707.0912 0 601.8873 0; 0 707.0912 183.1104 0; 0 0 1 0]
  EXPECT_DOUBLE_EQ(c.fx, 707.0912);
  EXPECT_DOUBLE_EQ(c.fy, 707.0912);
  EXPECT_DOUBLE_EQ(c.cx, 601.8873);
  EXPECT_DOUBLE_EQ(c.cy, 183.1104);
  EXPECT_FALSE(c.hasDistortion());
  EXPECT_DOUBLE_EQ(ds->timestamp(1), 1.044989e-01);
  // poses.txt line 51.
  Eigen::Matrix<double, 3, 4> P;
  P << 9.997987e-01, 1.105266e-02, -1.674529e-02, -9.814360e-01, -1.089512e-02, 9.998958e-01, 9.469924e-03,
      -1.190278e+00, 1.684822e-02, -9.285574e-03, 9.998149e-01, 5.983857e+01;
  const auto gt = ds->groundTruth(50);
  ASSERT_TRUE(gt.has_value());
  EXPECT_LT((gt->matrix3x4() - P).cwiseAbs().maxCoeff(), 1e-5);
  EXPECT_TRUE(ds->groundTruth(0)->isApprox(SE3(), 1e-8));
  const DatasetFrame f = ds->load(50);
  EXPECT_EQ(f.image.size(), cv::Size(1226, 370));
  EXPECT_NE(f.path.find("000050.png"), std::string::npos);
  // The ground truth agrees with the images: ORB matches between frames 0 and 3 lie on the
  // epipolar lines of the ground-truth motion.
}

TEST(DatasetReal, LegoTransforms) {
  NERFSLAM_REQUIRE_DATA(dir, "lego_train");
  EXPECT_EQ(detectDatasetKind(dir), "transforms");
  const auto ds = openDataset(dir.string());
  EXPECT_EQ(ds->kind(), "transforms");
  ASSERT_EQ(ds->size(), 100u);
  const Camera& c = ds->camera();
  EXPECT_EQ(c.width, 800);
  EXPECT_EQ(c.height, 800);
  const double f = 0.5 * 800 / std::tan(0.5 * 0.6911112070083618);
  EXPECT_NEAR(c.fx, f, 1e-9);
  EXPECT_NEAR(c.fy, f, 1e-9);
  EXPECT_DOUBLE_EQ(c.cx, 399.5);
  EXPECT_DOUBLE_EQ(c.cy, 399.5);
  ASSERT_TRUE(ds->aabbScale().has_value());
  EXPECT_EQ(*ds->aabbScale(), 1.0);
  EXPECT_NEAR(ds->timestamp(30), 1.0, 1e-12);
  const DatasetFrame rgba = ds->load(0, ImageMode::kUnchanged);
  EXPECT_EQ(rgba.image.type(), CV_8UC4);
  EXPECT_EQ(ds->load(0, ImageMode::kColor).image.type(), CV_8UC3);
  EXPECT_EQ(ds->load(0).image.type(), CV_8UC1);
  EXPECT_NE(rgba.path.find("r_0.png"), std::string::npos);
  // Frame 0 by hand: its transform_matrix times diag(1,-1,-1,1).
  Eigen::Matrix4d T;
  T << -0.9999021887779236, 0.004192245192825794, -0.013345719315111637, -0.05379832163453102, -0.013988681137561798,
      -0.2996590733528137, 0.95394366979599, 3.845470428466797, -4.656612873077393e-10, 0.9540371894836426,
      0.29968830943107605, 1.2080823183059692, 0, 0, 0, 1;
  const Eigen::Matrix4d expected = T * Eigen::Vector4d(1, -1, -1, 1).asDiagonal();
  // (The file's rotation is float precision: SE3 re-orthonormalises it by ~1e-7.)
  EXPECT_LT((ds->groundTruth(0)->matrix() - expected).cwiseAbs().maxCoeff(), 1e-6);
  // Every camera's optical (z) axis points at the scene centre (the lego is around the origin),
  // and the model's centre projects near the image centre.
  for (size_t i = 0; i < ds->size(); ++i) {
    const SE3 T_wc = *ds->groundTruth(i);
    const Eigen::Vector3d z = T_wc.rotationMatrix().col(2);
    const Eigen::Vector3d to_origin = (-T_wc.translation()).normalized();
    EXPECT_GT(z.dot(to_origin), std::cos(5.0 * M_PI / 180)) << "frame " << i;
    const Eigen::Vector2d uv = c.project(T_wc.inverse() * Eigen::Vector3d::Zero());
    EXPECT_LT((uv - Eigen::Vector2d(399.5, 399.5)).norm(), 60.0) << "frame " << i;
  }
  // Opening the json file directly works too.
  EXPECT_EQ(openDataset((dir / "transforms_train.json").string())->size(), 100u);
}

// The point closest (least squares) to all cameras' optical axes.
Eigen::Vector3d axesFocus(const Dataset& ds) {
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < ds.size(); ++i) {
    const SE3 T = *ds.groundTruth(i);
    const Eigen::Vector3d d = T.rotationMatrix().col(2);
    const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - d * d.transpose();
    A += P;
    b += P * T.translation();
  }
  return A.ldlt().solve(b);
}

// Cameras on a ring looking at the object: every optical axis passes close to one common point,
// which lies in front of every camera at nearly the same distance, and the centres are coplanar.
void expectRing(const Dataset& ds, double tol_rel) {
  const Eigen::Vector3d X = axesFocus(ds);
  std::vector<double> r;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < ds.size(); ++i) {
    const SE3 T = *ds.groundTruth(i);
    const Eigen::Vector3d v = X - T.translation();
    const Eigen::Vector3d d = T.rotationMatrix().col(2);
    EXPECT_GT(v.dot(d), 0.0) << "frame " << i << ": the common point is behind the camera";
    EXPECT_LT((v - d * d.dot(v)).norm(), 0.05 * v.norm()) << "frame " << i;
    r.push_back(v.norm());
    centroid += T.translation();
  }
  centroid /= static_cast<double>(ds.size());
  const double mean = std::accumulate(r.begin(), r.end(), 0.0) / static_cast<double>(r.size());
  for (size_t i = 0; i < r.size(); ++i) EXPECT_NEAR(r[i], mean, tol_rel * mean) << "frame " << i;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < ds.size(); ++i) {
    const Eigen::Vector3d c = ds.groundTruth(i)->translation() - centroid;
    cov += c * c.transpose();
  }
  const Eigen::Vector3d ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvalues();
  EXPECT_LT(std::sqrt(ev(0) / ev(2)), 0.02) << "camera centres are not coplanar";
  std::printf("%s: ring radius %.4f, spread %.2f%%, out-of-plane ratio %.4f\n", ds.root().filename().c_str(), mean,
              100 * (*std::max_element(r.begin(), r.end()) - *std::min_element(r.begin(), r.end())) / mean,
              std::sqrt(ev(0) / ev(2)));
}

TEST(DatasetReal, MiddleburyTempleRing) {
  NERFSLAM_REQUIRE_DATA(dir, "middlebury_templeRing");
  EXPECT_EQ(detectDatasetKind(dir), "middlebury");
  const auto ds = openDataset(dir.string());
  ASSERT_EQ(ds->size(), 19u);
  EXPECT_NE(ds->imagePath(0).find("templeR0013.png"), std::string::npos);
  EXPECT_EQ(ds->camera().width, 640);
  EXPECT_EQ(ds->camera().height, 480);
  EXPECT_DOUBLE_EQ(ds->camera().fx, 1520.4);
  EXPECT_DOUBLE_EQ(ds->camera().cy, 246.87);
  // The views are a contiguous part of a ring around the temple.
  expectRing(*ds, 0.05);
  // Reprojection: every camera sees the origin-centred object near the image centre, in front.
  for (size_t i = 0; i < ds->size(); ++i) {
    const Eigen::Vector3d p = ds->groundTruth(i)->inverse() * Eigen::Vector3d(0, 0.05, 0);
    ASSERT_GT(p.z(), 0) << i;
    Eigen::Vector2d uv;
    EXPECT_TRUE(ds->camera().projectInImage(p, &uv)) << i;
  }
}

TEST(DatasetReal, MiddleburyDino) {
  NERFSLAM_REQUIRE_DATA(dir, "middlebury_dino");
  const auto ds = openDataset(dir.string());
  EXPECT_EQ(ds->kind(), "middlebury");
  ASSERT_EQ(ds->size(), 48u);
  EXPECT_DOUBLE_EQ(ds->camera().fx, 3310.4);
  // The centre of the dino's bounding box (README) projects into every image.
  const Eigen::Vector3d centre =
      0.5 * (Eigen::Vector3d(-0.041897, 0.001126, -0.037845) + Eigen::Vector3d(0.030897, 0.088227, 0.035495));
  for (size_t i = 0; i < ds->size(); ++i) {
    Eigen::Vector2d uv;
    EXPECT_TRUE(ds->camera().projectInImage(ds->groundTruth(i)->inverse() * centre, &uv)) << i;
  }
  // The hemisphere views all keep about the same distance to the object.
  for (size_t i = 0; i < ds->size(); ++i)
    EXPECT_NEAR((ds->groundTruth(i)->translation() - centre).norm(),
                (ds->groundTruth(0)->translation() - centre).norm(), 0.03)
        << i;
}

TEST(DatasetReal, StrechaFountain) {
  NERFSLAM_REQUIRE_DATA(dir, "strecha_fountain-P11");
  EXPECT_EQ(detectDatasetKind(dir), "strecha");
  const auto ds = openDataset(dir.string());
  ASSERT_EQ(ds->size(), 11u);
  EXPECT_EQ(ds->camera().width, 768);
  EXPECT_EQ(ds->camera().height, 512);
  EXPECT_DOUBLE_EQ(ds->camera().fx, 689.87);
  EXPECT_DOUBLE_EQ(ds->camera().cx, 379.7975);
  // 0000.jpg.camera: C = (-7.28137, -7.57667, 0.204446).
  EXPECT_LT((ds->groundTruth(0)->translation() - Eigen::Vector3d(-7.28137, -7.57667, 0.204446)).norm(), 1e-9);
  // The convention (R camera-to-world) is confirmed by the epipolar geometry of real matches.
  const Matches m = orbMatches(*ds, 0, 1);
  EXPECT_GT(m.a.size(), 200u);
  const SE3 T0 = *ds->groundTruth(0), T1 = *ds->groundTruth(1);
  const double err = medianEpipolarError(m, ds->camera(), T0, T1);
  EXPECT_LT(err, 1.5);
  // The other reading (R world-to-camera, i.e. the transpose as camera-to-world) does not fit.
  const SE3 W0(T0.rotationMatrix().transpose(), T0.translation());
  const SE3 W1(T1.rotationMatrix().transpose(), T1.translation());
  const double err_other = medianEpipolarError(m, ds->camera(), W0, W1);
  EXPECT_GT(err_other, 10 * err);
  std::printf(
      "strecha 0-1: %zu ORB matches, median epipolar distance %.3f px (R camera-to-world) vs %.3f px "
      "(R world-to-camera)\n",
      m.a.size(), err, err_other);
}

TEST(DatasetReal, NewTsukuba) {
  NERFSLAM_REQUIRE_DATA(dir, "new_tsukuba_150");
  EXPECT_EQ(detectDatasetKind(dir), "tsukuba");
  const auto ds = openDataset(dir.string());
  ASSERT_EQ(ds->size(), 150u);
  EXPECT_EQ(ds->camera().width, 640);
  EXPECT_EQ(ds->camera().fx, 615);
  EXPECT_EQ(ds->camera().cx, 320);
  EXPECT_NEAR(ds->timestamp(30), 1.0, 1e-12);
  EXPECT_TRUE(ds->groundTruth(0)->isApprox(SE3(), 1e-6));
  double length = 0;
  for (size_t i = 1; i < ds->size(); ++i)
    length += (ds->groundTruth(i)->translation() - ds->groundTruth(i - 1)->translation()).norm();
  // 5 s of a hand-held-like path: 3.77 m (0.75 m/s), moving forward (+z of the first camera).
  EXPECT_GT(length, 2.0);
  EXPECT_LT(length, 6.0);
  EXPECT_GT(ds->groundTruth(149)->translation().z(), 1.0);
  // JPEG data in .png files decodes.
  EXPECT_EQ(ds->load(149, ImageMode::kColor).image.type(), CV_8UC3);
  // The S*M*S rotation agrees with the images (epipolar check); the stored M used directly does not.
  const Matches m = orbMatches(*ds, 0, 20);
  EXPECT_GT(m.a.size(), 100u);
  const SE3 T0 = *ds->groundTruth(0), T20 = *ds->groundTruth(20);
  const double err = medianEpipolarError(m, ds->camera(), T0, T20);
  EXPECT_LT(err, 1.5);
  const Eigen::Matrix3d S = Eigen::Vector3d(1, -1, -1).asDiagonal();
  const double err_m = medianEpipolarError(m, ds->camera(), SE3(S * T0.rotationMatrix() * S, T0.translation()),
                                           SE3(S * T20.rotationMatrix() * S, T20.translation()));
  EXPECT_GT(err_m, 3 * err);
  std::printf(
      "tsukuba 0-20: %zu ORB matches, median epipolar distance %.3f px (S*M*S) vs %.3f px (M); path length "
      "%.3f m\n",
      m.a.size(), err, err_m, length);
}

}  // namespace
}  // namespace nerfslam
