#include "nerfslam/mapping/mapping_thread.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <stdexcept>
#include <thread>
#include <vector>

#include "nerfslam/core/error.h"

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

// Work the tracking thread hands off (the bundle adjustment of a new map): it runs on the mapping
// thread, after the keyframes submitted before it, waitIdle() waits for it, and it is never
// dropped: with the queue full, or the thread stopped, it runs in the calling thread.
TEST(MappingThread, TasksRunOnTheMappingThreadInOrderAndAreNeverDropped) {
  Map map;
  MappingThread mt(map, {}, 2);
  mt.start();
  const auto caller = std::this_thread::get_id();
  std::atomic<bool> first_started{false}, release{false};
  std::thread::id first_thread;
  mt.submitTask([&] {
    first_thread = std::this_thread::get_id();
    first_started = true;
    while (!release) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  });
  while (!first_started) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  EXPECT_FALSE(mt.idle());
  KeyframeInsertion k;
  k.frame = syntheticFrame(50, 1);
  ASSERT_TRUE(mt.submit(std::move(k)));
  size_t keyframes_seen = 99;
  std::thread::id second_thread;
  mt.submitTask([&] {
    second_thread = std::this_thread::get_id();
    keyframes_seen = map.numKeyframes();
  });
  // The queue (2) holds the keyframe and the second task: the third runs here, now.
  bool third_ran = false;
  std::thread::id third_thread;
  mt.submitTask([&] {
    third_thread = std::this_thread::get_id();
    third_ran = true;
  });
  EXPECT_TRUE(third_ran);
  EXPECT_EQ(third_thread, caller);
  EXPECT_EQ(mt.droppedKeyframes(), 0u);  // a task is not a dropped keyframe
  release = true;
  mt.waitIdle();
  EXPECT_TRUE(mt.idle());
  EXPECT_NE(first_thread, caller);
  EXPECT_EQ(second_thread, first_thread);
  EXPECT_EQ(keyframes_seen, 1u);  // after the keyframe submitted before it
  // A throwing task is logged; the thread goes on.
  mt.submitTask([] { throw std::runtime_error("task failure (expected by the test)"); });
  KeyframeInsertion k2;
  k2.frame = syntheticFrame(50, 2);
  ASSERT_TRUE(mt.submit(std::move(k2)));
  mt.waitIdle();
  EXPECT_EQ(map.numKeyframes(), 2u);
  mt.stop();
  bool late_ran = false;
  mt.submitTask([&] { late_ran = std::this_thread::get_id() == caller; });
  EXPECT_TRUE(late_ran);
}

// A caller that writes the map itself (the tracking thread making a new map) holds the thread:
// hold() returns once the running job is done, the thread starts none while held (a submitted task
// waits), and insertNow is refused while the thread runs without a hold.
TEST(MappingThread, HoldWaitsForTheRunningJobAndKeepsTheThreadOffTheMap) {
  Map map;
  MappingThread mt(map, {}, 4);
  mt.start();
  KeyframeInsertion early;
  early.frame = syntheticFrame(50, 1);
  EXPECT_THROW(mt.insertNow(std::move(early), false), Error);
  std::atomic<bool> started{false}, release{false}, finished{false}, queued_ran{false};
  mt.submitTask([&] {
    started = true;
    while (!release) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    finished = true;
  });
  while (!started) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  std::thread releaser([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    release = true;
  });
  {
    const MappingThread::Hold hold = mt.hold();
    EXPECT_TRUE(finished);
    releaser.join();
    mt.submitTask([&] { queued_ran = true; });
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    EXPECT_FALSE(queued_ran);
    KeyframeInsertion k;
    k.frame = syntheticFrame(50, 2);
    const KeyframeId id = mt.insertNow(std::move(k), false);
    EXPECT_EQ(map.numKeyframes(), 1u);
    EXPECT_TRUE(map.keyframe(id));
  }
  mt.waitIdle();
  EXPECT_TRUE(queued_ran);
  KeyframeInsertion late;
  late.frame = syntheticFrame(50, 3);
  EXPECT_THROW(mt.insertNow(std::move(late), false), Error);  // the hold is over
  mt.stop();
}

}  // namespace
}  // namespace nerfslam
