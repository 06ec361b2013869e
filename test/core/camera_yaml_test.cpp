// Camera YAML: our format, ROS camera_info calibration files, error messages, and the presets.
#include <gtest/gtest.h>

#include <fstream>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {

namespace fs = std::filesystem;

// The message of the Error thrown by loading `text` as a camera YAML (empty if it loads).
std::string loadError(const test::TempDir& dir, const std::string& text, const std::string& name = "cam.yaml") {
  const fs::path p = dir / name;
  test::writeText(p, text);
  try {
    loadCameraYaml(p);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

const char* kOurs = R"(model: pinhole
width: 640
height: 480
fx: 517.306408
fy: 516.469215
cx: 318.643040
cy: 255.313989
distortion_model: radtan
distortion: [0.262383, -0.953104, -0.005358, 0.002628, 1.163314]
)";

TEST(CameraYaml, LoadsOurFormat) {
  test::TempDir dir;
  test::writeText(dir / "cam.yaml", kOurs);
  const Camera c = loadCameraYaml(dir / "cam.yaml");
  EXPECT_EQ(c.width, 640);
  EXPECT_EQ(c.height, 480);
  EXPECT_EQ(c.fx, 517.306408);
  EXPECT_EQ(c.fy, 516.469215);
  EXPECT_EQ(c.cx, 318.643040);
  EXPECT_EQ(c.cy, 255.313989);
  EXPECT_EQ(c.distortion_model, DistortionModel::kRadTan);
  EXPECT_EQ(c.distortion, (std::vector<double>{0.262383, -0.953104, -0.005358, 0.002628, 1.163314}));
}

TEST(CameraYaml, DistortionIsOptional) {
  test::TempDir dir;
  test::writeText(dir / "cam.yaml", "model: pinhole\nwidth: 100\nheight: 50\nfx: 80\nfy: 81\ncx: 49.5\ncy: 24.5\n");
  const Camera c = loadCameraYaml(dir / "cam.yaml");
  EXPECT_EQ(c.distortion_model, DistortionModel::kNone);
  EXPECT_TRUE(c.distortion.empty());
  EXPECT_EQ(c.fy, 81.0);
}

TEST(CameraYaml, SaveLoadRoundTripIsExact) {
  test::TempDir dir;
  Camera c = Camera::pinhole(848, 800, 286.18100000000001, 286.389, 416.938, 403.684);
  c.distortion_model = DistortionModel::kEquidistant;
  c.distortion = {-0.011042500000000001, 0.0489719, -0.0459712, 0.00886949};
  saveCameraYaml(c, dir / "out.yaml");
  const Camera back = loadCameraYaml(dir / "out.yaml");
  EXPECT_EQ(back.width, c.width);
  EXPECT_EQ(back.height, c.height);
  EXPECT_EQ(back.fx, c.fx);
  EXPECT_EQ(back.fy, c.fy);
  EXPECT_EQ(back.cx, c.cx);
  EXPECT_EQ(back.cy, c.cy);
  EXPECT_EQ(back.distortion_model, c.distortion_model);
  EXPECT_EQ(back.distortion, c.distortion);
  // No temporary files left behind.
  int files = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir.path())) ++files;
  EXPECT_EQ(files, 1);
}

TEST(CameraYaml, SaveRefusesInvalidCameraAndKeepsOldFile) {
  test::TempDir dir;
  const Camera good = Camera::pinhole(640, 480, 525, 525, 319.5, 239.5);
  saveCameraYaml(good, dir / "cam.yaml");
  Camera bad = good;
  bad.fx = -1;
  EXPECT_THROW(saveCameraYaml(bad, dir / "cam.yaml"), Error);
  EXPECT_EQ(loadCameraYaml(dir / "cam.yaml").fx, 525.0);
}

