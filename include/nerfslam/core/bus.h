#pragma once
// Publish/subscribe over bounded queues: any number of consumers subscribe, each with its own
// BoundedQueue and overflow policy, and publish() hands every subscriber a copy without ever
// blocking (a full queue drops by its policy and counts it). The mapping thread publishes its
// keyframes on one (KeyframeBus, mapping/mapping_thread.h) for the NeRF mapping thread and the ROS
// keyframe sender.
#include <algorithm>
#include <cstddef>
#include <memory>
#include <mutex>
#include <vector>

#include "nerfslam/core/bounded_queue.h"

namespace nerfslam {

template <typename T>
class Bus {
 public:
  using Queue = BoundedQueue<T>;
  // A new consumer queue; it receives every item published from now on.
  std::shared_ptr<Queue> subscribe(std::size_t capacity, OverflowPolicy policy = OverflowPolicy::kDropOldest) {
    auto q = std::make_shared<Queue>(capacity, policy);
    std::lock_guard<std::mutex> lock(mutex_);
    queues_.push_back(q);
    return q;
  }
  void unsubscribe(const std::shared_ptr<Queue>& queue) {
    std::lock_guard<std::mutex> lock(mutex_);
    queues_.erase(std::remove(queues_.begin(), queues_.end(), queue), queues_.end());
  }
  // Never blocks; returns the number of subscribers that accepted the item.
  int publish(const T& item) {
    std::lock_guard<std::mutex> lock(mutex_);
    int n = 0;
    for (auto& q : queues_) n += q->tryPush(item);
    return n;
  }
  // Closes every subscriber queue (consumers drain and finish).
  void close() {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto& q : queues_) q->close();
  }
  std::size_t numSubscribers() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return queues_.size();
  }

 private:
  mutable std::mutex mutex_;
  std::vector<std::shared_ptr<Queue>> queues_;
};

}  // namespace nerfslam
