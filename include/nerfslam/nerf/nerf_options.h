#pragma once
// Options of the NeRF pipeline around the radiance field: scene normalisation, occupancy grid,
// training schedule, rendering. Defaults follow instant-ngp where a CPU does not force a change
// (each such change is documented at the field).
#include <algorithm>
#include <cstdint>

#include "nerfslam/core/options.h"
#include "nerfslam/nerf/field.h"

namespace nerfslam::nerf {

struct SceneOptions {
  // instant-ngp's NeRF-synthetic defaults: p_nerf = 0.33 * p_world + 0.5, so the lego (inside
  // [-1.5, 1.5]^3) fills the unit cube.
  double scale = 0.33;
  std::vector<double> offset = {0.5, 0.5, 0.5};
  // 0: take it from the dataset (transforms.json "aabb_scale", 1 when absent).
  double aabb_scale = 0.0;

  template <class V>
  void visit(V& v) {
    v("scale", scale, "World-to-NeRF-space scale (p_nerf = scale * p_world + offset)", check::positive<double>());
    v("offset", offset, "World-to-NeRF-space offset (3 numbers)");
    v("aabb_scale", aabb_scale, "Scene box side in units of the unit cube (power of two); 0: from the dataset",
      check::range(0.0, 128.0));
  }
};

struct TrainOptions {
  // Samples per optimiser step (instant-ngp's target batch is 2^18). Rays per step adapt so the
  // sample count stays constant.
  int samples_per_step = 1 << 16;
  // A thread marches, evaluates and back-propagates its samples in chunks of about this many (plus
  // at most one ray): the activations kept for the backward pass are a chunk's, so memory does not
  // grow with samples_per_step.
  int samples_per_chunk = 1 << 14;
  int max_samples_per_ray = 1024;
  // Adam learning rate: lr * lr_decay_factor^k, k = number of lr_decay_interval boundaries passed
  // after lr_decay_start (instant-ngp's paper schedule is x0.33 at 20k steps and every 10k after).
  double lr = 1e-2;
  int lr_decay_start = 20000;
  int lr_decay_interval = 10000;
  double lr_decay_factor = 0.33;
  // A training with a known budget (`nerfslam train --seconds/--steps`, and the final training of
  // `nerfslam run`, nerf.final_train_seconds/steps; both report their progress through
  // Trainer::setBudgetProgress) lowers the rate exponentially over the last lr_tail of the budget, to
  // lr_tail_factor of it at the end: lego at 300 s 30.8 -> 31.8 dB, the synthetic room and New
  // Tsukuba +0.5 dB held-out. The NeRF thread while the sequence runs has no budget: full rate.
  double lr_tail = 0.3;
  double lr_tail_factor = 0.25;
  double huber_delta = 0.1;
  // Occupancy grid: updated every grid_update_interval steps. The first update samples every cell;
  // later updates during the first grid_warmup_steps sample a quarter of the cells uniformly
  // (instant-ngp samples every cell during its warm-up, 2M density queries per update, which a CPU
  // cannot afford every 16 steps); afterwards grid_update_fraction of the cells uniformly plus as
  // many among the occupied ones. instant-ngp samples 1/4 + 1/4 at 2^18 samples per step; 1/16 +
  // 1/16 keeps the same ratio of grid queries to training samples at 2^16 samples per step.
  int grid_update_interval = 16;
  int grid_warmup_steps = 256;
  double grid_update_fraction = 1.0 / 16.0;
  // Scales the cells sampled per update (warm-up and after). 0: samples_per_step / 2^16 (at most
  // 1), so grid queries stay proportional to the training samples of smaller steps.
  double grid_update_scale = 1.0;
  double grid_decay = 0.95;
  double grid_threshold = 0.01;
  // Views with alpha (object captures): a random background colour per ray, the target composited
  // over the same colour; false: white.
  bool random_background = true;
  // Views without alpha (real cameras) get the model's learned background instead (background.h: a
  // lat-long map by ray direction, trained with the field), so sky and far scenery outside the box
  // need no density inside it. The first such view creates it (frame: that view's camera).
  // false (the default): those views use the random (or white) background too. Driving, with sky
  // over every frame, gains from it: KITTI 06 held-out 21.60 against 21.25 dB (means of four and
  // three 60 s runs), so config/system/kitti.yaml turns it on; the synthetic room (-0.1 to +0.8 dB at a
  // fixed number of steps) and the photo sets (fountain -0.7, temple -0.1, one run each) do not
  // gain, so it stays off by default (docs/benchmarks.md).
  bool learned_background = false;
  // Steps (of this trainer) before the learned background is used: until then those views' rays get
  // random backgrounds (random_background), which only an opaque field matches, so the field and
  // not the background explains the walls of the first views (learned from step 0, it absorbed them
  // in short runs; kept grey, a half-transparent fog matched the images as well).
  int background_start_steps = 150;
  // Rows of the learned background's lat-long map (columns: twice as many); 64: 2.8 degrees a texel.
  int background_rows = 64;
  // Sparse depth (views with surface points, e.g. the SLAM map's points a keyframe observes): this
  // share of a view's rays is drawn through its points' projections and adds the line-of-sight loss
  // (composite.h: lineOfSightLoss) with weight depth_weight x the point's weight; the surface is
  // spread over depth_width x its distance (at least two march steps). The occupancy cells around the
  // points stay occupied, so the loss always has samples at the surface to act on.
  double depth_ray_fraction = 0.25;
  double depth_weight = 0.1;
  double depth_width = 0.03;
  // This share of those depth-supervised rays is drawn inside triangles between the view's surface
  // points instead of through the points (depth_triangles.h: Delaunay triangles in the image, kept
  // where their corners lie at similar depths close together), their target the triangle's plane:
  // the road and the walls between the keypoints are supervised too.
  double depth_triangle_share = 0.5;
  // The occupancy cells on a view's lines of sight to its surface points, short of the points by
  // three surface widths, are kept empty (space carving): a sparse map says what is free space.
  bool carve_free_space = true;
  // Distortion loss (composite.h: distortionLoss, mip-NeRF 360) on every ray with this weight: it
  // pulls each ray's weight into one compact peak, so fog and floaters in front of surfaces (what
  // makes real forward-moving sequences grey) cost more than a surface. Distances are NeRF-space.
  double distortion_weight = 0;
  // Per-view appearance (appearance.h) for views without alpha: an affine colour transform per view,
  // learned with its own Adam (appearance_lr) and L2 towards identity (appearance_reg).
  bool appearance = true;
  double appearance_lr = 2e-3;
  double appearance_reg = 1e-2;
  // Pose refinement by the field (pose_refine.h): each view's pose is corrected by the photometric
  // gradient through its rays' samples, every pose_refine_interval steps from step
  // pose_refine_start on (the field first learns the scene at the given poses), coarse to fine over
  // the hash levels during the first pose_c2f_steps refinement steps. Rotation learning rate
  // pose_lr (rad), translation pose_lr x the scene's size per radian; L2 pull pose_reg towards the
  // given pose. A correction beyond pose_max_rotation_deg or pose_max_translation (fraction of the
  // distance from the view to the scene box's centre) is reset and counted. The mean correction over
  // the views is taken out after each update (the gauge: the field stays in the frame of the given
  // poses, where held-out frames are rendered).
  bool pose_refinement = false;
  double pose_lr = 1e-3;
  int pose_refine_interval = 2;
  int pose_refine_start = 100;
  int pose_c2f_steps = 1000;
  double pose_reg = 1e-2;
  double pose_max_rotation_deg = 5.0;
  double pose_max_translation = 0.1;
  // Divergence guard: parameters are snapshotted every snapshot_interval steps; a non-finite loss
  // restores the snapshot (and restarts Adam's moments).
  int snapshot_interval = 100;
  int threads = 2;
  int64_t seed = 0;

