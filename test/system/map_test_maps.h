#pragma once
// Maps for the map store's tests (map_store_test, map_folder_test, map_codec_test,
// map_rebuild_test): a real SLAM map of the synthetic room, a small map built directly, a saved
// small map, and comparisons (exact equality, a fingerprint, the files of a folder).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "nerfslam/render/synth.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/slam_system.h"
#include "nerfslam/tracking/frame.h"
#include "test_support.h"

namespace nerfslam::maptest {
namespace fs = std::filesystem;
using nlohmann::json;

inline SystemOptions sparseOptions() {
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

inline SlamMap runSlamOnRoom(int frames, int width, int height) {
  SynthOptions so;
  so.scene = "room";
  so.trajectory = "handheld";
  so.frames = frames;
  so.width = width;
  so.height = height;
  so.textures = "procedural";
  SequenceRenderer seq(so);
  SlamMap m;
  m.camera = seq.camera();
  m.slam = std::make_unique<SlamSystem>(m.camera, m.options);
  for (int i = 0; i < frames; ++i) {
    const SynthFrame f = seq.render(i);
    m.slam->trackFrame(f.bgr, f.timestamp, static_cast<uint64_t>(i));
    m.slam->waitMappingIdle();
  }
  m.slam->finish(true);
  return m;
}

// A small map built directly (fast): keyframes at the ground-truth poses of rendered frames, points
// from descriptor matches between consecutive keyframes (positions arbitrary but finite), one
// keyframe and some points erased so ids have gaps as in a real map.
inline std::unique_ptr<Map> makeSmallMap(int keyframes, int width, int height, Camera* camera) {
  SynthOptions so;
  so.scene = "room";
  so.trajectory = "handheld";
  so.frames = keyframes * 4;
  so.width = width;
  so.height = height;
  so.textures = "procedural";
  SequenceRenderer seq(so);
  *camera = seq.camera();
  auto map = std::make_unique<Map>(*camera);
  FeatureOptions fo = systemTrackingDefaults().features;
  fo.max_features = 600;
  std::vector<KeyframeId> ids;
  for (int k = 0; k < keyframes; ++k) {
    const SynthFrame f = seq.render(4 * k);
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

// Keypoints `a` (every field) and their undistorted positions `ua` equal `b` and `ub`.
inline void expectSameKeypoints(const std::vector<cv::KeyPoint>& a, const std::vector<Eigen::Vector2d>& ua,
                                const std::vector<cv::KeyPoint>& b, const std::vector<Eigen::Vector2d>& ub) {
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(ua.size(), a.size());
  ASSERT_EQ(ub.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    const cv::KeyPoint &p = a[i], &q = b[i];
    ASSERT_TRUE(p.pt == q.pt && p.size == q.size && p.angle == q.angle && p.response == q.response &&
                p.octave == q.octave && p.class_id == q.class_id)
        << "keypoint " << i;
    ASSERT_EQ(ua[i], ub[i]) << "keypoint " << i;
  }
}

// Every stored field of map point `x` equals `y`'s.
inline void expectSamePoint(const MapPoint& x, const MapPoint& y) {
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

inline void expectSameMap(const Map& a, const Map& b) {
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
    expectSameKeypoints(f.keypoints, f.undistorted, g.keypoints, g.undistorted);
    if (::testing::Test::HasFatalFailure()) return;
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
    expectSamePoint(pa[i], pb[i]);
    if (::testing::Test::HasFatalFailure()) return;
  }
}

// A digest of everything saved (ids, poses, associations, points), for "is it map A or map B".
inline std::string fingerprint(const Map& m) {
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

inline json readJson(const fs::path& p) {
  std::ifstream in(p);
  EXPECT_TRUE(in.good()) << p;
  if (!in.good()) return {};
  return json::parse(in);
}

inline std::string fileOfRole(const fs::path& dir, const std::string& role) {
  const json manifest = readJson(dir / "map.json");
  for (const auto& f : manifest.at("files"))
    if (f.at("role") == role) return f.at("name").get<std::string>();
  return "";
}

inline std::set<std::string> folderFiles(const fs::path& dir) {
  std::set<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) out.insert(fs::relative(e.path(), dir).generic_string());
  return out;
}

// A small map saved into a fresh folder `dir`.
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

// Map B of the kill and disk-full tests (map A is the map as loaded): its newest keyframe removed and
// everything scaled (new poses, points and an image to write again when A follows B).
inline void makeVariantB(Map& m) {
  m.eraseKeyframe(*m.lastKeyframeId(), m.keyframeIds().front());
  m.transform(Sim3(1.5, SE3()));
}

}  // namespace nerfslam::maptest
