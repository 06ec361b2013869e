#include "nerfslam/system/runner.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <mutex>
#include <thread>

#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/bounded_queue.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/core/thread.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/run_outputs.h"

namespace nerfslam {
namespace {

using Clock = std::chrono::steady_clock;

struct InputFrame {
  std::size_t index = 0;
  double timestamp = 0;
  cv::Mat image;
};

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double pos = q * (v.size() - 1);
  const std::size_t lo = static_cast<std::size_t>(std::floor(pos));
  const std::size_t hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (pos - lo) * (v[hi] - v[lo]);
}

// Mean intensity and a sharpness measure to explain failures ("black", "saturated", "blurred").
std::string describeImageProblem(const cv::Mat& gray) {
  cv::Scalar mean, stddev;
  cv::meanStdDev(gray, mean, stddev);
  if (mean[0] < 8 && stddev[0] < 4) return "black";
  if (mean[0] > 247 && stddev[0] < 4) return "saturated";
  if (stddev[0] < 2) return "uniform";
  return "";
}

}  // namespace

void writeMapPly(const std::filesystem::path& path, const Map& map) {
  const auto points = map.points();
  writeFileAtomic(path, [&](std::ostream& os) {
    os << "ply\nformat ascii 1.0\ncomment nerfslam sparse map (world frame, map units)\n";
    os << "element vertex " << points.size() << "\n";
    os << "property double x\nproperty double y\nproperty double z\nproperty int observations\nend_header\n";
    char buf[160];
    for (const auto& p : points) {
      std::snprintf(buf, sizeof buf, "%.9g %.9g %.9g %d\n", p.position.x(), p.position.y(), p.position.z(),
                    static_cast<int>(p.observations.size()));
      os << buf;
    }
  });
}

