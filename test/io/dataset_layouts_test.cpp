// EuRoC, Middlebury, Strecha and New Tsukuba layouts written here: parsing, conventions and the
// errors for malformed files (each names the file and the line or field).
#include <fstream>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/io/dataset.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

void writeImage(const fs::path& p, cv::Size size = {64, 48}) {
  fs::create_directories(p.parent_path());
  cv::Mat img(size, CV_8UC1);
  cv::randu(img, 0, 255);
  ASSERT_TRUE(cv::imwrite(p.string(), img)) << p;
}

template <typename F>
void expectError(F&& f, std::initializer_list<std::string> needles) {
  try {
    f();
    ADD_FAILURE() << "no error thrown";
  } catch (const Error& e) {
    const std::string msg = e.what();
    for (const auto& n : needles) EXPECT_NE(msg.find(n), std::string::npos) << "'" << n << "' not in: " << msg;
  }
}

const char* kSensorYaml = R"(%YAML:1.0
sensor_type: camera
T_BS:
  cols: 4
  rows: 4
  data: [0, -1, 0, 0.1,
         1, 0, 0, 0.2,
         0, 0, 1, 0.3,
         0, 0, 0, 1]
rate_hz: 20
resolution: [64, 48]
camera_model: pinhole
intrinsics: [50, 51, 31.5, 23.5]
distortion_model: equidistant
distortion_coefficients: [0.01, 0.002, 0, 0]
)";

TEST(DatasetEuroc, InterpolatedGroundTruthTimesTbs) {
  test::TempDir tmp;
  const fs::path cam = tmp / "mav0" / "cam0";
  std::string csv = "#timestamp [ns],filename\n";
  for (int i = 0; i < 3; ++i) {
    const std::string n = std::to_string(1000000000LL + 50000000LL * i);
    writeImage(cam / "data" / (n + ".png"));
    csv += n + "," + n + ".png\n";
  }
  test::writeText(cam / "data.csv", csv);
  test::writeText(cam / "sensor.yaml", kSensorYaml);
  // Body moves along x at 1 m/s (x = t - 1 s); samples every 0.03 s from 0.985 s, so every image
  // time falls between two samples.
  std::string gt = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []\n";
  for (int k = 0; k < 6; ++k)
    gt += fmt::format("{},{},0,0,1,0,0,0,0,0,0\n", 985000000LL + 30000000LL * k, 0.03 * k - 0.015);
  test::writeText(tmp / "mav0" / "state_groundtruth_estimate0" / "data.csv", gt);
  const auto ds = openDataset(tmp.path().string());
  EXPECT_EQ(ds->kind(), "euroc");
  ASSERT_EQ(ds->size(), 3u);
  EXPECT_EQ(ds->camera().distortion_model, DistortionModel::kEquidistant);
  EXPECT_EQ(ds->camera().fy, 51);
  EXPECT_NEAR(ds->timestamp(1), 1.05, 1e-9);
  // Frame 1 at t = 1.05 s: body at x = 0.05 (interpolated), camera = body * T_BS.
  const SE3 T_bs(Eigen::Matrix3d((Eigen::Matrix3d() << 0, -1, 0, 1, 0, 0, 0, 0, 1).finished()),
                 Eigen::Vector3d(0.1, 0.2, 0.3));
  const SE3 expected = SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.05, 0, 0)) * T_bs;
  ASSERT_TRUE(ds->groundTruth(1).has_value());
  EXPECT_TRUE(ds->groundTruth(1)->isApprox(expected, 1e-6)) << ds->groundTruth(1)->matrix();
  // Frame 2 at 1.10 s, between the samples at 1.075 and 1.105 s.
  EXPECT_NEAR(ds->groundTruth(2)->translation().x(), 0.10 + 0.1, 1e-6);
}

