// `nerfslam train`: trains a NeRF on a transforms.json dataset (NeRF-synthetic / instant-ngp layout),
// holding out every Nth view for testing. Writes model.nerf, report.json, psnr_curve.csv and
// side-by-side test renders (render | ground truth) into --out, all atomically.
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>

#include <spdlog/spdlog.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "command.h"
#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/core/statistics.h"
#include "nerfslam/core/stop_signal.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/eval/image_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/nerf/trainer.h"
#include "nerfslam/system/slam_system.h"

namespace nerfslam::cli {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

struct TrainArgs {
  std::string transforms;
  std::string out;
  double seconds = 0;
  int64_t steps = 0;
  int test_every = 8;
  double downscale = 1.0;
  int threads = 2;
  int64_t seed = 0;
  double eval_interval = 10.0;
  int curve_views = 3;
  int samples_per_step = 1 << 16;
  // Frames with a depth image (transforms.json depth_path / depth_file_path): at most this many of
  // its pixels supervise each training view's depth (nerf.train.depth_*); 0: training ignores depth.
  // Test views' depth images give the report's depth error either way.
  int depth_points = 1000;
  // A `run --config` file: its nerf.train options (the same keys, docs/options.md) train here too;
  // --threads, --seed and --samples-per-step given on the command line override them.
  std::string config;
  bool threads_given = false, seed_given = false, samples_given = false;
};

struct Split {
  std::vector<nerf::TrainingView> train, test;
  std::vector<std::string> test_names;
  std::vector<cv::Mat> test_depth;  // per test view: depth at its (downscaled) size, or empty
  size_t depth_views = 0, depth_points = 0;
};

Split loadSplit(const TrainArgs& a, nerf::SceneTransform* scene) {
  const std::string spec = "transforms:" + a.transforms;
  auto ds = openDataset(spec);
  scene->aabb_scale = ds->aabbScale().value_or(1.0);
  if (const auto ns = ds->nerfScene()) {
    scene->scale = ns->scale;
    scene->offset = ns->offset;
  }
  Split s;
  for (size_t i = 0; i < ds->size(); ++i) {
    const DatasetFrame f = ds->load(i, ImageMode::kUnchanged);
    if (!f.T_world_cam) throw fieldError(a.transforms, fmt::format("frames[{}].transform_matrix", i), "missing");
    if (f.image.depth() != CV_8U)
      throw fieldError(f.path, "image", "only 8-bit images are supported for NeRF training");
    auto v = nerf::makeTrainingView(f.image, ds->camera(), *f.T_world_cam, a.downscale, f.path);
    const bool test = a.test_every > 0 && i % size_t(a.test_every) == 0;
    const cv::Mat depth = test || a.depth_points > 0 ? ds->loadDepth(i) : cv::Mat();
    if (!depth.empty() && !test) {
      v.points = nerf::surfacePointsFromDepth(depth, ds->camera(), *f.T_world_cam, size_t(a.depth_points), f.path);
      s.depth_points += v.points.size();
      s.depth_views += v.points.empty() ? 0 : 1;
    }
    if (test) {
      cv::Mat small;
      if (!depth.empty()) cv::resize(depth, small, cv::Size(v.camera.width, v.camera.height), 0, 0, cv::INTER_NEAREST);
      s.test_depth.push_back(small);
      s.test.push_back(std::move(v));
      s.test_names.push_back(fs::path(f.path).stem().string());
    } else {
      s.train.push_back(std::move(v));
    }
  }
  if (s.train.empty()) fail("{}: no training views left after holding out every {}th", a.transforms, a.test_every);
  return s;
}

struct Eval {
  double psnr = 0, ssim = 0;
  // Median over the test views with depth of each view's median |render - truth| / truth (pixels
  // where both have depth); -1 without depth.
  double depth_error = -1;
};

// Test views are rendered with the appearance of their nearest training view (appearance.h).
Eval evaluate(const nerf::NerfModel& model, const nerf::Trainer& trainer, const std::vector<nerf::TrainingView>& views,
              size_t count, int threads, bool with_ssim, std::vector<cv::Mat>* renders,
              const std::vector<cv::Mat>* depths = nullptr) {
  Eval e;
  count = std::min(count, views.size());
  if (count == 0) return e;
  const float white[3] = {1, 1, 1};
  nerf::RenderOptions ro;
  ro.threads = threads;
  ro.normals = false;
  std::vector<double> depth_errors;
  for (size_t i = 0; i < count; ++i) {
    const auto r = nerf::renderView(model, views[i].camera, views[i].T_world_cam, ro);
    const nerf::Appearance app = trainer.appearanceNear(views[i].T_world_cam);
    cv::Mat gt = nerf::compositeOver(views[i], white);
    cv::Mat pred = cv::min(cv::max(app.apply(r.rgb), 0.0), 1.0);
    e.psnr += psnr(pred, gt, 1.0);
    if (with_ssim) e.ssim += ssim(pred, gt, 1.0);
    if (depths && i < depths->size() && !(*depths)[i].empty())
      if (const auto err = depthMedianAbsRel(r.depth, (*depths)[i])) depth_errors.push_back(*err);
    if (renders) {
      cv::Mat side;
      cv::hconcat(nerf::toBgr8(pred), nerf::toBgr8(gt), side);
      renders->push_back(side);
    }
  }
  e.psnr /= double(count);
  e.ssim /= double(count);
  if (!depth_errors.empty()) e.depth_error = median(std::move(depth_errors));
  return e;
}

int runTrain(const TrainArgs& a) {
  if (a.seconds <= 0 && a.steps <= 0) fail("train: give --seconds or --steps");
  const fs::path out(a.out);
  ensureDirectory(out);
  nerf::SceneTransform scene;
  Split split = loadSplit(a, &scene);
  spdlog::info("train: {} training and {} test views of {}x{}, aabb_scale {}", split.train.size(), split.test.size(),
               split.train[0].camera.width, split.train[0].camera.height, scene.aabb_scale);
  if (split.depth_views > 0)
    spdlog::info("train: depth from the transforms' depth images: {} points on {} training views", split.depth_points,
                 split.depth_views);

  nerf::NerfModel model = nerf::NerfModel::create(nerf::FieldConfig{}, scene, uint64_t(a.seed));
  // `train`'s own defaults (and flags), then what the config file sets; flags given on the command
  // line win over the file. A key the file leaves out keeps `train`'s default, not the NeRF mapping
  // thread's (one thread, 2^14-sample steps), which a file with one learning-rate key had silently
  // brought in.
  nerf::TrainOptions to;
  to.threads = a.threads;
  to.seed = a.seed;
  to.samples_per_step = a.samples_per_step;
  if (!a.config.empty()) {
    SystemOptions so;
    so.nerf.train = to;
    loadOptionsFile(a.config, so);
    validateOptions(so, a.config);
    to = so.nerf.train;
    if (a.threads_given) to.threads = a.threads;
    if (a.seed_given) to.seed = a.seed;
    if (a.samples_given) to.samples_per_step = a.samples_per_step;
  }
  const size_t num_train = split.train.size();
  nerf::Trainer trainer(model, std::move(split.train), to);  // it keeps a compact copy of each image

  std::ostringstream curve;
  curve << "seconds,steps,test_psnr\n";
  double train_seconds = 0, next_eval = a.eval_interval;
  int64_t samples = 0;
  double last_loss = 0;
  // Ctrl-C / SIGTERM (core/stop_signal.h): the first stops the training and the model is evaluated
  // and saved as it is; a second skips the evaluation renders; a third exits at once.
  installStopHandlers();
  while (stopRequests() == 0) {
    if (a.steps > 0 && trainer.steps() >= a.steps) break;
    if (a.seconds > 0 && train_seconds >= a.seconds) break;
    // The budget used so far: the learning rate's tail (nerf.train.lr_tail) follows it.
    trainer.setBudgetProgress(nerf::budgetProgress(trainer.steps(), a.steps, train_seconds, a.seconds));
    const auto t0 = Clock::now();
    const auto st = trainer.step();
    train_seconds += std::chrono::duration<double>(Clock::now() - t0).count();
    samples += st.samples;
    last_loss = st.loss;
    if (trainer.steps() % 20 == 0)
      spdlog::debug(
          "step {}: loss {:.5f}, {} rays, {} samples; march {:.3f} fwd {:.3f} comp {:.3f} bwd {:.3f} adam {:.3f} "
          "grid {:.3f} s; grid {:.1f}% occupied",
          trainer.steps(), st.loss, st.rays, st.samples, st.times.march, st.times.field_forward, st.times.composite,
          st.times.field_backward, st.times.optimizer, st.times.grid_update, 100.0 * model.grid->occupiedFraction());
    if (a.eval_interval > 0 && train_seconds >= next_eval && !split.test.empty()) {
      const Eval e = evaluate(model, trainer, split.test, size_t(a.curve_views), a.threads, false, nullptr);
      curve << fmt::format("{:.3f},{},{:.4f}\n", train_seconds, trainer.steps(), e.psnr);
      spdlog::info("train: {:.1f} s, step {}, loss {:.5f}, test PSNR (first {} views) {:.2f} dB, grid {:.1f}% occupied",
                   train_seconds, trainer.steps(), st.loss, a.curve_views, e.psnr,
                   100.0 * model.grid->occupiedFraction());
      next_eval += a.eval_interval;
    }
  }
  const bool interrupted = stopRequests() > 0;
  if (interrupted) spdlog::warn("train: stopped by a signal after {} steps ({:.1f} s)", trainer.steps(), train_seconds);
  // The model first: it is what the training made, and a further signal must not lose it.
  nerf::saveModel(model, out / "model.nerf");
  std::vector<cv::Mat> renders;
  Eval final_eval;
  const bool evaluated = stopRequests() < 2;
  if (evaluated)
    final_eval = evaluate(model, trainer, split.test, split.test.size(), a.threads, true, &renders, &split.test_depth);
  if (evaluated && !split.test.empty())
    curve << fmt::format("{:.3f},{},{:.4f}\n", train_seconds, trainer.steps(), final_eval.psnr);

  for (size_t i = 0; i < renders.size(); ++i)
    writeImageAtomic(out / fmt::format("test_{:03d}_{}.png", i, split.test_names[i]), renders[i]);
  writeStringAtomic(out / "psnr_curve.csv", curve.str());
  const auto& tt = trainer.totalTimes();
  nlohmann::json rep;
  rep["transforms"] = a.transforms;
  rep["downscale"] = a.downscale;
  rep["threads"] = to.threads;
  rep["seed"] = to.seed;
  if (!a.config.empty()) rep["config"] = a.config;
  rep["train_views"] = num_train;
  rep["depth_views"] = split.depth_views;  // training views supervised by their depth image's points
  rep["depth_points"] = split.depth_points;
  if (final_eval.depth_error >= 0)
    rep["depth_error_test_median"] = final_eval.depth_error;
  else
    rep["depth_error_test_median"] = nullptr;  // no test view has a depth image
  rep["test_views"] = split.test.size();
  rep["interrupted"] = interrupted;
  if (evaluated) {
    rep["psnr_test_mean"] = final_eval.psnr;
    rep["ssim_test_mean"] = final_eval.ssim;
  } else {
    rep["psnr_test_mean"] = nullptr;  // stopped twice: not evaluated
    rep["ssim_test_mean"] = nullptr;
  }
  rep["steps"] = trainer.steps();
  rep["train_seconds"] = train_seconds;
  rep["samples_per_second"] = train_seconds > 0 ? double(samples) / train_seconds : 0.0;
  rep["samples_per_step"] = to.samples_per_step;
  rep["final_loss"] = last_loss;
  rep["rollbacks"] = trainer.rollbacks();
  rep["occupied_fraction"] = model.grid->occupiedFraction();
  rep["stage_seconds"] = {{"march", tt.march},         {"field_forward", tt.field_forward},
                          {"composite", tt.composite}, {"field_backward", tt.field_backward},
                          {"optimizer", tt.optimizer}, {"grid_update", tt.grid_update}};
  rep["peak_rss_mb"] = peakRssMb();
  writeStringAtomic(out / "report.json", rep.dump(2) + "\n");
  spdlog::info("train: {} steps in {:.1f} s ({:.2f} M samples/s), test PSNR {:.2f} dB, SSIM {:.4f}, peak RSS {:.0f} MB",
               trainer.steps(), train_seconds, double(samples) / std::max(train_seconds, 1e-9) / 1e6, final_eval.psnr,
               final_eval.ssim, peakRssMb());
  std::printf("psnr_test_mean %.3f ssim_test_mean %.4f steps %lld train_seconds %.2f\n", final_eval.psnr,
              final_eval.ssim, static_cast<long long>(trainer.steps()), train_seconds);
  return interrupted ? interruptedExitCode() : 0;
}

Registrar reg(
    "train", "Train a NeRF on a transforms.json dataset (every Nth view held out for testing)",
    [](CLI::App& sub) -> Runner {
      auto a = std::make_shared<TrainArgs>();
      sub.add_option("--transforms", a->transforms, "transforms.json (or its folder)")->required();
      sub.add_option("--out", a->out, "Output directory")->required();
      auto* secs = sub.add_option("--seconds", a->seconds, "Training time budget (s, evaluation excluded)")
                       ->check(nerfslam::cli::kPositive);
      auto* steps = sub.add_option("--steps", a->steps, "Number of optimiser steps")->check(nerfslam::cli::kPositive);
      secs->excludes(steps);
      sub.add_option("--test-every", a->test_every, "Hold out every Nth view (0: none)")->check(CLI::Range(0, 1000000));
      sub.add_option("--downscale", a->downscale, "Image downscale factor (>= 1)")->check(CLI::Range(1.0, 64.0));
      sub.add_option("--config", a->config,
                     "Options YAML as for `run --config`: its nerf.train options are used (docs/options.md)");
      auto* threads = sub.add_option("--threads", a->threads, "Threads")->check(CLI::Range(1, 256));
      auto* seed = sub.add_option("--seed", a->seed, "Random seed")->check(nerfslam::cli::kNonNegative);
      sub.add_option("--eval-interval", a->eval_interval,
                     "Seconds of training between PSNR-curve evaluations (0: none)")
          ->check(nerfslam::cli::kNonNegative);
      sub.add_option("--curve-views", a->curve_views, "Test views evaluated for the PSNR curve")
          ->check(CLI::Range(1, 1000));
      auto* samples = sub.add_option("--samples-per-step", a->samples_per_step, "Ray samples per optimiser step")
                          ->check(CLI::Range(256, 1 << 22));
      sub.add_option("--depth-points", a->depth_points,
                     "Pixels of a frame's depth image (transforms.json depth_path / depth_file_path) that supervise "
                     "its training view's depth, at most (0: training ignores depth; test views' depth still gives the "
                     "report's depth error)")
          ->check(CLI::Range(0, 1 << 20));
      return [a, threads, seed, samples]() -> int {
        a->threads_given = threads->count() > 0;
        a->seed_given = seed->count() > 0;
        a->samples_given = samples->count() > 0;
        return runTrain(*a);
      };
    });

}  // namespace
}  // namespace nerfslam::cli
