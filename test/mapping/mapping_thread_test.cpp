#include "nerfslam/mapping/mapping_thread.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <vector>

namespace nerfslam {
namespace {

std::shared_ptr<const Frame> syntheticFrame(int n, uint64_t id) {
  auto f = std::make_shared<Frame>();
  f->id = id;
  f->timestamp = 0.1 * id;
  f->camera = Camera::pinhole(640, 480, 500, 500, 319.5, 239.5);
  f->level_scale = {1.0};
  f->descriptors = cv::Mat(n, 32, CV_8U);
  cv::randu(f->descriptors, 0, 256);
  for (int i = 0; i < n; ++i) {
    f->keypoints.emplace_back(cv::Point2f(float(10 + i % 600), float(10 + i / 600 * 20)), 7.f, 0.f, 0.f, 0);
    f->undistorted.emplace_back(f->keypoints.back().pt.x, f->keypoints.back().pt.y);
  }
  return f;
}

TEST(KeyframeBus, EverySubscriberGetsEventsWithItsOwnPolicy) {
  KeyframeBus bus;
  auto all = bus.subscribe(100);
  auto latest = bus.subscribe(2, OverflowPolicy::kDropOldest);
  auto first = bus.subscribe(2, OverflowPolicy::kDropNewest);
  for (int i = 0; i < 10; ++i) bus.publish({i, SE3(), nullptr});
  EXPECT_EQ(all->size(), 10u);
  EXPECT_EQ(latest->dropped(), 8u);
  EXPECT_EQ(latest->pop()->id, 8);
  EXPECT_EQ(first->pop()->id, 0);
  bus.unsubscribe(first);
  EXPECT_EQ(bus.numSubscribers(), 2u);
  bus.close();
  EXPECT_EQ(latest->pop()->id, 9);
  EXPECT_FALSE(latest->pop());
}

TEST(MappingThread, SubmitNeverBlocksAndCountsDrops) {
  Map map;
  MappingThread mt(map, {}, 2);
  auto sub = mt.bus().subscribe(1000);
  const int n = 40;
  std::vector<KeyframeInsertion> ins(n);
  for (int i = 0; i < n; ++i) {
    ins[i].frame = syntheticFrame(300, i);
    ins[i].T_world_cam = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.1 * i, 0, 0));
  }
  // Submitted before the thread starts, so nothing is consumed: the queue of 2 fills, and every
  // further submit must come back at once with the keyframe dropped (a submit that waited for room
  // would hang here). Deterministic, unlike racing a running consumer, which can keep up with these
  // featureless keyframes (40 of 40 accepted in one run).
  int accepted = 0;
  for (auto& k : ins) accepted += mt.submit(std::move(k));
  EXPECT_EQ(accepted, 2);
  EXPECT_EQ(mt.droppedKeyframes(), static_cast<uint64_t>(n - 2));
  mt.start();
  mt.waitIdle();
  EXPECT_TRUE(mt.idle());
  mt.stop();
  EXPECT_EQ(static_cast<uint64_t>(accepted) + mt.droppedKeyframes(), static_cast<uint64_t>(n));
  EXPECT_EQ(map.numKeyframes(), static_cast<size_t>(accepted));
  EXPECT_EQ(mt.stats().size(), static_cast<size_t>(accepted));
  EXPECT_EQ(sub->size(), static_cast<size_t>(accepted));
  EXPECT_TRUE(map.keyframe(map.keyframeIds().front())->fixed);
  // After stop, submit is refused instead of blocking.
  KeyframeInsertion late;
  late.frame = syntheticFrame(10, 99);
  EXPECT_FALSE(mt.submit(std::move(late)));
}

}  // namespace
}  // namespace nerfslam
