#include "nerfslam/system/runner.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <limits>
#include <mutex>
#include <optional>
#include <thread>

#include <fmt/ranges.h>
#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/bounded_queue.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/core/stop_signal.h"
#include "nerfslam/core/thread.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam/system/run_outputs.h"
#include "nerfslam/system/run_stats.h"

namespace nerfslam {
namespace {

using Clock = std::chrono::steady_clock;

// ---- Opening: the options, the dataset and the saved map to start from.

// RunOptions::system, else the config file, else the options the map was made with, else the defaults.
SystemOptions loadRunOptions(const RunOptions& ro) {
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
  return sys;
}

// --dataset, or the demo (no data needed, no display): the synthetic room rendered into OUT/sequence.
std::unique_ptr<Dataset> openRunDataset(const RunOptions& ro) {
  std::string spec = ro.dataset;
  if (spec.empty()) {
    SynthOptions so;
    so.scene = "room";
    so.trajectory = "handheld";
    so.frames = ro.demo_frames;
    const std::filesystem::path seq = ro.out / "sequence";
    std::fprintf(stderr, "no --dataset: rendering the synthetic furnished room (%d frames, 640x480, OSMesa) into %s\n",
                 so.frames, seq.string().c_str());
    writeSynthSequence(so, seq);
    spec = "tum:" + seq.string();
  }
  DatasetOptions dopt;
  dopt.camera_override = ro.camera;
  dopt.max_frames = ro.max_frames;
  dopt.fps = ro.fps;
  dopt.image_topic = ro.image_topic;
  dopt.camera_info_topic = ro.camera_info_topic;
  dopt.odometry_topic = ro.odometry_topic;
  dopt.groundtruth_topic = ro.groundtruth_topic;
  dopt.odom_frame = ro.odom_frame;
  dopt.base_frame = ro.base_frame;
  dopt.groundtruth_parent_frame = ro.groundtruth_parent_frame;
  dopt.groundtruth_child_frame = ro.groundtruth_child_frame;
  return openDataset(spec, dopt);
}

// --odometry: the file read and checked (odometry.h), and its overlap with the frames' timestamps.
// *from: where the odometry came from ("file", or the dataset's: "topic", "tf").
std::shared_ptr<const OdometryTrack> openRunOdometry(const RunOptions& ro, const SystemOptions& sys, const Dataset& ds,
                                                     std::string* from) {
  std::shared_ptr<const OdometryTrack> odo;
  *from = "file";
  if (ro.odometry) {
    if (ro.map) fail("run: --odometry with --map is not supported (the map keeps the scale it was saved with)");
    odo = std::make_shared<const OdometryTrack>(OdometryTrack::load(*ro.odometry, sys.odometry));
    if (ds.odometry())
      spdlog::info("--odometry {} is used, not the dataset's {}", ro.odometry->string(), ds.odometry()->source);
  } else if (auto own = ds.odometry()) {
    // A bag's odometry topic: the same track as the file would give.
    if (ro.map) {
      spdlog::warn("{}: the dataset's odometry is not used with --map (the map keeps the scale it was saved with)",
                   own->source);
      return nullptr;
    }
    odo = std::make_shared<const OdometryTrack>(
        std::move(own->T_odom_base), rigidTransformFromRowMajor(sys.odometry.T_base_cam), own->source, sys.odometry);
    *from = own->from;
  } else {
    return nullptr;
  }
  std::size_t covered = 0;
  for (std::size_t i = 0; i < ds.size(); ++i) covered += odo->baseAt(ds.timestamp(i)).has_value();
  if (covered == 0)
    fail("{}: field 'timestamp': the odometry does not overlap the images: it spans {} .. {} s, the frames {} .. {} s",
         odo->source(), numberForMessage(odo->beginTime(), 3), numberForMessage(odo->endTime(), 3),
         numberForMessage(ds.size() ? ds.timestamp(0) : 0.0, 3),
         numberForMessage(ds.size() ? ds.timestamp(ds.size() - 1) : 0.0, 3));
  spdlog::info("odometry from {} {}: {} samples, {:.3f} .. {:.3f} s, {}/{} frames covered", *from, odo->source(),
               odo->size(), odo->beginTime(), odo->endTime(), covered, ds.size());
  return odo;
}

// scale_source ("odometry" once the odometry's scale was applied, else "none": a monocular map's
// scale is arbitrary) and, with odometry, where it came from (`from`: "file", a bag's "topic" or
// "tf") and the scale over time (SlamSystem::scaleHistory).
void addScaleReport(SlamSystem& slam, const std::string& odometry_from, nlohmann::json& rep) {
  rep["scale_source"] = slam.metricScale() ? "odometry" : "none";
  const OdometryTrack* odo = slam.odometry();
  if (!odo) return;
  nlohmann::json j;
  j["file"] = odo->source();
  j["from"] = odometry_from;
  j["samples"] = odo->size();
  j["scale_applied_at_frame"] = slam.scaleAppliedAtFrame();
  nlohmann::json over = nlohmann::json::array();
  double applied = 1.0;
  for (const ScaleSample& s : slam.scaleHistory()) {
    over.push_back({{"frame", s.frame},
                    {"timestamp", s.timestamp},
                    {"keyframes", s.keyframes},
                    {"pairs", s.estimate.pairs},
                    {"inliers", s.estimate.inliers},
                    {"odometry_path_m", s.estimate.path_m},
                    {"estimate", s.estimate.pairs > 0 ? nlohmann::json(s.estimate.scale) : nlohmann::json(nullptr)},
                    {"spread", s.estimate.spread},
                    {"applied_scale", s.applied_scale},
                    {"applied", s.applied}});
    applied = s.applied_scale;
  }
  j["applied_scale"] = applied;
  j["ba_pairs_gated"] = slam.mapping().mapper().odometryGated();
  j["scale_over_time"] = over;
  if (!slam.metricScale()) {
    const ScaleEstimate last = slam.scaleHistory().empty() ? ScaleEstimate{} : slam.scaleHistory().back().estimate;
    const OdometryOptions& o = odo->options();
    j["failure"] = fmt::format(
        "the scale was never set: {} usable keyframe pairs and {:.2f} m of odometry (needs {} pairs and {} m)",
        last.pairs, last.path_m, o.scale_min_pairs, o.scale_min_path_m);
  }
  rep["odometry"] = j;
}

// Outputs are not written into the dataset being read: a folder dataset's frames are every image in
// its folder, so the PNGs a run writes there (map_preview.png, trajectory.png) would be frames of the
// next run; and the outputs of any kind would be mixed with the dataset's own files. Checked before
// anything is written.
void refuseOutputsInDataset(const RunOptions& ro, const Dataset& ds) {
  const bool folder = ds.kind() == "folder";
  auto check = [&](const std::filesystem::path& dir, const char* option) {
    if (folder && isInsideDirectory(dir, ds.root()))
      fail(
          "run: {} {} is inside the folder dataset {}, whose frames are every image in it; choose an output "
          "folder outside it",
          option, dir.string(), ds.root().string());
    if (!folder && sameFile(dir, ds.root()))
      fail("run: {} {} is the {} dataset's own folder; choose another output folder", option, dir.string(), ds.kind());
  };
  check(ro.out, "--out");
  if (ro.save_map) check(*ro.save_map, "--save-map");
}

// camera:DEVICE (frame_stream.h): the stream (the device, or RunOptions::open_stream's) and the
// recording of the frames that reach tracking in OUT/frames. A device implies --realtime.
void openRunStream(RunOptions& ro, std::unique_ptr<FrameStream>* stream, std::unique_ptr<StreamRecording>* rec) {
  const std::string device = cameraDevice(ro.dataset);
  if (!ro.camera)
    fail(
        "--dataset {}: a live camera has no calibration; give its camera YAML (--camera FILE; `nerfslam calibrate` "
        "makes one)",
        ro.dataset);
  if (ro.odometry)
    fail(
        "run: --odometry with a live camera is not supported (the frames' times are the capture clock's, not the "
        "odometry file's)");
  Camera camera = loadCameraYaml(*ro.camera);
  camera.validate(ro.camera->string());
  if (ro.open_stream) {
    *stream = ro.open_stream(device);
  } else {
    *stream = openCameraStream(device, camera.width, camera.height);
    if (!ro.realtime) spdlog::info("camera {}: frames are taken at the device's rate (--realtime)", device);
    ro.realtime = true;
  }
  *rec = std::make_unique<StreamRecording>((*stream)->name(), ro.out / "frames", camera, *ro.camera);
}

// The saved map to start from (map_store.h): verified, and refused when made with another camera.
// Its size is kept for the report: SlamSystem takes the map.
struct StartMap {
  LoadedMap loaded;
  std::size_t keyframes = 0, points = 0;
};

StartMap openStartMap(const RunOptions& ro, const Camera& camera) {
  StartMap s;
  if (!ro.map) return s;
  s.loaded = loadMapFolder(*ro.map, camera);
  s.keyframes = s.loaded.map ? s.loaded.map->numKeyframes() : 0;
  s.points = s.loaded.map ? s.loaded.map->numPoints() : 0;
  return s;
}

// ---- Reading: the reader thread decodes frames and hands them to the tracking thread.

struct InputFrame {
  std::size_t index = 0;
  double timestamp = 0;
  cv::Mat image;
  std::string problem;  // a camera's frame: describeFrameProblem(), found by the reader, not by tracking
};

// What the reader and the tracking thread share. The failure messages are each written by one
// thread and read once both have been joined.
struct FramePipe {
  FramePipe(const SystemOptions& sys, const RunOptions& ro, std::size_t frames)
      : queue(static_cast<std::size_t>(sys.frame_queue),
              ro.realtime ? OverflowPolicy::kDropOldest : OverflowPolicy::kDropNewest),
        image_problems(frames) {}
  BoundedQueue<InputFrame> queue;
  std::atomic<std::size_t> processed{0};     // frames the tracking thread is done with
  std::atomic<std::size_t> queued{0};        // frames the reader handed over
  std::atomic<std::size_t> out_of_order{0};  // frames skipped for a timestamp not after the previous one
  std::atomic<bool> aborted{false};          // the tracking thread failed
  std::atomic<bool> tracking_done{false};    // the tracking thread has left its loop
  // Stopped by a signal (core/stop_signal.h): the index of the first frame not read, -1 otherwise.
  std::atomic<long long> stopped_at_frame{-1};
  // A camera (readStream): the recording every frame that reaches tracking goes into (the tracking
  // thread appends it and tracks it under the index it gets, or drops it when the recording's writer
  // lags: not_recorded), the frames read from the device, and the tracking thread's word that
  // --max-frames frames were tracked.
  StreamRecording* recording = nullptr;
  std::atomic<std::size_t> frames_read{0};
  std::atomic<std::size_t> not_recorded{0};  // dropped by the tracking thread: the recording's writer lagged
  std::atomic<bool> enough{false};
  std::string read_failure, tracking_failure;
  // The tracked poses as tracking made them (before the bundle adjustments that follow), appended by
  // the tracking thread and read by the checkpoint writer on the main thread.
  std::mutex live_mutex;
  Trajectory live;
  // By frame: describeImageProblem() ("" for most). Written by the reader, by index (a dataset), or
  // by the tracking thread, appended (a camera).
  std::vector<std::string> image_problems;
};

// Hands a frame read to the tracking thread: --realtime drops the oldest waiting frame when tracking
// lags; otherwise the reader waits for room, and in lockstep until the frame is tracked (or
// tracking failed, or --max-frames were tracked) and mapping is idle. False: the queue was closed.
bool handOver(FramePipe& pipe, InputFrame f, bool realtime, bool lockstep, SlamSystem& slam) {
  if (realtime) {
    pipe.queue.tryPush(std::move(f));
    ++pipe.queued;
    return true;
  }
  if (!pipe.queue.push(std::move(f))) return false;
  ++pipe.queued;
  if (lockstep) {
    while (pipe.processed.load() < pipe.queued.load() && !pipe.aborted && !pipe.enough)
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    slam.waitMappingIdle();
  }
  return true;
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

std::string describeFrameProblem(const cv::Mat& image) {
  if (image.channels() == 1) return describeImageProblem(image);
  cv::Mat grey;
  cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  return describeImageProblem(grey);
}

// The reader thread's loop. Frames whose timestamp is not after the previous one are skipped. With
// --realtime frames are paced at their timestamps (the queue drops the oldest waiting frame when
// tracking lags); otherwise the reader waits for room in the queue and, in lockstep, until each frame
// is tracked and mapping is idle. The memory and map size at the end of every window of frames
// (RunStats) are taken here: the map counts take the map's lock, which the tracking thread never
// waits for.
void readFrames(const Dataset& ds, SlamSystem& slam, const RunOptions& ro, const SystemOptions& sys, FramePipe& pipe,
                RunStats& stats) {
  setThreadName("nerfslam-read");
  const bool lockstep = !ro.realtime && sys.lockstep;
  const auto wall0 = Clock::now();
  double t_first = 0, last_ts = -std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < ds.size() && !pipe.aborted; ++i) {
    if (stopRequests() > 0) {
      pipe.stopped_at_frame = static_cast<long long>(i);
      break;
    }
    InputFrame f;
    try {
      // Colour for the NeRF (tracking converts to grey itself).
      DatasetFrame df = ds.load(i, sys.nerf.enabled ? ImageMode::kColor : ImageMode::kGray);
      f.index = i;
      f.timestamp = df.timestamp;
      f.image = std::move(df.image);
    } catch (const std::exception& e) {
      pipe.read_failure = e.what();
      spdlog::error("{}", e.what());
      break;
    }
    if (!(f.timestamp > last_ts)) {
      ++pipe.out_of_order;
      spdlog::warn("frame {}: timestamp {} not after the previous {}; skipped", i, numberForMessage(f.timestamp),
                   numberForMessage(last_ts));
      continue;
    }
    last_ts = f.timestamp;
    pipe.image_problems[i] = describeFrameProblem(f.image);
    if (i == 0) t_first = f.timestamp;
    if (ro.realtime) {
      const auto due =
          wall0 + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(f.timestamp - t_first));
      // In slices, so that a stop request does not wait for a long gap between timestamps.
      while (Clock::now() < due && stopRequests() == 0)
        std::this_thread::sleep_until(std::min(due, Clock::now() + std::chrono::milliseconds(100)));
    }
    if (!handOver(pipe, std::move(f), ro.realtime, lockstep, slam)) break;
    if (pipe.queued.load() % RunStats::kWindow == 0)
      stats.addWindowSample({currentRssMb(), slam.map().numKeyframes(), slam.map().numPoints()});
  }
  pipe.queue.close();
}

// A stream's 8-bit frame (grey, BGR or BGRA) as BGR (`colour`) or grey.
cv::Mat convertStreamImage(const cv::Mat& in, bool colour) {
  cv::Mat out;
  const int ch = in.channels();
  if (ch == (colour ? 3 : 1)) return in;
  if (ch == 1)
    cv::cvtColor(in, out, cv::COLOR_GRAY2BGR);
  else if (ch == 3)
    cv::cvtColor(in, out, cv::COLOR_BGR2GRAY);
  else
    cv::cvtColor(in, out, colour ? cv::COLOR_BGRA2BGR : cv::COLOR_BGRA2GRAY);
  return out;
}

// The reader thread's loop for a camera: frames as the stream delivers them (no pacing: the device
// is the clock), each checked against the calibration's size, handed over as readFrames does (with
// --realtime the queue drops the oldest waiting frame; otherwise, for an injected source, the reader
// waits for tracking). Ends at a stop request, when the tracking thread has had --max-frames frames,
// at the end of the stream, or when it fails (read_failure names the device).
void readStream(FrameStream& stream, const Camera& camera, SlamSystem& slam, const RunOptions& ro,
                const SystemOptions& sys, FramePipe& pipe, RunStats& stats) {
  setThreadName("nerfslam-read");
  const bool lockstep = !ro.realtime && sys.lockstep;
  double last_ts = -std::numeric_limits<double>::infinity();
  while (!pipe.aborted && !pipe.enough) {
    if (stopRequests() > 0) {
      pipe.stopped_at_frame = static_cast<long long>(pipe.frames_read.load());
      break;
    }
    StreamFrame sf;
    std::string why;
    bool ok = false;
    try {
      ok = stream.read(sf, why);
    } catch (const std::exception& e) {
      why = fmt::format("{}: {}", stream.name(), e.what());
    }
    if (!ok) {
      if (!why.empty()) {
        pipe.read_failure = why;
        spdlog::error("{}", why);
      }
      break;
    }
    const std::size_t n = pipe.frames_read++;
    const int ch = sf.image.channels();
    if (sf.image.cols != camera.width || sf.image.rows != camera.height || sf.image.depth() != CV_8U ||
        (ch != 1 && ch != 3 && ch != 4)) {
      pipe.read_failure = fmt::format(
          "{}: frame {} is {}x{} ({} channel(s), depth {}), the camera YAML is for {}x{} 8-bit frames", stream.name(),
          n, sf.image.cols, sf.image.rows, sf.image.channels(), sf.image.depth(), camera.width, camera.height);
      spdlog::error("{}", pipe.read_failure);
      break;
    }
    if (!(sf.timestamp > last_ts)) {
      ++pipe.out_of_order;
      spdlog::warn("{}: frame {}: timestamp {} not after the previous {}; skipped", stream.name(), n,
                   numberForMessage(sf.timestamp), numberForMessage(last_ts));
      continue;
    }
    last_ts = sf.timestamp;
    InputFrame f;
    f.index = n;  // the tracking thread gives it its index in the recording
    f.timestamp = sf.timestamp;
    // Colour for the NeRF (tracking converts to grey itself), else grey, as readFrames loads them.
    f.image = convertStreamImage(sf.image, sys.nerf.enabled);
    f.problem = describeFrameProblem(f.image);
    if (!handOver(pipe, std::move(f), ro.realtime, lockstep, slam)) break;
    if (pipe.queued.load() % RunStats::kWindow == 0)
      stats.addWindowSample({currentRssMb(), slam.map().numKeyframes(), slam.map().numPoints()});
  }
  pipe.queue.close();
}

// ---- The system: tracking on the tracking thread (mapping and the NeRF run on SlamSystem's own).

// The progress line on stderr.
void printProgress(SlamSystem& slam, std::size_t index, std::size_t frames, std::size_t processed, double secs) {
  std::string nerf_line;
  if (const NerfMapping* n = slam.nerf()) {
    const NerfMappingStats ns = n->stats();
    nerf_line = fmt::format("  | NeRF {} views, {} steps, {:.1f} steps/s, {:.2f} M samples/s, PSNR {:.1f} dB", ns.views,
                            ns.steps, ns.steps_per_second, ns.samples_per_second / 1e6, ns.psnr_recent);
    if (ns.psnr_heldout > 0) nerf_line += fmt::format(" (held-out {:.1f} dB)", ns.psnr_heldout);
  }
  // frames 0: a camera, no total.
  const std::string total = frames > 0 ? fmt::format("/{}", frames) : "";
  std::fprintf(stderr, "frame %zu%s  %.1f frames/s  keyframes %zu  map points %zu  %s%s\n", index + 1, total.c_str(),
               processed / std::max(secs, 1e-9), slam.map().numKeyframes(), slam.map().numPoints(),
               toString(slam.state()), nerf_line.c_str());
}

// The tracking thread's loop: tracks the queued frames until the reader closes the queue. A frame
// that throws ends the run (the reader stops too).
void trackFrames(SlamSystem& slam, const RunOptions& ro, std::size_t frames, Clock::time_point run0, FramePipe& pipe,
                 RunStats& stats) {
  setThreadName("nerfslam-track");
  auto last_print = Clock::now();
  while (auto f = pipe.queue.pop()) {
    try {
      if (pipe.recording) {  // a camera: the frame reaches tracking, so it is recorded, under its index there
        const std::optional<std::size_t> index = pipe.recording->tryAppend(f->timestamp, f->image);
        if (!index) {
          // The disk is slower than the camera: the frame is dropped (not recorded, not tracked)
          // rather than tracking waiting for the PNG writer.
          if (pipe.not_recorded++ % 100 == 0)
            spdlog::warn("camera: the recording of {} is {} frames behind; frame dropped ({} so far)",
                         pipe.recording->folder().string(), StreamRecording::kMaxPending, pipe.not_recorded.load());
          ++pipe.processed;
          continue;
        }
        f->index = *index;
        pipe.image_problems.push_back(std::move(f->problem));
      }
      const bool had_map = slam.initialized();
      const FrameRecord rec = slam.trackFrame(f->image, f->timestamp, f->index);
      stats.addFrame(rec, had_map);
      if (rec.tracked) {
        std::lock_guard<std::mutex> lock(pipe.live_mutex);
        pipe.live.push_back({rec.timestamp, rec.T_world_cam});
      }
    } catch (const std::exception& e) {
      pipe.tracking_failure = fmt::format("frame {}: {}", f->index, e.what());
      spdlog::error("{}", pipe.tracking_failure);
      pipe.aborted = true;
      ++pipe.processed;
      pipe.queue.close();
      break;
    }
    ++pipe.processed;
    if (ro.progress && (Clock::now() - last_print > std::chrono::seconds(1))) {
      last_print = Clock::now();
      printProgress(slam, f->index, frames, pipe.processed.load(),
                    std::chrono::duration<double>(Clock::now() - run0).count());
    }
    if (pipe.recording && ro.max_frames > 0 && pipe.recording->size() >= ro.max_frames) {
      pipe.enough = true;  // the frames still queued never reach tracking
      pipe.queue.close();
      break;
    }
  }
}

// While tracking runs: trajectory.txt (the poses as tracked) and report.json ("in_progress": true)
// replaced atomically every few seconds, so a run that is killed (SIGKILL, a power cut) leaves a
// trajectory prefix that `nerfslam eval` reads. The final outputs replace both.
class Checkpointer {
 public:
  Checkpointer(const std::filesystem::path& out, const Dataset& ds) : out_(out), ds_(ds) {}

