// Regression tests for inputs the fuzzers (test/fuzz, docs/fuzzing.md) found to crash or trip the
// sanitizers. Each feeds the minimised reproducer to the parser and expects a nerfslam::Error.
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/io/trajectory.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

// Expects openDataset to throw a nerfslam::Error whose message contains every needle; any other
// exception type is a failure (it would escape the CLI's error handling).
void expectDatasetError(const std::string& kind, const fs::path& root, std::initializer_list<std::string> needles) {
  try {
    openDataset(kind, root);
    ADD_FAILURE() << "no error thrown";
  } catch (const Error& e) {
    const std::string msg = e.what();
    for (const auto& n : needles) EXPECT_NE(msg.find(n), std::string::npos) << "'" << n << "' not in: " << msg;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected nerfslam::Error, got another exception: " << e.what();
  }
}

// A EuRoC cam0 folder with one 752x480 image listed in data.csv and the given sensor.yaml.
fs::path eurocWithSensor(const test::TempDir& dir, const std::string& sensor_yaml) {
  const fs::path cam0 = dir / "mav0/cam0";
  fs::create_directories(cam0 / "data");
  EXPECT_TRUE(cv::imwrite((cam0 / "data/1403715273262142976.png").string(), cv::Mat(480, 752, CV_8UC1, cv::Scalar(9))));
  test::writeText(cam0 / "data.csv", "#timestamp [ns],filename\n1403715273262142976,1403715273262142976.png\n");
  test::writeText(cam0 / "sensor.yaml", sensor_yaml);
  return dir.path();
}

const std::string kSensorHead =
    "sensor_type: camera\n"
    "camera_model: pinhole\n"
    "intrinsics: [458.654, 457.296, 367.215, 248.375]\n"
    "distortion_model: radial-tangential\n"
    "distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n";
const std::string kTBS = "T_BS:\n  cols: 4\n  rows: 4\n  data: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\n";

// fuzz_dataset_euroc: a sensor.yaml that is a scalar made readSensorYaml index a scalar node, and
// yaml-cpp's YAML::BadSubscript escaped (reader_euroc.cpp yamlNumbers, root[key] outside the try).
TEST(FuzzRegression, EurocSensorYamlWhoseRootIsAScalar) {
  test::TempDir dir;
  expectDatasetError("euroc", eurocWithSensor(dir, "1527336214\n"), {"sensor.yaml"});
}

// Same escape one level down: T_BS given as a scalar instead of a map with `data`.
TEST(FuzzRegression, EurocSensorYamlWhoseTBSIsAScalar) {
  test::TempDir dir;
  expectDatasetError("euroc", eurocWithSensor(dir, kSensorHead + "resolution: [752, 480]\nT_BS: 5\n"),
                     {"sensor.yaml", "T_BS"});
}

// UBSan: resolution [1e300, 480] was cast to int (float-cast-overflow, reader_euroc.cpp
// static_cast<int>(res[0])) before any range check. It must be rejected, naming the field.
TEST(FuzzRegression, EurocSensorYamlWithOutOfRangeResolution) {
  test::TempDir dir;
  expectDatasetError("euroc", eurocWithSensor(dir, kSensorHead + "resolution: [1e300, 480]\n" + kTBS),
                     {"sensor.yaml", "resolution"});
}

// A Strecha folder: images/0000.jpg and 0001.jpg (768x512) with the given .camera files.
fs::path strechaWithCameras(const test::TempDir& dir, const std::string& cam0, const std::string& cam1) {
  for (const char* n : {"0000.jpg", "0001.jpg"}) {
    fs::create_directories(dir / "images");
    EXPECT_TRUE(cv::imwrite((dir / "images" / n).string(), cv::Mat(512, 768, CV_8UC3, cv::Scalar(9, 9, 9))));
  }
  test::writeText(dir / "gt_dense_cameras/0000.jpg.camera", cam0);
  test::writeText(dir / "gt_dense_cameras/0001.jpg.camera", cam1);
  return dir.path();
}

std::string strechaCamera(const std::string& size_line) {
  return "689.87 0 379.7975\n0 691.04 251.3275\n0 0 1\n0 0 0\n"
         "0.450927 -0.0945642 -0.887537\n-0.892535 -0.0401974 -0.449183\n0.00679989 0.994707 -0.102528\n"
         "-7.28137 -7.57667 0.204446\n" +
         size_line + "\n";
}

// UBSan (fuzz_dataset_strecha): the "width height" line 1e13 512 was cast to int (float-cast-overflow,
// reader_multiview.cpp static_cast<int>(size[0])) before any range check, in the second camera
// (compared with the first) and in the first (taken as the sequence size). It must be rejected
// as a bad "width height" line of that file.
TEST(FuzzRegression, StrechaCameraWithOutOfRangeSizeInSecondFile) {
  test::TempDir dir;
  expectDatasetError("strecha", strechaWithCameras(dir, strechaCamera("768 512"), strechaCamera("1e13 512")),
                     {"0001.jpg.camera", "width height"});
}

TEST(FuzzRegression, StrechaCameraWithOutOfRangeSizeInFirstFile) {
  test::TempDir dir;
  expectDatasetError("strecha", strechaWithCameras(dir, strechaCamera("1e13 512"), strechaCamera("768 512")),
                     {"0000.jpg.camera", "width height"});
}

