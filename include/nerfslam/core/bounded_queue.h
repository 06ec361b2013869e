#pragma once
// Bounded multi-producer multi-consumer queue (basalt style) used between the tracking, mapping and
// NeRF threads. Producers on a real-time path use tryPush(), which never blocks: when the
// queue is full the item is dropped (kDropNewest) or the oldest queued item is evicted (kDropOldest),
// and the drop is counted. Consumers block in pop() until an item arrives or the queue is closed.
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>

namespace nerfslam {

enum class OverflowPolicy {
  kDropNewest,  // a full queue rejects the new item
  kDropOldest,  // a full queue evicts its oldest item to make room
};

template <typename T>
class BoundedQueue {
 public:
  explicit BoundedQueue(std::size_t capacity, OverflowPolicy policy = OverflowPolicy::kDropNewest)
      : capacity_(capacity == 0 ? 1 : capacity), policy_(policy) {}
  BoundedQueue(const BoundedQueue&) = delete;
  BoundedQueue& operator=(const BoundedQueue&) = delete;

  // Never blocks. Returns true when `item` was enqueued (with kDropOldest this may have evicted the
  // oldest item, counted in dropped()). Returns false when the item was dropped or the queue is closed.
  bool tryPush(T item) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (closed_) return false;
      if (items_.size() >= capacity_) {
        ++dropped_;
        if (policy_ == OverflowPolicy::kDropNewest) return false;
        items_.pop_front();
      }
      items_.push_back(std::move(item));
      ++pushed_;
    }
    not_empty_.notify_one();
    return true;
  }

  // Blocks while the queue is full (for producers that must not lose items, e.g. offline runs).
  // Returns false if the queue was closed.
  bool push(T item) {
    {
      std::unique_lock<std::mutex> lock(mutex_);
      not_full_.wait(lock, [&] { return closed_ || items_.size() < capacity_; });
      if (closed_) return false;
      items_.push_back(std::move(item));
      ++pushed_;
    }
    not_empty_.notify_one();
    return true;
  }

  // Blocks until an item is available; std::nullopt once the queue is closed and drained.
  std::optional<T> pop() {
    std::unique_lock<std::mutex> lock(mutex_);
    not_empty_.wait(lock, [&] { return closed_ || !items_.empty(); });
    return takeLocked(lock);
  }

  // As pop(), giving up after `timeout` (std::nullopt).
  template <class Rep, class Period>
  std::optional<T> popFor(std::chrono::duration<Rep, Period> timeout) {
    std::unique_lock<std::mutex> lock(mutex_);
    not_empty_.wait_for(lock, timeout, [&] { return closed_ || !items_.empty(); });
    return takeLocked(lock);
  }

  std::optional<T> tryPop() {
    std::unique_lock<std::mutex> lock(mutex_);
    return takeLocked(lock);
  }

  // Wakes every waiter; later pushes fail, pops drain what is left then return std::nullopt.
  void close() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      closed_ = true;
    }
    not_empty_.notify_all();
    not_full_.notify_all();
  }

  bool closed() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return closed_;
  }
  std::size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return items_.size();
  }
  bool empty() const { return size() == 0; }
  std::size_t capacity() const { return capacity_; }
  std::uint64_t dropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return dropped_;
  }
  std::uint64_t pushed() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return pushed_;
  }

 private:
  std::optional<T> takeLocked(std::unique_lock<std::mutex>& lock) {
    if (items_.empty()) return std::nullopt;
    std::optional<T> out(std::move(items_.front()));
    items_.pop_front();
    lock.unlock();
    not_full_.notify_one();
    return out;
  }

  const std::size_t capacity_;
  const OverflowPolicy policy_;
  mutable std::mutex mutex_;
  std::condition_variable not_empty_;
  std::condition_variable not_full_;
  std::deque<T> items_;
  bool closed_ = false;
  std::uint64_t dropped_ = 0;
  std::uint64_t pushed_ = 0;
};

}  // namespace nerfslam