  // Writes when kIntervalSeconds (or ten times the last write's duration) have passed.
  void maybeWrite(FramePipe& pipe, Clock::time_point run0) {
    const auto now = Clock::now();
    if (now - last_ < interval_) return;
    last_ = now;
    {
      std::lock_guard<std::mutex> lock(pipe.live_mutex);
      if (pipe.live.size() == written_) return;
      traj_.insert(traj_.end(), pipe.live.begin() + static_cast<std::ptrdiff_t>(traj_.size()), pipe.live.end());
    }
    try {
      writeTumTrajectory(out_ / "trajectory.txt", traj_);
      nlohmann::json rep;
      rep["in_progress"] = true;
      rep["dataset"] = ds_.root().string();
      rep["frames"] = ds_.size();
      rep["frames_processed"] = pipe.processed.load();
      rep["frames_tracked"] = traj_.size();
      rep["wall_time_s"] = std::chrono::duration<double>(now - run0).count();
      writeStringAtomic(out_ / "report.json", rep.dump(2) + "\n");
      written_ = traj_.size();
    } catch (const std::exception& e) {
      spdlog::warn("checkpoint: {}", e.what());  // the final write reports a lasting problem
    }
    interval_ = std::max<Clock::duration>(
        std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(kIntervalSeconds)),
        10 * (Clock::now() - now));
  }