  template <class V>
  void visit(V& v) {
    v("samples_per_step", samples_per_step, "Target ray samples per optimiser step", check::range(256, 1 << 22));
    v("samples_per_chunk", samples_per_chunk, "Samples a thread evaluates and back-propagates at a time",
      check::range(256, 1 << 22));
    v("max_samples_per_ray", max_samples_per_ray, "March samples per ray at most", check::range(16, 4096));
    v("lr", lr, "Adam learning rate", check::positive<double>());
    v("lr_decay_start", lr_decay_start, "Step of the first learning-rate decay", check::nonNegative<int>());
    v("lr_decay_interval", lr_decay_interval, "Steps between decays", check::positive<int>());
    v("lr_decay_factor", lr_decay_factor, "Learning-rate factor per decay", check::range(0.0, 1.0));
    v("lr_tail", lr_tail,
      "Share of a budgeted training (`train --seconds/--steps`, run's nerf.final_train_seconds/steps) at its end "
      "over which the learning rate falls to lr_tail_factor of it (0: never)",
      check::range(0.0, 1.0));
    v("lr_tail_factor", lr_tail_factor, "Learning-rate factor at the end of a budgeted training",
      check::range(0.0, 1.0));
    v("huber_delta", huber_delta, "Huber loss delta", check::positive<double>());
    v("grid_update_interval", grid_update_interval, "Steps between occupancy updates", check::positive<int>());
    v("grid_warmup_steps", grid_warmup_steps,
      "Steps during which occupancy updates sample a quarter of the cells uniformly (the first update: every cell)",
      check::nonNegative<int>());
    v("grid_update_fraction", grid_update_fraction, "Fraction of cells sampled per update after warm-up",
      check::range(0.0, 1.0));
    v("grid_update_scale", grid_update_scale,
      "Factor on the cells sampled per occupancy update (0: samples_per_step / 65536, at most 1)",
      check::range(0.0, 1.0));
    v("grid_decay", grid_decay, "Occupancy decay per update", check::range(0.0, 1.0));
    v("grid_threshold", grid_threshold, "Occupancy threshold cap (density * sqrt(3)/1024)", check::positive<double>());
    v("random_background", random_background,
      "Random background colour per training ray of views with alpha (false: white)");
    v("learned_background", learned_background,
      "Views without alpha learn the background by ray direction (a lat-long map) instead");
    v("background_start_steps", background_start_steps,
      "Steps before the learned background is used (until then: random backgrounds)", check::range(0, 100000000));
    v("background_rows", background_rows, "Rows of the learned background map (columns: twice as many)",
      check::range(2, 1024));
    v("depth_ray_fraction", depth_ray_fraction,
      "Share of the rays of views with surface points drawn through those points (sparse depth supervision)",
      check::range(0.0, 1.0));
    v("depth_weight", depth_weight, "Weight of the line-of-sight depth loss per ray (0: off)",
      check::range(0.0, 100.0));
    v("depth_width", depth_width, "Width of a supervised surface, as a fraction of its distance",
      check::range(1e-4, 1.0));
    v("depth_triangle_share", depth_triangle_share,
      "Share of the depth-supervised rays drawn inside triangles between the view's surface points (their plane "
      "the target; 0: through the points only)",
      check::range(0.0, 1.0));
    v("carve_free_space", carve_free_space,
      "Keep the occupancy cells between a view and its surface points empty (free space from the sparse map)");
    v("distortion_weight", distortion_weight,
      "Weight of the distortion loss per ray (compact weight along each ray against fog; 0: off)",
      check::range(0.0, 100.0));
    v("appearance", appearance, "Learn a per-view colour transform (exposure, white balance) for views without alpha");
    v("appearance_lr", appearance_lr, "Adam learning rate of the per-view appearance", check::range(0.0, 1.0));
    v("appearance_reg", appearance_reg, "L2 weight pulling each view's appearance towards identity",
      check::range(0.0, 100.0));
    v("pose_refinement", pose_refinement,
      "Refine each view's pose by the photometric gradient (BARF-style, coarse to fine over the hash levels)");
    v("pose_lr", pose_lr, "Adam learning rate of the pose corrections (radians; translation scaled by the scene)",
      check::range(0.0, 1.0));
    v("pose_refine_interval", pose_refine_interval, "Steps between pose updates", check::range(1, 1000000));
    v("pose_refine_start", pose_refine_start, "First step that refines poses", check::range(0, 100000000));
    v("pose_c2f_steps", pose_c2f_steps, "Refinement steps over which the hash levels join the pose gradient",
      check::range(1, 100000000));
    v("pose_reg", pose_reg, "L2 weight pulling each correction towards the given pose", check::range(0.0, 100.0));
    v("pose_max_rotation_deg", pose_max_rotation_deg, "A larger rotation correction is reset (diverged)",
      check::range(0.01, 90.0));
    v("pose_max_translation", pose_max_translation,
      "A larger translation correction (fraction of the view's distance to the box centre) is reset",
      check::range(1e-4, 10.0));
    v("snapshot_interval", snapshot_interval, "Steps between divergence snapshots", check::positive<int>());
    v("threads", threads, "Training threads", check::range(1, 256));
    v("seed", seed, "Random seed", check::nonNegative<int64_t>());
  }

  // grid_update_scale with 0 resolved.
  double effectiveGridUpdateScale() const {
    return grid_update_scale > 0 ? grid_update_scale : std::min(1.0, double(samples_per_step) / double(1 << 16));
  }
};

struct RenderOptions {
  int threads = 2;
  std::vector<double> background = {1.0, 1.0, 1.0};  // RGB in [0,1]
  // Rays of a model with a learned background (NerfModel::background) end on it instead of
  // `background`; false: `background` always (e.g. to see what the box holds).
  bool learned_background = true;
  bool normals = true;
  // Depth/normals are reported where the accumulated opacity reaches this (0 elsewhere).
  double min_opacity = 0.5;

  template <class V>
  void visit(V& v) {
    v("threads", threads, "Rendering threads", check::range(1, 256));
    v("background", background, "Background RGB in [0,1] (of models without a learned background)");
    v("learned_background", learned_background, "Use the model's learned background when it has one");
    v("normals", normals, "Render normals (costs density gradients)");
    v("min_opacity", min_opacity, "Opacity below which depth and normals are left 0", check::range(0.0, 1.0));
  }
};

}  // namespace nerfslam::nerf
