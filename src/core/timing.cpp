#include "nerfslam/core/timing.h"

#include <ctime>
#if defined(__linux__)
#include <pthread.h>
#endif
#include <fstream>
#include <string>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include <fmt/format.h>

#include "nerfslam/core/error.h"

namespace nerfslam {

void setThreadName(const char* name) {
#if defined(__linux__)
  char buf[16] = {};
  for (size_t i = 0; i < sizeof(buf) - 1 && name[i]; ++i) buf[i] = name[i];
  pthread_setname_np(pthread_self(), buf);
#else
  (void)name;
#endif
}

namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

double nearestRank(std::vector<double> v, double p) {
  if (v.empty()) return kNaN;
  std::sort(v.begin(), v.end());
  const double n = static_cast<double>(v.size());
  // Rounding guard: p/100*n is computed in floating point (e.g. 0.99 * 100 = 98.99999999999999).
  const double rank = std::ceil(p / 100.0 * n - 1e-9);
  const size_t idx = rank < 1 ? 0 : std::min(v.size() - 1, static_cast<size_t>(rank) - 1);
  return v[idx];
}
}  // namespace

TimingStats::TimingStats(const TimingStats& other) : samples_(other.samples()) {}

TimingStats& TimingStats::operator=(const TimingStats& other) {
  if (this != &other) {
    std::vector<double> copy = other.samples();
    std::lock_guard<std::mutex> lock(mutex_);
    samples_ = std::move(copy);
  }
  return *this;
}

void TimingStats::add(double ms) {
  std::lock_guard<std::mutex> lock(mutex_);
  samples_.push_back(ms);
}

void TimingStats::clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  samples_.clear();
}

size_t TimingStats::count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return samples_.size();
}

std::vector<double> TimingStats::samples() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return samples_;
}

double TimingStats::mean() const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (samples_.empty()) return kNaN;
  return std::accumulate(samples_.begin(), samples_.end(), 0.0) / static_cast<double>(samples_.size());
}

double TimingStats::min() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return samples_.empty() ? kNaN : *std::min_element(samples_.begin(), samples_.end());
}

double TimingStats::max() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return samples_.empty() ? kNaN : *std::max_element(samples_.begin(), samples_.end());
}

double TimingStats::percentile(double p) const {
  if (!(p >= 0.0 && p <= 100.0)) fail("TimingStats::percentile: p = {} is not in [0, 100]", p);
  return nearestRank(samples(), p);
}

double TimingStats::median() const { return percentile(50.0); }
double TimingStats::p99() const { return percentile(99.0); }

std::string TimingStats::summary() const {
  const std::vector<double> s = samples();
  if (s.empty()) return "n=0";
  const double mean = std::accumulate(s.begin(), s.end(), 0.0) / static_cast<double>(s.size());
  return fmt::format("n={} mean={:.3f} median={:.3f} p99={:.3f} max={:.3f} ms", s.size(), mean, nearestRank(s, 50),
                     nearestRank(s, 99), *std::max_element(s.begin(), s.end()));
}

namespace {
// A "Vm...:   <kB> kB" line of /proc/self/status, in MB.
double procStatusMb(const char* key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const size_t n = std::char_traits<char>::length(key);
  while (std::getline(in, line))
    if (line.compare(0, n, key) == 0) return std::stod(line.substr(n)) / 1024.0;
  return 0.0;
}
}  // namespace

double peakRssMb() { return procStatusMb("VmHWM:"); }
double currentRssMb() { return procStatusMb("VmRSS:"); }

double threadCpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) * 1e3 + static_cast<double>(ts.tv_nsec) * 1e-6;
}

}  // namespace nerfslam