  static constexpr double kIntervalSeconds = 2.0;

 private:
  std::filesystem::path out_;
  const Dataset& ds_;
  Trajectory traj_;
  std::size_t written_ = 0;
  Clock::time_point last_ = Clock::now();
  Clock::duration interval_ = std::chrono::seconds(2);
};

// After the last frame: the NeRF trained for final_train_seconds more with the final poses (or
// final_train_steps steps); after a stop request at most kShortenedFinalSeconds more, after a second
// one no more. Returns false when a second request skipped or ended it; *done: the steps it made.
bool trainNerfFinal(SlamSystem& slam, const SystemOptions& sys, int64_t* done) {
  *done = 0;
  NerfMapping* n = slam.nerf();
  const int64_t steps = sys.nerf.final_train_steps;
  if (!n || !n->hasModel() || !(sys.nerf.final_train_seconds > 0 || steps > 0)) return true;
  if (stopRequests() >= 2) return false;
  // By steps: no time limit of its own (1e6 s), only the stop requests'.
  double seconds = steps > 0 ? 1e6 : sys.nerf.final_train_seconds;
  if (stopRequests() >= 1) seconds = std::min(seconds, kShortenedFinalSeconds);
  if (steps > 0 && stopRequests() == 0)
    std::fprintf(stderr, "training the NeRF map for %lld steps more with the final poses...\n", (long long)steps);
  else
    std::fprintf(stderr, "training the NeRF map for %.0f s more with the final poses...\n", seconds);
  // A first request during the training leaves it kShortenedFinalSeconds from then; a second ends it.
  auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  bool shortened = stopRequests() >= 1;
  *done = n->trainFor(seconds, steps, resolveThreads(sys.nerf.final_threads), [&] {
    const int requests = stopRequests();
    if (requests >= 2) return true;
    if (requests >= 1 && !shortened) {
      shortened = true;
      deadline = std::min(deadline, Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                                       std::chrono::duration<double>(kShortenedFinalSeconds)));
    }
    return Clock::now() >= deadline;
  });
  return stopRequests() < 2;
}

