#include "nerfslam/core/thread.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <thread>

namespace nerfslam {

int resolveThreads(int threads) {
  if (threads > 0) return threads;
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

bool lowerThreadPriority(int increment) {
  if (increment <= 0) return true;
  const auto tid = static_cast<id_t>(syscall(SYS_gettid));
  return setpriority(PRIO_PROCESS, tid, getpriority(PRIO_PROCESS, tid) + increment) == 0;
}

}  // namespace nerfslam
