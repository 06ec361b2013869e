// Dataset readers on layouts written here (folder, TUM, and the other kinds' file formats), and the
// bad-input cases: each error names the file (and line or field).
#include <cmath>
#include <fstream>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/io/dataset.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

// A textured image whose pixel (0,0) encodes `id`, so tests can tell frames apart.
void writeImage(const fs::path& p, int id, cv::Size size = {64, 48}) {
  fs::create_directories(p.parent_path());
  cv::Mat img(size, CV_8UC1);
  cv::randu(img, 0, 255);
  img.at<uchar>(0, 0) = static_cast<uchar>(id);
  ASSERT_TRUE(cv::imwrite(p.string(), img)) << p;
}

void writeCamera(const fs::path& p, int w = 64, int h = 48) {
  saveCameraYaml(Camera::pinhole(w, h, 50, 50, (w - 1) / 2.0, (h - 1) / 2.0), p);
}

// Runs f, expects nerfslam::Error whose message contains every string in `needles`.
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

TEST(DatasetFolder, NaturalOrderTimesAndCamera) {
  test::TempDir tmp;
  const fs::path dir = tmp / "seq";
  for (int i : {10, 2, 1, 33}) writeImage(dir / ("img" + std::to_string(i) + ".png"), i);
  test::writeText(dir / "times.txt", "# t\n0.5\n0.6\n0.75\n1.0\n");
  writeCamera(dir / "camera.yaml");
  const auto ds = openDataset(dir.string());
  EXPECT_EQ(ds->kind(), "folder");
  ASSERT_EQ(ds->size(), 4u);
  const int expected_ids[] = {1, 2, 10, 33};
  const double expected_t[] = {0.5, 0.6, 0.75, 1.0};
  for (size_t i = 0; i < 4; ++i) {
    const DatasetFrame f = ds->load(i);
    EXPECT_EQ(f.image.at<uchar>(0, 0), expected_ids[i]);
    EXPECT_EQ(f.index, i);
    EXPECT_DOUBLE_EQ(f.timestamp, expected_t[i]);
    EXPECT_FALSE(f.T_world_cam.has_value());
  }
  EXPECT_FALSE(ds->hasGroundTruth());
  EXPECT_EQ(ds->camera().fx, 50);
  // Subsampling options.
  DatasetOptions o;
  o.start = 1;
  o.stride = 2;
  const auto sub = openDataset(dir.string(), o);
  ASSERT_EQ(sub->size(), 2u);
  EXPECT_EQ(sub->load(1).image.at<uchar>(0, 0), 33);
}

TEST(DatasetFolder, FpsAndOverride) {
  test::TempDir tmp;
  for (int i = 0; i < 3; ++i) writeImage(tmp / ("f" + std::to_string(i) + ".jpg"), i);
  writeCamera(tmp / "cam.yaml");
  DatasetOptions o;
  // Neither times.txt nor fps.
  o.camera_override = tmp / "cam.yaml";
  expectError([&] { openDataset("folder:" + tmp.path().string(), o); }, {tmp.path().string(), "--fps"});
  o.fps = 10;
  const auto ds = openDataset("folder:" + tmp.path().string(), o);
  EXPECT_DOUBLE_EQ(ds->timestamp(2), 0.2);
  // times.txt (preferred over fps) with the wrong count, then a bad number.
  test::writeText(tmp / "times.txt", "0\n1\n");
  expectError([&] { openDataset(tmp.path().string(), o); }, {(tmp / "times.txt").string(), "2 timestamps for 3"});
  test::writeText(tmp / "times.txt", "0\n1\nabc\n");
  expectError([&] { openDataset(tmp.path().string(), o); }, {(tmp / "times.txt").string() + ":3", "'abc'"});
  fs::remove(tmp / "times.txt");
  // Without any camera.
  o.camera_override.reset();
  expectError([&] { openDataset(tmp.path().string(), o); }, {tmp.path().string(), "camera"});
}

