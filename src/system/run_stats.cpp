#include "nerfslam/system/run_stats.h"

#include <algorithm>
#include <cmath>

#include <spdlog/spdlog.h>

namespace nerfslam {

double runPercentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double pos = q * (v.size() - 1);
  const std::size_t lo = static_cast<std::size_t>(std::floor(pos));
  const std::size_t hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (pos - lo) * (v[hi] - v[lo]);
}

void RunStats::addFrame(const FrameRecord& r, bool had_map) {
  tracking_ms_.push_back(r.tracking_ms);
  tracking_cpu_ms_.push_back(r.tracking_cpu_ms);
  (had_map ? after_init_cpu_ms_ : init_cpu_ms_).push_back(r.tracking_cpu_ms);
  if (!had_map) {
    init_stage_cpu_ms_["extract"].push_back(r.extract_cpu_ms);
    init_stage_cpu_ms_["klt"].push_back(r.init_klt_cpu_ms);
    init_stage_cpu_ms_["models"].push_back(r.init_models_cpu_ms);
    // The frame that succeeds also builds the map: two-keyframe BA, the frames in between.
    init_stage_cpu_ms_["other"].push_back(r.tracking_cpu_ms - r.extract_cpu_ms - r.init_klt_cpu_ms -
                                          r.init_models_cpu_ms);
  }
  if (r.track_cpu_ms > 0) {
    stage_cpu_ms_["extract"].push_back(r.extract_cpu_ms);
    stage_cpu_ms_["extract.pyramid"].push_back(r.extract_stages.pyramid_ms);
    stage_cpu_ms_["extract.fast"].push_back(r.extract_stages.fast_ms);
    stage_cpu_ms_["extract.descriptors"].push_back(r.extract_stages.descriptor_ms);
    stage_cpu_ms_["local_map"].push_back(r.local_map_cpu_ms);
    stage_cpu_ms_["track"].push_back(r.track_cpu_ms);
    stage_cpu_ms_["relocalize"].push_back(r.relocalize_cpu_ms);
    stage_cpu_ms_["other"].push_back(r.tracking_cpu_ms - r.extract_cpu_ms - r.local_map_cpu_ms - r.track_cpu_ms -
                                     r.relocalize_cpu_ms);
  }
}

void RunStats::addWindowSample(const RunWindowSample& sample) { window_samples_.push_back(sample); }

void RunStats::setMapping(const std::vector<MappingStats>& keyframes) {
  ba_ms_.clear();
  mapping_ms_.clear();
  for (const auto& s : keyframes) {
    ba_ms_.push_back(s.ba_ms);
    mapping_ms_.push_back(s.total_ms);
  }
}

// Does the cost per frame grow with the map? Tracking CPU time (the tracking thread's own, not
// inflated by the other threads) per window, with the process's resident memory and the map's size
// at the window's end (full windows only).
nlohmann::json RunStats::windowsJson() const {
  nlohmann::json windows = nlohmann::json::array();
  const std::size_t n = tracking_cpu_ms_.size();
  for (std::size_t b = 0; b < n && (b == 0 || b + kWindow / 2 <= n); b += kWindow) {
    const std::size_t e = std::min(b + kWindow, n);
    const std::vector<double> cpu(tracking_cpu_ms_.begin() + long(b), tracking_cpu_ms_.begin() + long(e));
    const std::vector<double> wall(tracking_ms_.begin() + long(b), tracking_ms_.begin() + long(e));
    windows.push_back({{"first_frame", b},
                       {"frames", e - b},
                       {"cpu_ms_median", runPercentile(cpu, 0.5)},
                       {"cpu_ms_p99", runPercentile(cpu, 0.99)},
                       {"wall_ms_median", runPercentile(wall, 0.5)},
                       {"wall_ms_p99", runPercentile(wall, 0.99)}});
    if (const std::size_t w = b / kWindow; e - b == kWindow && w < window_samples_.size()) {
      windows.back()["rss_mb"] = window_samples_[w].rss_mb;
      windows.back()["keyframes"] = window_samples_[w].keyframes;
      windows.back()["map_points"] = window_samples_[w].map_points;
    }
  }
  return windows;
}

void RunStats::writeReport(nlohmann::json& rep, bool nerf) const {
  rep["tracking_ms_median"] = runPercentile(tracking_ms_, 0.5);
  rep["tracking_ms_p99"] = runPercentile(tracking_ms_, 0.99);
  rep["tracking_cpu_ms_median"] = runPercentile(tracking_cpu_ms_, 0.5);
  rep["tracking_cpu_ms_p99"] = runPercentile(tracking_cpu_ms_, 0.99);
  rep["tracking_cpu_ms_after_init_median"] = runPercentile(after_init_cpu_ms_, 0.5);
  rep["tracking_cpu_ms_after_init_p99"] = runPercentile(after_init_cpu_ms_, 0.99);
  rep["initialization_frames"] = init_cpu_ms_.size();
  rep["initialization_cpu_ms_median"] = runPercentile(init_cpu_ms_, 0.5);
  rep["initialization_cpu_ms_max"] = runPercentile(init_cpu_ms_, 1.0);
  for (const auto& [stage, v] : init_stage_cpu_ms_)
    rep["initialization_stage_cpu_ms"][stage] = {{"median", runPercentile(v, 0.5)}, {"max", runPercentile(v, 1.0)}};
  for (const auto& [stage, v] : stage_cpu_ms_) {
    rep["tracking_stage_cpu_ms"][stage] = {{"median", runPercentile(v, 0.5)}, {"p99", runPercentile(v, 0.99)}};
    spdlog::info("tracking stage {:<19} CPU median {:6.2f} ms, p99 {:6.2f} ms ({} frames)", stage,
                 runPercentile(v, 0.5), runPercentile(v, 0.99), v.size());
  }
  rep["tracking_ms_windows"] = windowsJson();
  if (nerf) rep["tracking_ms_median_with_nerf"] = runPercentile(tracking_ms_, 0.5);
  rep["ba_ms_median"] = runPercentile(ba_ms_, 0.5);
  rep["ba_ms_max"] = ba_ms_.empty() ? 0.0 : *std::max_element(ba_ms_.begin(), ba_ms_.end());
  rep["mapping_ms_median"] = runPercentile(mapping_ms_, 0.5);
}

}  // namespace nerfslam
