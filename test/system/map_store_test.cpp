// Saved map folders (system/map_store.h), the round trips: a SLAM map saved and loaded back exactly
// (and localised in), a NeRF model file stored with it, a map refused with another camera, and
// `nerfslam run --map DIR --localize / --extend` end to end on synthetic sequences with ground
// truth. The folder's manifest, corruption and crash safety are in map_folder_test.cpp, the
// binaries in map_codec_test.cpp.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <iterator>
#include <string>

#include <nlohmann/json.hpp>

#include "map_test_maps.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/slam_system.h"
#include "test_support.h"

namespace nerfslam {
namespace {
using namespace maptest;

// ---- round trip -------------------------------------------------------------------------------

TEST(MapStore, RoundTripOfASlamMapIsExact) {
  SlamMap m = runSlamOnRoom(40, 640, 480);
  ASSERT_TRUE(m.slam->initialized());
  const Map& map = m.slam->map();
  ASSERT_GE(map.numKeyframes(), 4u);
  ASSERT_GE(map.numPoints(), 500u);
  test::TempDir dir;
  const MapSaveResult s1 = saveMapFolder(dir / "map", map, m.camera, m.options);
  EXPECT_EQ(s1.generation, 1u);
  EXPECT_EQ(s1.images_written, map.numKeyframes());
  std::printf("saved %zu keyframes, %zu points: %.2f MB in %.2f s\n", s1.keyframes, s1.points, s1.bytes / 1e6,
              s1.seconds);

  const LoadedMap l = loadMapFolder(dir / "map", m.camera);
  expectSameMap(map, *l.map);
  EXPECT_EQ(l.generation, 1u);
  EXPECT_EQ(l.keyframes_rebuilt_identical, static_cast<int>(map.numKeyframes()));
  EXPECT_EQ(printOptions(l.options), printOptions(m.options));
  EXPECT_EQ(l.camera.describe(), m.camera.describe());
  EXPECT_FALSE(l.nerf_model.has_value());
  std::printf("loaded in %.2f s\n", l.seconds);

  // A second save of the same map: generation 2, images reused, generation 1's files gone.
  const MapSaveResult s2 = saveMapFolder(dir / "map", *l.map, l.camera, l.options);
  EXPECT_EQ(s2.generation, 2u);
  EXPECT_EQ(s2.images_written, 0u);
  EXPECT_EQ(s2.images_reused, map.numKeyframes());
  const auto files = folderFiles(dir / "map");
  for (const auto& f : files) EXPECT_EQ(f.find(".000001.") != std::string::npos, f.rfind("images/", 0) == 0) << f;
  EXPECT_EQ(files.size(), 1 + 4 + map.numKeyframes()) << "map.json, 4 data files, one image per keyframe";
  expectSameMap(map, *loadMapFolder(dir / "map", m.camera).map);

  // A system started from the loaded map localises in it.
  {
    LoadedMap l2 = loadMapFolder(dir / "map");
    SlamSystem loc(l2.camera, sparseOptions(), std::move(l2.map), MapMode::kLocalize);
    EXPECT_EQ(loc.state(), TrackingState::kLost);
    SynthOptions so;
    so.scene = "room";
    so.frames = 40;
    so.textures = "procedural";
    SequenceRenderer seq(so);
    const SynthFrame f = seq.render(25);
    const FrameRecord r = loc.trackFrame(f.bgr, f.timestamp, 25);
    EXPECT_TRUE(r.tracked) << r.message;
    EXPECT_EQ(loc.relocalizedAtFrame(), 25);
    loc.finish(true);
    expectSameMap(map, loc.map());  // localisation changed nothing
  }
}

TEST(MapStore, NerfModelFileIsStoredAndAFailingWriterKeepsThePreviousMap) {
  Camera cam;
  const auto map = makeSmallMap(4, 320, 240, &cam);
  test::TempDir dir;
  saveMapFolder(dir / "m", *map, cam, sparseOptions(), [](const fs::path& p) { test::writeText(p, "model bytes"); });
  LoadedMap l = loadMapFolder(dir / "m", cam);
  ASSERT_TRUE(l.nerf_model.has_value());
  std::ifstream in(*l.nerf_model);
  std::string content((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(content, "model bytes");

  const auto before = folderFiles(dir / "m");
  const std::string e = test::errorOf([&] {
    saveMapFolder(dir / "m", *map, cam, sparseOptions(), [](const fs::path&) { throw Error("no model yet"); });
  });
  EXPECT_NE(e.find("no model yet"), std::string::npos) << e;
  EXPECT_EQ(loadMapFolder(dir / "m", cam).generation, 1u) << "the previous map is still the folder's map";
  // A save without a writer stores no model.
  saveMapFolder(dir / "m", *map, cam, sparseOptions());
  EXPECT_FALSE(loadMapFolder(dir / "m", cam).nerf_model.has_value());
}

TEST(MapStore, RefusesAMapMadeWithAnotherCamera) {
  SavedSmallMap s;
  const std::string camera_file = fileOfRole(s.dir, "camera");
  Camera other = s.camera;
  other.fx *= 1.01;
  std::string e = test::errorOf([&] { loadMapFolder(s.dir, other); });
  EXPECT_NE(e.find(camera_file + ": field 'fx'"), std::string::npos) << e;
  EXPECT_NE(e.find("another camera"), std::string::npos) << e;
  other = s.camera.scaled(2.0);
  e = test::errorOf([&] { loadMapFolder(s.dir, other); });
  EXPECT_NE(e.find("field 'width'"), std::string::npos) << e;
  other = s.camera;
  other.distortion_model = DistortionModel::kRadTan;
  other.distortion = {0.01, 0, 0, 0};
  e = test::errorOf([&] { loadMapFolder(s.dir, other); });
  EXPECT_NE(e.find("field 'distortion_model'"), std::string::npos) << e;
  EXPECT_NO_THROW(loadMapFolder(s.dir, s.camera));
}

// ---- nerfslam run --map ------------------------------------------------------------------------

// A TUM sequence folder playing `src` from its `first`-th frame (images shared through a symlink).
fs::path tumFrom(const fs::path& src, const fs::path& dst, int first) {
  fs::create_directories(dst);
  fs::create_directory_symlink(fs::absolute(src / "rgb"), dst / "rgb");
  fs::copy_file(src / "groundtruth.txt", dst / "groundtruth.txt");
  fs::copy_file(src / "camera.yaml", dst / "camera.yaml");
  std::ifstream in(src / "rgb.txt");
  std::ofstream out(dst / "rgb.txt");
  std::string line;
  int i = 0;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] == '#')
      out << line << "\n";
    else if (i++ >= first)
      out << line << "\n";
  }
  return dst;
}

void synth(const std::string& args) {
  const auto r = test::runCli("synth --scene room --trajectory handheld " + args);
  ASSERT_EQ(r.exit_code, 0) << r.output;
}

TEST(MapStoreCli, LocalizesInASavedMapAlongAnotherTrajectory) {
  if (!fs::exists(test::cliPath())) GTEST_SKIP() << "nerfslam binary not built";
  test::TempDir tmp;
  // The map: 80 frames at 30 fps (2.6 s of the handheld walk), saved by the run into OUT/map.
  synth("--frames 80 --out '" + (tmp / "seq").string() + "'");
  auto r = test::runCli("run --no-nerf --dataset tum:'" + (tmp / "seq").string() + "' --out '" +
                        (tmp / "slam").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const json slam = readJson(tmp / "slam" / "report.json");
  ASSERT_EQ(slam.at("frames_tracked").get<int>(), 80) << slam.dump(2);
  ASSERT_EQ(slam.at("map_saved").get<std::string>(), (tmp / "slam" / "map").string());
  const uint64_t generation = readJson(tmp / "slam" / "map" / "map.json").at("generation").get<uint64_t>();

  // Another trajectory through the same room: the walk sampled at 23 fps (other poses, other
  // images), entered in its middle (frame 25 of 60, 1.1 s in).
  synth("--frames 60 --fps 23 --out '" + (tmp / "seq23").string() + "'");
  const fs::path seq = tumFrom(tmp / "seq23", tmp / "seq23_from25", 25);
  r = test::runCli("run --no-nerf --dataset tum:'" + seq.string() + "' --out '" + (tmp / "loc").string() + "' --map '" +
                   (tmp / "slam" / "map").string() + "' --localize");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const json loc = readJson(tmp / "loc" / "report.json");
  EXPECT_EQ(loc.at("mode"), "localize");
  EXPECT_EQ(loc.at("map_loaded"), (tmp / "slam" / "map").string());
  EXPECT_EQ(loc.at("relocalized_at_frame").get<int>(), 0) << loc.dump(2);
  // The map folder holds no keyframe database: it is rebuilt at load, and relocalisation queries it.
  EXPECT_NE(r.output.find("keyframe database: not stored with the map, rebuilt from its " +
                          std::to_string(slam.at("keyframes").get<int>()) + " keyframes"),
            std::string::npos)
      << r.output;
  EXPECT_GE(loc.at("relocalization_cpu_ms").at("attempts").get<int>(), 1) << loc.dump(2);
  EXPECT_GT(loc.at("relocalization_cpu_ms").at("median").get<double>(), 0.0);
  EXPECT_EQ(loc.at("frames").get<int>(), 35);
  EXPECT_EQ(loc.at("frames_tracked").get<int>(), 35) << loc.dump(2);
  // The map is unchanged: no keyframe or point added or removed, nothing saved over it.
  EXPECT_EQ(loc.at("keyframes"), slam.at("keyframes"));
  EXPECT_EQ(loc.at("map_points"), slam.at("map_points"));
  EXPECT_EQ(loc.at("map_loaded_keyframes"), slam.at("keyframes"));
  EXPECT_FALSE(loc.contains("map_saved"));
  EXPECT_EQ(readJson(tmp / "slam" / "map" / "map.json").at("generation").get<uint64_t>(), generation);
  // Accuracy against ground truth (Sim3-aligned ATE, as the runner reports it).
  EXPECT_LT(loc.at("ate_percent_of_path").get<double>(), 1.5) << loc.dump(2);
  // And in the map's own frame: the mapping run's alignment to ground truth, applied unchanged to
  // the localised poses, puts them on the ground truth (they are poses in the saved map).
  const Trajectory gt = readTumTrajectory(tmp / "seq23" / "groundtruth.txt");
  TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-3;
  const TrajectoryReport map_fit = evaluateTrajectory(readTumTrajectory(tmp / "seq" / "groundtruth.txt"),
                                                      readTumTrajectory(tmp / "slam" / "trajectory.txt"), eo);
  Trajectory localized = readTumTrajectory(tmp / "loc" / "trajectory.txt");
  for (auto& e : localized) e.pose = map_fit.alignment.transformPose(e.pose);
  eo.align = "none";
  const TrajectoryReport in_map = evaluateTrajectory(gt, localized, eo);
  EXPECT_EQ(in_map.matched, 35u);
  std::printf("localised 35 frames: ATE %.4f m (Sim3) = %.3f%% of path; in the map's frame %.4f m (path %.2f m)\n",
              loc.at("ate_rmse_m").get<double>(), loc.at("ate_percent_of_path").get<double>(), in_map.ape.rmse,
              in_map.ref_path_length);
  EXPECT_LT(in_map.ape.rmse, 0.02) << "metres, on a walk of " << in_map.ref_path_length << " m";
}

TEST(MapStoreCli, ExtendAddsKeyframesToASavedMap) {
  if (!fs::exists(test::cliPath())) GTEST_SKIP() << "nerfslam binary not built";
  test::TempDir tmp;
  synth("--frames 90 --out '" + (tmp / "seq").string() + "'");
  // The map covers the first 45 frames; the extension replays from frame 30 to the end.
  auto r = test::runCli("run --no-nerf --dataset tum:'" + (tmp / "seq").string() + "' --max-frames 45 --out '" +
                        (tmp / "slam").string() + "' --save-map '" + (tmp / "map").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const json slam = readJson(tmp / "slam" / "report.json");
  ASSERT_EQ(slam.at("map_saved"), (tmp / "map").string());
  EXPECT_FALSE(fs::exists(tmp / "slam" / "map")) << "--save-map replaces the default OUT/map";
  const fs::path seq = tumFrom(tmp / "seq", tmp / "seq_from30", 30);
  r = test::runCli("run --no-nerf --dataset tum:'" + seq.string() + "' --out '" + (tmp / "ext").string() + "' --map '" +
                   (tmp / "map").string() + "' --extend --save-map '" + (tmp / "map").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const json ext = readJson(tmp / "ext" / "report.json");
  EXPECT_EQ(ext.at("mode"), "extend");
  EXPECT_EQ(ext.at("relocalized_at_frame").get<int>(), 0) << ext.dump(2);
  EXPECT_EQ(ext.at("frames_tracked").get<int>(), 60) << ext.dump(2);
  EXPECT_EQ(ext.at("map_loaded_keyframes"), slam.at("keyframes"));
  EXPECT_GT(ext.at("keyframes").get<int>(), slam.at("keyframes").get<int>()) << ext.dump(2);
  EXPECT_LT(ext.at("ate_percent_of_path").get<double>(), 1.5) << ext.dump(2);
  // Saved in place as the next generation; it loads with the new keyframes.
  const LoadedMap l = loadMapFolder(tmp / "map", loadCameraYaml(tmp / "seq" / "camera.yaml"));
  EXPECT_EQ(l.generation, 2u);
  EXPECT_EQ(l.map->numKeyframes(), ext.at("keyframes").get<size_t>());
  EXPECT_EQ(l.map->numPoints(), ext.at("map_points").get<size_t>());
}

TEST(MapStoreCli, RefusesBadMapArguments) {
  if (!fs::exists(test::cliPath())) GTEST_SKIP() << "nerfslam binary not built";
  test::TempDir tmp;
  Camera cam;
  const auto map = makeSmallMap(4, 320, 240, &cam);
  saveMapFolder(tmp / "map", *map, cam, sparseOptions());
  synth("--frames 3 --size 160x120 --textures procedural --out '" + (tmp / "seq").string() + "'");
  const std::string base =
      "run --no-nerf --dataset tum:'" + (tmp / "seq").string() + "' --out '" + (tmp / "out").string() + "'";
  auto r = test::runCli(base + " --localize");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--map"), std::string::npos) << r.output;
  r = test::runCli(base + " --map '" + (tmp / "map").string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("--map needs --localize or --extend"), std::string::npos) << r.output;
  r = test::runCli(base + " --map '" + (tmp / "map").string() + "' --localize --extend");
  EXPECT_NE(r.exit_code, 0);
  // A map made with another camera (320x240 against these 160x120 images).
  r = test::runCli(base + " --map '" + (tmp / "map").string() + "' --localize");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("camera.000001.yaml: field 'width'"), std::string::npos) << r.output;
  r = test::runCli(base + " --map '" + (tmp / "nomap").string() + "' --extend");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("map folder not found"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace nerfslam