TEST(DatasetTum, AssociationCameraYamlAndPreset) {
  test::TempDir tmp;
  const fs::path dir = tmp / "rgbd_dataset_freiburg1_test";
  std::string rgb = "# color images\n# file: 'x.bag'\n# timestamp filename\n";
  for (int i = 0; i < 5; ++i) {
    const std::string name = "rgb/" + std::to_string(100 + i) + ".png";
    writeImage(dir / name, i, {640, 480});
    rgb += fmt::format("{:.6f} {}\n", 1000.0 + 0.1 * i, name);
  }
  test::writeText(dir / "rgb.txt", rgb);
  // Ground truth at 0.005 s after frames 0, 1, 2 and 0.05 s after frame 4 (too far): frame 3 and 4
  // get none.
  test::writeText(dir / "groundtruth.txt",
                  "# ground truth\n"
                  "1000.005 1 2 3 0 0 0 1\n"
                  "1000.105 1.1 2 3 0 0 0 1\n"
                  "1000.195 1.2 2 3 0 0 0.7071068 0.7071068\n"
                  "1000.450 9 9 9 0 0 0 1\n");
  const auto ds = openDataset(dir.string());
  EXPECT_EQ(ds->kind(), "tum");
  ASSERT_EQ(ds->size(), 5u);
  ASSERT_TRUE(ds->groundTruth(2).has_value());
  EXPECT_NEAR(ds->groundTruth(1)->translation().x(), 1.1, 1e-12);
  EXPECT_NEAR(ds->groundTruth(2)->rotation().angularDistance(Eigen::Quaterniond(0.7071068, 0, 0, 0.7071068)), 0, 1e-6);
  EXPECT_FALSE(ds->groundTruth(3).has_value());
  EXPECT_FALSE(ds->groundTruth(4).has_value());
  EXPECT_DOUBLE_EQ(ds->timestamp(4), 1000.4);
  // No camera.yaml: the freiburg1 preset from the folder name.
  EXPECT_NEAR(ds->camera().fx, 517.306408, 1e-9);
  EXPECT_EQ(ds->camera().distortion_model, DistortionModel::kRadTan);
  // camera.yaml in the folder wins (our synthetic sequences write one).
  saveCameraYaml(Camera::pinhole(640, 480, 400, 401, 319.5, 239.5), dir / "camera.yaml");
  EXPECT_EQ(openDataset("tum:" + dir.string())->camera().fy, 401);
  // A TUM folder with neither camera.yaml nor a freiburg name.
  const fs::path other = tmp / "mine";
  fs::create_directories(other);
  fs::copy(dir / "rgb", other / "rgb");
  test::writeText(other / "rgb.txt", rgb);
  expectError([&] { openDataset(other.string()); }, {other.string(), "--camera"});
}

TEST(DatasetTum, MissingImageAndNonMonotonic) {
  test::TempDir tmp;
  writeImage(tmp / "rgb/a.png", 0);
  writeImage(tmp / "rgb/b.png", 1);
  writeCamera(tmp / "camera.yaml");
  test::writeText(tmp / "rgb.txt", "# x\n1.0 rgb/a.png\n2.0 rgb/missing.png\n");
  const std::string rgb = (tmp / "rgb.txt").string();
  expectError([&] { openDataset(tmp.path().string()); }, {rgb + ":3", "missing.png", "not found"});
  test::writeText(tmp / "rgb.txt", "1.0 rgb/a.png\n0.5 rgb/b.png\n");
  expectError([&] { openDataset(tmp.path().string()); }, {rgb + ":2", "timestamp"});
  test::writeText(tmp / "rgb.txt", "1.0 rgb/a.png\n2.0 rgb/b.png\n");
  test::writeText(tmp / "groundtruth.txt", "1.0 0 0 0 0 0 0 1\n0.9 0 0 0 0 0 0 1\n");
  expectError([&] { openDataset(tmp.path().string()); }, {(tmp / "groundtruth.txt").string(), "line 2"});
  test::writeText(tmp / "groundtruth.txt", "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n");
  EXPECT_EQ(openDataset(tmp.path().string())->size(), 2u);
}

TEST(DatasetBadInput, MissingAndEmptyFolders) {
  test::TempDir tmp;
  const std::string missing = (tmp / "nope").string();
  expectError([&] { openDataset(missing); }, {missing, "not found"});
  expectError([&] { openDataset("kitti:" + missing); }, {missing, "not found"});
  fs::create_directories(tmp / "empty");
  const std::string empty = (tmp / "empty").string();
  // Undetectable layout: the message lists the kinds.
  expectError([&] { openDataset(empty); }, {empty, "cannot tell", "tum", "euroc", "kitti", "transforms"});
  expectError([&] { openDataset("folder:" + empty); }, {empty, "no images"});
  expectError([&] { openDataset("tum:" + empty); }, {(tmp / "empty" / "rgb.txt").string(), "not found"});
  expectError([&] { openDataset("euroc:" + empty); }, {"data.csv", "not found"});
}

