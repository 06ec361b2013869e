#include "nerfslam/nerf/trainer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <exception>
#include <thread>

#include <spdlog/spdlog.h>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/composite.h"
#include "nerfslam/nerf/raymarch.h"

namespace nerfslam::nerf {
namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

}  // namespace

void parallelRun(int n, const std::function<void(int)>& fn) {
  if (n <= 1) {
    fn(0);
    return;
  }
  std::vector<std::exception_ptr> errors(static_cast<size_t>(n));
  std::vector<std::thread> pool;
  pool.reserve(size_t(n - 1));
  for (int i = 1; i < n; ++i)
    pool.emplace_back([&, i] {
      try {
        fn(i);
      } catch (...) {
        errors[size_t(i)] = std::current_exception();
      }
    });
  try {
    fn(0);
  } catch (...) {
    errors[0] = std::current_exception();
  }
  for (auto& t : pool) t.join();
  for (auto& e : errors)
    if (e) std::rethrow_exception(e);
}

struct Trainer::ThreadState {
  std::mt19937_64 rng;
  RadianceField::Workspace ws;
  RadianceField::Gradients grads;
  std::vector<float> pos, fpos, dir, t, dt, sigma, rgb, d_sigma, d_rgb;
  std::vector<uint8_t> needed;    // samples before their ray's early termination (colour evaluated)
  std::vector<float> bg_grad;     // dL/d(learned background logits) of the step
  std::vector<float> app_grad;    // dL/d(appearance) per view (Appearance::kParams each) of the step
  std::vector<float> d_pos;       // dL/d(sample position), field coordinates (steps that refine poses)
  std::vector<double> pose_grad;  // dL/d(pose correction) per view (6 each) of the step
  struct RayInfo {
    int offset, count, view;
    Eigen::Vector3f origin;  // NeRF space
    int used = 0;            // samples before early termination (those with a colour)
    float target[3], bg[3];
    float t_surf = -1.f;  // > 0: the ray passes through a surface point at this NeRF-space distance
    float surf_width = 0.f, surf_weight = 0.f;
    bool learned_bg = false;  // bg is the model's learned background (bg_sample)
    Background::Sample bg_sample;
  };
  std::vector<RayInfo> rays;              // of the current chunk (offsets into the chunk's buffers)
  int64_t num_rays = 0, num_samples = 0;  // of the step
  double loss = 0, depth_loss = 0, distortion_loss = 0;
  int64_t composited = 0, depth_rays = 0;
  std::vector<double> view_loss;  // per view: summed loss of this step's rays
  std::vector<int> view_rays;
  StageTimes times;
};

Trainer::Trainer(NerfModel& model, std::vector<TrainingView> views, const TrainOptions& options)
    : model_(model), appearance_opt_(model.field->config().adam), pose_opt_(model.field->config().adam), opt_(options) {
  if (views.empty()) fail("NeRF training: no training views");
  if (opt_.threads < 1) fail("NeRF training: threads must be >= 1");
  views_.reserve(views.size());
  images_.reserve(views.size());
  for (auto& v : views) addView(std::move(v));
  setThreads(opt_.threads);
  snapshot();
}

void Trainer::setThreads(int n) {
  if (n < 1) fail("NeRF training: threads must be >= 1");
  opt_.threads = n;
  threads_.resize(size_t(std::min<int>(n, int(threads_.size()))));
  for (int i = int(threads_.size()); i < n; ++i) {
    auto ts = std::make_unique<ThreadState>();
    if (step_ == 0) {
      std::seed_seq seq{uint64_t(opt_.seed), uint64_t(i), uint64_t(0x6e657266)};
      ts->rng.seed(seq);
    } else {
      std::seed_seq seq{uint64_t(opt_.seed), uint64_t(i), uint64_t(0x6e657266), uint64_t(step_)};
      ts->rng.seed(seq);
    }
    ts->ws = model_.field->makeWorkspace();
    ts->grads = model_.field->makeGradients();
    threads_.push_back(std::move(ts));
  }
}

Trainer::~Trainer() = default;

