// LoopClosing (mapping/loop_closing.h) on a map built by hand: a wall of 300 points seen by six
// keyframes (the first lap), and the same place mapped again by six more keyframes with their own
// copies of the points, drifted by a known similarity (the second lap: scale 0.8, 3 degrees, 0.5 m).
// Every keypoint sits at its point's exact projection and a point's two copies share their
// descriptor, as a revisit of the same texture does. Detection must wait for the consistency (the
// third second-lap keyframe), find the right keyframe and the drift's scale; the correction must
// bring the second lap back onto the first and fuse the duplicated points.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <map>
#include <memory>
#include <random>
#include <thread>
#include <vector>

#include "nerfslam/mapping/local_mapper.h"
#include "nerfslam/mapping/loop_closing.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/mapping/mapping_thread.h"
#include "nerfslam/tracking/vocabulary.h"
#include "test_support.h"

namespace nerfslam {
namespace {

constexpr int kPoints = 300;
constexpr int kKeyframesPerLap = 6;

struct Scene {
  Camera camera = Camera::pinhole(640, 480, 500, 500, 319.5, 239.5);
  std::vector<Eigen::Vector3d> points;  // ground truth
  cv::Mat descriptors;                  // one per point
  std::vector<SE3> poses;               // ground truth of one lap's keyframes
};

Scene makeScene() {
  Scene s;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> ux(-2.5, 2.5), uy(-1.8, 1.8), uz(4.0, 6.0);
  std::uniform_int_distribution<int> byte(0, 255);
  s.descriptors = cv::Mat(kPoints, 32, CV_8U);
  for (int i = 0; i < kPoints; ++i) {
    s.points.emplace_back(ux(rng), uy(rng), uz(rng));
    for (int b = 0; b < 32; ++b) s.descriptors.at<uint8_t>(i, b) = static_cast<uint8_t>(byte(rng));
  }
  for (int k = 0; k < kKeyframesPerLap; ++k) {
    const double a = (k - 2.5) * 0.02;  // a slow pan while moving sideways
    const Eigen::Quaterniond q(Eigen::AngleAxisd(a, Eigen::Vector3d::UnitY()));
    s.poses.emplace_back(q, Eigen::Vector3d(0.12 * (k - 2.5), 0.0, 0.0));
  }
  return s;
}

// Adds one lap: keyframes at drift * truth, observing copies of the points at drift * truth.
// Returns the keyframe ids.
std::vector<KeyframeId> addLap(Map& map, const Scene& s, const Sim3& drift, uint64_t first_frame) {
  std::vector<KeyframeId> ids;
  std::vector<std::map<KeyframeId, int>> obs(kPoints);
  for (int k = 0; k < kKeyframesPerLap; ++k) {
    auto f = std::make_shared<Frame>();
    f->id = first_frame + k;
    f->timestamp = double(f->id);
    f->camera = s.camera;
    f->level_scale = {1.0, 1.2, 1.44, 1.728};
    const SE3 T_cw = s.poses[k].inverse();
    std::vector<int> rows;
    for (int i = 0; i < kPoints; ++i) {
      Eigen::Vector2d uv;
      if (!s.camera.projectInImage(T_cw * s.points[i], &uv, 2.0)) continue;
      f->keypoints.emplace_back(cv::Point2f(float(uv.x()), float(uv.y())), 31.f, 0.f, 1.f, 0);
      f->undistorted.push_back(uv);
      rows.push_back(i);
    }
    f->descriptors = cv::Mat(static_cast<int>(rows.size()), 32, CV_8U);
    for (size_t r = 0; r < rows.size(); ++r) s.descriptors.row(rows[r]).copyTo(f->descriptors.row(int(r)));
    f->buildGrid();
    Keyframe kf;
    kf.frame = f;
    kf.T_world_cam = drift.transformPose(s.poses[k]);
    const KeyframeId id = map.addKeyframe(kf);
    ids.push_back(id);
    for (size_t r = 0; r < rows.size(); ++r) obs[rows[r]][id] = static_cast<int>(r);
  }
  for (int i = 0; i < kPoints; ++i) map.addPoint(drift * s.points[i], obs[i]);
  return ids;
}

// The second lap's drift of the header: scale 0.8, 3 degrees about z, 0.5 m.
Sim3 secondLapDrift() {
  return Sim3(0.8, Eigen::Quaterniond(Eigen::AngleAxisd(3.0 * M_PI / 180, Eigen::Vector3d::UnitZ())),
              Eigen::Vector3d(0.5, -0.1, 0.2));
}

TEST(LoopClosingMap, DetectsTheRevisitAfterThreeKeyframesAndCorrectsTheDrift) {
  const Scene s = makeScene();
  Map map(s.camera);
  const Sim3 drift = secondLapDrift();
  const auto lap1 = addLap(map, s, Sim3(), 0);
  const auto lap2 = addLap(map, s, drift, 100);
  ASSERT_EQ(map.numPoints(), std::size_t(2 * kPoints));
  // The two laps share no point: they are not covisible.
  EXPECT_TRUE(map.covisibleKeyframes(lap2[0]).size() == kKeyframesPerLap - 1);

  LoopClosingOptions o;
  o.min_keyframes = 2;
  o.min_keyframe_gap = 0;
  auto voc = std::make_shared<const Vocabulary>(loadVocabulary(vocabularyPath("")));
  LoopClosing lc(map, nullptr, voc, o);
  std::optional<LoopCandidate> loop;
  int fed = 0;
  for (KeyframeId id : map.keyframeIds()) {
    loop = lc.detect(id);
    ++fed;
    if (loop) break;
  }
  ASSERT_TRUE(loop.has_value());
  // Consistency: the first lap is a candidate from the second lap's first keyframe on, accepted at
  // its third.
  EXPECT_EQ(fed, kKeyframesPerLap + o.consistency);
  EXPECT_EQ(loop->current, lap2[o.consistency - 1]);
  // The same view in the first lap (identical descriptors: the best score).
  EXPECT_EQ(loop->loop, lap1[o.consistency - 1]);
  // p_current = S p_loop: the drift's scale, and no rotation between the two same views' cameras.
  EXPECT_NEAR(loop->S_cur_loop.scale(), 0.8, 0.01);
  EXPECT_LT(loop->S_cur_loop.rotation().angularDistance(Eigen::Quaterniond::Identity()) * 180 / M_PI, 0.5);
  EXPECT_GE(static_cast<int>(loop->matches.size()), o.min_projection_matches);

  LoopClosureRecord rec;
  ASSERT_TRUE(lc.correct(*loop, &rec));
  EXPECT_NEAR(rec.sim3_scale, 0.8, 0.01);
  EXPECT_GT(rec.correction_m, 0.3);
  // The second lap is back on the first (the loop keyframe, on the first lap, is fixed), and its
  // points were fused into the first lap's. Not exactly: here the whole drift sits on one edge of
  // the essential graph (the last keyframe of the first lap to the first of the second, measured
  // before the correction), which keeps a share of it (measured: 7 cm at most, 0.53-0.59 m before).
  for (int k = 0; k < kKeyframesPerLap; ++k) {
    const auto kf = map.keyframe(lap2[k]);
    ASSERT_TRUE(kf);
    const double before = (drift * s.poses[k].translation() - s.poses[k].translation()).norm();
    const double after = (kf->centre() - s.poses[k].translation()).norm();
    EXPECT_LT(after, 0.2 * before) << "keyframe " << k << ": " << before << " -> " << after;
    EXPECT_LT(kf->T_world_cam.rotation().angularDistance(s.poses[k].rotation()) * 180 / M_PI, 1.0);
    const auto first = map.keyframe(lap1[k]);
    EXPECT_LT((first->centre() - s.poses[k].translation()).norm(), 0.1);
  }
  EXPECT_NEAR((map.keyframe(loop->loop)->centre() - s.poses[o.consistency - 1].translation()).norm(), 0.0, 1e-9);
  EXPECT_GT(rec.fused_points, kPoints / 2);
  EXPECT_LT(map.numPoints(), std::size_t(kPoints + kPoints / 4));
  // The two laps now share points.
  bool shares = false;
  for (const auto& [k, w] : map.covisibleKeyframes(lap2[0])) shares |= k == lap1[0] && w > 50;
  EXPECT_TRUE(shares);
  // What the tracking thread takes: one correction, a similarity for every keyframe.
  uint64_t seen = 0;
  std::map<KeyframeId, Sim3> delta;
  ASSERT_TRUE(lc.correctionsSince(&seen, &delta));
  EXPECT_EQ(delta.size(), map.numKeyframes());
  EXPECT_NEAR(delta.at(lap2[0]).scale(), 1.0 / 0.8, 0.05);
  EXPECT_NEAR(delta.at(loop->loop).scale(), 1.0, 1e-9);
}

// The global BA after the closure: the share of the drift the essential graph kept goes (every
// keypoint sits at its point's exact projection), measured on the second lap's keyframe centres.
double maxCentreError(const Map& map, const Scene& s, const std::vector<KeyframeId>& lap) {
  double e = 0;
  for (int k = 0; k < kKeyframesPerLap; ++k)
    e = std::max(e, (map.keyframe(lap[k])->centre() - s.poses[k].translation()).norm());
  return e;
}

std::optional<LoopCandidate> firstLoop(LoopClosing& lc, const Map& map) {
  for (KeyframeId id : map.keyframeIds())
    if (auto loop = lc.detect(id)) return loop;
  return std::nullopt;
}

// Two laps of the scene, the second drifted by secondLapDrift(), and a loop closing over the map.
struct TwoLaps {
  Scene s = makeScene();
  Map map{s.camera};
  std::vector<KeyframeId> lap2;
  std::unique_ptr<LoopClosing> lc;
  TwoLaps() {
    addLap(map, s, Sim3(), 0);
    lap2 = addLap(map, s, secondLapDrift(), 100);
    LoopClosingOptions o;
    o.min_keyframes = 2;
    o.min_keyframe_gap = 0;
    lc = std::make_unique<LoopClosing>(map, nullptr,
                                       std::make_shared<const Vocabulary>(loadVocabulary(vocabularyPath(""))), o);
  }
  // The first loop found, corrected by the essential graph.
  bool closeFirstLoop() {
    const auto loop = firstLoop(*lc, map);
    return loop.has_value() && lc->correct(*loop);
  }
};

TEST(LoopClosingMap, GlobalBaAfterTheClosureRemovesTheDriftTheGraphKept) {
  TwoLaps t;
  ASSERT_TRUE(t.closeFirstLoop());
  const Scene& s = t.s;
  Map& map = t.map;
  const auto& lap2 = t.lap2;
  LoopClosing& lc = *t.lc;
  const double after_graph = maxCentreError(map, s, lap2);
  GlobalBaRecord g;
  ASSERT_TRUE(lc.runGlobalBa(&g));
  const double after_ba = maxCentreError(map, s, lap2);
  std::printf("second lap's largest keyframe error: %.4f after the essential graph, %.4f after the global BA\n",
              after_graph, after_ba);
  EXPECT_GT(after_graph, 0.01);
  EXPECT_LT(after_ba, 0.25 * after_graph);
  EXPECT_FALSE(g.stopped);
  EXPECT_EQ(g.closure, 0);
  EXPECT_EQ(g.keyframes, int(map.numKeyframes()) - 1);  // the first keyframe is fixed
  EXPECT_EQ(g.points, int(map.numPoints()));
  EXPECT_LT(g.rmse_after_px, g.rmse_before_px);
  EXPECT_EQ(g.propagated_keyframes, 0);
  ASSERT_EQ(lc.globalBas().size(), 1u);
}

// The global BA on a map without drift (one lap, every keypoint at its point's exact projection,
// the first keyframe the gauge) leaves it where it is: a converged BA moves a map only by what its
// observations disagree with (a bias in them, as the pyramid levels' keypoints had, shows as a move).
TEST(LoopClosingMap, GlobalBaLeavesADriftFreeMapWhereItIs) {
  const Scene s = makeScene();
  Map map(s.camera);
  const auto lap = addLap(map, s, Sim3(), 0);
  LoopClosing lc(map, nullptr, std::make_shared<const Vocabulary>(loadVocabulary(vocabularyPath(""))),
                 LoopClosingOptions{});
  std::map<PointId, Eigen::Vector3d> before;
  for (const MapPoint& p : map.points()) before[p.id] = p.position;
  GlobalBaRecord g;
  ASSERT_TRUE(lc.runGlobalBa(&g));
  EXPECT_EQ(g.keyframes, kKeyframesPerLap - 1);
  EXPECT_EQ(g.outliers, 0);
  EXPECT_LT(g.rmse_after_px, 1e-6);
  for (int k = 0; k < kKeyframesPerLap; ++k) {
    const auto kf = map.keyframe(lap[k]);
    EXPECT_LT((kf->centre() - s.poses[k].translation()).norm(), 1e-6) << "keyframe " << k;
    EXPECT_LT(kf->T_world_cam.rotation().angularDistance(s.poses[k].rotation()), 1e-8) << "keyframe " << k;
  }
  ASSERT_EQ(map.numPoints(), before.size());
  for (const MapPoint& p : map.points()) EXPECT_LT((p.position - before.at(p.id)).norm(), 1e-5);
}

// What the mapping thread made while the global BA was solving: a keyframe keeps its pose relative
// to its parent (the adjusted keyframe it shares the most points with), a point its position in its
// reference keyframe's camera.
TEST(LoopClosingMap, GlobalBaMovesWhatWasMadeMeanwhileWithItsParent) {
  TwoLaps t;
  ASSERT_TRUE(t.closeFirstLoop());
  Map& map = t.map;
  const auto& lap2 = t.lap2;
  LoopClosing& lc = *t.lc;
  LocalMapper mapper(map, MappingOptions{});
  MapUpdate solution;
  mapper.solveGlobalBundleAdjustment(10, {}, &solution);
  ASSERT_FALSE(solution.keyframe_poses.empty());
  // Made meanwhile: two keyframes beside the last one, each sharing 40 of its points, and a point
  // the two of them observe at a keypoint of their own.
  const KeyframeId parent = lap2.back();
  const Keyframe pk = *map.keyframe(parent);
  const int extra = static_cast<int>(pk.frame->size());
  const auto makeChild = [&](double dx) {
    auto f = std::make_shared<Frame>(*pk.frame);
    f->id += 500;
    f->keypoints.emplace_back(cv::Point2f(320.f, 240.f), 31.f, 0.f, 1.f, 0);
    f->undistorted.emplace_back(320.0, 240.0);
    cv::Mat d = f->descriptors.clone();
    d.push_back(cv::Mat(1, 32, CV_8U, cv::Scalar(7)));
    f->descriptors = d;
    f->buildGrid();
    Keyframe nk;
    nk.frame = f;
    nk.T_world_cam = pk.T_world_cam * SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(dx, 0, 0));
    const KeyframeId id = map.addKeyframe(nk);
    int shared = 0;
    for (size_t i = 0; i < pk.points.size() && shared < 40; ++i)
      if (pk.points[i] != kNoPoint) shared += map.addObservation(pk.points[i], id, int(i));
    EXPECT_EQ(shared, 40);
    return std::make_pair(id, nk.T_world_cam);
  };
  const auto [child, T_child] = makeChild(0.05);
  const auto [child2, T_child2] = makeChild(0.10);
  const Eigen::Vector3d p_new = T_child * Eigen::Vector3d(0.1, 0.2, 5.0);
  const PointId np = map.addPoint(p_new, {{child, extra}, {child2, extra}});
  ASSERT_NE(np, kNoPoint);
  const SE3 rel_before = pk.T_world_cam.inverse() * T_child;
  const SE3 rel2_before = pk.T_world_cam.inverse() * T_child2;