// Exactly what ROS camera_calibration (camera_calibration_parsers) writes as ost.yaml.
const char* kRosPlumbBob = R"(image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [517.306408, 0.000000, 318.643040, 0.000000, 516.469215, 255.313989, 0.000000, 0.000000, 1.000000]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.262383, -0.953104, -0.005358, 0.002628, 1.163314]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.000000, 0.000000, 0.000000, 0.000000, 1.000000, 0.000000, 0.000000, 0.000000, 1.000000]
projection_matrix:
  rows: 3
  cols: 4
  data: [534.241150, 0.000000, 321.086395, 0.000000, 0.000000, 536.352783, 253.623474, 0.000000, 0.000000, 0.000000, 1.000000, 0.000000]
)";

TEST(CameraYaml, LoadsRosCameraInfo) {
  test::TempDir dir;
  test::writeText(dir / "ost.yaml", kRosPlumbBob);
  const Camera c = loadCameraYaml(dir / "ost.yaml");
  EXPECT_EQ(c.width, 640);
  EXPECT_EQ(c.height, 480);
  EXPECT_EQ(c.fx, 517.306408);
  EXPECT_EQ(c.fy, 516.469215);
  EXPECT_EQ(c.cx, 318.643040);
  EXPECT_EQ(c.cy, 255.313989);
  EXPECT_EQ(c.distortion_model, DistortionModel::kRadTan);
  EXPECT_EQ(c.distortion, (std::vector<double>{0.262383, -0.953104, -0.005358, 0.002628, 1.163314}));
}

TEST(CameraYaml, RosWithoutCoefficientsIsPinhole) {
  test::TempDir dir;
  std::string text = kRosPlumbBob;
  const std::string d = "cols: 5\n  data: [0.262383, -0.953104, -0.005358, 0.002628, 1.163314]";
  text.replace(text.find(d), d.size(), "cols: 0\n  data: []");
  test::writeText(dir / "rect.yaml", text);
  const Camera c = loadCameraYaml(dir / "rect.yaml");
  EXPECT_EQ(c.distortion_model, DistortionModel::kNone);
  EXPECT_TRUE(c.distortion.empty());
  EXPECT_EQ(c.fx, 517.306408);
}

TEST(CameraYaml, LoadsRosEquidistant) {
  test::TempDir dir;
  test::writeText(dir / "fisheye.yaml", R"(image_width: 848
image_height: 800
camera_name: t265_fisheye1
camera_matrix:
  rows: 3
  cols: 3
  data: [286.181, 0.0, 416.938, 0.0, 286.389, 403.684, 0.0, 0.0, 1.0]
distortion_model: equidistant
distortion_coefficients:
  rows: 1
  cols: 4
  data: [-0.0110425, 0.0489719, -0.0459712, 0.00886949]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
projection_matrix:
  rows: 3
  cols: 4
  data: [286.181, 0.0, 416.938, 0.0, 0.0, 286.389, 403.684, 0.0, 0.0, 0.0, 1.0, 0.0]
)");
  const Camera c = loadCameraYaml(dir / "fisheye.yaml");
  EXPECT_EQ(c.distortion_model, DistortionModel::kEquidistant);
  EXPECT_EQ(c.distortion.size(), 4u);
  EXPECT_EQ(c.width, 848);
  EXPECT_EQ(c.cy, 403.684);
}

void expectMentions(const std::string& msg, const std::vector<std::string>& parts) {
  EXPECT_FALSE(msg.empty()) << "expected an error";
  for (const auto& p : parts) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
}

TEST(CameraYaml, RosRationalPolynomialIsRefusedClearly) {
  test::TempDir dir;
  std::string text = kRosPlumbBob;
  text.replace(text.find("plumb_bob"), 9, "rational_polynomial");
  text.replace(text.find("cols: 5\n  data: [0.262383, -0.953104, -0.005358, 0.002628, 1.163314]"),
               std::string("cols: 5\n  data: [0.262383, -0.953104, -0.005358, 0.002628, 1.163314]").size(),
               "cols: 8\n  data: [0.1, -0.2, 0.001, 0.002, 0.01, 0.05, 0.0, 0.0]");
  expectMentions(loadError(dir, text, "rational.yaml"),
                 {"rational.yaml", "'distortion_model'", "rational_polynomial", "not supported"});
}

