#pragma once
// Process-wide options shared by every subcommand: threads, log level, random seed.
#include <algorithm>
#include <cstdint>
#include <string>
#include <thread>

#include "nerfslam/core/options.h"

namespace nerfslam {

struct CoreOptions {
  int threads = 0;
  std::string log_level = "info";
  int64_t seed = 0;

  template <class V>
  void visit(V& v) {
    v("threads", threads, "Worker threads for parallel stages; 0 = all cores", check::range(0, 1024));
    v("log_level", log_level, "spdlog level for console output",
      check::oneOf({"trace", "debug", "info", "warn", "error", "off"}));
    v("seed", seed, "Seed of every random number generator (same seed and input, same result)",
      check::nonNegative<int64_t>());
  }
};

// The thread count `threads` stands for: itself when > 0, otherwise the number of cores (>= 1).
inline int resolveThreads(int threads) {
  if (threads > 0) return threads;
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

}  // namespace nerfslam
