#include "nerfslam/mapping/mapping_thread.h"

#include <algorithm>

#include <spdlog/spdlog.h>

#include "nerfslam/core/error.h"
#include "nerfslam/core/timing.h"

namespace nerfslam {

MappingThread::MappingThread(Map& map, MappingOptions options, std::size_t queue_capacity)
    : map_(map), mapper_(map, std::move(options)), queue_(queue_capacity, OverflowPolicy::kDropNewest) {}

MappingThread::~MappingThread() { stop(); }

void MappingThread::start() {
  if (started_) return;
  started_ = true;
  thread_running_ = true;
  thread_ = std::thread([this] {
    setThreadName("nerfslam-map");
    run();
    thread_running_ = false;
    idle_cv_.notify_all();
  });
}

void MappingThread::stop() {
  queue_.close();
  if (thread_.joinable()) thread_.join();
  bus_.close();
}

bool MappingThread::submit(KeyframeInsertion kf) {
  if (!kf.frame) fail("MappingThread::submit: keyframe without a frame");
  pending_.fetch_add(1);
  const bool ok = queue_.tryPush(Job{std::move(kf), {}});
  if (!ok) pending_.fetch_sub(1);
  if (!ok) spdlog::debug("mapping busy: keyframe dropped ({} so far)", queue_.dropped());
  return ok;
}

namespace {
void runTask(const std::function<void()>& task) {
  try {
    task();
  } catch (const std::exception& e) {
    spdlog::error("mapping thread task: {}", e.what());
  }
}
}  // namespace

void MappingThread::submitTask(std::function<void()> task) {
  if (!task) return;
  // Only producers push, so a queue with room keeps it until the push below (tryPush would count a
  // refused task as a dropped keyframe).
  if (thread_running_.load() && queue_.size() < queue_.capacity()) {
    pending_.fetch_add(1);
    if (queue_.tryPush(Job{KeyframeInsertion{}, task})) return;
    pending_.fetch_sub(1);
  }
  runTask(task);
}

KeyframeId MappingThread::insert(KeyframeInsertion in) {
  Keyframe kf;
  kf.frame = in.frame;
  kf.T_world_cam = in.T_world_cam;
  kf.points.assign(in.frame->keypoints.size(), kNoPoint);
  for (const auto& [idx, pid] : in.matches)
    if (idx >= 0 && idx < static_cast<int>(kf.points.size())) kf.points[idx] = pid;
  const KeyframeId id = map_.addKeyframe(std::move(kf));
  bus_.publish({id, in.T_world_cam, in.frame});
  return id;
}

MappingThread::Hold MappingThread::hold() {
  std::unique_lock<std::mutex> work(work_mutex_);
  // Jobs submitted before: the thread must finish them first (it cannot start one while `work` is
  // held, so pending_ only falls while it is released).
  while (pending_.load() != 0 && thread_running_.load()) {
    work.unlock();
    waitIdle();
    work.lock();
  }
  held_ = true;
  return Hold(this, std::move(work));
}

MappingThread::Hold::~Hold() {
  if (owner_) owner_->held_ = false;
}

KeyframeId MappingThread::insertNow(KeyframeInsertion kf, bool process) {
  if (thread_running_.load() && !held_.load())
    fail("MappingThread::insertNow while the mapping thread runs (hold() it first)");
  const KeyframeId id = insert(std::move(kf));
  if (process) {
    MappingStats s = mapper_.processKeyframe(id);
    std::lock_guard<std::mutex> lock(stats_mutex_);
    stats_.push_back(s);
  }
  if (processed_) processed_(id);
  return id;
}

void MappingThread::run() {
  for (;;) {
    auto item = queue_.pop();
    if (!item) break;
    std::lock_guard<std::mutex> work(work_mutex_);
    if (item->task) {
      runTask(item->task);
    } else {
      try {
        const KeyframeId id = insert(std::move(item->keyframe));
        MappingStats s = mapper_.processKeyframe(id);
        {
          std::lock_guard<std::mutex> lock(stats_mutex_);
          stats_.push_back(s);
        }
        if (processed_) processed_(id);
      } catch (const std::exception& e) {
        spdlog::error("mapping thread: {}", e.what());
      }
    }
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      pending_.fetch_sub(1);
    }
    idle_cv_.notify_all();
  }
  idle_cv_.notify_all();
}

bool MappingThread::idle() const { return pending_.load() == 0; }

void MappingThread::waitIdle() const {
  std::unique_lock<std::mutex> lock(stats_mutex_);
  while (pending_.load() != 0 && !(queue_.closed() && queue_.empty() && !thread_running_.load()))
    idle_cv_.wait_for(lock, std::chrono::milliseconds(5));
}

std::vector<MappingStats> MappingThread::stats() const {
  std::lock_guard<std::mutex> lock(stats_mutex_);
  return stats_;
}

}  // namespace nerfslam