TEST(DatasetEuroc, BadSensorYaml) {
  test::TempDir tmp;
  const fs::path cam = tmp / "mav0" / "cam0";
  writeImage(cam / "data" / "1000.png");
  test::writeText(cam / "data.csv", "#timestamp [ns],filename\n1000,1000.png\n");
  const std::string yaml = (cam / "sensor.yaml").string();
  std::string s = kSensorYaml;
  test::writeText(cam / "sensor.yaml", s.replace(s.find("[50, 51, 31.5, 23.5]"), 20, "[50, 51, 31.5]"));
  expectError([&] { openDataset(tmp.path().string()); }, {yaml, "intrinsics", "4"});
  s = kSensorYaml;
  test::writeText(cam / "sensor.yaml", s.replace(s.find("equidistant"), 11, "fov"));
  expectError([&] { openDataset(tmp.path().string()); }, {yaml, "distortion_model", "fov"});
  s = kSensorYaml;
  test::writeText(cam / "sensor.yaml", s.replace(s.find("[0, -1, 0, 0.1"), 14, "[2, -1, 0, 0.1"));
  expectError([&] { openDataset(tmp.path().string()); }, {yaml, "T_BS"});
  s = kSensorYaml;
  test::writeText(cam / "sensor.yaml", s.replace(s.find("[64, 48]"), 8, "[640, 480]"));
  expectError([&] { openDataset(tmp.path().string()); }, {yaml, "640x480", "64x48"});
  test::writeText(cam / "sensor.yaml", kSensorYaml);
  test::writeText(cam / "data.csv", "#timestamp [ns],filename\n1000,1000.png\n900,1000.png\n");
  expectError([&] { openDataset(tmp.path().string()); }, {(cam / "data.csv").string() + ":3", "timestamp"});
}

TEST(DatasetMiddlebury, ParFileSubsetAndErrors) {
  test::TempDir tmp;
  // Two views of a camera at (0, 0, -1) looking at +z (R = I, t = (0, 0, 1)) and one rotated 90
  // degrees about y; only the first and third images are present.
  writeImage(tmp / "v1.png");
  writeImage(tmp / "v3.png");
  const std::string K = "50 0 31.5 0 51 23.5 0 0 1";
  test::writeText(tmp / "obj_par.txt",
                  "3\n"
                  "v1.png " +
                      K +
                      " 1 0 0 0 1 0 0 0 1 0 0 1\n"
                      "v2.png " +
                      K +
                      " 1 0 0 0 1 0 0 0 1 0 0 2\n"
                      "v3.png " +
                      K + " 0 0 -1 0 1 0 1 0 0 0 0 1\n");
  const auto ds = openDataset(tmp.path().string());
  EXPECT_EQ(ds->kind(), "middlebury");
  ASSERT_EQ(ds->size(), 2u);
  EXPECT_TRUE(ds->groundTruth(0)->translation().isApprox(Eigen::Vector3d(0, 0, -1)));
  // View 3: x_cam = R X + t; its centre is -R^T t = (1, 0, 0)... and the world origin is in front.
  const SE3 T = *ds->groundTruth(1);
  EXPECT_TRUE(T.translation().isApprox(Eigen::Vector3d(-1, 0, 0))) << T.translation().transpose();
  EXPECT_NEAR((T.inverse() * Eigen::Vector3d::Zero()).z(), 1.0, 1e-12);
  EXPECT_NEAR(ds->camera().fy, 51, 0);
  const std::string par = (tmp / "obj_par.txt").string();
  test::writeText(tmp / "obj_par.txt", "2\nv1.png " + K + " 1 0 0 0 1 0 0 0 1 0 0 1\n");
  expectError([&] { openDataset(tmp.path().string()); }, {par + ":1", "count"});
  test::writeText(tmp / "obj_par.txt", "1\nv1.png " + K + " 1 0 0 0 1 0 0 0 1 0 x 1\n");
  expectError([&] { openDataset(tmp.path().string()); }, {par + ":2", "'x'"});
  test::writeText(tmp / "obj_par.txt", "1\nv1.png " + K + " 1 0 0 0 2 0 0 0 1 0 0 1\n");
  expectError([&] { openDataset(tmp.path().string()); }, {par + ":2", "rotation"});
}