void Trainer::setSamplesPerStep(int n) {
  if (n < 256 || n > (1 << 22)) fail("NeRF training: samples per step must be in [256, 2^22], not {}", n);
  opt_.samples_per_step = n;
}

double Trainer::learningRate() const {
  double lr = opt_.lr;
  if (step_ >= opt_.lr_decay_start) {
    const int64_t k = 1 + (step_ - opt_.lr_decay_start) / opt_.lr_decay_interval;
    lr *= std::pow(opt_.lr_decay_factor, double(k));
  }
  const double tail_start = 1.0 - opt_.lr_tail;
  if (opt_.lr_tail > 0 && budget_progress_ > tail_start)
    lr *= std::pow(opt_.lr_tail_factor, (budget_progress_ - tail_start) / opt_.lr_tail);
  return lr;
}

double budgetProgress(int64_t steps, int64_t step_budget, double seconds, double second_budget) {
  return std::max(step_budget > 0 ? double(steps) / double(step_budget) : 0.0,
                  second_budget > 0 ? seconds / second_budget : 0.0);
}

void Trainer::setBudgetProgress(double fraction) {
  budget_progress_ = std::isfinite(fraction) ? std::clamp(fraction, 0.0, 1.0) : 0.0;
}

void Trainer::densityBatch(const float* xyz, int n, float* sigma) {
  const int T = opt_.threads;
  parallelRun(T, [&](int ti) {
    const int begin = int(int64_t(n) * ti / T), end = int(int64_t(n) * (ti + 1) / T);
    if (end <= begin) return;
    std::vector<float> q(size_t(end - begin) * 3);
    model_.toFieldCoords(xyz + 3 * size_t(begin), size_t(end - begin), q.data());
    model_.field->queryDensity(q.data(), size_t(end - begin), sigma + begin);
  });
}

void Trainer::updateGrid() {
  OccupancyGrid::UpdateParams p;
  const int64_t total = int64_t(model_.grid->cascades()) * OccupancyGrid::kCells;
  if (step_ == 0) {
    // Every cell once: the grid starts from a full, untested occupancy. An untrained field is
    // nearly uniform, so there one sample per 2^3 cells is as good a start and costs 1/8 of the
    // queries (a full sweep of 2-5 cascades is 4-10 M queries, seconds on a CPU at every start); a
    // trained one (resumed, distilled) is swept cell by cell. Blocks of 4^3 cost 1/64 but left the
    // synthetic sphere 0.4 dB and its normals 0.03 of cosine worse after 300 steps.
    p.uniform_cells = -1;
    p.sweep_block = model_.training_steps == 0 ? 2 : 1;
  } else {
    const double per_step = opt_.effectiveGridUpdateScale();
    if (step_ < opt_.grid_warmup_steps) {
      p.uniform_cells = std::max<int64_t>(1, int64_t(double(total) / 4 * per_step));  // instant-ngp's share, uniform
    } else {
      p.uniform_cells = std::max<int64_t>(1, int64_t(double(total) * opt_.grid_update_fraction * per_step));
      p.occupied_cells = p.uniform_cells;
    }
  }
  p.decay = float(opt_.grid_decay);
  p.threshold_cap = float(opt_.grid_threshold);
  p.seed = uint64_t(opt_.seed) * 0x9E3779B97F4A7C15ull + uint64_t(step_);
  if (opt_.depth_weight > 0 && opt_.depth_ray_fraction > 0) p.keep_occupied = surfacePointsNerf();
  if (opt_.carve_free_space) p.keep_empty = freeSpaceSegments();
  model_.grid->update([this](const float* xyz, int n, float* sigma) { densityBatch(xyz, n, sigma); }, p);
}

std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>> Trainer::freeSpaceSegments() const {
  std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>> out;
  const float reach = std::max(0.f, 1.f - 3.f * float(opt_.depth_width));
  for (const auto& v : views_) {
    const Eigen::Vector3f c = model_.scene.toNerf(v.T_world_cam.translation()).cast<float>();
    for (const auto& p : v.points) {
      if (p.weight < 0.5f) continue;  // only points the map is sure of carve
      const Eigen::Vector3f q = model_.scene.toNerf(p.position.cast<double>()).cast<float>();
      out.emplace_back(c, c + reach * (q - c));
    }
  }
  return out;
}

