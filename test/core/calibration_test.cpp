#include "nerfslam/core/calibration.h"

#include <gtest/gtest.h>

#include <fstream>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {

namespace fs = std::filesystem;

TEST(Calibration, ParseBoardSize) {
  const ChessboardSpec b = parseBoardSize("9x6", 0.025);
  EXPECT_EQ(b.cols, 9);
  EXPECT_EQ(b.rows, 6);
  EXPECT_EQ(b.square, 0.025);
  EXPECT_EQ(parseBoardSize("7X5", 0.03).rows, 5);
  for (const char* bad : {"9", "9x", "x6", "9*6", "9x6x2", "nine by six", "1x6", "-9x6", ""}) {
    const std::string msg = test::errorOf([&] { parseBoardSize(bad, 0.025); });
    EXPECT_NE(msg.find("--board"), std::string::npos) << bad << ": " << msg;
    EXPECT_NE(msg.find(std::string("'") + bad + "'"), std::string::npos) << msg;
  }
  EXPECT_NE(test::errorOf([] { parseBoardSize("9x6", 0.0); }).find("--square"), std::string::npos);
  EXPECT_NE(test::errorOf([] { parseBoardSize("9x6", -0.1); }).find("--square"), std::string::npos);
}

TEST(Calibration, NoImagesIsAnError) {
  test::TempDir dir;
  std::ofstream(dir / "notes.txt") << "not an image";
  const std::string msg = test::errorOf([&] { calibrateFromImages(dir.path(), parseBoardSize("9x6", 0.025)); });
  EXPECT_NE(msg.find(dir.path().string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("no images"), std::string::npos) << msg;
  EXPECT_NE(test::errorOf([&] {
              calibrateFromImages(dir / "missing", parseBoardSize("9x6", 0.025));
            }).find("not a directory"),
            std::string::npos);
}

TEST(Calibration, TooFewBoardsIsAnError) {
  test::TempDir dir;
  // Two blank images and one unreadable file: no board anywhere.
  cv::imwrite((dir / "a.png").string(), cv::Mat(480, 640, CV_8UC1, cv::Scalar(128)));
  cv::imwrite((dir / "b.png").string(), cv::Mat(480, 640, CV_8UC1, cv::Scalar(30)));
  std::ofstream(dir / "c.jpg") << "garbage";
  const std::string msg = test::errorOf([&] { calibrateFromImages(dir.path(), parseBoardSize("9x6", 0.025)); });
  EXPECT_NE(msg.find("found in 0 of 3 images"), std::string::npos) << msg;
  EXPECT_NE(msg.find("at least 3"), std::string::npos) << msg;
}

TEST(Calibration, OpenCvChessboardRadTan) {
  NERFSLAM_REQUIRE_DATA(dir, "opencv_chessboard");
  const CalibrationResult r = calibrateFromImages(dir, parseBoardSize("9x6", 0.025), DistortionModel::kRadTan);
  EXPECT_EQ(r.images.size(), 13u);
  EXPECT_GE(r.images_used, 10);
  EXPECT_LT(r.rms, 0.5);
  std::printf("opencv_chessboard radtan: board in %d/%zu images, RMS %.4f px, %s\n", r.images_used, r.images.size(),
              r.rms, r.camera.describe().c_str());
  for (const auto& im : r.images) {
    if (im.board_found) {
      EXPECT_LT(im.rms, 1.0) << im.path;
    }
  }
  // The per-image errors combine into the overall one (54 corners per image).
  double sum = 0;
  for (const auto& im : r.images) sum += im.board_found ? im.rms * im.rms * 54 : 0;
  EXPECT_NEAR(std::sqrt(sum / (54.0 * r.images_used)), r.rms, 1e-9);
  // A 640x480 webcam: focal length ~ 535 px, principal point near the centre.
  EXPECT_GT(r.camera.fx, 450);
  EXPECT_LT(r.camera.fx, 650);
  EXPECT_NEAR(r.camera.fx / r.camera.fy, 1.0, 0.02);
  EXPECT_NEAR(r.camera.cx, 320, 40);
  EXPECT_NEAR(r.camera.cy, 240, 40);

  test::TempDir out;
  saveCameraYaml(r.camera, out / "camera.yaml");
  const Camera back = loadCameraYaml(out / "camera.yaml");
  EXPECT_EQ(back.fx, r.camera.fx);
  EXPECT_EQ(back.fy, r.camera.fy);
  EXPECT_EQ(back.cx, r.camera.cx);
  EXPECT_EQ(back.cy, r.camera.cy);
  EXPECT_EQ(back.distortion, r.camera.distortion);
}

TEST(Calibration, OpenCvChessboardEquidistant) {
  NERFSLAM_REQUIRE_DATA(dir, "opencv_chessboard");
  const CalibrationResult r = calibrateFromImages(dir, parseBoardSize("9x6", 0.025), DistortionModel::kEquidistant);
  std::printf("opencv_chessboard equidistant: board in %d/%zu images, RMS %.4f px, %s\n", r.images_used,
              r.images.size(), r.rms, r.camera.describe().c_str());
  EXPECT_EQ(r.camera.distortion_model, DistortionModel::kEquidistant);
  EXPECT_EQ(r.camera.distortion.size(), 4u);
  EXPECT_LT(r.rms, 0.5);
}

TEST(Calibration, WrongBoardSizeFindsNothing) {
  NERFSLAM_REQUIRE_DATA(dir, "opencv_chessboard");
  const std::string msg = test::errorOf([&] { calibrateFromImages(dir, parseBoardSize("12x11", 0.025)); });
  EXPECT_NE(msg.find("12x11"), std::string::npos) << msg;
  EXPECT_NE(msg.find("at least 3"), std::string::npos) << msg;
}

TEST(Calibration, CliEndToEnd) {
  NERFSLAM_REQUIRE_DATA(dir, "opencv_chessboard");
  if (!fs::exists(test::cliPath())) {
    if (test::dataRequired()) FAIL() << "nerfslam binary not built: " << test::cliPath();
    GTEST_SKIP() << "nerfslam binary not built: " << test::cliPath();
  }
  test::TempDir out;
  const auto r = test::runCli("calibrate --images '" + dir.string() + "' --board 9x6 --square 0.025 --out '" +
                              (out / "camera.yaml").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("left01.jpg"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("overall RMS reprojection error"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("board found in"), std::string::npos) << r.output;
  const Camera cam = loadCameraYaml(out / "camera.yaml");
  const CalibrationResult lib = calibrateFromImages(dir, parseBoardSize("9x6", 0.025));
  EXPECT_EQ(cam.fx, lib.camera.fx);
  EXPECT_EQ(cam.cy, lib.camera.cy);
  EXPECT_EQ(cam.distortion, lib.camera.distortion);

  // A photo cut short (half its bytes, then the JPEG end marker: OpenCV decodes it in part, with only
  // libjpeg's warning) is named, left out, and the calibration goes on with the others.
  const fs::path copy = out / "photos";
  fs::create_directories(copy);
  for (const auto& e : fs::directory_iterator(dir)) fs::copy_file(e.path(), copy / e.path().filename());
  {
    std::ifstream in(copy / "left02.jpg", std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    bytes.resize(bytes.size() / 2);
    bytes += "\xff\xd9";
    std::ofstream(copy / "left02.jpg", std::ios::binary | std::ios::trunc) << bytes;
  }
  const auto cut = test::runCli("calibrate --images '" + copy.string() + "' --board 9x6 --square 0.025 --out '" +
                                (out / "cut.yaml").string() + "'");
  ASSERT_EQ(cut.exit_code, 0) << cut.output;
  EXPECT_NE(cut.output.find("left02.jpg: corrupt JPEG"), std::string::npos) << cut.output;
  EXPECT_TRUE(fs::exists(out / "cut.yaml"));
  const CalibrationResult with_cut =
      calibrateFromImages(copy, parseBoardSize("9x6", 0.025), DistortionModel::kRadTan, [](const fs::path& p) {
        if (p.filename() == "left02.jpg") fail("{}: corrupt", p.string());
        return cv::imread(p.string(), cv::IMREAD_GRAYSCALE);
      });
  EXPECT_EQ(with_cut.images_used, lib.images_used - 1);
  EXPECT_EQ(with_cut.images[1].problem, (copy / "left02.jpg").string() + ": corrupt");

  // Bad input: clear message, exit code 1, nothing written.
  const auto bad = test::runCli("calibrate --images '" + dir.string() + "' --board 9by6 --square 0.025 --out '" +
                                (out / "bad.yaml").string() + "'");
  EXPECT_EQ(bad.exit_code, 1) << bad.output;
  EXPECT_NE(bad.output.find("--board '9by6'"), std::string::npos) << bad.output;
  EXPECT_FALSE(fs::exists(out / "bad.yaml"));
  const auto empty = test::runCli("calibrate --images '" + out.path().string() +
                                  "' --board 9x6 --square 0.025 --out '" + (out / "bad.yaml").string() + "'");
  EXPECT_EQ(empty.exit_code, 1) << empty.output;
  EXPECT_NE(empty.output.find("no images"), std::string::npos) << empty.output;
  EXPECT_FALSE(fs::exists(out / "bad.yaml"));
}

}  // namespace
}  // namespace nerfslam