TEST(DatasetStrecha, CameraFileAndErrors) {
  test::TempDir tmp;
  writeImage(tmp / "images" / "0000.jpg");
  writeImage(tmp / "images" / "0001.jpg");
  const std::string cam0 = "50 0 31.5\n0 51 23.5\n0 0 1\n0 0 0\n0 0 1\n1 0 0\n0 1 0\n1 2 3\n64 48\n";
  test::writeText(tmp / "gt_dense_cameras" / "0000.jpg.camera", cam0);
  test::writeText(tmp / "gt_dense_cameras" / "0001.jpg.camera", cam0);
  const auto ds = openDataset(tmp.path().string());
  EXPECT_EQ(ds->kind(), "strecha");
  ASSERT_EQ(ds->size(), 2u);
  // R is camera-to-world: the camera's z axis in world is R's third column.
  EXPECT_TRUE(ds->groundTruth(0)->rotationMatrix().col(2).isApprox(Eigen::Vector3d(1, 0, 0)));
  EXPECT_TRUE(ds->groundTruth(0)->translation().isApprox(Eigen::Vector3d(1, 2, 3)));
  const std::string f1 = (tmp / "gt_dense_cameras" / "0001.jpg.camera").string();
  test::writeText(f1, "50 0 31.5\n0 51 23.5\n0 0 1\n0.1 0 0\n0 0 1\n1 0 0\n0 1 0\n1 2 3\n64 48\n");
  expectError([&] { openDataset(tmp.path().string()); }, {f1 + ":4", "distortion"});
  test::writeText(f1, "60 0 31.5\n0 51 23.5\n0 0 1\n0 0 0\n0 0 1\n1 0 0\n0 1 0\n1 2 3\n64 48\n");
  expectError([&] { openDataset(tmp.path().string()); }, {f1, "intrinsics differ"});
  test::writeText(f1, "50 0 31.5\n0 51 23.5\n0 0 1\n");
  expectError([&] { openDataset(tmp.path().string()); }, {f1, "9 lines"});
}

TEST(DatasetTsukuba, TrajectoryConventionAndErrors) {
  test::TempDir tmp;
  writeImage(tmp / "images" / "rgb_00000.png", {640, 480});
  writeImage(tmp / "images" / "rgb_00001.png", {640, 480});
  test::writeText(tmp / "intrinsics.txt", "fx fy cx cy width height\n615 615 320 240 640 480\n");
  // Frame 1: 10 cm along stored x; M = rotation of 90 degrees about z.
  test::writeText(tmp / "cam_traj_truth.txt", "0 0 0 1 0 0 0 1 0 0 0 1\n10 0 0 0 -1 0 1 0 0 0 0 1\n");
  const auto ds = openDataset(tmp.path().string());
  EXPECT_EQ(ds->kind(), "tsukuba");
  EXPECT_TRUE(ds->groundTruth(0)->isApprox(SE3(), 1e-12));
  EXPECT_TRUE(ds->groundTruth(1)->translation().isApprox(Eigen::Vector3d(0.1, 0, 0)));
  Eigen::Matrix3d M;
  M << 0, -1, 0, 1, 0, 0, 0, 0, 1;
  const Eigen::Matrix3d S = Eigen::Vector3d(1, -1, -1).asDiagonal();
  EXPECT_TRUE(ds->groundTruth(1)->rotationMatrix().isApprox(S * M * S));
  EXPECT_NEAR(ds->timestamp(1), 1.0 / 30, 1e-15);
  const std::string traj = (tmp / "cam_traj_truth.txt").string();
  test::writeText(tmp / "cam_traj_truth.txt", "0 0 0 1 0 0 0 1 0 0 0 1\n");
  expectError([&] { openDataset(tmp.path().string()); }, {traj, "1 poses for 2 images"});
  test::writeText(tmp / "cam_traj_truth.txt", "0 0 0 1 0 0 0 1 0 0 0 1\n0 0 0 1 0 0 0 1\n");
  expectError([&] { openDataset(tmp.path().string()); }, {traj + ":2", "12 numbers"});
}

}  // namespace
}  // namespace nerfslam
