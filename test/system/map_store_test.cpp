// Saved map folders (system/map_store.h): exact round trip of a SLAM map, refusal of foreign,
// other-camera, truncated, corrupted and incomplete folders with messages naming file and field, a
// SIGKILL loop during saves, and `nerfslam run --map DIR --localize / --extend` end to end on
// synthetic sequences with ground truth.
#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <cstdlib>
#include <fstream>
#include <random>
#include <regex>
#include <set>
#include <string>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/slam_system.h"
#include "nerfslam/tracking/frame.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

SystemOptions sparseOptions() {
  SystemOptions o;
  o.nerf.enabled = false;
  return o;
}

// ---- maps to store ----------------------------------------------------------------------------

// A real SLAM map: `frames` frames of the synthetic handheld room tracked in lock-step.
struct SlamMap {
  Camera camera;
  SystemOptions options = sparseOptions();
  std::unique_ptr<SlamSystem> slam;
};

SlamMap runSlamOnRoom(int frames, int width, int height) {
  render::SynthOptions so;
  so.scene = "room";
  so.trajectory = "handheld";
  so.frames = frames;
  so.width = width;
  so.height = height;
  so.textures = "procedural";
  render::SequenceRenderer seq(so);
  SlamMap m;
  m.camera = seq.camera();
  m.slam = std::make_unique<SlamSystem>(m.camera, m.options);
  for (int i = 0; i < frames; ++i) {
    const render::SynthFrame f = seq.render(i);
    m.slam->trackFrame(f.bgr, f.timestamp, static_cast<uint64_t>(i));
    m.slam->waitMappingIdle();
  }
  m.slam->finish(true);
  return m;
}

// A small map built directly (fast): keyframes at the ground-truth poses of rendered frames, points
// from descriptor matches between consecutive keyframes (positions arbitrary but finite), one
// keyframe and some points erased so ids have gaps as in a real map.
std::unique_ptr<Map> makeSmallMap(int keyframes, int width, int height, Camera* camera) {
  render::SynthOptions so;
  so.scene = "room";
  so.trajectory = "handheld";
  so.frames = keyframes * 4;
  so.width = width;
  so.height = height;
  so.textures = "procedural";
  render::SequenceRenderer seq(so);
  *camera = seq.camera();
  auto map = std::make_unique<Map>(*camera);
  FeatureOptions fo = systemTrackingDefaults().features;
  fo.max_features = 600;
  std::vector<KeyframeId> ids;
  for (int k = 0; k < keyframes; ++k) {
    const render::SynthFrame f = seq.render(4 * k);
    Keyframe kf;
    kf.frame =
        std::make_shared<const Frame>(extractFrame(f.bgr, *camera, fo, static_cast<uint64_t>(4 * k), f.timestamp));
    kf.T_world_cam = f.T_world_cam;
    ids.push_back(map->addKeyframe(std::move(kf)));
  }
  for (size_t k = 0; k + 1 < ids.size(); ++k) {
    const auto a = map->keyframe(ids[k]), b = map->keyframe(ids[k + 1]);
    for (int i = 0; i < a->frame->descriptors.rows; i += 2) {
      int best = 41, best_j = -1;
      for (int j = 0; j < b->frame->descriptors.rows; ++j) {
        const int d = descriptorDistance(a->frame->descriptors.row(i), b->frame->descriptors.row(j));
        if (d < best) {
          best = d;
          best_j = j;
        }
      }
      if (best_j < 0) continue;
      const Eigen::Vector3d ray = camera->unproject({a->frame->keypoints[i].pt.x, a->frame->keypoints[i].pt.y});
      map->addPoint(a->T_world_cam * (2.0 * ray), {{ids[k], i}, {ids[k + 1], best_j}});
    }
  }
  map->eraseKeyframe(ids[ids.size() / 2], ids[0]);
  const auto pts = map->points();
  for (size_t i = 0; i < pts.size(); i += 7) map->erasePoint(pts[i].id);
  std::vector<PointId> some;
  for (size_t i = 1; i < pts.size(); i += 3) some.push_back(pts[i].id);
  map->increaseVisible(some);
  return map;
}