  GlobalBaRecord g;
  lc.writeGlobalBa(solution, &g);
  EXPECT_EQ(g.propagated_keyframes, 2);
  EXPECT_EQ(g.propagated_points, 1);
  const Keyframe pk2 = *map.keyframe(parent), ck2 = *map.keyframe(child);
  const auto solved = std::find_if(solution.keyframe_poses.begin(), solution.keyframe_poses.end(),
                                   [&](const auto& kp) { return kp.first == parent; });
  ASSERT_NE(solved, solution.keyframe_poses.end());
  EXPECT_LT((pk2.centre() - solved->second.translation()).norm(), 1e-9);  // the parent: the solution's pose
  EXPECT_GT((pk2.centre() - pk.centre()).norm(), 1e-4);                   // which moved it
  const SE3 rel_after = pk2.T_world_cam.inverse() * ck2.T_world_cam;
  EXPECT_LT((rel_after.translation() - rel_before.translation()).norm(), 1e-9);
  EXPECT_LT(rel_after.rotation().angularDistance(rel_before.rotation()), 1e-9);
  const SE3 rel2_after = pk2.T_world_cam.inverse() * map.keyframe(child2)->T_world_cam;
  EXPECT_LT((rel2_after.translation() - rel2_before.translation()).norm(), 1e-9);
  // The new point keeps its place in its reference keyframe's camera (its first observation).
  const MapPoint q = *map.point(np);
  ASSERT_EQ(q.observations.begin()->first, child);
  EXPECT_LT((ck2.T_world_cam.inverse() * q.position - T_child.inverse() * p_new).norm(), 1e-9);
}

// loop_closing.consistency counts: with 4, three second-lap keyframes finding the first lap are not
// enough, the fourth is.
TEST(LoopClosingMap, NoLoopBeforeTheConsistencyIsReached) {
  const Scene s = makeScene();
  Map map(s.camera);
  addLap(map, s, Sim3(), 0);
  const auto lap2 = addLap(map, s, Sim3(0.9, SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.3, 0, 0))), 100);
  LoopClosingOptions o;
  o.min_keyframes = 2;
  o.min_keyframe_gap = 0;
  o.consistency = 4;
  LoopClosing lc(map, nullptr, std::make_shared<const Vocabulary>(loadVocabulary(vocabularyPath(""))), o);
  int found_at = -1, fed = 0;
  for (KeyframeId id : map.keyframeIds()) {
    ++fed;
    if (lc.detect(id)) {
      found_at = fed;
      break;
    }
  }
  EXPECT_EQ(found_at, kKeyframesPerLap + 4);
  EXPECT_EQ(lc.corrections(), 0u);
  EXPECT_EQ(lc.database().size(), std::size_t(fed));
  (void)lap2;
}

