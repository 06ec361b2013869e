#pragma once
// The timings of a `nerfslam run` (system/runner.h) and the report.json fields made from them:
//   tracking_ms_*, tracking_cpu_ms_*       the tracking thread's wall and CPU time per frame
//   tracking_cpu_ms_after_init_*           ... of the frames tracked against the map
//   initialization_*                       ... of the frames before the map existed (initialisation
//                                          attempts), in total and per stage (median and max)
//   tracking_stage_cpu_ms                  per stage of the frames tracked against the map
//   tracking_ms_windows                    per window of 200 frames, with the process's resident
//                                          memory and the map's size at the window's end
//   tracking_ms_median_with_nerf           with the NeRF thread running
//   ba_ms_median, ba_ms_max, mapping_ms_median   the mapping thread's keyframes
// Percentiles interpolate linearly between the two nearest samples (runPercentile), unlike
// core/timing.h's nearest-rank TimingStats.
#include <cstddef>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "nerfslam/mapping/local_mapper.h"
#include "nerfslam/system/slam_system.h"

namespace nerfslam {

// The q-quantile (q in [0, 1]) of `samples`, interpolated linearly between the two nearest sorted
// samples (q = 1: the maximum); 0 when there are none.
double runPercentile(std::vector<double> samples, double q);

// The state of the run at the end of a window of RunStats::kWindow frames.
struct RunWindowSample {
  double rss_mb = 0;
  std::size_t keyframes = 0, map_points = 0;
};

class RunStats {
 public:
  static constexpr std::size_t kWindow = 200;  // frames per tracking_ms_windows entry

  // A frame the tracking thread tracked; `had_map`: the map existed before it (else the frame was an
  // initialisation attempt, and the one that succeeds also builds the map).
  void addFrame(const FrameRecord& record, bool had_map);
  // The state at the end of the next window (taken by the reader thread after every kWindow-th frame
  // it queued). addFrame and addWindowSample touch different members: one thread may call each.
  void addWindowSample(const RunWindowSample& sample);
  // The mapping thread's keyframes (MappingThread::stats()), once it has stopped.
  void setMapping(const std::vector<MappingStats>& keyframes);

  std::size_t frames() const { return tracking_ms_.size(); }

  // Sets the fields listed at the top of this file in `report` (tracking_ms_median_with_nerf when
  // `nerf`: the NeRF thread ran), and logs the per-stage figures. initialization_stage_cpu_ms and
  // tracking_stage_cpu_ms are absent when no frame had that kind. A window starts every kWindow
  // frames from the first; a last window shorter than kWindow / 2 frames is left out unless it is the
  // only one, and only full windows carry rss_mb, keyframes and map_points.
  void writeReport(nlohmann::json& report, bool nerf) const;

 private:
  nlohmann::json windowsJson() const;

  std::vector<double> tracking_ms_, tracking_cpu_ms_;
  // The same CPU times split: frames before the map existed (initialisation attempts: KLT and the
  // two-view models) and frames tracked against it.
  std::vector<double> init_cpu_ms_, after_init_cpu_ms_;
  // Per-stage CPU time of the frames tracked against the map, and of the initialisation attempts.
  std::map<std::string, std::vector<double>> stage_cpu_ms_, init_stage_cpu_ms_;
  std::vector<RunWindowSample> window_samples_;
  std::vector<double> ba_ms_, mapping_ms_;
};

}  // namespace nerfslam