std::vector<Eigen::Vector3f> Trainer::surfacePointsNerf() const {
  std::vector<Eigen::Vector3f> out;
  for (const auto& v : views_)
    for (const auto& p : v.points) out.push_back(model_.scene.toNerf(p.position.cast<double>()).cast<float>());
  return out;
}

void Trainer::snapshot() {
  auto params = model_.field->parameters();
  for (const auto& a : params)
    for (size_t i = 0; i < a.size; ++i)
      if (!std::isfinite(a.data[i])) {
        spdlog::warn("NeRF training: parameters not finite at step {}; keeping the snapshot of step {}", step_,
                     snap_step_);
        return;
      }
  snap_params_.resize(params.size());
  for (size_t i = 0; i < params.size(); ++i) snap_params_[i].assign(params[i].data, params[i].data + params[i].size);
  if (model_.background) {
    for (float x : model_.background->logits())
      if (!std::isfinite(x)) {
        spdlog::warn("NeRF training: background not finite at step {}; keeping the snapshot of step {}", step_,
                     snap_step_);
        return;
      }
    snap_background_ = model_.background->logits();
  }
  snap_pose_corr_ = pose_corr_;
  snap_grid_ = model_.grid->values();
  snap_threshold_ = model_.grid->threshold();
  snap_step_ = step_;
}

void Trainer::rollback() {
  auto params = model_.field->parameters();
  for (size_t i = 0; i < params.size(); ++i)
    std::memcpy(params[i].data, snap_params_[i].data(), params[i].size * sizeof(float));
  for (auto& m : model_.field->optimizerMoments()) std::fill(m.data, m.data + m.size, 0.f);
  for (auto& c : model_.field->optimizerCounters()) std::fill(c.data, c.data + c.size, 0u);
  model_.field->parametersChanged();
  if (model_.background) {
    if (snap_background_.size() == model_.background->numParameters())
      model_.background->logits() = snap_background_;
    else  // created after the snapshot
      std::fill(model_.background->logits().begin(), model_.background->logits().end(), 0.f);
    model_.background->resetOptimizer();
  }
  model_.grid->setValues(snap_grid_, snap_threshold_);
  for (size_t v = 0; v < pose_corr_.size(); ++v) {
    pose_corr_[v] = v < snap_pose_corr_.size() ? snap_pose_corr_[v] : PoseCorrection{};
    pose_opt_.reset(v);
  }
  ++rollbacks_;
}

// What every thread of a step shares.
struct Trainer::StepPlan {
  MarchParams march;
  int budget = 0;      // samples per thread
  int chunk = 0;       // samples per chunk (at most budget)
  float delta = 0;     // Huber delta
  bool depth = false;  // draw depth-supervised rays through views' surface points
  float depth_fraction = 0, depth_weight = 0;
  float distortion_weight = 0;  // TrainOptions::distortion_weight
  bool refine_poses = false;    // back-propagate to the sample positions and the views' poses
};

// A thread's ray draws over one step: which view, pixel, jitter and background.
struct Trainer::RayPicker {
  std::uniform_real_distribution<float> u01{0.f, 1.f};
  std::uniform_int_distribution<size_t> uniform;
  std::discrete_distribution<size_t> weighted;
  bool use_weights = false;
  size_t view(std::mt19937_64& rng) { return use_weights ? weighted(rng) : uniform(rng); }
};