// ---- Outputs: the files and report.json.

// loop_closing (enabled), loop_closures (one object per closed loop) and loop_closing_ms (detection per
// keyframe: median, p99, max; correction per loop: the same).
void addLoopClosing(const SlamSystem& slam, nlohmann::json& rep) {
  const LoopClosing* lc = slam.loopClosing();
  rep["loop_closing"] = lc != nullptr;
  rep["loop_closures"] = nlohmann::json::array();
  if (!lc) return;
  std::vector<double> correction;
  for (const LoopClosureRecord& c : lc->closures()) {
    rep["loop_closures"].push_back({{"frame", c.frame},
                                    {"loop_frame", c.loop_frame},
                                    {"keyframe", c.current},
                                    {"loop_keyframe", c.loop},
                                    {"sim3_scale", c.sim3_scale},
                                    {"correction_translation", c.correction_m},
                                    {"correction_rotation_deg", c.correction_deg},
                                    {"sim3_inliers", c.sim3_inliers},
                                    {"projection_matches", c.projection_matches},
                                    {"fused_points", c.fused_points},
                                    {"corrected_keyframes", c.corrected_keyframes},
                                    {"detection_ms", c.detection_ms},
                                    {"correction_ms", c.correction_ms}});
    correction.push_back(c.correction_ms);
  }
  const auto summary = [](std::vector<double> v) {
    nlohmann::json j = {{"count", v.size()}};
    if (v.empty()) return j;
    std::sort(v.begin(), v.end());
    j["median"] = v[v.size() / 2];
    j["p99"] = v[std::min(v.size() - 1, static_cast<size_t>(0.99 * double(v.size())))];
    j["max"] = v.back();
    return j;
  };
  rep["loop_closing_ms"] = {{"detection", summary(lc->detectionTimes())}, {"correction", summary(correction)}};
  rep["loop_closing_dropped_keyframes"] = lc->droppedKeyframes();
  // The background global BAs after the closures: the written ones' times, and each one.
  std::vector<double> gba_ms;
  int gba_stopped = 0;
  rep["global_bas"] = nlohmann::json::array();
  for (const GlobalBaRecord& g : lc->globalBas()) {
    if (g.stopped)
      ++gba_stopped;
    else
      gba_ms.push_back(g.solve_ms + g.write_ms);
    rep["global_bas"].push_back({{"after_closure", g.closure},
                                 {"keyframes", g.keyframes},
                                 {"points", g.points},
                                 {"iterations", g.iterations},
                                 {"outliers", g.outliers},
                                 {"rmse_before_px", g.rmse_before_px},
                                 {"rmse_after_px", g.rmse_after_px},
                                 {"propagated_keyframes", g.propagated_keyframes},
                                 {"propagated_points", g.propagated_points},
                                 {"stopped", g.stopped},
                                 {"solve_ms", g.solve_ms},
                                 {"write_ms", g.write_ms}});
  }
  rep["global_ba_ms"] = summary(gba_ms);
  rep["global_ba_stopped"] = gba_stopped;
  rep["loop_corrections_applied_by_tracking"] = slam.loopCorrectionsApplied();
}