TEST(CameraYaml, RosErrorsNameFileAndField) {
  test::TempDir dir;
  std::string text = kRosPlumbBob;
  const std::string k = "0.000000, 516.469215, 255.313989, ";
  text.replace(text.find(k), k.size(), "516.469215, 255.313989, ");  // 8 numbers for a 3x3 matrix
  expectMentions(loadError(dir, text), {"cam.yaml", "camera_matrix.data", "8 numbers"});

  text = kRosPlumbBob;
  text.replace(text.find("image_width: 640"), 16, "image_widht: 640");
  expectMentions(loadError(dir, text), {"cam.yaml", "image_widht", "did you mean 'image_width'"});

  text = kRosPlumbBob;
  text.replace(text.find("plumb_bob"), 9, "plumbbob");
  expectMentions(loadError(dir, text), {"cam.yaml", "'distortion_model'", "plumbbob"});
}

TEST(CameraYaml, ErrorsNameFileAndField) {
  test::TempDir dir;
  const std::string base = kOurs;
  auto with = [&](const std::string& from, const std::string& to) {
    std::string t = base;
    const size_t at = t.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    return t.replace(at, from.size(), to);
  };
  // Missing file.
  try {
    loadCameraYaml(dir / "nope.yaml");
    ADD_FAILURE() << "loaded a missing file";
  } catch (const Error& e) {
    expectMentions(e.what(), {"nope.yaml", "not found"});
  }
  // Unparsable YAML: the line is named.
  expectMentions(loadError(dir, "model: pinhole\nwidth: [640\nheight: 480\n"), {"cam.yaml", "invalid YAML", "line"});
  // Not a map at all.
  expectMentions(loadError(dir, "- 1\n- 2\n"), {"cam.yaml", "map"});
  // Missing fields.
  expectMentions(loadError(dir, with("fx: 517.306408\n", "")), {"cam.yaml", "'fx'", "missing"});
  expectMentions(loadError(dir, with("height: 480\n", "")), {"cam.yaml", "'height'", "missing"});
  expectMentions(loadError(dir, with("model: pinhole\n", "")), {"cam.yaml", "'model'", "missing"});
  // Wrong types.
  expectMentions(loadError(dir, with("width: 640", "width: 640.5")), {"cam.yaml", "'width'", "integer", "640.5"});
  expectMentions(loadError(dir, with("fy: 516.469215", "fy: fast")), {"cam.yaml", "'fy'", "number", "fast"});
  expectMentions(loadError(dir, with("cx: 318.643040", "cx: [1, 2]")), {"cam.yaml", "'cx'", "number", "list"});
  expectMentions(loadError(dir, with("distortion: [0.262383,", "distortion: [abc,")),
                 {"cam.yaml", "'distortion'", "element 0", "abc"});
  expectMentions(
      loadError(dir, with("distortion: [0.262383, -0.953104, -0.005358, 0.002628, 1.163314]", "distortion: 0.26")),
      {"cam.yaml", "'distortion'", "list"});
  // NaN and infinity.
  expectMentions(loadError(dir, with("fx: 517.306408", "fx: .nan")), {"cam.yaml", "'fx'", "finite"});
  expectMentions(loadError(dir, with("cy: 255.313989", "cy: .inf")), {"cam.yaml", "'cy'", "finite"});
  expectMentions(loadError(dir, with("-0.953104", ".nan")), {"cam.yaml", "'distortion'", "finite"});
  // Unknown keys and values, with hints.
  expectMentions(loadError(dir, with("fx: 517.306408", "fxx: 517.306408")),
                 {"cam.yaml", "'fxx'", "unknown", "did you mean 'fx'"});
  expectMentions(loadError(dir, base + "distortion_modle: radtan\n"),
                 {"cam.yaml", "'distortion_modle'", "did you mean 'distortion_model'"});
  expectMentions(loadError(dir, with("distortion_model: radtan", "distortion_model: radtann")),
                 {"cam.yaml", "'distortion_model'", "radtann", "did you mean 'radtan'"});
  expectMentions(loadError(dir, with("model: pinhole", "model: omni")), {"cam.yaml", "'model'", "omni"});
  // Semantic validation goes through Camera::validate with the file name.
  expectMentions(loadError(dir, with("fx: 517.306408", "fx: -517")), {"cam.yaml", "'fx'", "> 0"});
  expectMentions(loadError(dir, with("width: 640", "width: 0")), {"cam.yaml", "'width'", "> 0"});
  expectMentions(loadError(dir, with("cx: 318.643040", "cx: 900")), {"cam.yaml", "'cx'", "outside the image"});
  expectMentions(loadError(dir, with("distortion: [0.262383, -0.953104, -0.005358,", "distortion: [0.262383,")),
                 {"cam.yaml", "'distortion'", "4 or 5"});
  expectMentions(loadError(dir, with("distortion_model: radtan\n", "")), {"cam.yaml", "'distortion_model'"});
}