// Marches rays into the thread's chunk buffers until the chunk holds plan.chunk samples, the
// thread's budget is reached (total samples before this chunk), or a ray would be truncated
// (*full: the step is over for this thread). Returns the chunk's samples.
int Trainer::marchChunk(ThreadState& ts, const StepPlan& plan, RayPicker& pick, int total, int* attempts_io,
                        bool* full) {
  ts.rays.clear();
  int used = 0, attempts = *attempts_io;  // a local: no reload after the buffer writes below
  while (used < plan.chunk) {
    if (total + used >= plan.budget || attempts >= plan.budget) {
      *full = true;
      break;
    }
    ++attempts;
    const size_t vi = pick.view(ts.rng);
    const ImageData& im = images_[vi];
    int px = std::uniform_int_distribution<int>(0, im.width - 1)(ts.rng);
    int py = std::uniform_int_distribution<int>(0, im.height - 1)(ts.rng);
    float ju = pick.u01(ts.rng) - 0.5f, jv = pick.u01(ts.rng) - 0.5f;
    const float jt = pick.u01(ts.rng);
    float t_surf = -1.f, surf_weight = 0.f;
    if (plan.depth && !views_[vi].points.empty() && pick.u01(ts.rng) < plan.depth_fraction)
      t_surf = throughSurfacePoint(vi, ts.rng, &px, &py, &ju, &jv, &surf_weight);
    float bg[3] = {1.f, 1.f, 1.f};
    if (opt_.random_background)
      for (float& b : bg) b = pick.u01(ts.rng);
    const RayGenerator gen(views_[vi].camera, step_poses_[vi], model_.scene);
    const Ray ray = gen.ray(px + ju, py + jv);
    // Before background_start_steps the view's rays get random backgrounds as views with alpha do:
    // the target does not depend on them only where the field is opaque, so the walls grow first.
    const bool learned_bg = model_.background && !im.has_alpha && step_ >= opt_.background_start_steps;
    RayMarcher marcher(ray, *model_.grid, model_.scene, plan.march, jt);
    const int room = std::min(opt_.max_samples_per_ray, plan.budget - total - used);
    const int n = marcher.next(room, ts.pos.data() + 3 * used, ts.t.data() + used, ts.dt.data() + used);
    // A ray without samples (it misses the box, or every cell it crosses is empty) still teaches the
    // learned background: its colour is the background's alone. Otherwise it teaches nothing.
    if (n == 0 && !learned_bg) continue;
    if (!marcher.done() && n == room && room < opt_.max_samples_per_ray) {  // would be truncated
      *full = true;
      break;
    }
    ThreadState::RayInfo ri;
    ri.offset = used;
    ri.count = n;
    ri.view = int(vi);
    ri.origin = ray.origin;
    if (t_surf > 0.f) {
      ri.t_surf = t_surf;
      ri.surf_weight = surf_weight;
      ri.surf_width = std::max(float(opt_.depth_width) * t_surf, 2.f * plan.march.dt(t_surf));
    }
    if (learned_bg) {
      ri.learned_bg = true;
      ri.bg_sample = model_.background->lookup(ray.dir.data());
      for (int c = 0; c < 3; ++c) bg[c] = ri.bg_sample.rgb[c];
    }
    const uint8_t* px_rgba = im.rgba.data() + (size_t(py) * im.width + px) * 4;
    const float a = px_rgba[3] / 255.f;
    for (int c = 0; c < 3; ++c) {
      ri.bg[c] = bg[c];
      ri.target[c] = px_rgba[c] / 255.f * a + bg[c] * (1.f - a);
    }
    for (int k = 0; k < n; ++k) {
      float* d = ts.dir.data() + 3 * (used + k);
      d[0] = ray.dir.x();
      d[1] = ray.dir.y();
      d[2] = ray.dir.z();
    }
    ts.rays.push_back(ri);
    used += n;
  }
  *attempts_io = attempts;
  return used;
}