// The thread: keyframes submitted as the mapping thread would, the mapping thread held while the
// map is corrected, a reader copying the map all along (as tracking does, never waiting).
TEST(LoopClosingMap, ThreadClosesTheLoopWhileTheMapIsRead) {
  const Scene s = makeScene();
  Map map(s.camera);
  const Sim3 drift = secondLapDrift();
  const auto lap1 = addLap(map, s, Sim3(), 0);
  const auto lap2 = addLap(map, s, drift, 100);
  MappingThread mapping(map, MappingOptions{});
  mapping.start();
  LoopClosingOptions o;
  o.min_keyframes = 2;
  o.min_keyframe_gap = 0;
  o.queue = 2 * kKeyframesPerLap;
  o.global_ba = true;  // the default; its thread is tested here
  LoopClosing lc(map, &mapping, std::make_shared<const Vocabulary>(loadVocabulary(vocabularyPath(""))), o);
  lc.start();
  std::atomic<bool> done{false};
  std::atomic<int> reads{0};
  std::thread reader([&] {
    TrackingLocalMap m;
    while (!done.load()) {
      if (map.localMapForTracking(lap2.back(), 10, &m, false)) reads.fetch_add(1);
      std::this_thread::yield();
    }
  });
  for (KeyframeId id : map.keyframeIds()) EXPECT_TRUE(lc.submit(id));
  lc.waitIdle();
  done = true;
  reader.join();
  lc.stop();
  mapping.stop();
  EXPECT_GT(reads.load(), 0);
  const auto closures = lc.closures();
  ASSERT_EQ(closures.size(), 1u);
  EXPECT_EQ(closures[0].current, lap2[o.consistency - 1]);
  EXPECT_EQ(closures[0].loop, lap1[o.consistency - 1]);
  EXPECT_EQ(lc.detectionTimes().size(), std::size_t(2 * kKeyframesPerLap));
  // The rest of the second lap came after the closure, within min_keyframe_gap 0: nothing more to close
  // (they now share the first lap's points).
  EXPECT_EQ(lc.corrections(), 1u);
  EXPECT_EQ(lc.droppedKeyframes(), 0u);
  EXPECT_LT((map.keyframe(lap2[0])->centre() - s.poses[0].translation()).norm(), 0.1);
  // The global BA after the closure ran on its own thread, and waitIdle() waited for it.
  const auto gbas = lc.globalBas();
  ASSERT_EQ(gbas.size(), 1u);
  EXPECT_FALSE(gbas[0].stopped);
  EXPECT_GT(gbas[0].keyframes, 0);
}

}  // namespace
}  // namespace nerfslam
