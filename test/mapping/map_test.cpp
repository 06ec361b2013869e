#include "nerfslam/mapping/map.h"

#include <gtest/gtest.h>

#include <atomic>
#include <map>
#include <random>
#include <thread>

namespace nerfslam {
namespace {

std::shared_ptr<Frame> makeFrame(int n, uint32_t seed) {
  auto f = std::make_shared<Frame>();
  std::mt19937 rng(seed);
  f->descriptors = cv::Mat(n, 32, CV_8U);
  cv::randu(f->descriptors, 0, 256);
  for (int i = 0; i < n; ++i) {
    f->keypoints.emplace_back(cv::Point2f(float(i), float(i)), 7.f);
    f->undistorted.emplace_back(i, i);
  }
  return f;
}

Keyframe makeKf(int n, uint32_t seed, const Eigen::Vector3d& centre = Eigen::Vector3d::Zero()) {
  Keyframe kf;
  kf.frame = makeFrame(n, seed);
  kf.T_world_cam = SE3(Eigen::Matrix3d::Identity(), centre);
  return kf;
}

TEST(Map, ObservationsCovisibilityAndErasure) {
  Map map;
  const KeyframeId a = map.addKeyframe(makeKf(10, 1));
  const KeyframeId b = map.addKeyframe(makeKf(10, 2, {1, 0, 0}));
  const KeyframeId c = map.addKeyframe(makeKf(10, 3, {2, 0, 0}));
  EXPECT_TRUE(map.keyframe(a)->fixed);
  EXPECT_FALSE(map.keyframe(b)->fixed);
  std::vector<PointId> ab, abc;
  for (int i = 0; i < 5; ++i) ab.push_back(map.addPoint(Eigen::Vector3d(i, 0, 5), {{a, i}, {b, i}}));
  for (int i = 5; i < 8; ++i) abc.push_back(map.addPoint(Eigen::Vector3d(i, 0, 5), {{a, i}, {b, i}, {c, i}}));
  EXPECT_EQ(map.numPoints(), 8u);
  // A keypoint already associated cannot take a second point.
  EXPECT_EQ(map.addPoint(Eigen::Vector3d(0, 0, 1), {{a, 0}, {c, 9}}), kNoPoint);
  auto cov = map.covisibleKeyframes(a);
  ASSERT_EQ(cov.size(), 2u);
  EXPECT_EQ(cov[0], std::make_pair(b, 8));
  EXPECT_EQ(cov[1], std::make_pair(c, 3));
  EXPECT_EQ(map.covisibleKeyframes(a, 4).size(), 1u);
  EXPECT_EQ(map.keyframe(a)->numTrackedPoints(), 8);
  // Descriptor is one of the observing keypoints' descriptors.
  const MapPoint p = *map.point(ab[0]);
  const cv::Mat da = map.keyframe(a)->frame->descriptors.row(0), db = map.keyframe(b)->frame->descriptors.row(0);
  EXPECT_TRUE(cv::norm(p.descriptor, da, cv::NORM_HAMMING) == 0 || cv::norm(p.descriptor, db, cv::NORM_HAMMING) == 0);
  EXPECT_NEAR(p.normal.norm(), 1.0, 1e-12);
  // Erasing one of two observations removes the point and frees the other keypoint.
  map.eraseObservation(ab[0], a);
  EXPECT_FALSE(map.point(ab[0]));
  EXPECT_EQ(map.keyframe(b)->points[0], kNoPoint);
  // Erasing keyframe c leaves the abc points with 2 observations.
  map.eraseKeyframe(c);
  EXPECT_EQ(map.numKeyframes(), 2u);
  EXPECT_EQ(map.point(abc[0])->observations.size(), 2u);
  // Erasing b removes every remaining point (each left with one observation).
  map.eraseKeyframe(b);
  EXPECT_EQ(map.numPoints(), 0u);
  EXPECT_EQ(map.keyframe(a)->numTrackedPoints(), 0);
}

TEST(Map, FuseMergesObservations) {
  Map map;
  const KeyframeId a = map.addKeyframe(makeKf(4, 1));
  const KeyframeId b = map.addKeyframe(makeKf(4, 2));
  const KeyframeId c = map.addKeyframe(makeKf(4, 3));
  const PointId p = map.addPoint({0, 0, 5}, {{a, 0}, {b, 0}});
  const PointId q = map.addPoint({0, 0, 5.1}, {{b, 1}, {c, 1}});
  map.fusePoints(q, p);
  EXPECT_FALSE(map.point(q));
  const auto obs = map.point(p)->observations;
  EXPECT_EQ(obs.size(), 3u);
  EXPECT_EQ(obs.at(c), 1);
  EXPECT_EQ(map.keyframe(b)->points[1], kNoPoint);  // b already observed p at keypoint 0
  EXPECT_EQ(map.keyframe(c)->points[1], p);
}

TEST(Map, ApplyUpdateIsAtomicForReaders) {
  // A writer moves all keyframes and points by the same offset in one update; readers must always
  // see keyframes and points consistent (same offset) — never a half-applied update.
  Map map;
  std::vector<KeyframeId> kfs;
  for (int i = 0; i < 5; ++i) kfs.push_back(map.addKeyframe(makeKf(20, i, {double(i), 0, 0})));
  std::vector<PointId> pts;
  for (int j = 0; j < 20; ++j) pts.push_back(map.addPoint({double(j), 0, 10}, {{kfs[0], j}, {kfs[1], j}}));
  std::atomic<bool> stop{false};
  std::atomic<int> inconsistent{0}, reads{0};
  auto reader = [&] {
    while (!stop) {
      const auto ks = map.keyframes();
      // Keyframe 1..4 centres are i + offset; all share one offset.
      const double off = ks[1].centre().x() - 1.0;
      for (size_t i = 2; i < ks.size(); ++i)
        if (std::abs(ks[i].centre().x() - double(i) - off) > 1e-9) ++inconsistent;
      const auto ps = map.points();
      for (const auto& p : ps) (void)p.position;
      ++reads;
      std::this_thread::yield();
    }
  };
  std::thread r1(reader), r2(reader);
  while (reads.load() == 0) std::this_thread::yield();
  int it = 1;
  for (; it <= 300 || reads.load() < 20; ++it) {
    MapUpdate u;
    for (int i = 1; i < 5; ++i)
      u.keyframe_poses.emplace_back(kfs[i], SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(i + it, 0, 0)));
    for (int j = 0; j < 20; ++j) u.point_positions.emplace_back(pts[j], Eigen::Vector3d(j + it, 0, 10));
    map.applyUpdate(u);
    map.increaseVisible(pts);
  }
  stop = true;
  r1.join();
  r2.join();
  EXPECT_EQ(inconsistent.load(), 0);
  EXPECT_GE(reads.load(), 20);
  const int last = it - 1;
  // increaseVisible never waits: a call that finds a reader holding the lock queues its ids, counted
  // at the next call that gets the lock. Count what the last calls may have queued.
  map.flushTrackingStatistics();
  EXPECT_TRUE(map.keyframe(kfs[0])->centre().isZero());  // fixed gauge keyframe never moves
  EXPECT_DOUBLE_EQ(map.keyframe(kfs[4])->centre().x(), 4.0 + last);
  EXPECT_EQ(map.point(pts[0])->visible, 1 + last);
}

TEST(Map, ConcurrentInsertAndEraseKeepInvariants) {
  Map map;
  const KeyframeId base = map.addKeyframe(makeKf(500, 0));
  std::atomic<bool> stop{false};
  std::atomic<bool> reading{false};
  std::thread writer([&] {
    // Under a loaded CI machine the writer could finish before the reader first looked; start only
    // once the reader is in its loop, so that the reads do overlap the writes.
    while (!reading) std::this_thread::yield();
    std::mt19937 rng(4);
    for (int it = 0; it < 200; ++it) {
      const KeyframeId k = map.addKeyframe(makeKf(50, it + 1));
      for (int j = 0; j < 20; ++j) map.addPoint({0, 0, 1.0 + j}, {{base, int(rng() % 500)}, {k, j}});
      if (it % 3 == 2) map.eraseKeyframe(k);
    }
    stop = true;
  });
  int checks = 0;
  do {
    reading = true;
    // Every point referenced by a keyframe exists and lists that keyframe at that keypoint.
    for (const Keyframe& kf : map.keyframes()) {
      for (size_t i = 0; i < kf.points.size(); ++i) {
        if (kf.points[i] == kNoPoint) continue;
        (void)map.point(kf.points[i]);  // may have been erased since the copy: only must not crash
      }
    }
    for (const MapPoint& p : map.points()) EXPECT_GE(p.observations.size(), 1u);
    ++checks;
  } while (!stop);
  writer.join();
  // Final state is consistent.
  for (const Keyframe& kf : map.keyframes())
    for (size_t i = 0; i < kf.points.size(); ++i)
      if (kf.points[i] != kNoPoint) {
        const auto p = map.point(kf.points[i]);
        ASSERT_TRUE(p);
        EXPECT_EQ(p->observations.at(kf.id), int(i));
      }
  for (const MapPoint& p : map.points()) EXPECT_GE(p.observations.size(), 2u);
  EXPECT_GT(checks, 0);
}

// A point's descriptor is the medoid of its observations: the observed descriptor with the least
// median Hamming distance to the others (reference computed here with cv::norm), for 2 to 9
// observations.
TEST(Map, DescriptorIsTheHammingMedoid) {
  for (int n_obs = 2; n_obs <= 9; ++n_obs) {
    Map map;
    std::vector<KeyframeId> kfs;
    for (int k = 0; k < n_obs; ++k) kfs.push_back(map.addKeyframe(makeKf(4, 100 * n_obs + k)));
    std::map<KeyframeId, int> obs;
    for (KeyframeId k : kfs) obs[k] = 2;
    const PointId pid = map.addPoint(Eigen::Vector3d(0, 0, 5), obs);
    ASSERT_NE(pid, kNoPoint);
    std::vector<cv::Mat> d;
    for (KeyframeId k : kfs) d.push_back(map.keyframe(k)->frame->descriptors.row(2));
    int best_median = 1 << 30;
    cv::Mat expected;
    for (size_t i = 0; i < d.size(); ++i) {
      std::vector<int> dist;
      for (size_t j = 0; j < d.size(); ++j) dist.push_back(static_cast<int>(cv::norm(d[i], d[j], cv::NORM_HAMMING)));
      std::nth_element(dist.begin(), dist.begin() + dist.size() / 2, dist.end());
      if (dist[dist.size() / 2] < best_median) {
        best_median = dist[dist.size() / 2];
        expected = d[i];
      }
    }
    EXPECT_EQ(cv::norm(map.point(pid)->descriptor, expected, cv::NORM_HAMMING), 0) << n_obs << " observations";
  }
}

// Lock statistics count the calling thread's acquisitions; an uncontended lock never waits.
TEST(Map, ThreadLockWaitCountsAcquisitions) {
  Map map;
  map.addKeyframe(makeKf(4, 1));
  Map::resetThreadLockWait();
  EXPECT_EQ(Map::threadLockWait().acquisitions, 0u);
  for (int i = 0; i < 3; ++i) EXPECT_EQ(map.numKeyframes(), 1u);
  const MapLockWait w = Map::threadLockWait();
  EXPECT_EQ(w.acquisitions, 3u);
  EXPECT_EQ(w.contended, 0u);
  EXPECT_EQ(w.max_ms, 0.0);
  // Another thread's acquisitions are not counted here.
  std::thread([&] { EXPECT_EQ(map.numPoints(), 0u); }).join();
  EXPECT_EQ(Map::threadLockWait().acquisitions, 3u);
}

// Relocalisation's input: per keyframe (in the given order, the first max_candidates still in the map) its points.
TEST(Map, RelocalisationInputsFollowThePointsAndKeyframes) {
  Map map;
  const KeyframeId a = map.addKeyframe(makeKf(6, 1));
  const KeyframeId b = map.addKeyframe(makeKf(6, 2, {1, 0, 0}));
  const KeyframeId c = map.addKeyframe(makeKf(6, 3, {2, 0, 0}));
  map.addPoint({0, 0, 5}, {{a, 0}, {b, 0}});
  const PointId p1 = map.addPoint({1, 0, 5}, {{a, 1}, {c, 1}});
  const PointId p2 = map.addPoint({2, 0, 5}, {{a, 4}, {b, 3}, {c, 2}});
  const KeyframeId d = map.addKeyframe(makeKf(6, 4, {3, 0, 0}));
  const PointId p3 = map.addPoint({3, 0, 5}, {{a, 5}, {d, 5}});  // a's, not c's
  map.eraseKeyframe(b);                                          // p0 goes with it (one observation left)
  const auto cands = map.relocalizationCandidates({c, b, a}, 5);
  ASSERT_EQ(cands.size(), 2u);  // b is gone
  EXPECT_EQ(cands[0].keyframe_id, static_cast<uint64_t>(c));
  EXPECT_EQ(cands[1].keyframe_id, static_cast<uint64_t>(a));
  EXPECT_TRUE(cands[0].T_world_cam.translation().isApprox(Eigen::Vector3d(2, 0, 0)));
  ASSERT_EQ(cands[0].points.size(), 2u);  // keypoint order: p1 (keypoint 1), p2 (keypoint 2)
  EXPECT_EQ(cands[0].points[0].id, static_cast<uint64_t>(p1));
  EXPECT_EQ(cands[0].points[1].id, static_cast<uint64_t>(p2));
  EXPECT_TRUE(cands[0].points[1].p_world.isApprox(Eigen::Vector3d(2, 0, 5)));
  EXPECT_EQ(cv::norm(cands[0].points[1].descriptor, map.point(p2)->descriptor, cv::NORM_HAMMING), 0);
  ASSERT_EQ(cands[1].points.size(), 3u);
  EXPECT_EQ(cands[1].points[0].id, static_cast<uint64_t>(p1));
  EXPECT_EQ(cands[1].points[1].id, static_cast<uint64_t>(p2));
  EXPECT_EQ(cands[1].points[2].id, static_cast<uint64_t>(p3));
  // The neighbours: the points of the covisible keyframes the candidate does not see itself (c's
  // covisible keyframe is a, which also sees p3; a's are c and d, which see nothing a does not).
  ASSERT_EQ(cands[0].neighbours.size(), 1u);
  EXPECT_EQ(cands[0].neighbours[0].id, static_cast<uint64_t>(p3));
  EXPECT_TRUE(cands[1].neighbours.empty());
  EXPECT_TRUE(map.relocalizationCandidates({c}, 1, 0)[0].neighbours.empty());
  // At most max_candidates of them.
  const auto one = map.relocalizationCandidates({b, a, c}, 1);
  ASSERT_EQ(one.size(), 1u);
  EXPECT_EQ(one[0].keyframe_id, static_cast<uint64_t>(a));
}

}  // namespace
}  // namespace nerfslam