// The report's fields on the run itself: the dataset, the frames, the system's state at the end.
nlohmann::json runReport(const Dataset& ds, const RunOptions& ro, const SlamSystem& slam, const FramePipe& pipe,
                         const StartMap& start, std::size_t frames_tracked, double wall_s) {
  nlohmann::json rep;
  rep["dataset"] = ds.root().string();
  rep["dataset_kind"] = ds.kind();
  rep["frames"] = ds.size();
  rep["frames_processed"] = pipe.processed.load();
  rep["frames_dropped"] = ro.realtime ? pipe.queue.dropped() : 0;
  rep["frames_out_of_order"] = pipe.out_of_order.load();
  rep["frames_tracked"] = frames_tracked;
  rep["initialized"] = slam.initialized();
  rep["initializations"] = slam.initializationCount();
  rep["initialization_model"] = slam.initializationModel();
  rep["relocalizations"] = slam.relocalizations();
  rep["local_map_rebuilds"] = slam.localMapRebuilds();
  rep["mode"] = toString(slam.mapMode());
  rep["map_loaded"] = ro.map ? nlohmann::json(ro.map->string()) : nlohmann::json(nullptr);
  rep["relocalized_at_frame"] = slam.relocalizedAtFrame();
  {  // CPU time of each relocalisation attempt (keyframe-database query, then PnP on the candidates)
    std::vector<double> ms;
    for (const FrameRecord& r : slam.records())
      if (r.relocalization_attempted) ms.push_back(r.relocalize_cpu_ms);
    std::sort(ms.begin(), ms.end());
    nlohmann::json j = {{"attempts", ms.size()}};
    if (!ms.empty()) {
      j["median"] = ms[ms.size() / 2];
      j["max"] = ms.back();
    }
    rep["relocalization_cpu_ms"] = j;
  }
  if (ro.map) {
    rep["map_loaded_keyframes"] = start.keyframes;
    rep["map_loaded_points"] = start.points;
    rep["map_load_s"] = start.loaded.seconds;
  }
  rep["keyframes"] = slam.map().numKeyframes();
  rep["keyframes_dropped"] = slam.droppedKeyframes();
  rep["map_points"] = slam.map().numPoints();
  rep["realtime"] = ro.realtime;
  rep["wall_time_s"] = wall_s;
  rep["peak_rss_mb"] = peakRssMb();
  rep["frames_per_second"] = pipe.processed.load() / std::max(wall_s, 1e-9);
  rep["nerf"] = slam.nerf() != nullptr;
  addLoopClosing(slam, rep);
  return rep;
}