// A depth-supervised ray: a random surface point of the view that projects into its image sets the
// pixel (and the sub-pixel offset, so the ray passes through the point), or, for the
// depth_triangle_share of them, a random point inside one of the view's depth triangles; returns
// the NeRF-space distance from the camera to the point (to the triangle's plane), or -1 (the ray
// stays as drawn) when it does not project.
float Trainer::throughSurfacePoint(size_t view, std::mt19937_64& rng, int* px, int* py, float* ju, float* jv,
                                   float* weight) const {
  const TrainingView& v = views_[view];
  const SE3& T_world_cam = step_poses_[view];
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  Eigen::Vector2d uv;
  double distance = 0;
  if (!triangles_[view].empty() && u01(rng) < opt_.depth_triangle_share) {
    const double ua = u01(rng), r1 = u01(rng), r2 = u01(rng);
    const auto s = sampleDepthTriangle(triangles_[view], v.points, v.camera, T_world_cam, ua, r1, r2);
    if (!s) return -1.f;
    uv = s->uv;
    distance = s->distance;
    *weight = s->weight;
  } else {
    const SurfacePoint& sp = v.points[std::uniform_int_distribution<size_t>(0, v.points.size() - 1)(rng)];
    const Eigen::Vector3d p_cam = T_world_cam.inverse() * sp.position.cast<double>();
    if (!v.camera.projectInImage(p_cam, &uv)) return -1.f;
    distance = p_cam.norm();
    *weight = sp.weight;
  }
  // The pixel and the sub-pixel offset that make the ray pass through uv.
  *px = std::clamp(int(std::lround(uv.x())), 0, v.camera.width - 1);
  *py = std::clamp(int(std::lround(uv.y())), 0, v.camera.height - 1);
  *ju = float(uv.x() - *px);
  *jv = float(uv.y() - *py);
  return float(distance * model_.scene.scale);
}

// Density of every sample of the chunk, then colour only where the composite will read it: up to
// each ray's early termination (the rest get zero gradients anyway).
void Trainer::forwardChunk(ThreadState& ts, int used) {
  model_.toFieldCoords(ts.pos.data(), size_t(used), ts.fpos.data());
  model_.field->forwardDensity(ts.ws, ts.fpos.data(), ts.dir.data(), size_t(used), ts.sigma.data());
  ts.needed.assign(size_t(used), 0);
  for (auto& ri : ts.rays) {
    ri.used = compositeUsedSamples(ri.count, ts.sigma.data() + ri.offset, ts.dt.data() + ri.offset);
    std::fill(ts.needed.begin() + ri.offset, ts.needed.begin() + ri.offset + ri.used, uint8_t(1));
  }
  model_.field->forwardColor(ts.ws, ts.needed.data(), ts.rgb.data());
}

// Composites each ray of the chunk, adds its Huber loss to the thread's sums and writes the loss
// gradients of its samples (d_sigma, d_rgb).
void Trainer::compositeChunk(ThreadState& ts, const StepPlan& plan) {
  const float delta = plan.delta, depth_weight = plan.depth_weight;
  for (const auto& ri : ts.rays) {
    const int o = ri.offset;
    const CompositeResult r = compositeForward(ri.count, ts.sigma.data() + o, ts.rgb.data() + 3 * o, ts.dt.data() + o,
                                               ts.t.data() + o, ri.bg);
    if (r.used != ri.used)  // the same arithmetic on the same densities: a bug if ever different
      fail(fmt::format("NeRF training: composite used {} samples of a ray, the colour pass {}", r.used, ri.used));
    float d_color[3];
    double ray_loss;
    if (learnsAppearance(size_t(ri.view))) {
      const Appearance& app = appearance_[size_t(ri.view)];
      float out[3], d_out[3];
      app.apply(r.rgb, out);
      ray_loss = huberLoss3(out, ri.target, delta, d_out);
      app.backward(r.rgb, d_out, ts.app_grad.data() + size_t(ri.view) * Appearance::kParams, d_color);
    } else {
      ray_loss = huberLoss3(r.rgb, ri.target, delta, d_color);
    }
    ts.loss += ray_loss;
    ts.composited += r.used;
    ts.view_loss[size_t(ri.view)] += ray_loss;
    ++ts.view_rays[size_t(ri.view)];
    compositeBackward(ri.count, ts.sigma.data() + o, ts.rgb.data() + 3 * o, ts.dt.data() + o, ts.t.data() + o, ri.bg, r,
                      d_color, 0.f, ts.d_sigma.data() + o, ts.d_rgb.data() + 3 * o);
    if (ri.t_surf > 0.f) {
      ts.depth_loss += lineOfSightLoss(ri.count, ts.sigma.data() + o, ts.dt.data() + o, ts.t.data() + o, r, ri.t_surf,
                                       ri.surf_width, depth_weight * ri.surf_weight, ts.d_sigma.data() + o);
      ++ts.depth_rays;
    }
    if (plan.distortion_weight > 0.f)
      ts.distortion_loss += distortionLoss(ts.sigma.data() + o, ts.dt.data() + o, ts.t.data() + o, r,
                                           plan.distortion_weight, ts.d_sigma.data() + o);
    if (ri.learned_bg) {
      float d_bg[3];
      backgroundGradient(r.opacity, d_color, d_bg);
      model_.background->backward(ri.bg_sample, d_bg, ts.bg_grad.data());
    }
  }
}