RunResult runSlam(const RunOptions& ro) {
  if (ro.out.empty()) fail("run: --out is required");
  if (ro.map.has_value() != (ro.map_mode != MapMode::kSlam))
    fail("run: --map needs --localize or --extend, and those need --map");
  SystemOptions sys;
  if (ro.system) {
    sys = *ro.system;
  } else if (ro.config) {
    loadOptionsFile(*ro.config, sys);
  } else if (ro.map) {
    sys = loadMapOptions(*ro.map);  // the options the map was made with
  }
  if (!ro.nerf) sys.nerf.enabled = false;
  validateOptions(sys, ro.config ? ro.config->string() : std::string("options"));
  std::string dataset_spec = ro.dataset;
  if (dataset_spec.empty()) {
    // The demo: no data needed, no display.
    render::SynthOptions so;
    so.scene = "room";
    so.trajectory = "handheld";
    so.frames = ro.demo_frames;
    const std::filesystem::path seq = ro.out / "sequence";
    std::fprintf(stderr, "no --dataset: rendering the synthetic furnished room (%d frames, 640x480, OSMesa) into %s\n",
                 so.frames, seq.string().c_str());
    render::writeSynthSequence(so, seq);
    dataset_spec = "tum:" + seq.string();
  }
  DatasetOptions dopt;
  dopt.camera_override = ro.camera;
  dopt.max_frames = ro.max_frames;
  auto ds = openDataset(dataset_spec, dopt);
  ensureDirectory(ro.out);
  const Camera& camera = ds->camera();
  spdlog::info("dataset {} ({}), {} frames, camera {}", ds->root().string(), ds->kind(), ds->size(), camera.describe());
  spdlog::info("options:\n{}", printOptions(sys));

  // A saved map to start from (map_store.h): verified, and refused when made with another camera.
  LoadedMap loaded;
  if (ro.map) loaded = loadMapFolder(*ro.map, camera);
  const std::size_t loaded_keyframes = loaded.map ? loaded.map->numKeyframes() : 0;
  const std::size_t loaded_points = loaded.map ? loaded.map->numPoints() : 0;
  SlamSystem slam(camera, sys, std::move(loaded.map), ro.map_mode);
  if (loaded.nerf_model && slam.nerf()) slam.nerf()->resume(*loaded.nerf_model, ro.map_mode != MapMode::kLocalize);
  BoundedQueue<InputFrame> frames(static_cast<std::size_t>(sys.frame_queue),
                                  ro.realtime ? OverflowPolicy::kDropOldest : OverflowPolicy::kDropNewest);
  std::atomic<std::size_t> processed{0};
  std::atomic<std::size_t> frames_in{0};
  std::atomic<std::size_t> out_of_order{0};
  std::atomic<bool> abort_run{false};
  std::mutex failure_mutex;
  std::string read_failure;
  std::string tracking_failure;
  std::vector<std::string> image_problems(ds->size());
  const bool lockstep = !ro.realtime && sys.lockstep;

  // Reader.
  // Memory and map size at the end of every 200-frame window (tracking_ms_windows), taken
  // by the reader thread: the map counts take the map's lock, which the tracking thread never waits for.
  struct WindowSample {
    double rss_mb;
    size_t keyframes, map_points;
  };
  std::vector<WindowSample> window_samples;
  constexpr size_t kWindow = 200;
  std::thread reader([&] {
    setThreadName("nerfslam-read");
    const auto wall0 = Clock::now();
    double t_first = 0, last_ts = -std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < ds->size() && !abort_run; ++i) {
      InputFrame f;
      try {
        // Colour for the NeRF (tracking converts to grey itself).
        DatasetFrame df = ds->load(i, sys.nerf.enabled ? ImageMode::kColor : ImageMode::kGray);
        f.index = i;
        f.timestamp = df.timestamp;
        f.image = std::move(df.image);
      } catch (const std::exception& e) {
        std::lock_guard<std::mutex> lock(failure_mutex);
        read_failure = e.what();
        spdlog::error("{}", e.what());
        break;
      }
      if (!(f.timestamp > last_ts)) {
        ++out_of_order;
        spdlog::warn("frame {}: timestamp {:.6f} not after the previous {:.6f}; skipped", i, f.timestamp, last_ts);
        continue;
      }
      last_ts = f.timestamp;
      if (f.image.channels() == 1) {
        image_problems[i] = describeImageProblem(f.image);
      } else {
        cv::Mat grey;
        cv::cvtColor(f.image, grey, cv::COLOR_BGR2GRAY);
        image_problems[i] = describeImageProblem(grey);
      }
      if (i == 0) t_first = f.timestamp;
      if (ro.realtime) {
        const auto due =
            wall0 + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(f.timestamp - t_first));
        std::this_thread::sleep_until(due);
        frames.tryPush(std::move(f));  // drops the oldest waiting frame when tracking lags
        ++frames_in;
      } else {
        if (!frames.push(std::move(f))) break;
        ++frames_in;
        if (lockstep) {
          while (processed.load() < frames_in.load() && !abort_run)
            std::this_thread::sleep_for(std::chrono::microseconds(200));
          slam.waitMappingIdle();
        }
      }
      if (frames_in.load() % kWindow == 0)
        window_samples.push_back({currentRssMb(), slam.map().numKeyframes(), slam.map().numPoints()});
    }
    frames.close();
  });

  // Tracking thread.
  std::vector<double> tracking_ms, tracking_cpu_ms;
  // The same CPU times split: frames before the map existed (initialisation attempts: KLT and the
  // two-view models) and frames tracked against it.
  std::vector<double> init_cpu_ms, after_init_cpu_ms;
  // Per-stage CPU time of the frames tracked against the map (not the initialisation attempts).
  std::map<std::string, std::vector<double>> stage_cpu_ms;
  // The same for the initialisation attempts (median and max: there are few).
  std::map<std::string, std::vector<double>> init_stage_cpu_ms;
  const auto run0 = Clock::now();
  std::thread tracker([&] {
    setThreadName("nerfslam-track");
    auto last_print = Clock::now();
    while (auto f = frames.pop()) {
      try {
        const bool had_map = slam.initialized();
        const FrameRecord r = slam.trackFrame(f->image, f->timestamp, f->index);
        tracking_ms.push_back(r.tracking_ms);
        tracking_cpu_ms.push_back(r.tracking_cpu_ms);
        (had_map ? after_init_cpu_ms : init_cpu_ms).push_back(r.tracking_cpu_ms);
        if (!had_map) {
          init_stage_cpu_ms["extract"].push_back(r.extract_cpu_ms);
          init_stage_cpu_ms["klt"].push_back(r.init_klt_cpu_ms);
          init_stage_cpu_ms["models"].push_back(r.init_models_cpu_ms);
          // The frame that succeeds also builds the map: two-keyframe BA, the frames in between.
          init_stage_cpu_ms["other"].push_back(r.tracking_cpu_ms - r.extract_cpu_ms - r.init_klt_cpu_ms -
                                               r.init_models_cpu_ms);
        }
        if (r.track_cpu_ms > 0) {
          stage_cpu_ms["extract"].push_back(r.extract_cpu_ms);
          stage_cpu_ms["extract.pyramid"].push_back(r.extract_stages.pyramid_ms);
          stage_cpu_ms["extract.fast"].push_back(r.extract_stages.fast_ms);
          stage_cpu_ms["extract.descriptors"].push_back(r.extract_stages.descriptor_ms);
          stage_cpu_ms["local_map"].push_back(r.local_map_cpu_ms);
          stage_cpu_ms["track"].push_back(r.track_cpu_ms);
          stage_cpu_ms["relocalize"].push_back(r.relocalize_cpu_ms);
          stage_cpu_ms["other"].push_back(r.tracking_cpu_ms - r.extract_cpu_ms - r.local_map_cpu_ms - r.track_cpu_ms -
                                          r.relocalize_cpu_ms);
        }
      } catch (const std::exception& e) {
        std::lock_guard<std::mutex> lock(failure_mutex);
        tracking_failure = fmt::format("frame {}: {}", f->index, e.what());
        spdlog::error("{}", tracking_failure);
        abort_run = true;
        ++processed;
        frames.close();
        break;
      }
      ++processed;
      if (ro.progress && (Clock::now() - last_print > std::chrono::seconds(1))) {
        last_print = Clock::now();
        const double secs = std::chrono::duration<double>(Clock::now() - run0).count();
        std::string nerf_line;
        if (const NerfMapping* n = slam.nerf()) {
          const NerfMappingStats ns = n->stats();
          nerf_line = fmt::format("  | NeRF {} views, {} steps, {:.1f} steps/s, {:.2f} M samples/s, PSNR {:.1f} dB",
                                  ns.views, ns.steps, ns.steps_per_second, ns.samples_per_second / 1e6, ns.psnr_recent);
        }
        std::fprintf(stderr, "frame %zu/%zu  %.1f frames/s  keyframes %zu  map points %zu  %s%s\n", f->index + 1,
                     ds->size(), processed.load() / std::max(secs, 1e-9), slam.map().numKeyframes(),
                     slam.map().numPoints(), toString(slam.state()), nerf_line.c_str());
      }
    }
  });
  reader.join();
  tracker.join();
  const double wall_s = std::chrono::duration<double>(Clock::now() - run0).count();
  slam.finish(true);
  if (NerfMapping* n = slam.nerf(); n && n->hasModel() && sys.nerf.final_train_seconds > 0) {
    std::fprintf(stderr, "training the NeRF map for %.0f s more with the final poses...\n",
                 sys.nerf.final_train_seconds);
    const int threads = resolveThreads(sys.nerf.final_threads);
    n->trainFor(sys.nerf.final_train_seconds, 0, threads);
  }

  // Outputs.
  const Trajectory traj = slam.trajectory();
  const auto& records = slam.records();
  nlohmann::json rep;
  rep["dataset"] = ds->root().string();
  rep["dataset_kind"] = ds->kind();
  rep["frames"] = ds->size();
  rep["frames_processed"] = processed.load();
  rep["frames_dropped"] = ro.realtime ? frames.dropped() : 0;
  rep["frames_out_of_order"] = out_of_order.load();
  rep["frames_tracked"] = traj.size();
  rep["initialized"] = slam.initialized();
  rep["initializations"] = slam.initializationCount();
  rep["initialization_model"] = slam.initializationModel();
  rep["relocalizations"] = slam.relocalizations();
  rep["local_map_rebuilds"] = slam.localMapRebuilds();
  rep["mode"] = toString(slam.mapMode());
  rep["map_loaded"] = ro.map ? nlohmann::json(ro.map->string()) : nlohmann::json(nullptr);
  rep["relocalized_at_frame"] = slam.relocalizedAtFrame();
  if (ro.map) {
    rep["map_loaded_keyframes"] = loaded_keyframes;
    rep["map_loaded_points"] = loaded_points;
    rep["map_load_s"] = loaded.seconds;
  }
  rep["keyframes"] = slam.map().numKeyframes();
  rep["keyframes_dropped"] = slam.droppedKeyframes();
  rep["map_points"] = slam.map().numPoints();
  rep["realtime"] = ro.realtime;
  rep["wall_time_s"] = wall_s;
  rep["peak_rss_mb"] = peakRssMb();
  rep["frames_per_second"] = processed.load() / std::max(wall_s, 1e-9);
  rep["tracking_ms_median"] = percentile(tracking_ms, 0.5);
  rep["tracking_ms_p99"] = percentile(tracking_ms, 0.99);
  rep["tracking_cpu_ms_median"] = percentile(tracking_cpu_ms, 0.5);
  rep["tracking_cpu_ms_p99"] = percentile(tracking_cpu_ms, 0.99);
  rep["tracking_cpu_ms_after_init_median"] = percentile(after_init_cpu_ms, 0.5);
  rep["tracking_cpu_ms_after_init_p99"] = percentile(after_init_cpu_ms, 0.99);
  rep["initialization_frames"] = init_cpu_ms.size();
  rep["initialization_cpu_ms_median"] = percentile(init_cpu_ms, 0.5);
  rep["initialization_cpu_ms_max"] = percentile(init_cpu_ms, 1.0);
  for (const auto& [stage, v] : init_stage_cpu_ms)
    rep["initialization_stage_cpu_ms"][stage] = {{"median", percentile(v, 0.5)}, {"max", percentile(v, 1.0)}};
  for (const auto& [stage, v] : stage_cpu_ms) {
    rep["tracking_stage_cpu_ms"][stage] = {{"median", percentile(v, 0.5)}, {"p99", percentile(v, 0.99)}};
    spdlog::info("tracking stage {:<19} CPU median {:6.2f} ms, p99 {:6.2f} ms ({} frames)", stage, percentile(v, 0.5),
                 percentile(v, 0.99), v.size());
  }
  // Does the cost per frame grow with the map? Tracking CPU time (the tracking thread's own, not
  // inflated by the other threads) per window of 200 frames, with the process's resident memory and
  // the map's size at the window's end (full windows only).
  {
    nlohmann::json windows = nlohmann::json::array();
    // Windows of 200 frames from the first; a last window shorter than 100 frames is left out
    // (unless it is the only one).
    for (size_t b = 0; b < tracking_cpu_ms.size() && (b == 0 || b + kWindow / 2 <= tracking_cpu_ms.size());
         b += kWindow) {
      const size_t e = std::min(b + kWindow, tracking_cpu_ms.size());
      const std::vector<double> cpu(tracking_cpu_ms.begin() + long(b), tracking_cpu_ms.begin() + long(e));
      const std::vector<double> wall(tracking_ms.begin() + long(b), tracking_ms.begin() + long(e));
      windows.push_back({{"first_frame", b},
                         {"frames", e - b},
                         {"cpu_ms_median", percentile(cpu, 0.5)},
                         {"cpu_ms_p99", percentile(cpu, 0.99)},
                         {"wall_ms_median", percentile(wall, 0.5)},
                         {"wall_ms_p99", percentile(wall, 0.99)}});
      if (const size_t w = b / kWindow; e - b == kWindow && w < window_samples.size()) {
        windows.back()["rss_mb"] = window_samples[w].rss_mb;
        windows.back()["keyframes"] = window_samples[w].keyframes;
        windows.back()["map_points"] = window_samples[w].map_points;
      }
    }
    rep["tracking_ms_windows"] = windows;
  }
  rep["nerf"] = slam.nerf() != nullptr;
  if (slam.nerf()) rep["tracking_ms_median_with_nerf"] = percentile(tracking_ms, 0.5);
  std::vector<double> ba_ms, map_ms;
  for (const auto& s : slam.mapping().stats()) {
    ba_ms.push_back(s.ba_ms);
    map_ms.push_back(s.total_ms);
  }
  rep["ba_ms_median"] = percentile(ba_ms, 0.5);
  rep["ba_ms_max"] = ba_ms.empty() ? 0.0 : *std::max_element(ba_ms.begin(), ba_ms.end());
  rep["mapping_ms_median"] = percentile(map_ms, 0.5);
  int first_tracked = -1;
  for (const auto& r : records)
    if (r.tracked) {
      first_tracked = static_cast<int>(r.index);
      break;
    }
  rep["first_tracked_frame"] = first_tracked;
  // Frames after the first tracked one that were not tracked.
  std::size_t untracked_after = 0;
  if (first_tracked >= 0)
    for (const auto& r : records) untracked_after += (static_cast<int>(r.index) > first_tracked && !r.tracked);
  rep["frames_lost_after_init"] = untracked_after;

  std::string failure;
  if (!read_failure.empty()) failure = read_failure;
  if (!tracking_failure.empty()) failure = tracking_failure;
  if (failure.empty() && !slam.initialized()) {
    std::size_t black = 0, saturated = 0, uniform = 0;
    for (const auto& p : image_problems) {
      black += p == "black";
      saturated += p == "saturated";
      uniform += p == "uniform";
    }
    failure = fmt::format("not initialised after {} frames", processed.load());
    if (black + saturated + uniform > 0)
      failure += fmt::format(" ({} black, {} saturated, {} featureless frames)", black, saturated, uniform);
    if (!slam.lastInitMessage().empty()) failure += "; last attempt: " + slam.lastInitMessage();
  }
  if (!failure.empty()) rep["failure"] = failure;

  Trajectory ref;
  std::optional<Sim3> gt_alignment;
  if (ds->hasGroundTruth() && traj.size() >= 3) {
    for (std::size_t i = 0; i < ds->size(); ++i)
      if (auto gt = ds->groundTruth(i)) ref.push_back({ds->timestamp(i), *gt});
    try {
      eval::TrajectoryEvalOptions eo;
      eo.align = "sim3";
      eo.max_dt = 1e-3;
      const eval::TrajectoryReport tr = eval::evaluateTrajectory(ref, traj, eo);
      gt_alignment = tr.alignment;
      rep["ate_rmse_m"] = tr.ape.rmse;
      rep["ate_max_m"] = tr.ape.max;
      rep["ate_scale"] = tr.scale;
      rep["ate_matched"] = tr.matched;
      rep["rpe_trans"] = tr.has_rpe ? tr.rpe_translation.rmse : 0.0;
      rep["rpe_rot_deg"] = tr.has_rpe ? tr.rpe_rotation_deg.rmse : 0.0;
      rep["path_length_m"] = tr.ref_path_length;
      rep["ate_percent_of_path"] = tr.ape_rmse_percent;
      // Scene extent (largest distance between ground-truth centres) for multi-view sets.
      double extent = 0;
      for (std::size_t a = 0; a < ref.size(); ++a)
        for (std::size_t b = a + 1; b < ref.size(); ++b)
          extent = std::max(extent, (ref[a].pose.translation() - ref[b].pose.translation()).norm());
      rep["gt_extent_m"] = extent;
      rep["ate_max_percent_of_extent"] = extent > 0 ? 100.0 * tr.ape.max / extent : 0.0;
    } catch (const std::exception& e) {
      rep["eval_error"] = e.what();
    }
  }

  writeTumTrajectory(ro.out / "trajectory.txt", traj);
  writeTumTrajectory(ro.out / "keyframes.txt", slam.keyframeTrajectory());
  writeMapPly(ro.out / "map_points.ply", slam.map());
  render::PreviewCloud dense;
  if (slam.nerf()) {
    try {
      writeNerfOutputs(slam, *ds, traj, gt_alignment, ro.out, NerfEvalOptions{}, rep, &dense);
    } catch (const std::exception& e) {
      rep["nerf_error"] = e.what();
      spdlog::error("NeRF outputs: {}", e.what());
    }
  }
  writeRunPreviews(slam, traj, ref, gt_alignment, dense, ro.out);
  // The map folder (map_store.h): --save-map DIR, else OUT/map (not after --localize: the map is as loaded).
  bool map_save_failed = false;
  std::optional<std::filesystem::path> map_dir = ro.save_map;
  if (!map_dir && ro.save_default_map && ro.map_mode != MapMode::kLocalize) map_dir = ro.out / "map";
  if (map_dir && slam.map().numKeyframes() > 0) {
    // The NeRF model goes into the map folder too (written under the model lock).
    NerfModelWriter write_nerf_model;
    if (NerfMapping* n = slam.nerf(); n && n->hasModel())
      write_nerf_model = [n](const std::filesystem::path& p) {
        n->withModel([&](nerf::NerfModel& m) { nerf::saveModel(m, p); });
      };
    try {
      const MapSaveResult ms = saveMapFolder(*map_dir, slam.map(), camera, sys, write_nerf_model);
      rep["map_saved"] = map_dir->string();
      rep["map_save_s"] = ms.seconds;
      rep["map_bytes"] = ms.bytes;
    } catch (const std::exception& e) {
      rep["map_save_error"] = e.what();
      spdlog::error("saving the map: {}", e.what());
      map_save_failed = ro.save_map.has_value();
    }
  }
  writeStringAtomic(ro.out / "report.json", rep.dump(2) + "\n");

  std::fprintf(stderr, "done: %zu/%zu frames tracked, %zu keyframes, %zu map points, %.1f frames/s%s\n", traj.size(),
               ds->size(), slam.map().numKeyframes(), slam.map().numPoints(), processed.load() / std::max(wall_s, 1e-9),
               failure.empty() ? "" : (" — " + failure).c_str());
  if (rep.contains("ate_rmse_m"))
    std::fprintf(stderr, "ATE (Sim3) %.4f m = %.3f%% of %.1f m path, scale %.4f\n", rep["ate_rmse_m"].get<double>(),
                 rep["ate_percent_of_path"].get<double>(), rep["path_length_m"].get<double>(),
                 rep["ate_scale"].get<double>());
  if (rep.contains("nerf_psnr_heldout"))
    std::fprintf(stderr, "NeRF: %lld steps, held-out PSNR %.2f dB (%zu frames), keyframes %.2f dB%s\n",
                 static_cast<long long>(rep["nerf_steps"].get<int64_t>()), rep["nerf_psnr_heldout"].get<double>(),
                 rep["nerf_psnr_heldout_frames"].get<size_t>(), rep["nerf_psnr_keyframes"].get<double>(),
                 rep.contains("nerf_depth_median_abs_rel")
                     ? fmt::format(", depth error (median abs rel) {:.1f}%",
                                   100 * rep["nerf_depth_median_abs_rel"].get<double>())
                           .c_str()
                     : "");
  std::fprintf(stderr, "results in %s (report.json, trajectory.txt, map_preview.png%s)\n", ro.out.string().c_str(),
               slam.nerf() ? ", nerf/, nerf_cloud.ply, mesh.ply" : "");
  RunResult res;
  res.report = rep;
  res.initialized = slam.initialized();
  res.exit_code = (!read_failure.empty() || !tracking_failure.empty() || map_save_failed) ? 1 : 0;
  return res;
}

}  // namespace nerfslam