// first_tracked_frame (-1: none) and frames_lost_after_init (frames after it that were not tracked).
void addTrackingContinuity(const std::vector<FrameRecord>& records, nlohmann::json& rep) {
  int first_tracked = -1;
  for (const auto& r : records)
    if (r.tracked) {
      first_tracked = static_cast<int>(r.index);
      break;
    }
  rep["first_tracked_frame"] = first_tracked;
  std::size_t untracked_after = 0;
  if (first_tracked >= 0)
    for (const auto& r : records) untracked_after += (static_cast<int>(r.index) > first_tracked && !r.tracked);
  rep["frames_lost_after_init"] = untracked_after;
}

// Why the run failed: a frame that could not be read or tracked, or no initialisation (with the
// frames' image problems and the last attempt's message). Empty: it did not.
std::string runFailure(const FramePipe& pipe, const SlamSystem& slam) {
  std::string failure;
  if (!pipe.read_failure.empty()) failure = pipe.read_failure;
  if (!pipe.tracking_failure.empty()) failure = pipe.tracking_failure;
  if (!failure.empty() || slam.initialized()) return failure;
  std::size_t black = 0, saturated = 0, uniform = 0;
  for (const auto& p : pipe.image_problems) {
    black += p == "black";
    saturated += p == "saturated";
    uniform += p == "uniform";
  }
  failure = fmt::format("not initialised after {} frames", pipe.processed.load());
  if (black + saturated + uniform > 0)
    failure += fmt::format(" ({} black, {} saturated, {} featureless frames)", black, saturated, uniform);
  if (!slam.lastInitMessage().empty()) failure += "; last attempt: " + slam.lastInitMessage();
  return failure;
}

struct GroundTruthEval {
  Trajectory reference;           // empty without ground truth or with fewer than 3 tracked frames
  std::optional<Sim3> alignment;  // estimate -> ground truth, when the evaluation succeeded
};

// The estimate against the dataset's ground truth (Sim(3)-aligned): the ate_*, rpe_*, path_length_m,
// gt_extent_m and ate_max_percent_of_extent fields, or eval_error.
GroundTruthEval evaluateAgainstGroundTruth(const Dataset& ds, const Trajectory& traj, nlohmann::json& rep) {
  GroundTruthEval ge;
  if (!ds.hasGroundTruth() || traj.size() < 3) return ge;
  Trajectory& ref = ge.reference;
  for (std::size_t i = 0; i < ds.size(); ++i)
    if (auto gt = ds.groundTruth(i)) ref.push_back({ds.timestamp(i), *gt});
  try {
    TrajectoryEvalOptions eo;
    eo.align = "sim3";
    eo.max_dt = 1e-3;
    const TrajectoryReport tr = evaluateTrajectory(ref, traj, eo);
    ge.alignment = tr.alignment;
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
    // Under SE(3) alignment (no scale fitted): meaningful for a metric map (scale_source "odometry");
    // for a monocular one beside it for comparison.
    eo.align = "se3";
    const TrajectoryReport se3 = evaluateTrajectory(ref, traj, eo);
    rep["ate_se3_rmse_m"] = se3.ape.rmse;
    rep["ate_se3_percent_of_path"] = se3.ape_rmse_percent;
  } catch (const std::exception& e) {
    rep["eval_error"] = e.what();
  }
  return ge;
}