// One thread's share of a step: rays until it holds plan.budget samples, in chunks of about
// plan.chunk: march, field forward, composite, loss gradient and field backward of a chunk before
// the next, so the activations the backward reads are held for one chunk, not for the whole step.
// The gradients are of the summed per-ray loss.
void Trainer::trainThread(ThreadState& ts, const StepPlan& plan) {
  ts.times = StageTimes{};
  ts.loss = 0;
  ts.depth_loss = 0;
  ts.distortion_loss = 0;
  ts.depth_rays = 0;
  ts.composited = 0;
  ts.num_rays = 0;
  ts.num_samples = 0;
  const size_t cap = size_t(plan.chunk + opt_.max_samples_per_ray);
  for (auto* v : {&ts.pos, &ts.dir, &ts.fpos, &ts.rgb, &ts.d_rgb}) v->resize(3 * cap);
  if (plan.refine_poses) {
    ts.d_pos.resize(3 * cap);
    ts.pose_grad.assign(6 * views_.size(), 0.0);
  }
  for (auto* v : {&ts.t, &ts.dt, &ts.sigma, &ts.d_sigma}) v->resize(cap);
  if (model_.background && ts.bg_grad.size() != model_.background->numParameters())
    ts.bg_grad.assign(model_.background->numParameters(), 0.f);
  ts.app_grad.assign(views_.size() * Appearance::kParams, 0.f);
  RayPicker pick;
  pick.uniform = std::uniform_int_distribution<size_t>(0, views_.size() - 1);
  pick.use_weights = !view_weights_.empty();
  if (pick.use_weights) pick.weighted = std::discrete_distribution<size_t>(view_weights_.begin(), view_weights_.end());
  ts.view_loss.assign(views_.size(), 0.0);
  ts.view_rays.assign(views_.size(), 0);
  int total = 0, attempts = 0;
  bool full = false;
  while (!full && total < plan.budget) {
    auto t0 = Clock::now();
    const int used = marchChunk(ts, plan, pick, total, &attempts, &full);
    ts.times.march += since(t0);
    if (used == 0) break;
    total += used;
    ts.num_rays += int64_t(ts.rays.size());

    t0 = Clock::now();
    forwardChunk(ts, used);
    ts.times.field_forward += since(t0);

    t0 = Clock::now();
    compositeChunk(ts, plan);
    ts.times.composite += since(t0);

    t0 = Clock::now();
    if (plan.refine_poses) {
      model_.field->backward(ts.ws, ts.d_sigma.data(), ts.d_rgb.data(), ts.grads, ts.d_pos.data(),
                             level_weights_.data());
      // Field coordinates are NeRF space / aabb_scale around the box centre: dq/dp = fieldCoordScale.
      const float dq = model_.fieldCoordScale();
      for (int k = 0; k < 3 * used; ++k) ts.d_pos[size_t(k)] *= dq;
      for (const auto& ri : ts.rays)
        accumulatePoseGradient(ri.origin, ts.pos.data() + 3 * ri.offset, ts.d_pos.data() + 3 * ri.offset, ri.used,
                               model_.scene.scale, ts.pose_grad.data() + 6 * size_t(ri.view));
    } else {
      model_.field->backward(ts.ws, ts.d_sigma.data(), ts.d_rgb.data(), ts.grads);
    }
    ts.times.field_backward += since(t0);
  }
  ts.num_samples = total;
}