TEST(DatasetBadInput, UnknownKind) {
  test::TempDir tmp;
  expectError(
      [&] { openDataset("foo:" + tmp.path().string()); },
      {"'foo'", "folder", "tum", "euroc", "kitti", "transforms", "middlebury", "strecha", "tsukuba", "video", "bag"});
  EXPECT_EQ(datasetKinds().size(), 10u);
}

TEST(DatasetBadInput, TruncatedImageMidSequence) {
  test::TempDir tmp;
  for (int i = 0; i < 3; ++i) writeImage(tmp / fmt::format("{:03d}.png", i), i);
  test::writeText(tmp / "times.txt", "0\n1\n2\n");
  writeCamera(tmp / "camera.yaml");
  // Cut frame 1 in half.
  const fs::path bad = tmp / "001.png";
  std::string bytes;
  {
    std::ifstream in(bad, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  test::writeText(bad, bytes.substr(0, bytes.size() / 2));
  const auto ds = openDataset(tmp.path().string());  // opening reads only the first frame
  EXPECT_EQ(ds->load(0).image.at<uchar>(0, 0), 0);
  expectError([&] { ds->load(1); }, {bad.string(), "truncated"});
  EXPECT_EQ(ds->load(2).image.at<uchar>(0, 0), 2);
  // A truncated first frame fails at open time.
  test::writeText(tmp / "000.png", bytes.substr(0, 100));
  expectError([&] { openDataset(tmp.path().string()); }, {(tmp / "000.png").string()});
}

TEST(DatasetBadInput, SizeChangeMidSequence) {
  test::TempDir tmp;
  writeImage(tmp / "a1.png", 0);
  writeImage(tmp / "a2.png", 1, {80, 48});
  test::writeText(tmp / "times.txt", "0\n1\n");
  writeCamera(tmp / "camera.yaml");
  const auto ds = openDataset(tmp.path().string());
  expectError([&] { ds->load(1); }, {(tmp / "a2.png").string(), "frame 1", "80x48", "64x48"});
}

TEST(DatasetBadInput, CameraOverrideSizeMismatch) {
  test::TempDir tmp;
  writeImage(tmp / "a1.png", 0);
  test::writeText(tmp / "times.txt", "0\n");
  writeCamera(tmp / "wrong.yaml", 640, 480);
  DatasetOptions o;
  o.camera_override = tmp / "wrong.yaml";
  expectError([&] { openDataset(tmp.path().string(), o); }, {(tmp / "wrong.yaml").string(), "640x480", "64x48"});
}

TEST(DatasetKitti, LayoutAndErrors) {
  test::TempDir tmp;
  const fs::path seq = tmp / "sequences" / "07";
  for (int i = 0; i < 3; ++i) writeImage(seq / "image_0" / fmt::format("{:06d}.png", i), i);
  test::writeText(seq / "times.txt", "0.0\n0.1\n0.2\n");
  test::writeText(seq / "calib.txt", "P0: 50 0 31.5 0 0 51 23.5 0 0 0 1 0\nP1: 50 0 31.5 -20 0 51 23.5 0 0 0 1 0\n");
  // Official layout: dataset/poses/07.txt next to dataset/sequences/.
  test::writeText(tmp / "poses" / "07.txt",
                  "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 1\n1 0 0 0.5 0 1 0 0 0 0 1 2\n");
  const auto ds = openDataset(seq.string());
  EXPECT_EQ(ds->kind(), "kitti");
  ASSERT_EQ(ds->size(), 3u);
  EXPECT_EQ(ds->camera().fy, 51);
  EXPECT_TRUE(ds->groundTruth(2)->translation().isApprox(Eigen::Vector3d(0.5, 0, 2)));
  test::writeText(seq / "times.txt", "0.0\n0.1\n0.1\n");
  expectError([&] { openDataset(seq.string()); }, {(seq / "times.txt").string() + ":3"});
  test::writeText(seq / "times.txt", "0.0\n0.1\n0.2\n0.3\n");
  expectError([&] { openDataset(seq.string()); }, {(seq / "times.txt").string() + ":4", "000003"});
  test::writeText(seq / "times.txt", "0.0\n0.1\n0.2\n");
  test::writeText(seq / "calib.txt", "P1: 1 2 3\n");
  expectError([&] { openDataset(seq.string()); }, {(seq / "calib.txt").string(), "P0"});
}

TEST(DatasetTransforms, IntrinsicsDistortionAndErrors) {
  test::TempDir tmp;
  writeImage(tmp / "images" / "0.png", 0);
  writeImage(tmp / "images" / "1.png", 1);
  test::writeText(tmp / "transforms.json", R"({
    "fl_x": 60, "fl_y": 61, "cx": 32, "cy": 24, "w": 64, "h": 48, "k1": 0.1, "k2": -0.01, "p1": 0.001, "p2": 0,
    "aabb_scale": 16,
    "frames": [
      {"file_path": "images/0.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},
      {"file_path": "images/1", "transform_matrix": [[1,0,0,1],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}
    ]})");
  const auto ds = openDataset(tmp.path().string());
  EXPECT_EQ(ds->kind(), "transforms");
  EXPECT_EQ(*ds->aabbScale(), 16);
  EXPECT_EQ(ds->camera().fy, 61);
  EXPECT_EQ(ds->camera().cx, 31.5);  // instant-ngp pixel centres at +0.5
  EXPECT_EQ(ds->camera().distortion_model, DistortionModel::kRadTan);
  EXPECT_EQ(ds->camera().distortion, (std::vector<double>{0.1, -0.01, 0.001, 0}));
  // Identity in OpenGL axes is a camera looking down world -z with y up: OpenCV z = -world z.
  const Eigen::Matrix3d R = ds->groundTruth(0)->rotationMatrix();
  EXPECT_TRUE(R.col(2).isApprox(Eigen::Vector3d(0, 0, -1)));
  EXPECT_TRUE(R.col(1).isApprox(Eigen::Vector3d(0, -1, 0)));
  EXPECT_DOUBLE_EQ(ds->timestamp(1), 1.0 / 30);
  const std::string json = (tmp / "transforms.json").string();
  test::writeText(tmp / "transforms.json", R"({"camera_angle_x": 1.0, "frames": [{"file_path": "images/7"}]})");
  expectError([&] { openDataset(tmp.path().string()); }, {json, "frames[0].file_path", "not found"});
  test::writeText(tmp / "transforms.json", R"({"camera_angle_x": 1.0, "frames": [{"file_path": "images/0"}]})");
  expectError([&] { openDataset(tmp.path().string()); }, {json, "frames[0].transform_matrix"});
  test::writeText(tmp / "transforms.json", R"({"camera_angle_x": 1.0, "frames": [)");
  expectError([&] { openDataset(tmp.path().string()); }, {json, "JSON"});
}

// A sequence written by `nerfslam synth` reads as TUM (its camera.yaml honoured, ground truth for
// every frame), and its transforms.json describes the same camera and poses.
TEST(DatasetSynth, TumAndTransformsAgree) {
  test::TempDir tmp;
  const fs::path out = tmp / "syn";
  const auto r = test::runCli(
      "synth --frames 6 --size 160x120 --distortion 0.05,-0.01,0.001,0.0005 "
      "--textures procedural --out '" +
      out.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto tum = openDataset(out.string());
  EXPECT_EQ(tum->kind(), "tum");
  ASSERT_EQ(tum->size(), 6u);
  const auto tf = openDataset("transforms:" + out.string());
  ASSERT_EQ(tf->size(), 6u);
  const Camera& a = tum->camera();
  const Camera& b = tf->camera();
  EXPECT_EQ(a.width, 160);
  EXPECT_EQ(a.distortion_model, DistortionModel::kRadTan);
  EXPECT_EQ(a.distortion, (std::vector<double>{0.05, -0.01, 0.001, 0.0005}));
  EXPECT_EQ(b.width, a.width);
  EXPECT_EQ(b.height, a.height);
  EXPECT_NEAR(b.fx, a.fx, 1e-9);
  EXPECT_NEAR(b.fy, a.fy, 1e-9);
  EXPECT_NEAR(b.cx, a.cx, 1e-9);
  EXPECT_NEAR(b.cy, a.cy, 1e-9);
  EXPECT_EQ(b.distortion, a.distortion);
  for (size_t i = 0; i < 6; ++i) {
    ASSERT_TRUE(tum->groundTruth(i).has_value()) << i;
    EXPECT_TRUE(tum->groundTruth(i)->isApprox(*tf->groundTruth(i), 1e-9)) << i;
    EXPECT_NEAR(tum->timestamp(i), tf->timestamp(i), 1e-6);
    EXPECT_EQ(tum->imagePath(i), tf->imagePath(i));
  }
  EXPECT_EQ(tum->load(5, ImageMode::kColor).image.type(), CV_8UC3);

  // The transforms' depth images (depth_path, integer_depth_scale) are z-depth in metres: a pixel of
  // frame 0 back-projected with its depth and projected into frame 1 lands where frame 1's depth is
  // the point's z there (the distortion included), for the pixels both see.
  EXPECT_TRUE(tum->loadDepth(0).empty()) << "the TUM layout's depth is ground truth, not training input";
  const cv::Mat d0 = tf->loadDepth(0), d1 = tf->loadDepth(1);
  ASSERT_EQ(d0.type(), CV_32FC1);
  ASSERT_EQ(d0.size(), cv::Size(160, 120));
  const SE3 T_1_0 = tf->groundTruth(1)->inverse() * *tf->groundTruth(0);
  int checked = 0, agree = 0;
  for (int y = 4; y < 120; y += 8)
    for (int x = 4; x < 160; x += 8) {
      const float z = d0.at<float>(y, x);
      if (!(z > 0.f)) continue;
      const Eigen::Vector3d p1 = T_1_0 * (b.unproject(Eigen::Vector2d(x, y)) * double(z));
      Eigen::Vector2d uv;
      if (!b.projectInImage(p1, &uv, 2.0)) continue;
      const float z1 = d1.at<float>(int(std::lround(uv.y())), int(std::lround(uv.x())));
      if (!(z1 > 0.f)) continue;
      ++checked;
      agree += std::abs(z1 - p1.z()) < 0.02 * p1.z() ? 1 : 0;
    }
  ASSERT_GT(checked, 100);
  EXPECT_GT(agree, checked * 9 / 10) << agree << " of " << checked;
}

// A transforms.json frame's depth image: nerfstudio's keys too, and bad input named.
TEST(DatasetTransforms, DepthImagesAndTheirErrors) {
  test::TempDir tmp;
  writeImage(tmp / "images" / "0.png", 0);
  cv::Mat mm(48, 64, CV_16UC1, cv::Scalar(2500));
  mm.at<uint16_t>(0, 0) = 0;
  ASSERT_TRUE(cv::imwrite((tmp / "depth0.png").string(), mm));
  const std::string frame =
      R"({"file_path": "images/0.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]])";
  const std::string json = (tmp / "transforms.json").string();
  auto write = [&](const std::string& top, const std::string& extra) {
    test::writeText(tmp / "transforms.json",
                    R"({"fl_x": 60, "w": 64, "h": 48, )" + top + R"("frames": [)" + frame + extra + "}]}");
  };
  write("", R"(, "depth_file_path": "depth0.png")");  // nerfstudio: millimetres by default
  auto ds = openDataset(tmp.path().string());
  cv::Mat d = ds->loadDepth(0);
  ASSERT_EQ(d.type(), CV_32FC1);
  EXPECT_FLOAT_EQ(d.at<float>(10, 10), 2.5f);
  EXPECT_EQ(d.at<float>(0, 0), 0.f);
  write(R"("integer_depth_scale": 0.0002, )", R"(, "depth_path": "depth0.png")");  // instant-ngp
  EXPECT_FLOAT_EQ(openDataset(tmp.path().string())->loadDepth(0).at<float>(10, 10), 0.5f);
  write("", R"(, "depth_path": "missing.png")");
  expectError([&] { openDataset(tmp.path().string()); }, {json, "frames[0].depth_path", "not found"});
  write("", R"(, "depth_path": 3)");
  expectError([&] { openDataset(tmp.path().string()); }, {json, "frames[0].depth_path", "not a string"});
  write(R"("depth_unit_scale_factor": 0, )", R"(, "depth_path": "depth0.png")");
  expectError([&] { openDataset(tmp.path().string()); }, {json, "depth_unit_scale_factor", "> 0"});
  const std::string dp = (tmp / "depth0.png").string();
  ASSERT_TRUE(cv::imwrite(dp, cv::Mat(24, 32, CV_16UC1, cv::Scalar(1))));
  write("", R"(, "depth_path": "depth0.png")");
  expectError([&] { openDataset(tmp.path().string())->loadDepth(0); }, {dp, "32x24", "64x48"});
  ASSERT_TRUE(cv::imwrite(dp, cv::Mat(48, 64, CV_8UC3, cv::Scalar(1, 2, 3))));
  expectError([&] { openDataset(tmp.path().string())->loadDepth(0); }, {dp, "single-channel"});
}

}  // namespace
}  // namespace nerfslam