// ---- comparison -------------------------------------------------------------------------------

void expectSameMap(const Map& a, const Map& b) {
  const auto [ka, pa] = a.snapshot();
  const auto [kb, pb] = b.snapshot();
  ASSERT_EQ(ka.size(), kb.size());
  ASSERT_EQ(pa.size(), pb.size());
  for (size_t k = 0; k < ka.size(); ++k) {
    const Keyframe &x = ka[k], &y = kb[k];
    SCOPED_TRACE("keyframe " + std::to_string(x.id));
    ASSERT_EQ(x.id, y.id);
    EXPECT_EQ(x.fixed, y.fixed);
    EXPECT_EQ(x.T_world_cam.rotation().coeffs(), y.T_world_cam.rotation().coeffs());
    EXPECT_EQ(x.T_world_cam.translation(), y.T_world_cam.translation());
    EXPECT_EQ(x.points, y.points);
    const Frame &f = *x.frame, &g = *y.frame;
    EXPECT_EQ(f.id, g.id);
    EXPECT_EQ(f.timestamp, g.timestamp);
    ASSERT_EQ(f.keypoints.size(), g.keypoints.size());
    for (size_t i = 0; i < f.keypoints.size(); ++i) {
      const cv::KeyPoint &p = f.keypoints[i], &q = g.keypoints[i];
      ASSERT_TRUE(p.pt == q.pt && p.size == q.size && p.angle == q.angle && p.response == q.response &&
                  p.octave == q.octave && p.class_id == q.class_id)
          << "keypoint " << i;
      ASSERT_EQ(f.undistorted[i], g.undistorted[i]) << "keypoint " << i;
    }
    ASSERT_EQ(f.descriptors.size(), g.descriptors.size());
    EXPECT_EQ(cv::norm(f.descriptors, g.descriptors, cv::NORM_HAMMING), 0.0);
    ASSERT_EQ(f.pyramid.size(), g.pyramid.size());
    for (size_t l = 0; l < f.pyramid.size(); ++l) EXPECT_EQ(cv::norm(f.pyramid[l], g.pyramid[l], cv::NORM_INF), 0.0);
    EXPECT_EQ(f.level_scale, g.level_scale);
    EXPECT_EQ(f.colour.empty(), g.colour.empty());
    if (!f.colour.empty()) {
      EXPECT_EQ(cv::norm(f.colour, g.colour, cv::NORM_INF), 0.0);
    }
    EXPECT_EQ(f.grid, g.grid);
  }
  for (size_t i = 0; i < pa.size(); ++i) {
    const MapPoint &x = pa[i], &y = pb[i];
    SCOPED_TRACE("point " + std::to_string(x.id));
    ASSERT_EQ(x.id, y.id);
    EXPECT_EQ(x.position, y.position);
    EXPECT_EQ(x.normal, y.normal);
    EXPECT_EQ(x.observations, y.observations);
    EXPECT_EQ(x.first_keyframe, y.first_keyframe);
    EXPECT_EQ(x.visible, y.visible);
    EXPECT_EQ(x.found, y.found);
    ASSERT_EQ(x.descriptor.empty(), y.descriptor.empty());
    if (!x.descriptor.empty()) {
      EXPECT_EQ(cv::norm(x.descriptor, y.descriptor, cv::NORM_HAMMING), 0.0);
    }
  }
}

// A digest of everything saved (ids, poses, associations, points), for "is it map A or map B".
std::string fingerprint(const Map& m) {
  const auto [kfs, pts] = m.snapshot();
  std::string s;
  for (const Keyframe& k : kfs) {
    s += fmt::format("k{} {} {:.17g} {:.17g};", k.id, k.frame->id, k.T_world_cam.translation().x(),
                     k.T_world_cam.rotation().w());
    for (PointId p : k.points) s += std::to_string(p) + ",";
  }
  for (const MapPoint& p : pts) {
    s += fmt::format("p{} {:.17g} {:.17g} {:.17g}", p.id, p.position.x(), p.position.y(), p.position.z());
    for (const auto& [k, i] : p.observations) s += fmt::format(" {}:{}", k, i);
  }
  return s;
}