// Sums the threads' results into stats (wall time per stage: the slowest thread's) and, when the
// loss is finite, updates the per-view losses. Returns the sum of every loss term (the step's
// divergence check: finite or not).
double Trainer::gatherThreads(StepStats* stats) {
  double loss = 0, depth_loss = 0, distortion_loss = 0;
  for (const auto& ts : threads_) {
    loss += ts->loss;
    depth_loss += ts->depth_loss;
    distortion_loss += ts->distortion_loss;
    stats->depth_rays += ts->depth_rays;
    stats->rays += ts->num_rays;
    stats->samples += ts->num_samples;
    stats->samples_composited += ts->composited;
    stats->times.march = std::max(stats->times.march, ts->times.march);
    stats->times.field_forward = std::max(stats->times.field_forward, ts->times.field_forward);
    stats->times.composite = std::max(stats->times.composite, ts->times.composite);
    stats->times.field_backward = std::max(stats->times.field_backward, ts->times.field_backward);
  }
  if (std::isfinite(loss))
    for (size_t v = 0; v < views_.size(); ++v) {
      double sum = 0;
      int n = 0;
      for (const auto& ts : threads_) {
        sum += ts->view_loss[v];
        n += ts->view_rays[v];
      }
      if (n == 0) continue;
      const double mean = sum / n;
      view_loss_[v] = view_loss_[v] < 0 ? mean : 0.5 * view_loss_[v] + 0.5 * mean;
    }
  stats->loss = stats->rays > 0 ? loss / double(stats->rays) : 0.0;
  stats->depth_loss = stats->depth_rays > 0 ? depth_loss / double(stats->depth_rays) : 0.0;
  stats->distortion_loss = stats->rays > 0 ? distortion_loss / double(stats->rays) : 0.0;
  return loss + depth_loss + distortion_loss;
}

// Applies the threads' gradients with Adam (the mean-per-ray loss: scaled by 1/rays). False when
// the MLP weights came out non-finite (then rolled back).
bool Trainer::applyGradients(int64_t rays, StepStats* stats) {
  const float scale = 1.f / float(rays);
  auto t0 = Clock::now();
  std::vector<RadianceField::Gradients*> grads;
  for (auto& ts : threads_) grads.push_back(&ts->grads);
  model_.field->step(grads, float(learningRate()), opt_.threads, scale);
  if (model_.background) {
    // Threads' gradients summed in thread order (deterministic), then one Adam step.
    float* sum = threads_[0]->bg_grad.data();
    const size_t n = model_.background->numParameters();
    for (size_t k = 1; k < threads_.size(); ++k) {
      float* g = threads_[k]->bg_grad.data();
      for (size_t i = 0; i < n; ++i) {
        sum[i] += g[i];
        g[i] = 0.f;
      }
    }
    // Before background_start_steps no ray uses it (marchChunk): its gradient is zero, and step()
    // leaves texels with a zero gradient as they are.
    model_.background->step(sum, float(learningRate()), model_.field->config().adam, scale);
  }
  stepAppearance();
  stats->times.optimizer = since(t0);
  // A NaN that the forward pass hides (e.g. behind a ReLU) still shows in the MLP weights after the
  // update; they are small (~10^4 floats), so they are checked every step. The hash grid is
  // checked with every snapshot.
  for (const auto& a : model_.field->parameters()) {
    if (a.name == "hash_grid") continue;
    for (size_t i = 0; i < a.size; ++i)
      if (!std::isfinite(a.data[i])) {
        spdlog::warn("NeRF training diverged at step {} ({} not finite); rolling back to the snapshot of step {}",
                     step_, a.name, snap_step_);
        rollback();
        return false;
      }
  }
  if (model_.background)
    for (float x : model_.background->logits())
      if (!std::isfinite(x)) {
        spdlog::warn(
            "NeRF training diverged at step {} (background not finite); rolling back to the snapshot of step {}", step_,
            snap_step_);
        rollback();
        return false;
      }
  return true;
}

