#include "nerfslam/system/nerf_mapping.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/core/statistics.h"
#include "nerfslam/core/thread.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/eval/image_metrics.h"
#include "nerfslam/nerf/distill.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/nerf/scene_box.h"

namespace nerfslam {
namespace {

using Clock = std::chrono::steady_clock;
double nowSeconds() { return std::chrono::duration<double>(Clock::now().time_since_epoch()).count(); }

// A keyframe's image in colour: its colour frame, or its grey one replicated (empty without either).
cv::Mat keyframeBgr(const Frame& frame) {
  if (!frame.colour.empty() || frame.pyramid.empty()) return frame.colour;
  cv::Mat bgr;
  cv::cvtColor(frame.pyramid[0], bgr, cv::COLOR_GRAY2BGR);
  return bgr;
}

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
  start_time_ = nowSeconds();
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
      // Caught up: one keyframe the queue dropped while the thread was behind, per step.
      if (queue_->empty()) recoverDropped(1);
      if (frozen_) {
        lock.unlock();
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        continue;
      }
      if (trainer_) stepOnce();
      letWaitersIn(lock);
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

size_t NerfMapping::recoverDropped(size_t max) {
  const uint64_t dropped = queue_->dropped();
  if (dropped == recovered_through_ || frozen_) return 0;
  size_t n = 0;
  bool complete = true;
  for (const KeyframeId id : map_.keyframeIds()) {
    if (offered_.count(id)) continue;
    if (n >= max) {
      complete = false;
      break;
    }
    const auto kf = map_.keyframe(id);
    if (!kf || !kf->frame) continue;  // culled meanwhile
    addKeyframe({kf->id, kf->T_world_cam, kf->frame});
    ++n;
  }
  if (complete) recovered_through_ = dropped;
  if (n > 0) {
    std::lock_guard<std::mutex> s(stats_mutex_);
    stats_.keyframes_recovered += n;
  }
  return n;
}

void NerfMapping::addKeyframe(const KeyframeEvent& ev) {
  if (!ev.frame) return;
  // Once each: a keyframe recovered from the map may still have been on its way through the queue.
  if (!offered_.insert(ev.id).second) return;
  if (opt_.holdout_every > 0 && ++keyframes_seen_ % opt_.holdout_every == 0) {
    if (opt_.heldout_interval_s > 0) keepHeldout(ev);
    std::lock_guard<std::mutex> s(stats_mutex_);
    ++stats_.keyframes_held_out;
    return;
  }
  const cv::Mat bgr = keyframeBgr(*ev.frame);
  if (bgr.empty()) return;
  const SE3 pose = map_.resolvePose(ev.id).value_or(ev.T_world_cam);
  View view;
  view.keyframe = ev.id;
  view.frame = ev.frame->id;
  view.pose = pose;
  keyframe_camera_ = ev.frame->camera;
  if (const auto kf = map_.keyframe(ev.id)) {
    for (size_t k = 0; k < kf->points.size() && k < ev.frame->keypoints.size(); ++k)
      if (kf->points[k] != kNoPoint) {
        view.point_ids.push_back(kf->points[k]);
        view.keypoints.emplace_back(ev.frame->keypoints[k].pt.x, ev.frame->keypoints[k].pt.y);
      }
  }
  std::vector<nerf::SurfacePoint> points = std::move(surfacePoints({view}).front());
  std::vector<double> depths;
  for (const auto& p : points) depths.push_back((p.position.cast<double>() - pose.translation()).norm());
  const double median_depth = depths.empty() ? 0.0 : median(depths);
  if (model_ && !isNewView(pose, median_depth)) {
    std::lock_guard<std::mutex> s(stats_mutex_);
    ++stats_.keyframes_skipped;
    return;
  }
  PendingView pending;
  pending.training =
      nerf::makeTrainingView(bgr, ev.frame->camera, pose, opt_.downscale, fmt::format("keyframe {}", ev.id));
  pending.training.points = std::move(points);
  pending.view = std::move(view);
  train_camera_ = pending.training.camera;
  pending_.push_back(std::move(pending));
  if (!model_) createModel();
  if (!model_) return;
  for (PendingView& p : pending_) {
    if (!trainer_) {
      trainer_ =
          std::make_unique<nerf::Trainer>(*model_, std::vector<nerf::TrainingView>{std::move(p.training)}, opt_.train);
    } else {
      trainer_->addView(std::move(p.training));
    }
    views_.push_back(p.view);
  }
  pending_.clear();
  updateWeights();
  std::lock_guard<std::mutex> s(stats_mutex_);
  stats_.views = int(views_.size());
}

bool NerfMapping::isNewView(const SE3& pose, double median_depth) const {
  // World distance threshold: a fraction of the scene depth the view sees (parallax), or of the
  // fitted box (the unit cube is 1 / scale wide) when it sees no map point.
  const double min_dist = opt_.min_view_distance * (median_depth > 0 ? median_depth : 1.0 / model_->scene.scale);
  const double min_angle = opt_.min_view_angle_deg * M_PI / 180.0;
  for (const View& view : views_) {
    const SE3& T = view.pose;
    const double d = (T.translation() - pose.translation()).norm();
    const double a = T.rotation().angularDistance(pose.rotation());
    if (d < min_dist && a < min_angle) return false;
  }
  return true;
}

std::vector<std::vector<nerf::SurfacePoint>> NerfMapping::surfacePoints(const std::vector<View>& views) const {
  std::vector<PointId> ids;
  for (const View& v : views) ids.insert(ids.end(), v.point_ids.begin(), v.point_ids.end());
  const std::vector<Map::PointSummary> sums = map_.pointSummaries(ids);
  std::vector<std::vector<nerf::SurfacePoint>> out(views.size());
  size_t k = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const SE3 T_cam_world = views[i].pose.inverse();
    for (size_t j = 0; j < views[i].point_ids.size(); ++j, ++k) {
      const Map::PointSummary& p = sums[k];
      if (p.observations == 0) continue;  // culled: it stops supervising
      const Eigen::Vector3d p_cam = T_cam_world * p.position;
      if (!(p_cam.z() > 0) || !p_cam.allFinite()) continue;
      // Trust: seen by more keyframes, matched when it should be, and where its keypoint is.
      const double err = (keyframe_camera_.project(p_cam) - views[i].keypoints[j].cast<double>()).norm();
      const double w =
          std::min(1.0, p.observations / 4.0) * std::min(1.0, 2.0 * p.found_ratio) / (1.0 + (err / 2.0) * (err / 2.0));
      if (!(w >= 0.05)) continue;
      out[i].push_back({p.position.cast<float>(), float(std::min(w, 1.0))});
    }
  }
  return out;
}

std::vector<Eigen::Vector3d> NerfMapping::mapPoints() const {
  std::vector<Eigen::Vector3d> pts;
  for (const auto& p : map_.points()) pts.push_back(p.position);
  return pts;
}

void NerfMapping::createModel() {
  const std::vector<Eigen::Vector3d> pts = mapPoints();
  std::vector<Eigen::Vector3d> cams;
  for (const auto& kf : map_.keyframes()) cams.push_back(kf.centre());
  if (pts.size() < 20 || cams.size() < 2) return;  // wait for an initialised map
  nerf::SceneTransform scene = nerf::fitSceneBox(pts, cams, opt_.box_margin, opt_.aabb_scale);
  scene.cone_angle = opt_.cone_angle;
  nerf::FieldConfig fc;
  fc.log2_hashmap_size = opt_.log2_hashmap_size;
  model_ = std::make_unique<nerf::NerfModel>(nerf::NerfModel::create(fc, scene, uint64_t(opt_.train.seed)));
  field_steps_before_ = 0;
  spdlog::info("NeRF: scene box fitted to {} map points and {} keyframes: scale {:.4g}, aabb_scale {}", pts.size(),
               cams.size(), scene.scale, scene.aabb_scale);
}

void NerfMapping::refreshPoses() {
  const uint64_t v = map_.version();
  if (v == seen_map_version_) return;
  seen_map_version_ = v;
  const auto t0 = Clock::now();
  size_t lost = 0;
  for (size_t i = 0; i < views_.size(); ++i) {
    View& view = views_[i];
    const auto pose = map_.resolvePose(view.keyframe);
    view.valid = pose.has_value();
    lost += !pose;
    if (!pose) continue;
    trainer_->setViewPose(i, *pose);
    view.pose = *pose;
  }
  std::vector<std::vector<nerf::SurfacePoint>> points = surfacePoints(views_);
  for (size_t i = 0; i < views_.size(); ++i) trainer_->setViewPoints(i, std::move(points[i]));
  {
    std::lock_guard<std::mutex> s(stats_mutex_);
    stats_.refresh_seconds += std::chrono::duration<double>(Clock::now() - t0).count();
  }
  if (lost > 0 && lost == views_.size()) {
    // The sparse map was reset (tracking re-initialised): its keyframes and scale are gone.
    spdlog::warn("NeRF: the sparse map was reset; starting the NeRF map again");
    trainer_.reset();
    model_.reset();
    views_.clear();
    std::lock_guard<std::mutex> s(stats_mutex_);
    step_offset_ = stats_.steps;
    stats_.views = 0;
  }
}

std::vector<double> viewRayShares(const std::vector<double>& loss, const std::vector<bool>& valid, size_t recent,
                                  double recent_share, double min_weight) {
  const size_t n = loss.size();
  if (valid.size() != n) fail("viewRayShares: {} losses but {} validity flags", n, valid.size());
  // Loss-proportional share over all views (unseen views get the largest loss seen so far).
  double max_loss = 0, sum = 0;
  for (double l : loss) max_loss = std::max(max_loss, l);
  std::vector<double> w(n);
  for (size_t i = 0; i < n; ++i) w[i] = loss[i] < 0 ? std::max(max_loss, 1e-3) : std::max(loss[i], 1e-6);
  for (double x : w) sum += x;
  const double mean = n > 0 ? sum / double(n) : 0.0;
  sum = 0;
  for (double& x : w) {
    x = std::max(x, min_weight * mean);
    sum += x;
  }
  recent = recent_share > 0 ? std::min(n, recent) : 0;  // no share: no window
  const double old_share = recent == n ? 0.0 : 1.0 - recent_share;
  for (size_t i = 0; i < n; ++i) {
    w[i] = old_share * w[i] / sum;
    if (i + recent >= n) w[i] += (1.0 - old_share) / double(recent);
    if (!valid[i]) w[i] = 0;
  }
  return w;
}

void NerfMapping::updateWeights() {
  const size_t n = views_.size();
  if (n == 0 || !trainer_) return;
  std::vector<bool> valid(n);
  for (size_t i = 0; i < n; ++i) valid[i] = views_[i].valid;  // false: its keyframe left the map without a parent
  std::vector<double> w =
      viewRayShares(trainer_->viewLoss(), valid, size_t(opt_.recent_keyframes), opt_.recent_share, opt_.min_weight);
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
    if (const auto box = newBox()) refit(*box);
  }
  const double lr = trainer_->learningRate();
  const auto t0 = Clock::now();
  const nerf::StepStats st = trainer_->step();
  const double dt = std::chrono::duration<double>(Clock::now() - t0).count();
  const double now = nowSeconds();
  {
    std::lock_guard<std::mutex> s(stats_mutex_);
    stats_.steps = step_offset_ + trainer_->steps();
    stats_.samples += st.samples;
    stats_.samples_composited += st.samples_composited;
    stats_.rays += st.rays;
    stats_.depth_rays += st.depth_rays;
    stats_.rollbacks = trainer_->rollbacks();
    stats_.train_seconds += dt;
    stats_.last_loss = st.loss;
    stats_.last_depth_loss = st.depth_loss;
    stats_.learning_rate = lr;
    stats_.times += st.times;
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
  if (opt_.heldout_interval_s > 0 && now - last_heldout_time_ >= opt_.heldout_interval_s) {
    measureHeldout();
    // At most a tenth of the thread's time: the next measurement waits 9 times this one's cost.
    last_heldout_time_ = now + 9.0 * std::max(0.0, nowSeconds() - now);
  }
}

void NerfMapping::keepHeldout(const KeyframeEvent& ev) {
  const cv::Mat bgr = keyframeBgr(*ev.frame);
  if (bgr.empty()) return;
  const nerf::TrainingView small =
      nerf::makeTrainingView(bgr, ev.frame->camera, ev.T_world_cam, opt_.downscale * opt_.heldout_downscale,
                             fmt::format("held-out keyframe {}", ev.id));
  HeldOutView h;
  h.keyframe = ev.id;
  h.pose = ev.T_world_cam;
  cv::Mat rgb = small.image;
  if (rgb.channels() == 4) cv::cvtColor(rgb, rgb, cv::COLOR_RGBA2RGB);  // renders are RGB
  rgb.convertTo(h.rgb, CV_32F, 1.0 / 255.0);
  heldout_camera_ = small.camera;
  heldout_.push_back(std::move(h));
  if (int(heldout_.size()) > opt_.heldout_eval_views) heldout_.erase(heldout_.begin());
}

void NerfMapping::measureHeldout() {
  std::vector<double> psnr;
  for (HeldOutView& h : heldout_) {
    h.pose = map_.resolvePose(h.keyframe).value_or(h.pose);
    nerf::RenderOptions ro;
    ro.threads = 1;
    ro.normals = false;
    ro.background = {0.0, 0.0, 0.0};
    const nerf::RenderResult r = nerf::renderView(*model_, heldout_camera_, h.pose, ro);
    const nerf::Appearance app = trainer_->appearanceNear(h.pose);
    psnr.push_back(nerfslam::psnr(cv::min(cv::max(app.apply(r.rgb), 0.0), 1.0), h.rgb, 1.0));
  }
  double mean = 0;
  for (double p : psnr) mean += p / double(psnr.size());
  std::lock_guard<std::mutex> s(stats_mutex_);
  if (!psnr.empty()) stats_.psnr_heldout = mean;
  auto& hist = stats_.psnr_history;
  hist.push_back({nowSeconds() - start_time_, stats_.steps, stats_.psnr_recent, psnr.empty() ? 0.0 : mean});
  if (hist.size() >= 512) {
    for (size_t i = 1; 2 * i < hist.size(); ++i) hist[i] = hist[2 * i];
    hist.resize(hist.size() / 2);
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
    if (loss[i] >= 0 && views_[i].valid) {
      sum += loss[i];
      ++n;
    }
  const auto poses =
      opt_.train.pose_refinement ? trainer_->poseRefinementStats() : nerf::Trainer::PoseRefinementStats{};
  std::lock_guard<std::mutex> s(stats_mutex_);
  stats_.pose_refinement = poses;
  if (n == 0) return;
  const double mse = std::max(2.0 * opt_.train.huber_delta * (sum / n) / 3.0, 1e-10);
  stats_.psnr_recent = -10.0 * std::log10(mse);
}

std::vector<Eigen::Vector3d> NerfMapping::viewCentres() const {
  std::vector<Eigen::Vector3d> cams;
  for (const View& view : views_) cams.push_back(view.pose.translation());
  return cams;
}

std::optional<NerfMapping::NewBox> NerfMapping::newBox() const {
  const auto points = mapPoints();
  const auto cameras = viewCentres();
  if (nerf::sceneBoxOutgrown(model_->scene, points, cameras, opt_.refit_outside_fraction))
    return NewBox{nerf::refitSceneBox(model_->scene, points, cameras, opt_.box_margin, opt_.aabb_scale), false};
  if (auto shrunk = nerf::shrunkSceneBox(model_->scene, points, cameras, opt_.box_margin, opt_.refit_shrink_ratio))
    return NewBox{*shrunk, true};
  return std::nullopt;
}

void NerfMapping::refit(const NewBox& box) {
  const auto t0 = Clock::now();
  const nerf::SceneTransform old = model_->scene;
  nerf::SceneTransform scene = box.scene;
  scene.cone_angle = opt_.cone_angle;
  int64_t refits;
  {
    std::lock_guard<std::mutex> s(stats_mutex_);
    refits = ++stats_.refits;
    step_offset_ += trainer_->steps();
  }
  auto fresh = std::make_unique<nerf::NerfModel>(
      nerf::NerfModel::create(model_->field->config(), scene, uint64_t(opt_.train.seed) + uint64_t(refits)));
  // The learned background is by direction alone: it does not depend on the box and carries over.
  if (model_->background) fresh->background = std::make_unique<nerf::Background>(*model_->background);
  // A field trained for fewer steps than the distillation would take knows less than those steps
  // would teach from the images: the new field starts from scratch instead.
  const int64_t old_steps = field_steps_before_ + trainer_->steps();
  const bool distil = old_steps >= opt_.distill_steps;
  field_steps_before_ = distil ? old_steps : 0;
  std::string how = fmt::format("the old field had trained {} steps (< {}), the new one starts afresh", old_steps,
                                opt_.distill_steps);
  if (distil) {
    nerf::DistillOptions d;
    d.steps = opt_.distill_steps;
    d.lr = opt_.train.lr;
    d.seed = uint64_t(opt_.train.seed);
    const double loss = nerf::distill(*model_, *fresh, d);
    how = fmt::format("old field distilled in {} steps (final loss {:.4f})", opt_.distill_steps, loss);
  }
  spdlog::info("NeRF: {}; re-fitted (scale {:.4g} -> {:.4g}), {}",
               box.shrunk ? "the map is much smaller than the scene box" : "the map outgrew the scene box", old.scale,
               scene.scale, how);
  std::vector<nerf::TrainingView> views;
  std::vector<nerf::Appearance> appearance;
  std::vector<nerf::PoseCorrection> corrections;
  for (size_t i = 0; i < trainer_->numViews(); ++i) {
    views.push_back(trainer_->view(i));
    appearance.push_back(trainer_->viewAppearance(i));
    corrections.push_back(trainer_->viewPoseCorrection(i));
  }
  trainer_.reset();
  model_ = std::move(fresh);
  trainer_ = std::make_unique<nerf::Trainer>(*model_, std::move(views), opt_.train);
  for (size_t i = 0; i < appearance.size(); ++i) {
    trainer_->setViewAppearance(i, appearance[i]);
    trainer_->setViewPoseCorrection(i, corrections[i]);
  }
  seen_map_version_ = 0;
  refreshPoses();
  updateWeights();
  std::lock_guard<std::mutex> s(stats_mutex_);
  stats_.refit_seconds += std::chrono::duration<double>(Clock::now() - t0).count();
}

bool NerfMapping::refitNow() {
  const auto lock = lockModel();
  if (!trainer_) return false;
  refit({nerf::refitSceneBox(model_->scene, mapPoints(), viewCentres(), opt_.box_margin, opt_.aabb_scale), false});
  return true;
}

void NerfMapping::resume(const std::filesystem::path& model_file, bool train) {
  nerf::NerfModel loaded = nerf::loadModel(model_file);
  const auto lock = lockModel();
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
               views_.size(), train ? "" : "; frozen (localisation only)");
}

int64_t NerfMapping::trainFor(double seconds, int64_t steps, int threads, const std::function<bool()>& stop) {
  auto lock = lockModel();
  if (!trainer_ || frozen_ || (seconds <= 0 && steps <= 0)) return 0;
  drainQueue(false);
  recoverDropped(std::numeric_limits<size_t>::max());
  refreshPoses();
  if (!trainer_) return 0;
  // The map is complete: fit the box to it now, not refit_check_steps into the training.
  since_refit_check_ = 0;
  if (const auto box = newBox()) refit(*box);
  // Once the sequence is over no view is newer than another in any sense that matters.
  opt_.recent_share = opt_.final_recent_share;
  updateWeights();
  if (threads > 0) trainer_->setThreads(threads);
  if (opt_.final_samples_per_step > 0) {
    opt_.train.samples_per_step = opt_.final_samples_per_step;  // a box re-fit's new trainer keeps it
    trainer_->setSamplesPerStep(opt_.final_samples_per_step);
  }
  const auto t0 = Clock::now();
  int64_t done = 0;
  while (trainer_) {
    if (steps > 0 && done >= steps) break;
    if (seconds > 0 && std::chrono::duration<double>(Clock::now() - t0).count() >= seconds) break;
    if (stop && stop()) break;
    // The budget used so far: the learning rate's tail (train.lr_tail) follows it.
    trainer_->setBudgetProgress(
        nerf::budgetProgress(done, steps, std::chrono::duration<double>(Clock::now() - t0).count(), seconds));
    stepOnce();
    ++done;
    letWaitersIn(lock);
  }
  if (trainer_) trainer_->setBudgetProgress(0.0);  // training that follows (a resumed map) at the full rate
  return done;
}

NerfMappingStats NerfMapping::stats() const {
  std::lock_guard<std::mutex> s(stats_mutex_);
  return stats_;
}

bool NerfMapping::hasModel() const {
  const auto lock = lockModel();
  return model_ != nullptr && trainer_ != nullptr;
}

bool NerfMapping::renderable() const { return hasModel() && stats().steps > opt_.train.grid_update_interval; }

std::vector<KeyframeId> NerfMapping::viewKeyframes() const {
  const auto lock = lockModel();
  std::vector<KeyframeId> out;
  for (const View& view : views_) out.push_back(view.keyframe);
  return out;
}

std::vector<uint64_t> NerfMapping::viewFrameIds() const {
  const auto lock = lockModel();
  std::vector<uint64_t> out;
  for (const View& view : views_) out.push_back(view.frame);
  return out;
}

nerf::TrainingView NerfMapping::trainingView(size_t i) const {
  const auto lock = lockModel();
  if (!trainer_) fail("NeRF: no training views yet");
  return trainer_->view(i);
}

std::vector<SE3> NerfMapping::viewPoses() const {
  const auto lock = lockModel();
  std::vector<SE3> out;
  for (const View& view : views_) out.push_back(view.pose);
  return out;
}

std::vector<nerf::Appearance> NerfMapping::viewAppearances() const {
  const auto lock = lockModel();
  std::vector<nerf::Appearance> out;
  for (size_t i = 0; trainer_ && i < trainer_->numViews(); ++i) out.push_back(trainer_->viewAppearance(i));
  return out;
}

std::unique_lock<std::mutex> NerfMapping::lockModel() const {
  ++model_waiters_;
  std::unique_lock<std::mutex> lock(model_mutex_);
  --model_waiters_;
  return lock;
}

void NerfMapping::letWaitersIn(std::unique_lock<std::mutex>& lock) {
  if (model_waiters_.load() == 0) return;
  lock.unlock();
  // Each waiter leaves the count once it holds the lock; bounded, in case one never comes.
  const auto until = Clock::now() + std::chrono::milliseconds(200);
  while (model_waiters_.load() > 0 && Clock::now() < until) std::this_thread::yield();
  lock.lock();
}

bool NerfMapping::withModel(const std::function<void(nerf::NerfModel&)>& fn) const {
  const auto lock = lockModel();
  if (!model_) return false;
  fn(*model_);
  return true;
}

Camera NerfMapping::trainingCamera() const {
  const auto lock = lockModel();
  return train_camera_;
}

}  // namespace nerfslam
