#pragma once
// The mapping thread and the keyframe bus.
//
// Tracking hands keyframes over with submit(), which never blocks: the input queue is bounded and a
// keyframe that does not fit is dropped and counted (tracking then simply keeps tracking against the
// existing map and asks again later). The thread inserts each keyframe into the Map, publishes it on
// the KeyframeBus, then runs the LocalMapper on it.
//
// KeyframeBus (a core/bus.h Bus): any number of consumers (e.g. the NeRF mapping thread) subscribe
// with their own bounded queue and overflow policy; publishing never blocks the mapping thread. A
// consumer reads geometry that BA refines later from the Map (Map::keyframe(id)) when it needs the
// latest pose.
#include <atomic>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "nerfslam/core/bounded_queue.h"
#include "nerfslam/core/bus.h"
#include "nerfslam/mapping/local_mapper.h"
#include "nerfslam/mapping/map.h"

namespace nerfslam {

struct KeyframeInsertion {
  std::shared_ptr<const Frame> frame;
  SE3 T_world_cam;
  std::vector<std::pair<int, PointId>> matches;  // keypoint index -> map point tracked in this frame
};

struct KeyframeEvent {
  KeyframeId id = -1;
  SE3 T_world_cam;  // at insertion (before local BA)
  std::shared_ptr<const Frame> frame;
};

// Every keyframe the mapping thread inserts, to any number of consumers (core/bus.h).
using KeyframeBus = Bus<KeyframeEvent>;

class MappingThread {
 public:
  MappingThread(Map& map, MappingOptions options, std::size_t queue_capacity = 3);
  ~MappingThread();
  MappingThread(const MappingThread&) = delete;
  MappingThread& operator=(const MappingThread&) = delete;

  void start();
  // Finishes the queued keyframes, then joins. Idempotent.
  void stop();

  // Non-blocking; false when the queue is full (counted in droppedKeyframes()) or stopped.
  bool submit(KeyframeInsertion kf);
  // Runs `task` on the mapping thread after what was submitted before it (work taken off the
  // tracking thread, e.g. the bundle adjustment of a new map). Never dropped and never blocks: when
  // the queue is full or stopped the task runs here, in the calling thread. idle() and waitIdle()
  // count it like a keyframe; an exception it throws is logged.
  void submitTask(std::function<void()> task);
  // Holds the thread between two jobs while the caller writes the map itself (a new map from the
  // initialiser, with insertNow): waits until what was submitted before has been processed, then the
  // thread starts nothing until the Hold is destroyed (submitted jobs wait for it). A no-op wait when
  // the thread is idle, as it is before a map exists.
  class Hold {
   public:
    Hold(Hold&& other) noexcept : owner_(other.owner_), lock_(std::move(other.lock_)) { other.owner_ = nullptr; }
    Hold(const Hold&) = delete;
    Hold& operator=(const Hold&) = delete;
    Hold& operator=(Hold&&) = delete;
    ~Hold();

   private:
    friend class MappingThread;
    Hold(MappingThread* owner, std::unique_lock<std::mutex> lock) : owner_(owner), lock_(std::move(lock)) {}
    MappingThread* owner_;
    std::unique_lock<std::mutex> lock_;
  };
  [[nodiscard]] Hold hold();
  // Inserts and processes a keyframe in the calling thread (initialisation, tests): before start(),
  // after stop(), or under a hold(); throws an Error while the thread runs otherwise.
  KeyframeId insertNow(KeyframeInsertion kf, bool process = true);
  // No submitted keyframe waiting or being processed.
  bool idle() const;
  // Blocks until idle() (used by lock-step offline runs, never by tracking).
  void waitIdle() const;

  // Called on the mapping thread with each keyframe it has processed (after local mapping; e.g. the
  // loop closer's submit). Set before start().
  void setKeyframeProcessed(std::function<void(KeyframeId)> callback) { processed_ = std::move(callback); }

  KeyframeBus& bus() { return bus_; }
  LocalMapper& mapper() { return mapper_; }
  uint64_t droppedKeyframes() const { return queue_.dropped(); }
  std::vector<MappingStats> stats() const;

 private:
  // One queue item: a keyframe, or a task when `task` is set.
  struct Job {
    KeyframeInsertion keyframe;
    std::function<void()> task;
  };
  void run();
  KeyframeId insert(KeyframeInsertion kf);

  Map& map_;
  LocalMapper mapper_;
  BoundedQueue<Job> queue_;
  KeyframeBus bus_;
  std::thread thread_;
  std::atomic<int> pending_{0};  // submitted, not yet processed
  std::atomic<bool> thread_running_{false};
  // Held by the thread while it processes a job, and by a Hold (hold()) for as long as it lives.
  std::mutex work_mutex_;
  std::atomic<bool> held_{false};
  mutable std::mutex stats_mutex_;
  mutable std::condition_variable idle_cv_;
  std::vector<MappingStats> stats_;
  bool started_ = false;
  std::function<void(KeyframeId)> processed_;
};

}  // namespace nerfslam