// UBSan (fuzz_dataset_middlebury, found by CI): a view count of 4.4e124 in templeR_par.txt was cast
// to size_t (float-cast-overflow, reader_multiview.cpp) to compare it with the number of view lines.
// It must be rejected as a view count that does not match the lines.
TEST(FuzzRegression, MiddleburyViewCountOutOfRange) {
  test::TempDir dir;
  test::writeText(dir / "templeR_par.txt",
                  "444444444444444444444444444444444444444444444444444444444444444444444444"
                  "4444444444444444444444444444444444444444444444444444447\n"
                  "templeR0001.png 1 0 0 0 1 0 0 0 1 1 0 0 0 1 0 0 0 1 0 0 0\n");
  expectDatasetError("middlebury", dir.path(), {"templeR_par.txt", "view count"});
}

// fuzz_dataset_folder: a times.txt line of form feeds was a data line to readDataLines (which trimmed
// only spaces and tabs) but held no token for splitTokens (std::isspace), and the folder reader read
// the first token of an empty list. Lines of any whitespace are blank now.
TEST(FuzzRegression, FolderTimesLineOfOnlyFormFeeds) {
  test::TempDir dir;
  for (int i = 0; i < 2; ++i)
    ASSERT_TRUE(cv::imwrite((dir / (std::to_string(i) + ".png")).string(), cv::Mat(48, 64, CV_8UC1, cv::Scalar(i))));
  saveCameraYaml(Camera::pinhole(64, 48, 50, 50, 31.5, 23.5), dir / "camera.yaml");
  test::writeText(dir / "times.txt", "\f\f\v\n0.5\n\f 0.75 \f\n");
  const auto ds = openDataset("folder", dir.path());
  ASSERT_EQ(ds->size(), 2u);
  EXPECT_DOUBLE_EQ(ds->timestamp(1), 0.75);
  test::writeText(dir / "times.txt", "\f\f\n0.5\n");
  expectDatasetError("folder", dir.path(), {"times.txt", "1 timestamps for 2 images"});
}

// fuzz_trajectory (CI, stop 18): an EuRoC timestamp of more than 19 digits is a finite double, but
// the seconds part before its last 9 digits overflowed std::stoll, whose std::out_of_range escaped
// readEurocTrajectory (and readTrajectory's auto-detection). It keeps the double's precision now.
TEST(FuzzRegression, EurocTrajectoryTimestampOfMoreThan19Digits) {
  test::TempDir dir;
  const fs::path p = dir / "gt.csv";
  test::writeText(p, "123456789012345678901234567890,1,2,3,1,0,0,0\n");
  for (const auto& read : {+[](const fs::path& f) { return readEurocTrajectory(f); },
                           +[](const fs::path& f) { return readTrajectory(f); }}) {
    const Trajectory t = read(p);
    ASSERT_EQ(t.size(), 1u);
    EXPECT_NEAR(t[0].timestamp, 1.2345678901234568e20, 1e6);
    EXPECT_EQ(t[0].pose.translation(), Eigen::Vector3d(1, 2, 3));
  }
  // 19 digits still read as seconds since the epoch, to well under a microsecond.
  test::writeText(p, "1403715273262142976,1,2,3,1,0,0,0\n1403715273263142976,1,2,3,1,0,0,0\n");
  const Trajectory t = readEurocTrajectory(p);
  ASSERT_EQ(t.size(), 2u);
  EXPECT_NEAR(t[0].timestamp, 1403715273.262142976, 1e-6);
  EXPECT_NEAR(t[1].timestamp - t[0].timestamp, 1e-3, 1e-6);
}

// fuzz_image (a local 120 s campaign): a PNG whose tEXt chunk declares 956301344 bytes in a 16 KB
// file made libpng allocate and clear about 1 GB before it found the file short, over 10 s under
// ASan. The chunk walk refuses it before decoding.
TEST(FuzzRegression, PngChunkDeclaringMoreBytesThanTheFileHas) {
  test::TempDir dir;
  cv::Mat img(32, 32, CV_8UC3, cv::Scalar(10, 20, 30));
  std::vector<uchar> png;
  ASSERT_TRUE(cv::imencode(".png", img, png));
  // A tEXt chunk after IHDR (8 + 25 bytes) whose length field claims 956301344 bytes.
  const unsigned char text[] = {0x39, 0x00, 0x00, 0x20, 't', 'E', 'X', 't', 'k', 0, 'v', 0, 0, 0, 0};
  png.insert(png.begin() + 33, std::begin(text), std::end(text));
  const fs::path p = dir / "big_text.png";
  test::writeText(p, std::string(png.begin(), png.end()));
  try {
    readImage(p, ImageMode::kColor);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("big_text.png: truncated PNG image: chunk 'tEXt' at byte 33 declares 956301344 bytes"),
              std::string::npos)
        << msg;
  }
  // The PNG as written, and with bytes after IEND, still reads.
  test::writeText(p, std::string(png.begin(), png.begin() + 33) + std::string(png.begin() + 48, png.end()) + "trailer");
  EXPECT_EQ(readImage(p, ImageMode::kColor).at<cv::Vec3b>(5, 5), cv::Vec3b(10, 20, 30));
}

}  // namespace
}  // namespace nerfslam