// The source tree, derived from this file's path (test/core/camera_yaml_test.cpp).

TEST(CameraYaml, EveryPresetLoads) {
  const fs::path dir = test::sourceDir() / "config" / "camera";
  ASSERT_TRUE(fs::is_directory(dir)) << dir;
  int n = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() != ".yaml") continue;
    SCOPED_TRACE(e.path().string());
    EXPECT_NO_THROW(loadCameraYaml(e.path()));
    ++n;
  }
  EXPECT_GE(n, 6);
}

TEST(CameraYaml, PresetValues) {
  const fs::path dir = test::sourceDir() / "config" / "camera";
  const Camera fr1 = loadCameraYaml(dir / "tum_fr1.yaml");
  EXPECT_EQ(fr1.fx, 517.306408);
  EXPECT_EQ(fr1.distortion.size(), 5u);
  EXPECT_EQ(fr1.distortion[4], 1.163314);
  const Camera fr2 = loadCameraYaml(dir / "tum_fr2.yaml");
  EXPECT_EQ(fr2.cy, 249.701764);
  EXPECT_EQ(fr2.distortion[3], -0.000105);
  const Camera fr3 = loadCameraYaml(dir / "tum_fr3.yaml");
  EXPECT_EQ(fr3.fy, 539.2);
  EXPECT_FALSE(fr3.hasDistortion());
  const Camera euroc = loadCameraYaml(dir / "euroc_cam0.yaml");
  EXPECT_EQ(euroc.width, 752);
  EXPECT_EQ(euroc.distortion, (std::vector<double>{-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05}));
  const Camera kitti = loadCameraYaml(dir / "kitti_00-02.yaml");
  EXPECT_EQ(kitti.width, 1241);
  EXPECT_EQ(kitti.height, 376);
  EXPECT_EQ(kitti.cx, 607.1928);
  const Camera syn = loadCameraYaml(dir / "synthetic.yaml");
  EXPECT_EQ(syn.K(), Camera::pinhole(640, 480, 525, 525, 319.5, 239.5).K());
}

// The EuRoC preset agrees with the sensor.yaml shipped with the dataset.
TEST(CameraYaml, EurocPresetMatchesDatasetSensorYaml) {
  NERFSLAM_REQUIRE_DATA(euroc, "euroc_V1_01_piece");
  const fs::path sensor = euroc / "mav0" / "cam0" / "sensor.yaml";
  ASSERT_TRUE(fs::exists(sensor)) << sensor;
  std::ifstream in(sensor);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  const Camera c = loadCameraYaml(test::sourceDir() / "config" / "camera" / "euroc_cam0.yaml");
  for (const char* s : {"458.654", "457.296", "367.215", "248.375", "-0.28340811", "0.07395907", "0.00019359",
                        "1.76187114e-05", "752", "480"})
    EXPECT_NE(text.find(s), std::string::npos) << s;
  EXPECT_EQ(c.fx, 458.654);
}

}  // namespace
}  // namespace nerfslam
