#include "nerfslam/system/nerf_mapping.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>

#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/core/thread.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/eval/image_metrics.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/renderer.h"

namespace nerfslam {
namespace {

using Clock = std::chrono::steady_clock;
double nowSeconds() { return std::chrono::duration<double>(Clock::now().time_since_epoch()).count(); }

// Robust box of the sparse map: per axis the 2nd..98th percentile of the points, widened to hold
// every camera centre.
void robustBox(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& cameras,
               Eigen::Vector3d* lo, Eigen::Vector3d* hi) {
  *lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  *hi = -*lo;
  if (!points.empty()) {
    for (int a = 0; a < 3; ++a) {
      std::vector<double> v;
      v.reserve(points.size());
      for (const auto& p : points) v.push_back(p[a]);
      const size_t k0 = size_t(0.02 * double(v.size() - 1)), k1 = size_t(0.98 * double(v.size() - 1));
      std::nth_element(v.begin(), v.begin() + long(k0), v.end());
      (*lo)[a] = v[k0];
      std::nth_element(v.begin(), v.begin() + long(k1), v.end());
      (*hi)[a] = v[k1];
    }
  }
  for (const auto& c : cameras) {
    *lo = lo->cwiseMin(c);
    *hi = hi->cwiseMax(c);
  }
}

// The transform mapping the box (times margin, as a cube) onto the unit cube.
nerf::SceneTransform fitTransform(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double margin,
                                  double aabb_scale, double min_half) {
  nerf::SceneTransform s;
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  const double half = std::max(0.5 * (hi - lo).maxCoeff() * margin, min_half);
  s.scale = 0.5 / half;
  s.offset = Eigen::Vector3d::Constant(0.5) - s.scale * centre;
  s.aabb_scale = aabb_scale;
  return s;
}

bool insideUnitCube(const Eigen::Vector3d& p) { return (p.array() >= 0.0).all() && (p.array() <= 1.0).all(); }

}  // namespace

NerfMapping::NerfMapping(Map& map, KeyframeBus& bus, NerfMappingOptions options)
    : map_(map), bus_(bus), opt_(std::move(options)) {
  // Never blocks the publisher: when the NeRF falls behind, the oldest waiting keyframes go.
  queue_ = bus_.subscribe(size_t(opt_.keyframe_queue), OverflowPolicy::kDropOldest);
}

NerfMapping::~NerfMapping() {
  stop();
  bus_.unsubscribe(queue_);
}

void NerfMapping::start() {
  if (started_) return;
  started_ = true;
  thread_ = std::thread([this] {
    setThreadName("nerfslam-nerf");
    run();
  });
}

void NerfMapping::stop() {
  if (stopped_) return;
  stopped_ = true;
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  std::lock_guard<std::mutex> lock(model_mutex_);
  drainQueue(false);
  if (trainer_) refreshPoses();
}

void NerfMapping::run() {
  // Threads the trainer spawns inherit the niceness.
  if (!lowerThreadPriority(opt_.nice_increment)) spdlog::debug("NeRF thread: could not lower its priority");
  while (!stop_) {
    try {
      std::unique_lock<std::mutex> lock(model_mutex_);
      const bool have = trainer_ != nullptr;
      if (!have) {
        lock.unlock();
        // Nothing to train yet: wait for keyframes without holding the model lock.
        if (auto ev = queue_->popFor(std::chrono::milliseconds(50))) {
          lock.lock();
          addKeyframe(*ev);
        }
        continue;
      }
      drainQueue(false);
      if (frozen_) {
        lock.unlock();
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        continue;
      }
      if (trainer_) stepOnce();
    } catch (const std::exception& e) {
      spdlog::error("NeRF mapping thread: {}; NeRF training stopped (tracking and sparse mapping go on)", e.what());
      return;
    }
  }
}

void NerfMapping::drainQueue(bool wait) {
  if (wait) {
    if (auto ev = queue_->popFor(std::chrono::milliseconds(50))) addKeyframe(*ev);
  }
  while (auto ev = queue_->tryPop()) addKeyframe(*ev);
  std::lock_guard<std::mutex> s(stats_mutex_);
  stats_.keyframes_dropped = queue_->dropped();
}

void NerfMapping::addKeyframe(const KeyframeEvent& ev) {
  if (!ev.frame) return;
  if (opt_.holdout_every > 0 && ++keyframes_seen_ % opt_.holdout_every == 0) {
    std::lock_guard<std::mutex> s(stats_mutex_);
    ++stats_.keyframes_held_out;
    return;
  }
  cv::Mat bgr = ev.frame->colour;
  if (bgr.empty()) {
    if (ev.frame->pyramid.empty()) return;
    cv::cvtColor(ev.frame->pyramid[0], bgr, cv::COLOR_GRAY2BGR);
  }
  const SE3 pose = map_.resolvePose(ev.id).value_or(ev.T_world_cam);
  if (model_ && !isNewView(pose)) {
    std::lock_guard<std::mutex> s(stats_mutex_);
    ++stats_.keyframes_skipped;
    return;
  }
  nerf::TrainingView view =
      nerf::makeTrainingView(bgr, ev.frame->camera, pose, opt_.downscale, fmt::format("keyframe {}", ev.id));
  train_camera_ = view.camera;
  pending_.push_back(std::move(view));
  pending_kf_.push_back(ev.id);
  pending_frame_.push_back(ev.frame->id);
  if (!model_) createModel();
  if (!model_) return;
  for (size_t i = 0; i < pending_.size(); ++i) {
    if (!trainer_) {
      trainer_ = std::make_unique<nerf::Trainer>(*model_, std::vector<nerf::TrainingView>{pending_[i]}, trainOptions());
    } else {
      trainer_->addView(pending_[i]);
    }
    poses_.push_back(pending_[i].T_world_cam);
    view_kf_.push_back(pending_kf_[i]);
    view_frame_.push_back(pending_frame_[i]);
    view_valid_.push_back(true);
  }
  pending_.clear();
  pending_kf_.clear();
  pending_frame_.clear();
  updateWeights();
  std::lock_guard<std::mutex> s(stats_mutex_);
  stats_.views = int(view_kf_.size());
}

bool NerfMapping::isNewView(const SE3& pose) const {
  // World distance threshold: a fraction of the fitted box (the unit cube is 1 / scale wide).
  const double min_dist = opt_.min_view_distance / model_->scene.scale;
  const double min_angle = opt_.min_view_angle_deg * M_PI / 180.0;
  for (const SE3& T : poses_) {
    const double d = (T.translation() - pose.translation()).norm();
    const double a = T.rotation().angularDistance(pose.rotation());
    if (d < min_dist && a < min_angle) return false;
  }
  return true;
}

void NerfMapping::createModel() {
  std::vector<Eigen::Vector3d> pts, cams;
  for (const auto& p : map_.points()) pts.push_back(p.position);
  for (const auto& kf : map_.keyframes()) cams.push_back(kf.centre());
  if (pts.size() < 20 || cams.size() < 2) return;  // wait for an initialised map
  Eigen::Vector3d lo, hi;
  robustBox(pts, cams, &lo, &hi);
  const double baseline = (cams.front() - cams.back()).norm();
  const nerf::SceneTransform scene = fitTransform(lo, hi, opt_.box_margin, opt_.aabb_scale, std::max(baseline, 1e-3));
  nerf::FieldConfig fc;
  fc.log2_hashmap_size = opt_.log2_hashmap_size;
  model_ = std::make_unique<nerf::NerfModel>(nerf::NerfModel::create(fc, scene, uint64_t(opt_.seed)));
  field_steps_before_ = 0;
  spdlog::info("NeRF: scene box fitted to {} map points and {} keyframes: scale {:.4g}, aabb_scale {}", pts.size(),
               cams.size(), scene.scale, scene.aabb_scale);
}

void NerfMapping::refreshPoses() {
  const uint64_t v = map_.version();
  if (v == seen_map_version_) return;
  seen_map_version_ = v;
  size_t lost = 0;
  for (size_t i = 0; i < view_kf_.size(); ++i) {
    const auto pose = map_.resolvePose(view_kf_[i]);
    view_valid_[i] = pose.has_value();
    lost += !pose;
    if (!pose) continue;
    trainer_->setViewPose(i, *pose);
    poses_[i] = *pose;
  }
  if (lost > 0 && lost == view_kf_.size()) {
    // The sparse map was reset (tracking re-initialised): its keyframes and scale are gone.
    spdlog::warn("NeRF: the sparse map was reset; starting the NeRF map again");
    trainer_.reset();
    model_.reset();
    poses_.clear();
    view_kf_.clear();
    view_frame_.clear();
    view_valid_.clear();
    std::lock_guard<std::mutex> s(stats_mutex_);
    step_offset_ = stats_.steps;
    stats_.views = 0;
  }
}

void NerfMapping::updateWeights() {
  const size_t n = view_kf_.size();
  if (n == 0 || !trainer_) return;
  const auto& loss = trainer_->viewLoss();
  // Loss-proportional share over all views (unseen views get the largest loss seen so far).
  double max_loss = 0, sum = 0;
  for (double l : loss) max_loss = std::max(max_loss, l);
  std::vector<double> w(n);
  for (size_t i = 0; i < n; ++i) w[i] = loss[i] < 0 ? std::max(max_loss, 1e-3) : std::max(loss[i], 1e-6);
  for (double x : w) sum += x;
  const double mean = sum / double(n);
  sum = 0;
  for (double& x : w) {
    x = std::max(x, opt_.min_weight * mean);
    sum += x;
  }
  const size_t recent = std::min(n, size_t(opt_.recent_keyframes));
  const double old_share = recent == n ? 0.0 : 1.0 - opt_.recent_share;
  for (size_t i = 0; i < n; ++i) {
    w[i] = old_share * w[i] / sum;
    if (i + recent >= n) w[i] += (1.0 - old_share) / double(recent);
    if (!view_valid_[i]) w[i] = 0;  // its keyframe left the map without a parent
  }
  double total = 0;
  for (double x : w) total += x;
  if (!(total > 0)) return;
  trainer_->setViewWeights(std::move(w));
}

void NerfMapping::stepOnce() {
  if (trainer_->steps() % opt_.pose_refresh_steps == 0) {
    refreshPoses();
    if (!trainer_) return;  // the map was reset
    updateWeights();
  }
  if (++since_refit_check_ >= opt_.refit_check_steps) {
    since_refit_check_ = 0;
    if (checkRefit()) refit();
  }
  const auto t0 = Clock::now();
  const nerf::StepStats st = trainer_->step();
  const double dt = std::chrono::duration<double>(Clock::now() - t0).count();
  const double now = nowSeconds();
  {
    std::lock_guard<std::mutex> s(stats_mutex_);
    stats_.steps = step_offset_ + trainer_->steps();
    stats_.samples += st.samples;
    stats_.rollbacks = trainer_->rollbacks();
    stats_.train_seconds += dt;
    stats_.last_loss = st.loss;
    rate_window_.emplace_back(now, stats_.samples);
    while (rate_window_.size() > 2 && now - rate_window_.front().first > 5.0) rate_window_.erase(rate_window_.begin());
    if (rate_window_.size() >= 2) {
      const double span = rate_window_.back().first - rate_window_.front().first;
      if (span > 0) {
        stats_.samples_per_second = double(rate_window_.back().second - rate_window_.front().second) / span;
        stats_.steps_per_second = double(rate_window_.size() - 1) / span;
      }
    }
  }
  if (now - last_psnr_time_ >= opt_.psnr_interval_s) {
    last_psnr_time_ = now;
    measurePsnr();
  }
}

void NerfMapping::measurePsnr() {
  // From the training rays of the newest keyframes (free: no render). The trainer's Huber loss is
  // e^2 / (2 delta) for the small errors of a converging model, summed over 3 channels: MSE per
  // channel ~ 2 delta loss / 3 (an upper bound on the PSNR error where some errors exceed delta).
  const auto& loss = trainer_->viewLoss();
  double sum = 0;
  int n = 0;
  for (size_t i = loss.size(); i-- > 0 && n < opt_.recent_keyframes;)
    if (loss[i] >= 0 && view_valid_[i]) {
      sum += loss[i];
      ++n;
    }
  if (n == 0) return;
  const double mse = std::max(2.0 * trainOptions().huber_delta * (sum / n) / 3.0, 1e-10);
  std::lock_guard<std::mutex> s(stats_mutex_);
  stats_.psnr_recent = -10.0 * std::log10(mse);
}

bool NerfMapping::checkRefit() {
  const auto points = map_.points();
  if (points.empty()) return false;
  size_t outside = 0;
  for (const auto& p : points) outside += !insideUnitCube(model_->scene.toNerf(p.position));
  bool camera_out = false;
  for (const auto& T : poses_) camera_out |= !insideUnitCube(model_->scene.toNerf(T.translation()));
  return camera_out || double(outside) > opt_.refit_outside_fraction * double(points.size());
}

void NerfMapping::refit() {
  std::vector<Eigen::Vector3d> pts, cams;
  for (const auto& p : map_.points()) pts.push_back(p.position);
  for (const auto& T : poses_) cams.push_back(T.translation());
  Eigen::Vector3d lo, hi;
  robustBox(pts, cams, &lo, &hi);
  // Keep the old box inside the new one, and grow by at least 1.5x so refits stay rare.
  const nerf::SceneTransform old = model_->scene;
  lo = lo.cwiseMin(old.toWorld(Eigen::Vector3d::Zero()));
  hi = hi.cwiseMax(old.toWorld(Eigen::Vector3d::Ones()));
  const double old_half = 0.5 / old.scale;
  const nerf::SceneTransform scene = fitTransform(lo, hi, opt_.box_margin, opt_.aabb_scale, 1.5 * old_half);
  int64_t refits;
  {
    std::lock_guard<std::mutex> s(stats_mutex_);
    refits = ++stats_.refits;
    step_offset_ += trainer_->steps();
  }
  auto fresh = std::make_unique<nerf::NerfModel>(
      nerf::NerfModel::create(model_->field->config(), scene, uint64_t(opt_.seed) + uint64_t(refits)));
  // A field trained for fewer steps than the distillation would take knows less than those steps
  // would teach from the images: the new field starts from scratch instead.
  const int64_t old_steps = field_steps_before_ + trainer_->steps();
  const bool distil = old_steps >= opt_.distill_steps;
  field_steps_before_ = distil ? old_steps : 0;
  std::string how = fmt::format("the old field had trained {} steps (< {}), the new one starts afresh", old_steps,
                                opt_.distill_steps);
  if (distil) {
    const double loss = distill(*model_, *fresh, opt_.distill_steps);
    how = fmt::format("old field distilled in {} steps (final loss {:.4f})", opt_.distill_steps, loss);
  }
  spdlog::info("NeRF: the map outgrew the scene box; re-fitted (scale {:.4g} -> {:.4g}), {}", old.scale, scene.scale,
               how);
  std::vector<nerf::TrainingView> views;
  for (size_t i = 0; i < trainer_->numViews(); ++i) views.push_back(trainer_->view(i));
  trainer_.reset();
  model_ = std::move(fresh);
  trainer_ = std::make_unique<nerf::Trainer>(*model_, std::move(views), trainOptions());
  seen_map_version_ = 0;
  refreshPoses();
  updateWeights();
}

nerf::TrainOptions NerfMapping::trainOptions() const {
  nerf::TrainOptions to;
  to.threads = opt_.threads;
  to.samples_per_step = opt_.samples_per_step;
  to.lr = opt_.lr;
  to.seed = opt_.seed;
  // Small steps: grid queries proportional to the training samples (the trainer's shares are for 2^16).
  to.grid_update_scale = std::min(1.0, double(opt_.samples_per_step) / double(1 << 16));
  return to;
}

double NerfMapping::distill(const nerf::NerfModel& from, nerf::NerfModel& to, int steps) const {
  // Regresses the new field's log-density (converted to the new NeRF-space units: sigma is per
  // NeRF length, so sigma_to = sigma_from * scale_from / scale_to) and, where the old field is
  // dense, its colour, at random points of the old unit cube (half uniform, half in occupied cells).
  const int n = 4096;
  const double k = from.scene.scale / to.scene.scale;
  const float log_floor = std::log(0.1f);
  std::mt19937_64 rng(uint64_t(opt_.seed) ^ 0x64697374ull);
  std::uniform_real_distribution<float> u01(0.f, 1.f);
  std::normal_distribution<float> gauss(0.f, 1.f);
  std::uniform_int_distribution<int> cell(0, nerf::OccupancyGrid::kRes - 1);
  auto ws = to.field->makeWorkspace();
  auto grads = to.field->makeGradients();
  std::vector<float> p_from(3 * n), q_from(3 * n), p_to(3 * n), q_to(3 * n), dir(3 * n), sig_f(n), rgb_f(3 * n),
      sig_t(n), rgb_t(3 * n), d_sig(n), d_rgb(3 * n);
  double loss = 0;
  for (int it = 0; it < steps; ++it) {
    for (int i = 0; i < n; ++i) {
      Eigen::Vector3f p(u01(rng), u01(rng), u01(rng));
      if (i % 2 == 1) {
        for (int tries = 0; tries < 64; ++tries) {
          const int x = cell(rng), y = cell(rng), z = cell(rng);
          if (!from.grid->occupiedCell(0, x, y, z)) continue;
          const float c = nerf::OccupancyGrid::cellSize(0);
          p = from.grid->cellCenter(0, x, y, z) +
              c * Eigen::Vector3f(u01(rng) - 0.5f, u01(rng) - 0.5f, u01(rng) - 0.5f);
          break;
        }
      }
      const Eigen::Vector3d pt = to.scene.toNerf(from.scene.toWorld(p.cast<double>()));
      Eigen::Vector3f d(gauss(rng), gauss(rng), gauss(rng));
      d /= std::max(d.norm(), 1e-6f);
      for (int a = 0; a < 3; ++a) {
        p_from[3 * i + a] = p[a];
        p_to[3 * i + a] = float(pt[a]);
        dir[3 * i + a] = d[a];
      }
    }
    from.toFieldCoords(p_from.data(), size_t(n), q_from.data());
    to.toFieldCoords(p_to.data(), size_t(n), q_to.data());
    from.field->query(q_from.data(), dir.data(), size_t(n), sig_f.data(), rgb_f.data());
    to.field->forward(ws, q_to.data(), dir.data(), size_t(n), sig_t.data(), rgb_t.data());
    loss = 0;
    for (int i = 0; i < n; ++i) {
      const float target_sigma = float(sig_f[i] * k);
      const float target = std::max(std::log(std::max(target_sigma, 1e-30f)), log_floor);
      const float s = std::max(sig_t[i], 1e-30f);
      float e = std::log(s) - target;
      if (target <= log_floor && e < 0) e = 0;  // empty space: anything below the floor will do
      loss += double(e) * e;
      d_sig[i] = 2.f * e / s / float(n);
      const float w = 1.f - std::exp(-0.01f * target_sigma);  // colour matters where the old field is dense
      for (int c = 0; c < 3; ++c) {
        const float ec = rgb_t[3 * i + c] - rgb_f[3 * i + c];
        loss += double(w) * ec * ec;
        d_rgb[3 * i + c] = 2.f * w * ec / float(n);
      }
    }
    loss /= n;
    to.field->backward(ws, d_sig.data(), d_rgb.data(), grads);
    to.field->step({&grads}, float(opt_.lr), 1);
  }
  return loss;
}

bool NerfMapping::refitNow() {
  std::lock_guard<std::mutex> lock(model_mutex_);
  if (!trainer_) return false;
  refit();
  return true;
}

void NerfMapping::resume(const std::filesystem::path& model_file, bool train) {
  nerf::NerfModel loaded = nerf::loadModel(model_file);
  std::lock_guard<std::mutex> lock(model_mutex_);
  model_ = std::make_unique<nerf::NerfModel>(std::move(loaded));
  trainer_.reset();
  {
    std::lock_guard<std::mutex> s(stats_mutex_);
    step_offset_ = int64_t(model_->training_steps);
    stats_.steps = step_offset_;
  }
  field_steps_before_ = int64_t(model_->training_steps);
  for (const auto& kf : map_.keyframes()) addKeyframe({kf.id, kf.T_world_cam, kf.frame});
  frozen_ = !train;
  spdlog::info("NeRF: continuing from {} ({} training steps, {} views){}", model_file.string(), model_->training_steps,
               view_kf_.size(), train ? "" : "; frozen (localisation only)");
}

int64_t NerfMapping::trainFor(double seconds, int64_t steps, int threads) {
  std::lock_guard<std::mutex> lock(model_mutex_);
  if (!trainer_ || frozen_ || (seconds <= 0 && steps <= 0)) return 0;
  refreshPoses();
  if (!trainer_) return 0;
  // The map is complete: fit the box to it now, not refit_check_steps into the training.
  since_refit_check_ = 0;
  if (checkRefit()) refit();
  updateWeights();
  if (threads > 0) trainer_->setThreads(threads);
  const auto t0 = Clock::now();
  int64_t done = 0;
  while (trainer_) {
    if (steps > 0 && done >= steps) break;
    if (seconds > 0 && std::chrono::duration<double>(Clock::now() - t0).count() >= seconds) break;
    stepOnce();
    ++done;
  }
  return done;
}

NerfMappingStats NerfMapping::stats() const {
  std::lock_guard<std::mutex> s(stats_mutex_);
  return stats_;
}

bool NerfMapping::hasModel() const {
  std::lock_guard<std::mutex> lock(model_mutex_);
  return model_ != nullptr && trainer_ != nullptr;
}

std::vector<KeyframeId> NerfMapping::viewKeyframes() const {
  std::lock_guard<std::mutex> lock(model_mutex_);
  return view_kf_;
}

std::vector<uint64_t> NerfMapping::viewFrameIds() const {
  std::lock_guard<std::mutex> lock(model_mutex_);
  return view_frame_;
}

nerf::TrainingView NerfMapping::trainingView(size_t i) const {
  std::lock_guard<std::mutex> lock(model_mutex_);
  if (!trainer_) fail("NeRF: no training views yet");
  return trainer_->view(i);
}

std::vector<SE3> NerfMapping::viewPoses() const {
  std::lock_guard<std::mutex> lock(model_mutex_);
  std::vector<SE3> out;
  for (const auto& T : poses_) out.push_back(T);
  return out;
}

bool NerfMapping::withModel(const std::function<void(nerf::NerfModel&)>& fn) const {
  std::lock_guard<std::mutex> lock(model_mutex_);
  if (!model_) return false;
  fn(*model_);
  return true;
}

Camera NerfMapping::trainingCamera() const {
  std::lock_guard<std::mutex> lock(model_mutex_);
  return train_camera_;
}

}  // namespace nerfslam