json readJson(const fs::path& p) {
  std::ifstream in(p);
  EXPECT_TRUE(in.good()) << p;
  if (!in.good()) return {};
  return json::parse(in);
}

std::string fileOfRole(const fs::path& dir, const std::string& role) {
  const json manifest = readJson(dir / "map.json");
  for (const auto& f : manifest.at("files"))
    if (f.at("role") == role) return f.at("name").get<std::string>();
  return "";
}

std::set<std::string> folderFiles(const fs::path& dir) {
  std::set<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) out.insert(fs::relative(e.path(), dir).generic_string());
  return out;
}

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
    render::SynthOptions so;
    so.scene = "room";
    so.frames = 40;
    so.textures = "procedural";
    render::SequenceRenderer seq(so);
    const render::SynthFrame f = seq.render(25);
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

// ---- refusals ---------------------------------------------------------------------------------

struct SavedSmallMap {
  test::TempDir tmp;
  Camera camera;
  std::unique_ptr<Map> map;
  fs::path dir;
  SavedSmallMap() {
    map = makeSmallMap(4, 320, 240, &camera);
    dir = tmp / "map";
    saveMapFolder(dir, *map, camera, sparseOptions());
  }
};

TEST(MapStore, RefusesAnotherFormatVersion) {
  SavedSmallMap s;
  json j = readJson(s.dir / "map.json");
  for (int v : {kMapFormatVersion - 1, kMapFormatVersion + 1}) {
    j["format_version"] = v;
    test::writeText(s.dir / "map.json", j.dump());
    const std::string e = test::errorOf([&] { loadMapFolder(s.dir, s.camera); });
    EXPECT_NE(e.find("map.json: field 'format_version'"), std::string::npos) << e;
    EXPECT_NE(e.find("format version " + std::to_string(v)), std::string::npos) << e;
    EXPECT_NE(e.find(v < kMapFormatVersion ? "older" : "newer"), std::string::npos) << e;
    // Nor is a map of another version overwritten by a save.
    const std::string es = test::errorOf([&] { saveMapFolder(s.dir, *s.map, s.camera, sparseOptions()); });
    EXPECT_NE(es.find("format_version"), std::string::npos) << es;
  }
  j["format"] = "something-else";
  j["format_version"] = kMapFormatVersion;
  test::writeText(s.dir / "map.json", j.dump());
  const std::string e = test::errorOf([&] { loadMapFolder(s.dir); });
  EXPECT_NE(e.find("map.json: field 'format'"), std::string::npos) << e;
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

TEST(MapStore, RefusesTruncatedAndCorruptedFiles) {
  for (const char* role : {"keyframes", "points", "image", "config", "camera"}) {
    SCOPED_TRACE(role);
    SavedSmallMap s;
    const std::string name = fileOfRole(s.dir, role);
    const fs::path p = s.dir / name;
    const auto size = fs::file_size(p);
    fs::resize_file(p, size / 2);
    std::string e = test::errorOf([&] { loadMapFolder(s.dir, s.camera); });
    EXPECT_NE(e.find(name + ": field 'size'"), std::string::npos) << e;
    EXPECT_NE(e.find("truncated"), std::string::npos) << e;
    // Same size, one byte changed.
    SavedSmallMap t;
    const fs::path q = t.dir / fileOfRole(t.dir, role);
    {
      std::fstream f(q, std::ios::in | std::ios::out | std::ios::binary);
      f.seekg(static_cast<std::streamoff>(fs::file_size(q) / 2));
      const char c = static_cast<char>(f.peek());
      f.seekp(static_cast<std::streamoff>(fs::file_size(q) / 2));
      f.put(static_cast<char>(c ^ 0x20));
    }
    e = test::errorOf([&] { loadMapFolder(t.dir, t.camera); });
    EXPECT_NE(e.find(fileOfRole(t.dir, role) + ": field 'crc32'"), std::string::npos) << e;
    EXPECT_NE(e.find("corrupted"), std::string::npos) << e;
  }
  // A truncated manifest.
  SavedSmallMap s;
  const auto size = fs::file_size(s.dir / "map.json");
  fs::resize_file(s.dir / "map.json", size - 20);
  const std::string e = test::errorOf([&] { loadMapFolder(s.dir); });
  EXPECT_NE(e.find("map.json: not valid JSON"), std::string::npos) << e;
}

TEST(MapStore, RefusesMissingFiles) {
  for (const char* role : {"keyframes", "points", "image", "config", "camera"}) {
    SCOPED_TRACE(role);
    SavedSmallMap s;
    const std::string name = fileOfRole(s.dir, role);
    fs::remove(s.dir / name);
    const std::string e = test::errorOf([&] { loadMapFolder(s.dir, s.camera); });
    EXPECT_NE(e.find(name + ": missing"), std::string::npos) << e;
  }
  SavedSmallMap s;
  fs::remove(s.dir / "map.json");
  std::string e = test::errorOf([&] { loadMapFolder(s.dir); });
  EXPECT_NE(e.find("map.json: missing"), std::string::npos) << e;
  EXPECT_NE(e.find("not a map folder"), std::string::npos) << e;
  e = test::errorOf([&] { loadMapFolder(s.tmp / "nowhere"); });
  EXPECT_NE(e.find("nowhere: map folder not found"), std::string::npos) << e;
  // A manifest entry missing a field.
  SavedSmallMap t;
  json j = readJson(t.dir / "map.json");
  j["files"][0].erase("crc32");
  test::writeText(t.dir / "map.json", j.dump());
  e = test::errorOf([&] { loadMapFolder(t.dir); });
  EXPECT_NE(e.find("map.json: field 'files[0].crc32': missing"), std::string::npos) << e;
}

// A save over a folder whose manifest is unreadable starts after the largest generation number in
// the file names. A stray name whose number does not fit 64 bits is not ours: it is ignored, not an
// escaped std::out_of_range (found by review after fuzz_trajectory's std::stoll finding).
TEST(MapStore, SaveOverAnUnreadableMapIgnoresNamesWithHugeNumbers) {
  SavedSmallMap s;
  test::writeText(s.dir / "map.json", "{ not json");
  test::writeText(s.dir / "points.123456789012345678901234567890.bin", "stray");
  test::writeText(s.dir / "points.000041.bin", "stray");
  saveMapFolder(s.dir, *s.map, s.camera, sparseOptions());
  const LoadedMap l = loadMapFolder(s.dir, s.camera);
  EXPECT_EQ(l.generation, 42u) << "one after the largest generation that fits";
  EXPECT_EQ(l.map->keyframeIds().size(), s.map->keyframeIds().size());
}

// ---- SIGKILL during saves -----------------------------------------------------------------------

constexpr const char* kSaveLoopEnv = "NERFSLAM_MAP_SAVE_LOOP";

// The two maps the child alternates between: A as loaded, B with its newest keyframe removed and
// everything scaled (new poses, points and an image to write again when A follows B).
void makeVariantB(Map& m) {
  m.eraseKeyframe(*m.lastKeyframeId(), m.keyframeIds().front());
  m.transform(Sim3(1.5, SE3()));
}

// Child of MapStore.KillDuringSaveLeavesPreviousMapLoadable (skipped otherwise): loads SRC, then
// saves A, B, A, B, ... into DST until it is killed.
TEST(MapStoreKillHelper, SaveLoopChild) {
  const char* env = std::getenv(kSaveLoopEnv);
  if (!env) GTEST_SKIP() << "helper process of MapStore.KillDuringSaveLeavesPreviousMapLoadable";
  const std::string arg(env);
  const fs::path src = arg.substr(0, arg.find('|')), dst = arg.substr(arg.find('|') + 1);
  LoadedMap a = loadMapFolder(src);
  LoadedMap b = loadMapFolder(src);
  makeVariantB(*b.map);
  for (uint64_t i = 0;; ++i) saveMapFolder(dst, i % 2 ? *b.map : *a.map, a.camera, a.options);
}

TEST(MapStore, KillDuringSaveLeavesPreviousMapLoadable) {
  test::TempDir tmp;
  Camera cam;
  {
    const auto map = makeSmallMap(6, 320, 240, &cam);
    saveMapFolder(tmp / "src", *map, cam, sparseOptions());
  }
  LoadedMap a = loadMapFolder(tmp / "src");
  LoadedMap b = loadMapFolder(tmp / "src");
  makeVariantB(*b.map);
  const std::string fa = fingerprint(*a.map), fb = fingerprint(*b.map);
  ASSERT_NE(fa, fb);
  const fs::path dst = tmp / "dst";
  saveMapFolder(dst, *a.map, a.camera, a.options);

  // How long a child needs to start and finish one save (to aim the kills at its saves).
  const auto t0 = std::chrono::steady_clock::now();
  saveMapFolder(tmp / "timing", *b.map, a.camera, a.options);
  saveMapFolder(tmp / "timing", *a.map, a.camera, a.options);
  const double save_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / 2;

  const fs::path self = fs::read_symlink("/proc/self/exe");
  std::mt19937 rng(12345);
  // Startup + two loads take a few hundred ms; then saves follow each other every ~save_s.
  std::uniform_real_distribution<double> when(0.25, 0.6 + 6 * save_s);
  int kills = 0, interrupted_saves = 0, a_seen = 0, b_seen = 0;
  uint64_t last_generation = 0;
  const std::regex temp_or_newer(R"(\.tmp\.)");
  for (int it = 0; it < 60; ++it) {
    const double after = when(rng);
    const auto r = test::runCommand(fmt::format("{}='{}|{}' timeout -s KILL {:.3f} '{}' --gtest_filter={}",
                                                kSaveLoopEnv, (tmp / "src").string(), dst.string(), after,
                                                self.string(), "MapStoreKillHelper.SaveLoopChild"));
    ASSERT_EQ(r.exit_code, 128 + 9) << "the helper was expected to be killed after " << after << " s: " << r.output;
    ++kills;
    // Files the manifest does not name: a save was interrupted after writing some of them.
    const json manifest = readJson(dst / "map.json");
    std::set<std::string> named{"map.json"};
    for (const auto& f : manifest.at("files")) named.insert(f.at("name").get<std::string>());
    bool partial = false;
    for (const auto& f : folderFiles(dst)) partial = partial || !named.count(f);
    interrupted_saves += partial;

    LoadedMap l;
    ASSERT_NO_THROW(l = loadMapFolder(dst, cam)) << "after a kill at " << after << " s";
    const std::string fl = fingerprint(*l.map);
    ASSERT_TRUE(fl == fa || fl == fb) << "the loaded map is neither of the maps saved (kill at " << after << " s)";
    a_seen += fl == fa;
    b_seen += fl == fb;
    EXPECT_GE(l.generation, last_generation);
    last_generation = l.generation;
  }
  std::printf(
      "%d kills: %d interrupted a save mid-way (files not in the manifest), map A loaded %d times, B %d; "
      "generation %llu; one save %.0f ms\n",
      kills, interrupted_saves, a_seen, b_seen, static_cast<unsigned long long>(last_generation), 1000 * save_s);
  EXPECT_GE(kills, 50);
  EXPECT_GE(interrupted_saves, 10) << "too few kills landed inside a save";
  EXPECT_GT(a_seen, 0);
  EXPECT_GT(b_seen, 0);
  EXPECT_GT(last_generation, 20u);
  // The next complete save removes every leftover of the killed ones.
  saveMapFolder(dst, *a.map, a.camera, a.options);
  std::set<std::string> named{"map.json"};
  const json manifest = readJson(dst / "map.json");
  for (const auto& f : manifest.at("files")) named.insert(f.at("name").get<std::string>());
  EXPECT_EQ(folderFiles(dst), named);
}

// A save that runs out of space. The child process (the helper below) gets a file-size limit
// (RLIMIT_FSIZE via `ulimit -f`) with SIGXFSZ ignored, so a write past the limit fails with EFBIG
// as a full disk fails with ENOSPC: the save must fail with an error naming the file, and the map
// saved before must stay loadable and unchanged, with no temporary file left behind.
constexpr const char* kDiskFullEnv = "NERFSLAM_TEST_MAP_DISK_FULL";

TEST(MapStoreDiskFullHelper, SaveOnceChild) {
  const char* env = std::getenv(kDiskFullEnv);
  if (!env) GTEST_SKIP() << "helper process of MapStore.SaveIntoAFullDiskFailsAndKeepsThePreviousMap";
  std::signal(SIGXFSZ, SIG_IGN);
  const std::string arg(env);
  const fs::path src = arg.substr(0, arg.find('|')), dst = arg.substr(arg.find('|') + 1);
  LoadedMap b = loadMapFolder(src);
  makeVariantB(*b.map);
  try {
    saveMapFolder(dst, *b.map, b.camera, b.options);
  } catch (const Error& e) {
    std::printf("save failed: %s\n", e.what());
    std::fflush(stdout);
    std::_Exit(3);
  }
  std::printf("save succeeded\n");
  std::fflush(stdout);
  std::_Exit(0);
}

TEST(MapStore, SaveIntoAFullDiskFailsAndKeepsThePreviousMap) {
  test::TempDir tmp;
  Camera cam;
  {
    const auto map = makeSmallMap(6, 320, 240, &cam);
    saveMapFolder(tmp / "src", *map, cam, sparseOptions());
  }
  LoadedMap a = loadMapFolder(tmp / "src");
  const std::string fa = fingerprint(*a.map);
  const fs::path self = fs::read_symlink("/proc/self/exe");
  // Into an empty folder (every file new; measured: the first keyframe image fails) and over the
  // previous map (images reused; the keyframes file fails), at limits of 4 and 256 KiB.
  for (const bool over_previous : {false, true})
    for (const int kib : {4, 256}) {
      const fs::path dst = tmp / fmt::format("dst_{}_{}", int(over_previous), kib);
      if (over_previous) saveMapFolder(dst, *a.map, a.camera, a.options);
      auto filesIn = [](const fs::path& d) { return fs::exists(d) ? folderFiles(d) : std::set<std::string>{}; };
      const auto before = filesIn(dst);
      const auto r = test::runCommand(fmt::format("ulimit -f {}; {}='{}|{}' '{}' --gtest_filter={}", kib, kDiskFullEnv,
                                                  (tmp / "src").string(), dst.string(), self.string(),
                                                  "MapStoreDiskFullHelper.SaveOnceChild"));
      ASSERT_EQ(r.exit_code, 3) << "the save into a full disk did not fail with an Error (" << kib
                                << " KiB): " << r.output;
      const auto pos = r.output.find("save failed: ");
      ASSERT_NE(pos, std::string::npos) << r.output;
      const std::string message = r.output.substr(pos, r.output.find('\n', pos) - pos);
      std::printf("%s, %d KiB: %s\n", over_previous ? "over the previous map" : "new folder", kib, message.c_str());
      EXPECT_NE(message.find(dst.string()), std::string::npos) << "the error does not name the file: " << message;
      const auto after = filesIn(dst);
      if (over_previous) {
        // Nothing half-written is left: the folder holds what it held before.
        EXPECT_EQ(after, before) << message;
      } else {
        // No manifest (so no map that could load half of it) and no temporary file.
        EXPECT_EQ(after.count("map.json"), 0u) << message;
        for (const auto& f : after) EXPECT_EQ(f.find(".tmp"), std::string::npos) << f;
        EXPECT_THROW(loadMapFolder(dst, cam), Error);
      }
      if (over_previous) {
        LoadedMap l;
        ASSERT_NO_THROW(l = loadMapFolder(dst, cam));
        EXPECT_EQ(fingerprint(*l.map), fa);
      }
    }
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
  eval::TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-3;
  const eval::TrajectoryReport map_fit = eval::evaluateTrajectory(
      readTumTrajectory(tmp / "seq" / "groundtruth.txt"), readTumTrajectory(tmp / "slam" / "trajectory.txt"), eo);
  Trajectory localized = readTumTrajectory(tmp / "loc" / "trajectory.txt");
  for (auto& e : localized) e.pose = map_fit.alignment.transformPose(e.pose);
  eo.align = "none";
  const eval::TrajectoryReport in_map = eval::evaluateTrajectory(gt, localized, eo);
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