// trajectory.txt, keyframes.txt, map_points.ply, the NeRF outputs (run_outputs.h; a failure there is
// nerf_error in the report) and the previews.
void writeRunFiles(SlamSystem& slam, const Dataset& ds, const Trajectory& traj, const GroundTruthEval& ge,
                   const std::filesystem::path& out, const NerfEvalOptions& eo, nlohmann::json& rep) {
  writeTumTrajectory(out / "trajectory.txt", traj);
  addRunOutput(rep, "trajectory.txt");
  writeTumTrajectory(out / "keyframes.txt", slam.keyframeTrajectory());
  addRunOutput(rep, "keyframes.txt");
  writeMapPly(out / "map_points.ply", slam.map());
  addRunOutput(rep, "map_points.ply");
  PreviewCloud dense;
  if (slam.nerf()) {
    try {
      writeNerfOutputs(slam, ds, traj, ge.alignment, out, eo, rep, &dense);
    } catch (const std::exception& e) {
      rep["nerf_error"] = e.what();
      rep["nerf_outputs_failed"] = true;  // a write that failed: the run's exit status is 1
      spdlog::error("NeRF outputs: {}", e.what());
    }
  }
  writeRunPreviews(slam, traj, ge.reference, ge.alignment, dense, rep, out);
}

// The map folder (map_store.h), with the NeRF model: --save-map DIR, else OUT/map (not after
// --localize: the map is as loaded), when the map has keyframes. Adds map_saved, map_save_s and
// map_bytes, or map_save_error. Returns true when saving to --save-map failed (the run then exits
// with 1; OUT/map failing is only reported).
bool saveRunMap(SlamSystem& slam, const RunOptions& ro, const Camera& camera, const SystemOptions& sys,
                nlohmann::json& rep) {
  std::optional<std::filesystem::path> map_dir = ro.save_map;
  if (!map_dir && ro.save_default_map && ro.map_mode != MapMode::kLocalize) map_dir = ro.out / "map";
  if (!map_dir || slam.map().numKeyframes() == 0) return false;
  // The NeRF model goes into the map folder too (written under the model lock).
  NerfModelWriter write_nerf_model;
  if (NerfMapping* n = slam.nerf(); n && n->hasModel())
    write_nerf_model = [n](const std::filesystem::path& p) {
      n->withModel([&](nerf::NerfModel& m) { nerf::saveModel(m, p); });
    };
  try {
    const MapSaveResult ms = saveMapFolder(*map_dir, slam.map(), camera, sys, write_nerf_model);
    rep["map_saved"] = map_dir->string();
    std::error_code ec;
    const std::filesystem::path rel = std::filesystem::relative(*map_dir, ro.out, ec);
    addRunOutput(rep, (ec || rel.empty() || *rel.begin() == ".." ? map_dir->string() : rel.string()) + "/");
    rep["map_save_s"] = ms.seconds;
    rep["map_bytes"] = ms.bytes;
  } catch (const std::exception& e) {
    rep["map_save_error"] = e.what();
    spdlog::error("saving the map: {}", e.what());
    return ro.save_map.has_value();
  }
  return false;
}

