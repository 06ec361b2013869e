#include "nerfslam/core/bounded_queue.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

namespace nerfslam {
namespace {

TEST(BoundedQueue, DropNewestCountsDropsAndKeepsOrder) {
  BoundedQueue<int> q(3);
  for (int i = 0; i < 5; ++i) EXPECT_EQ(q.tryPush(i), i < 3);
  EXPECT_EQ(q.dropped(), 2u);
  EXPECT_EQ(q.pushed(), 3u);
  EXPECT_EQ(*q.pop(), 0);
  EXPECT_EQ(*q.pop(), 1);
  EXPECT_EQ(*q.pop(), 2);
  EXPECT_FALSE(q.tryPop());
}

TEST(BoundedQueue, DropOldestKeepsNewest) {
  BoundedQueue<int> q(2, OverflowPolicy::kDropOldest);
  for (int i = 0; i < 5; ++i) EXPECT_TRUE(q.tryPush(i));
  EXPECT_EQ(q.dropped(), 3u);
  EXPECT_EQ(*q.pop(), 3);
  EXPECT_EQ(*q.pop(), 4);
}

TEST(BoundedQueue, CloseWakesBlockedConsumerAndDrains) {
  BoundedQueue<int> q(4);
  q.tryPush(7);
  q.close();
  EXPECT_FALSE(q.tryPush(8));
  EXPECT_EQ(*q.pop(), 7);
  EXPECT_FALSE(q.pop());
  BoundedQueue<int> q2(4);
  std::thread t([&] { EXPECT_FALSE(q2.pop()); });
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  q2.close();
  t.join();
}

TEST(BoundedQueue, PopForTimesOut) {
  BoundedQueue<int> q(1);
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_FALSE(q.popFor(std::chrono::milliseconds(30)));
  EXPECT_GE(std::chrono::steady_clock::now() - t0, std::chrono::milliseconds(25));
}

TEST(BoundedQueue, ProducerNeverBlocksOnSlowConsumer) {
  // A consumer that takes 2 ms per item; the producer pushes 2000 items as fast as it can. Every item
  // is either delivered or counted as dropped, and the producer finishes long before the consumer
  // could have drained them all.
  BoundedQueue<int> q(8);
  std::atomic<int> consumed{0};
  std::vector<int> got;
  std::thread consumer([&] {
    while (auto v = q.pop()) {
      got.push_back(*v);
      ++consumed;
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  });
  const int n = 2000;
  int accepted = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < n; ++i) accepted += q.tryPush(i);
  const double producer_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  q.close();
  consumer.join();
  EXPECT_LT(producer_ms, 200.0);  // 2000 items x 2 ms would be 4 s if it blocked
  EXPECT_EQ(static_cast<uint64_t>(accepted) + q.dropped(), static_cast<uint64_t>(n));
  EXPECT_EQ(consumed.load(), accepted);
  EXPECT_GT(q.dropped(), 0u);
  for (size_t i = 1; i < got.size(); ++i) EXPECT_LT(got[i - 1], got[i]);
}

TEST(BoundedQueue, ManyProducersManyConsumersLoseNothingWithBlockingPush) {
  BoundedQueue<int> q(4);
  std::atomic<long> sum{0};
  std::atomic<int> count{0};
  std::vector<std::thread> consumers, producers;
  for (int c = 0; c < 3; ++c)
    consumers.emplace_back([&] {
      while (auto v = q.pop()) {
        sum += *v;
        ++count;
      }
    });
  for (int p = 0; p < 3; ++p)
    producers.emplace_back([&, p] {
      for (int i = 0; i < 1000; ++i) q.push(p * 1000 + i);
    });
  for (auto& t : producers) t.join();
  q.close();
  for (auto& t : consumers) t.join();
  EXPECT_EQ(count.load(), 3000);
  EXPECT_EQ(sum.load(), 3000L * 2999 / 2);
  EXPECT_EQ(q.dropped(), 0u);
}

}  // namespace
}  // namespace nerfslam