// One Adam step of each learnt appearance from the mean gradient of its view's rays in this step
// (threads summed in thread order), then the mean over the views that learn one is taken out (the
// gauge: the field's colours are those of the views' mean appearance). A transform that comes out
// non-finite is reset to identity.
void Trainer::stepAppearance() {
  constexpr size_t K = Appearance::kParams;
  double mean[K] = {};
  int learning = 0;
  for (size_t v = 0; v < views_.size(); ++v) {
    int n = 0;
    for (const auto& ts : threads_) n += ts->view_rays[v];
    if (n == 0 || !learnsAppearance(v)) continue;
    float g[K] = {};
    for (const auto& ts : threads_)
      for (size_t k = 0; k < K; ++k) g[k] += ts->app_grad[v * K + k];
    for (float& x : g) x /= float(n);
    appearance_opt_.step(v, appearance_[v], g, float(opt_.appearance_lr), float(opt_.appearance_reg));
    if (!appearance_[v].finite()) {
      spdlog::warn("NeRF training: the appearance of view {} diverged at step {}; reset to identity", v, step_);
      appearance_[v] = Appearance{};
      appearance_opt_.reset(v);
    }
  }
  for (size_t v = 0; v < views_.size(); ++v) {
    if (!learnsAppearance(v)) continue;
    ++learning;
    for (size_t c = 0; c < 3; ++c) {
      mean[c] += appearance_[v].log_gain[c];
      mean[3 + c] += appearance_[v].bias[c];
    }
  }
  if (learning == 0) return;
  for (size_t v = 0; v < views_.size(); ++v) {
    if (!learnsAppearance(v)) continue;
    for (size_t c = 0; c < 3; ++c) {
      appearance_[v].log_gain[c] -= float(mean[c] / learning);
      appearance_[v].bias[c] -= float(mean[3 + c] / learning);
    }
  }
}

StepStats Trainer::step() {
  StepStats stats;
  auto t_grid = Clock::now();
  if (step_ % opt_.grid_update_interval == 0) {
    updateGrid();
    stats.times.grid_update = since(t_grid);
  }
  const int T = opt_.threads;
  StepPlan plan;
  plan.march = MarchParams::forScene(model_.scene, model_.grid->cascades());
  plan.budget = std::max(1, opt_.samples_per_step / T);
  plan.chunk = std::max(1, std::min(plan.budget, opt_.samples_per_chunk));
  plan.delta = float(opt_.huber_delta);
  plan.depth = opt_.depth_weight > 0 && opt_.depth_ray_fraction > 0;
  plan.depth_fraction = float(opt_.depth_ray_fraction);
  plan.depth_weight = float(opt_.depth_weight);
  plan.distortion_weight = float(opt_.distortion_weight);
  plan.refine_poses = refinesPosesThisStep();
  preparePoses(plan.refine_poses);
  parallelRun(T, [&](int ti) { trainThread(*threads_[size_t(ti)], plan); });

  const double loss = gatherThreads(&stats);
  if (!std::isfinite(loss)) {
    spdlog::warn("NeRF training diverged at step {} (loss {}); rolling back to the snapshot of step {}", step_, loss,
                 snap_step_);
    for (auto& ts : threads_) {
      model_.field->clearGradients(ts->grads);
      std::fill(ts->bg_grad.begin(), ts->bg_grad.end(), 0.f);
    }
    rollback();
    stats.rolled_back = true;
    ++step_;
    return stats;
  }
  if (stats.rays > 0 && !applyGradients(stats.rays, &stats)) {
    stats.rolled_back = true;
    ++step_;
    return stats;
  }
  if (plan.refine_poses) {  // the threads' pose gradients and rays per view, summed in thread order
    std::vector<double> grad(6 * views_.size(), 0.0);
    std::vector<int> rays(views_.size(), 0);
    for (const auto& ts : threads_)
      for (size_t v = 0; v < views_.size(); ++v) {
        rays[v] += ts->view_rays[v];
        for (size_t k = 0; k < 6; ++k) grad[6 * v + k] += ts->pose_grad[6 * v + k];
      }
    stepPoses(grad, rays);
  }
  ++step_;
  model_.training_steps = uint64_t(step_);
  if (step_ % opt_.snapshot_interval == 0) snapshot();
  total_ += stats.times;
  return stats;
}

}  // namespace nerfslam::nerf