// The summary on stderr.
void printSummary(const SlamSystem& slam, const Dataset& ds, const Trajectory& traj, const nlohmann::json& rep,
                  const std::string& failure, double frames_per_second, const std::filesystem::path& out) {
  std::fprintf(stderr, "done: %zu/%zu frames tracked, %zu keyframes, %zu map points, %.1f frames/s%s\n", traj.size(),
               ds.size(), slam.map().numKeyframes(), slam.map().numPoints(), frames_per_second,
               failure.empty() ? "" : (" — " + failure).c_str());
  if (rep.contains("ate_rmse_m"))
    std::fprintf(stderr, "ATE (Sim3) %.4f m = %.3f%% of %.1f m path, scale %.4f\n", rep["ate_rmse_m"].get<double>(),
                 rep["ate_percent_of_path"].get<double>(), rep["path_length_m"].get<double>(),
                 rep["ate_scale"].get<double>());
  if (rep.contains("ate_se3_rmse_m"))
    std::fprintf(stderr, "ATE (SE3, no scale fitted) %.4f m = %.3f%% of the path; scale from %s\n",
                 rep["ate_se3_rmse_m"].get<double>(), rep["ate_se3_percent_of_path"].get<double>(),
                 rep.value("scale_source", "none").c_str());
  if (rep.contains("nerf_psnr_heldout"))
    std::fprintf(stderr, "NeRF: %lld steps, held-out PSNR %.2f dB (%zu frames), keyframes %.2f dB%s\n",
                 static_cast<long long>(rep["nerf_steps"].get<int64_t>()), rep["nerf_psnr_heldout"].get<double>(),
                 rep["nerf_psnr_heldout_frames"].get<size_t>(), rep["nerf_psnr_keyframes"].get<double>(),
                 rep.contains("nerf_depth_median_abs_rel")
                     ? fmt::format(", depth error (median abs rel) {:.1f}%",
                                   100 * rep["nerf_depth_median_abs_rel"].get<double>())
                           .c_str()
                     : "");
  if (rep.value("interrupted", false))
    std::fprintf(stderr, "interrupted%s; skipped: %s\n",
                 rep["interrupted_at_frame"].is_null()
                     ? " after the last frame"
                     : fmt::format(" at frame {}", rep["interrupted_at_frame"].get<long long>()).c_str(),
                 rep["skipped"].empty()
                     ? "nothing"
                     : fmt::format("{}", fmt::join(rep["skipped"].get<std::vector<std::string>>(), ", ")).c_str());
  // What was written (a NeRF output that failed is not among them: nerf_error says why).
  std::string written;
  for (const auto& o : rep.value("outputs", nlohmann::json::array()))
    written += (written.empty() ? "" : ", ") + o.get<std::string>();
  std::fprintf(stderr, "results in %s (%s)\n", out.string().c_str(), written.c_str());
  if (rep.contains("nerf_error"))
    std::fprintf(stderr, "NeRF outputs not written: %s\n", rep["nerf_error"].get<std::string>().c_str());
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

RunResult runSlam(const RunOptions& options) {
  RunOptions ro = options;  // a camera implies realtime
  const SystemOptions sys = loadRunOptions(ro);
  // A dataset, or a camera's stream and the recording of its frames (the dataset of the outputs).
  std::unique_ptr<FrameStream> stream;
  std::unique_ptr<StreamRecording> recording;
  std::unique_ptr<Dataset> dataset;
  if (isCameraSpec(ro.dataset)) {
    openRunStream(ro, &stream, &recording);
  } else {
    dataset = openRunDataset(ro);
    refuseOutputsInDataset(ro, *dataset);
  }
  const Dataset* ds = recording ? static_cast<const Dataset*>(recording.get()) : dataset.get();
  std::string odometry_from;
  const std::shared_ptr<const OdometryTrack> odometry = openRunOdometry(ro, sys, *ds, &odometry_from);
  ensureDirectory(ro.out);
  const Camera& camera = ds->camera();
  spdlog::info("dataset {} ({}), {} frames, camera {}", ds->root().string(), ds->kind(), ds->size(), camera.describe());
  spdlog::info("options:\n{}", printOptions(sys));
  StartMap start = openStartMap(ro, camera);
  const std::unique_ptr<SlamSystem> slam_owner = startSlamSystem(camera, sys, start.loaded, ro.map_mode);
  SlamSystem& slam = *slam_owner;
  if (odometry) slam.setOdometry(odometry);

  // Reading and the system: the reader thread feeds the tracking thread.
  FramePipe pipe(sys, ro, ds->size());
  pipe.recording = recording.get();
  RunStats stats;
  std::thread reader([&] {
    if (stream)
      readStream(*stream, camera, slam, ro, sys, pipe, stats);
    else
      readFrames(*ds, slam, ro, sys, pipe, stats);
  });
  const auto run0 = Clock::now();
  std::thread tracker([&] {
    trackFrames(slam, ro, stream ? 0 : ds->size(), run0, pipe, stats);
    pipe.tracking_done = true;
  });
  // The main thread keeps trajectory.txt and report.json up to date meanwhile.
  Checkpointer checkpoint(ro.out, *ds);
  while (!pipe.tracking_done) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    checkpoint.maybeWrite(pipe, run0);
  }
  reader.join();
  tracker.join();
  const double wall_s = std::chrono::duration<double>(Clock::now() - run0).count();
  if (recording) {  // every recorded frame on disk before the outputs read them
    try {
      recording->flush();
    } catch (const std::exception& e) {
      if (pipe.read_failure.empty()) pipe.read_failure = e.what();
      spdlog::error("{}", e.what());
    }
  }
  // Stopped by a signal (core/stop_signal.h): a second one skips what only improves the result.
  std::vector<std::string> skipped;
  const bool global_ba = stopRequests() < 2;
  if (!global_ba) skipped.push_back("global_ba");
  // A second signal during the global BA ends it after the iteration in hand.
  slam.finish(global_ba, [] { return stopRequests() >= 2; });
  int64_t final_steps = 0;
  if (!trainNerfFinal(slam, sys, &final_steps)) skipped.push_back("final_nerf_training");
  NerfEvalOptions eval_options = sys.nerf.outputs;
  eval_options.model_only = stopRequests() >= 2;
  if (eval_options.model_only && slam.nerf()) skipped.push_back("nerf_renders_cloud_mesh");

  // Outputs.
  const Trajectory traj = slam.trajectory();
  nlohmann::json rep = runReport(*ds, ro, slam, pipe, start, traj.size(), wall_s);
  stats.setMapping(slam.mapping().stats());
  stats.writeReport(rep, slam.nerf() != nullptr);
  addTrackingContinuity(slam.records(), rep);
  if (slam.nerf()) rep["nerf_final_train_steps"] = final_steps;
  const std::string failure = runFailure(pipe, slam);
  if (!failure.empty()) rep["failure"] = failure;
  const bool interrupted = stopRequests() > 0;
  rep["interrupted"] = interrupted;
  if (interrupted) {
    rep["interrupted_by_signal"] = lastStopSignal();
    // The first frame not read; null when the signal came after the last frame was read.
    rep["interrupted_at_frame"] =
        pipe.stopped_at_frame >= 0 ? nlohmann::json(pipe.stopped_at_frame.load()) : nlohmann::json(nullptr);
    rep["skipped"] = skipped;
  }
  if (recording) {
    rep["camera"] = {{"device", stream->name()},
                     {"frames_read", pipe.frames_read.load()},
                     {"frames_recorded", recording->size()},
                     {"frames_dropped_recording_behind", pipe.not_recorded.load()},
                     {"recorded_to", recording->folder().string()}};
    addRunOutput(rep, "frames/");
  }
  const GroundTruthEval ge = evaluateAgainstGroundTruth(*ds, traj, rep);
  addScaleReport(slam, odometry_from, rep);
  writeRunFiles(slam, *ds, traj, ge, ro.out, eval_options, rep);
  const bool map_save_failed = saveRunMap(slam, ro, camera, sys, rep);
  addRunOutput(rep, "report.json");
  writeStringAtomic(ro.out / "report.json", rep.dump(2) + "\n");
  printSummary(slam, *ds, traj, rep, failure, pipe.processed.load() / std::max(wall_s, 1e-9), ro.out);

  RunResult res;
  res.report = rep;
  res.initialized = slam.initialized();
  const bool failed = !pipe.read_failure.empty() || !pipe.tracking_failure.empty() || map_save_failed ||
                      rep.value("nerf_outputs_failed", false);
  res.exit_code = failed ? 1 : interrupted ? interruptedExitCode() : 0;
  return res;
}

}  // namespace nerfslam
