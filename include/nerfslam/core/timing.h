#pragma once
// Wall-clock timing for logs and benchmarks: a stopwatch, a sample collector with order statistics
// and a scoped timer feeding it.
//
//   TimingStats track_ms;
//   { ScopedTimer t(track_ms); tracker.track(frame); }
//   spdlog::info("tracking: {}", track_ms.summary());   // "n=300 mean=4.1 median=3.9 p99=9.2 max=11.0 ms"
//
// Percentiles use the nearest-rank definition: the p-th percentile of n sorted samples x[1..n] is
// x[ceil(p/100 * n)] (and x[1] for p = 0). So median() = percentile(50) is the lower of the two
// middle samples when n is even, and p99 of 100 samples is the 99th smallest. Every statistic of an
// empty TimingStats is NaN. TimingStats is thread-safe: add() and the statistics may be called
// concurrently from several threads (each call takes an internal mutex).
#include <chrono>
#include <cstddef>
#include <mutex>
#include <string>
#include <vector>

namespace nerfslam {

// CPU time consumed by the calling thread so far, in milliseconds (CLOCK_THREAD_CPUTIME_ID). The cost
// of work on one core, independent of how many other processes share the machine; wall time minus
// this is time spent preempted or blocked.
double threadCpuMs();
// Names the calling thread (at most 15 characters are kept; Linux only, a no-op elsewhere) so that
// top -H, perf and gdb show which of the system's threads is which ("track", "map", "nerf", ...).
void setThreadName(const char* name);
// Peak resident set size of this process in MB (VmHWM; 0 where /proc is not available).
double peakRssMb();
// Current resident set size of this process in MB (VmRSS; 0 where /proc is not available).
double currentRssMb();

// Monotonic (steady_clock) stopwatch, started on construction.
class Stopwatch {
 public:
  Stopwatch() : start_(Clock::now()) {}
  void reset() { start_ = Clock::now(); }
  double elapsedMs() const { return std::chrono::duration<double, std::milli>(Clock::now() - start_).count(); }
  // Elapsed time, then restarts.
  double lapMs() {
    const auto now = Clock::now();
    const double ms = std::chrono::duration<double, std::milli>(now - start_).count();
    start_ = now;
    return ms;
  }

 private:
  using Clock = std::chrono::steady_clock;
  Clock::time_point start_;
};

class TimingStats {
 public:
  TimingStats() = default;
  TimingStats(const TimingStats& other);
  TimingStats& operator=(const TimingStats& other);

  void add(double ms);
  void clear();
  size_t count() const;
  double mean() const;
  double min() const;
  double max() const;
  double median() const;  // nearest-rank 50th percentile
  double p99() const;     // nearest-rank 99th percentile
  // Nearest-rank percentile, p in [0, 100]; throws nerfslam::Error otherwise.
  double percentile(double p) const;
  // "n=N mean=.. median=.. p99=.. max=.. ms" (or "n=0").
  std::string summary() const;
  std::vector<double> samples() const;

 private:
  mutable std::mutex mutex_;
  std::vector<double> samples_;
};

// Adds the time from construction to destruction to `stats`.
class ScopedTimer {
 public:
  explicit ScopedTimer(TimingStats& stats) : stats_(stats) {}
  ~ScopedTimer() { stats_.add(watch_.elapsedMs()); }
  ScopedTimer(const ScopedTimer&) = delete;
  ScopedTimer& operator=(const ScopedTimer&) = delete;

 private:
  TimingStats& stats_;
  Stopwatch watch_;
};

}  // namespace nerfslam
