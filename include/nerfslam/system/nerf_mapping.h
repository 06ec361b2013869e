#pragma once
// The NeRF mapping thread: trains the CPU radiance field (nerf module) online on the keyframes the
// sparse SLAM makes, beside tracking and bundle adjustment.
//
// Input: a subscription to the mapping thread's KeyframeBus (bounded, drop-oldest: publishing never
// waits for us, so neither the mapping thread nor tracking ever waits for the NeRF). Each keyframe's
// colour image (Frame::colour; grey frames are replicated to RGB) becomes a training view, downscaled.
// Poses: every pose_refresh_steps steps the thread reads the keyframes' current poses from the Map
// (Map::resolvePose, which follows culled keyframes to their parents), so the poses that local and
// global bundle adjustment keep improving reach the trainer.
//
// Training policy (iMAP / NICE-SLAM style window): a share `recent_share` of each step's rays comes
// from the `recent_keyframes` newest keyframes; the rest is spread over all keyframes in proportion to
// their running photometric loss (poorly reconstructed views get more rays, none gets fewer than
// `min_weight` of the mean), so old areas keep being revisited and are not forgotten. The training
// after the sequence (trainFor) uses `final_recent_share` (0: by loss alone) instead: the window
// had kept 40 % of the final minute's rays on the last 4 views (New Tsukuba 0.9 dB held-out).
//
// Scene bounds (nerf/scene_box.h): the first keyframes fix a NeRF-space transform from the sparse map
// (robust extent of points and camera centres, times box_margin, inside an aabb_scale box with
// cascades). When the map later outgrows the box (more than refit_outside_fraction of the points, or
// any camera, outside it) the box is re-fitted around everything and the old field is distilled into
// the new one (nerf/distill.h) before training continues, so what was learned is carried over rather
// than dropped. When the map has become much smaller than the box (the box fitted to it afresh has
// a side below refit_shrink_ratio of the box's: a monocular map's first points reach far beyond the
// finished map), the box is fitted anew to the map and the field inside it distilled the same way.
//
// Thread budget: the trainer runs `train.threads` threads at a lower scheduling priority (nice
// `nice_increment`): tracking keeps its core, and when the machine is short of cores the NeRF yields.
//
// Everything that reads the model from another thread (renders, saving, export) goes through
// withModel(), which holds the model lock between steps.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "nerfslam/core/options.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/mapping/mapping_thread.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/nerf_options.h"
#include "nerfslam/nerf/trainer.h"

namespace nerfslam {

// The system's defaults of the trainer where they differ from nerf::TrainOptions': one training
// thread (tracking keeps its core), small steps (a pose refresh, a box check and a view-weight
// update can come between any two) and occupancy updates proportional to them.
inline nerf::TrainOptions nerfMappingTrainDefaults() {
  nerf::TrainOptions t;
  t.threads = 1;
  t.samples_per_step = 1 << 14;
  t.grid_update_scale = 0.0;  // samples_per_step / 2^16
  return t;
}

// The maps a robot plans in, written by `nerfslam run` beside the mesh (nerf/voxel_map.h):
// occupancy.bt (+ .ot, .meta.yaml) and map.yaml + map.pgm (+ map.meta.yaml).
struct OccupancyOutputOptions {
  bool enabled = true;
  double resolution = 0.05;                                // metres, when the run knows its scale (ground truth)
  double relative_resolution = 1 / 160.;                   // otherwise: of the mapped region's diagonal
  double band_lo = 0.1, band_hi = 1.5;                     // metres above the floor, when metric
  double relative_band_lo = 0.05, relative_band_hi = 0.9;  // otherwise: of the cameras' height above the floor
  int pixel_stride = 8;

  template <class V>
  void visit(V& v) {
    v("enabled", enabled, "Write occupancy.bt/.ot (OctoMap) and map.yaml/map.pgm (map_server) beside the mesh");
    v("resolution", resolution, "Voxel and cell side in metres, when the run has ground truth to scale the map",
      check::range(1e-4, 100.0));
    v("relative_resolution", relative_resolution,
      "Without a metric scale: voxel side as a fraction of the mapped region's diagonal", check::range(1e-5, 0.5));
    v("band_lo", band_lo, "2D grid: lowest height above the floor projected, metres (when metric)",
      check::range(-100.0, 100.0));
    const double lo = band_lo, rlo = relative_band_lo;
    v("band_hi", band_hi, "2D grid: highest height above the floor projected, metres (when metric); > band_lo",
      Check<double>([lo](const double& x) -> std::string {
        if (!std::isfinite(x) || x > 100) return "must be a finite number <= 100";
        return x > lo ? "" : "must be > band_lo";
      }));
    v("relative_band_lo", relative_band_lo,
      "Without a metric scale: lowest height as a fraction of the cameras' median height above the floor",
      check::range(-10.0, 10.0));
    v("relative_band_hi", relative_band_hi,
      "Without a metric scale: highest height as a fraction of the cameras' median height above the floor; > "
      "relative_band_lo",
      Check<double>([rlo](const double& x) -> std::string {
        if (!std::isfinite(x) || x > 10) return "must be a finite number <= 10";
        return x > rlo ? "" : "must be > relative_band_lo";
      }));
    v("pixel_stride", pixel_stride, "One keyframe ray per pixel_stride x pixel_stride pixels finds the free space",
      check::range(1, 256));
  }
};

// What `nerfslam run` renders from the trained map after the sequence (system/run_outputs.h).
struct NerfEvalOptions {
  int heldout_frames = 8;            // tracked frames the NeRF did not train on, rendered and compared (evenly spread)
  int keyframe_frames = 4;           // training views rendered and compared
  int cloud_views = 8;               // training views back-projected into nerf_cloud and map_preview.png
  int flythrough_frames = 60;        // renders along the trajectory in nerf/flythrough.mp4 (0: none)
  double flythrough_seconds = 30.0;  // time budget of the fly-through (fewer frames when slower)
  int64_t mesh_max_triangles = 5'000'000;  // mesh.ply: the density threshold is raised above this
  OccupancyOutputOptions occupancy;
  // Set by the run, not options:
  int threads = 2;
  // Write nerf/model.nerf and the training statistics only: no renders, cloud, mesh or fly-through
  // (a run stopped a second time, core/stop_signal.h).
  bool model_only = false;

  template <class V>
  void visit(V& v) {
    v("heldout_frames", heldout_frames,
      "Tracked frames the NeRF never trained on, rendered beside the real ones (nerf/heldout/) and scored",
      check::range(0, 100000));
    v("keyframe_frames", keyframe_frames, "Training views rendered beside the real ones (nerf/keyframes/) and scored",
      check::range(0, 100000));
    v("cloud_views", cloud_views, "Training views whose depth renders make nerf_cloud.ply and map_preview.png",
      check::range(0, 100000));
    v("flythrough_frames", flythrough_frames,
      "Frames of nerf/flythrough.mp4, renders along the estimated trajectory at the training size (0: none)",
      check::range(0, 100000));
    v("flythrough_seconds", flythrough_seconds,
      "Time budget of the fly-through: when its first frame says the rest would take longer, fewer frames (at "
      "least 2) cover the trajectory (0: no limit)",
      check::range(0.0, 1e6));
    v("mesh_max_triangles", mesh_max_triangles,
      "mesh.ply's size: above this many triangles its density threshold is raised (x1.25 at a time) until it "
      "fits, so fog goes before surfaces (report.json: mesh_density_threshold; 0: no limit)",
      check::range<int64_t>(0, int64_t(1) << 40));
    v("occupancy", occupancy, "The 3D occupancy map and the 2D grid written beside the mesh");
  }
};

struct NerfMappingOptions {
  bool enabled = true;
  int nice_increment = 19;
  double downscale = 2.0;
  // 2^17 entries per level, not instant-ngp's 2^19: on a CPU the sparse Adam's cost grows with the
  // table (each step touches most of a level's cache lines), and in the minute of final training the
  // steps matter more than the capacity: 1.5-1.6 times the steps and +0.4 dB held-out on the room,
  // New Tsukuba and KITTI 06 (docs/benchmarks.md); 2^16 lost again on the room.
  int log2_hashmap_size = 17;
  int keyframe_queue = 32;
  double min_view_distance = 0.05;
  double min_view_angle_deg = 5.0;
  int holdout_every = 0;
  int recent_keyframes = 4;
  double recent_share = 0.4;
  double min_weight = 0.25;
  int pose_refresh_steps = 8;
  double box_margin = 1.2;
  double aabb_scale = 2.0;
  double cone_angle = 1.0 / 64.0;  // nerf::SceneTransform::cone_angle of the boxes this fits
  double refit_outside_fraction = 0.05;
  int refit_check_steps = 200;
  double refit_shrink_ratio = 0.5;
  int distill_steps = 300;
  double psnr_interval_s = 1.0;
  double heldout_interval_s = 10.0;
  int heldout_eval_views = 4;
  double heldout_downscale = 8.0;
  // Offline runs: training after the sequence, with the final poses (tracking and mapping may end
  // before the NeRF has had much time beside them).
  double final_train_seconds = 60.0;
  // Or a fixed number of steps (reproducible figures whatever the machine's load); 0: by time.
  int64_t final_train_steps = 0;
  // Samples per step of the final training (0: train.samples_per_step). Larger steps spread the
  // per-step costs (sparse Adam, grid updates) over more samples but make fewer steps: on KITTI 06
  // 2^16 gave twice the samples per second of 2^14 and a better held-out PSNR, on New Tsukuba
  // 2 dB less (config/system/kitti.yaml sets it for driving).
  int final_samples_per_step = 0;
  // Share of the final training's rays drawn from the newest keyframes. The window serves a camera
  // that is still exploring; once the sequence is over every view is as new as any other, so 0
  // spreads the rays over all views by their loss alone.
  double final_recent_share = 0.0;
  int final_threads = 0;                                  // threads for the final training (0: all hardware threads)
  nerf::TrainOptions train = nerfMappingTrainDefaults();  // the trainer; train.seed also seeds the field
  NerfEvalOptions outputs;                                // what `run` renders from the map at the end

  template <class V>
  void visit(V& v) {
    v("enabled", enabled, "Train the NeRF map online (false: sparse-only, like --no-nerf)");
    v("nice_increment", nice_increment, "Scheduling niceness added to the NeRF threads (0: same priority)",
      check::range(0, 19));
    v("downscale", downscale, "Keyframe images are downscaled by this factor for training", check::range(1.0, 16.0));
    v("log2_hashmap_size", log2_hashmap_size, "Hash table entries per level (log2)", check::range(14, 22));
    v("keyframe_queue", keyframe_queue, "Keyframes waiting for the NeRF thread before the oldest are dropped",
      check::range(1, 100000));
    v("min_view_distance", min_view_distance,
      "A keyframe becomes a training view unless an existing view is closer than this (fraction of the median "
      "depth of the map points it sees; of the scene box when it sees none) and within min_view_angle_deg",
      check::range(0.0, 1.0));
    v("min_view_angle_deg", min_view_angle_deg, "See min_view_distance", check::range(0.0, 180.0));
    v("holdout_every", holdout_every,
      "Every n-th keyframe is not trained on (kept to evaluate the NeRF, e.g. on sparse photo sets); 0: none",
      check::range(0, 1000000));
    v("recent_keyframes", recent_keyframes, "Newest keyframes that get the recent share of the rays",
      check::range(1, 1000));
    v("recent_share", recent_share, "Share of each step's rays drawn from the newest keyframes",
      check::range(0.0, 1.0));
    v("min_weight", min_weight, "Smallest sampling weight of a keyframe, relative to the mean", check::range(0.0, 1.0));
    v("pose_refresh_steps", pose_refresh_steps, "Steps between reading bundle-adjusted keyframe poses",
      check::range(1, 100000));
    v("box_margin", box_margin, "Scene box = robust extent of the sparse map times this", check::range(1.0, 100.0));
    v("aabb_scale", aabb_scale, "NeRF box side in units of the fitted box (power of two: cascades)",
      check::range(1.0, 128.0));
    v("cone_angle", cone_angle,
      "With aabb_scale > 1, the march's step grows as distance x cone_angle (instant-ngp: 1/256); larger: fewer "
      "samples per ray far away",
      check::range(0.0, 0.1));
    v("refit_outside_fraction", refit_outside_fraction,
      "Re-fit the box when more than this fraction of the map points is outside it", check::range(0.0, 1.0));
    v("refit_check_steps", refit_check_steps, "Steps between box checks", check::range(1, 1000000));
    v("refit_shrink_ratio", refit_shrink_ratio,
      "Fit the box anew when the box fitted to the map has a side below this fraction of the box's (0: never shrink)",
      check::range(0.0, 1.0));
    v("distill_steps", distill_steps, "Steps distilling the old field into the re-fitted one",
      check::range(0, 1000000));
    v("psnr_interval_s", psnr_interval_s, "Seconds between running-PSNR updates (newest keyframes' training rays)",
      check::range(0.1, 1e6));
    v("heldout_interval_s", heldout_interval_s,
      "Seconds between renders of the newest held-out keyframes (holdout_every) for the running held-out PSNR "
      "(0: never)",
      check::range(0.0, 1e6));
    v("heldout_eval_views", heldout_eval_views, "Newest held-out keyframes rendered for the running held-out PSNR",
      check::range(1, 100));
    v("heldout_downscale", heldout_downscale,
      "Those renders are this much smaller than the training views (they cost the NeRF thread's time)",
      check::range(1.0, 64.0));
    v("final_train_seconds", final_train_seconds,
      "Offline runs: seconds of NeRF training after the sequence, with the final poses", check::range(0.0, 1e6));
    v("final_train_steps", final_train_steps,
      "Offline runs: when > 0, the training after the sequence makes exactly this many steps instead, however long "
      "they take (the same model whatever the machine's load; a stop request still shortens it)",
      check::range(int64_t(0), int64_t(100000000)));
    v("final_samples_per_step", final_samples_per_step,
      "Samples per step of the final training (0: train.samples_per_step)", check::range(0, 1 << 22));
    v("final_recent_share", final_recent_share,
      "Share of the final training's rays drawn from the newest keyframes (recent_share while the sequence runs)",
      check::range(0.0, 1.0));
    v("final_threads", final_threads, "Threads of the final training (0: all hardware threads)", check::range(0, 256));
    v("outputs", outputs,
      "What `nerfslam run` renders from the map after the sequence: held-out and keyframe comparisons, the "
      "cloud and map preview, the fly-through");
    v("train", train,
      "The NeRF trainer (nerf::TrainOptions with the system's defaults); train.seed also seeds the field, its "
      "re-fits and their distillation");
  }
};

// Each training view's share of a step's rays (the trainer normalises them): recent_share to the
// `recent` newest views in equal parts, the rest in proportion to each view's running loss (a view
// not seen yet, loss < 0, counts as the largest loss), none below min_weight of the mean; a view
// whose keyframe left the map (valid false) gets 0. recent >= the number of views: equal shares.
// recent_share 0 is no window at all: the loss alone, however few the views.
std::vector<double> viewRayShares(const std::vector<double>& loss, const std::vector<bool>& valid, size_t recent,
                                  double recent_share, double min_weight);

struct NerfMappingStats {
  int64_t steps = 0;
  int64_t samples = 0;
  int64_t samples_composited = 0;  // of those, before their ray's early termination (coloured)
  int64_t rays = 0;
  int64_t depth_rays = 0;  // of those, drawn through a map point (sparse depth)
  int64_t rollbacks = 0;
  int64_t refits = 0;
  int views = 0;
  uint64_t keyframes_dropped = 0;  // by the bounded input queue
  // Of those, taken from the map once the thread had caught up (the queue empty) or before the
  // final training: a dropped keyframe still in the map becomes a view after all.
  uint64_t keyframes_recovered = 0;
  uint64_t keyframes_skipped = 0;   // too close to an existing view
  uint64_t keyframes_held_out = 0;  // holdout_every
  double train_seconds = 0;         // wall time inside training steps
  double steps_per_second = 0;      // over the last few seconds
  double samples_per_second = 0;
  double psnr_recent = 0;  // PSNR of the training rays of the newest keyframes (0 before any)
  // How far the field moved the training views' poses (train.pose_refinement; updated with
  // psnr_recent): reprojection shift of each view's map points, anchor (bundle-adjusted) vs refined.
  nerf::Trainer::PoseRefinementStats pose_refinement;
  // PSNR of renders of the newest held-out keyframes (holdout_every; with their nearest view's
  // appearance, heldout_downscale smaller than the training views), every heldout_interval_s; 0
  // before the first.
  double psnr_heldout = 0;
  // The map learning over time: one entry per heldout_interval_s (seconds since start(), steps, the
  // two PSNRs above), at most 512 (every other one dropped when full).
  struct PsnrPoint {
    double seconds;
    int64_t steps;
    double psnr_recent, psnr_heldout;
  };
  std::vector<PsnrPoint> psnr_history;
  double last_loss = 0;
  double last_depth_loss = 0;  // mean line-of-sight loss of the last step's depth rays
  double learning_rate = 0;    // of the last step: train.lr, lower over the final training's tail (lr_tail)
  // Where the NeRF thread's time goes: the trainer's stages (seconds, summed over steps), reading
  // poses and points back from the map, and box re-fits (with their distillation).
  nerf::StageTimes times;
  double refresh_seconds = 0;
  double refit_seconds = 0;
};

class NerfMapping {
 public:
  NerfMapping(Map& map, KeyframeBus& bus, NerfMappingOptions options);
  ~NerfMapping();
  NerfMapping(const NerfMapping&) = delete;
  NerfMapping& operator=(const NerfMapping&) = delete;

  void start();
  // Takes the keyframes still queued, refreshes the poses, then stops the thread. Idempotent.
  void stop();
  // Trains in the calling thread (after stop()): `seconds` of wall time or `steps` steps, whichever
  // ends first (0: not limiting; both 0: nothing), with the latest poses, on `threads` threads from
  // now on (0: unchanged). `stop`, when given, is asked before every step and ends the training
  // when it returns true (a stopped run). Returns the steps made.
  // Steps are final_samples_per_step large from then on.
  int64_t trainFor(double seconds, int64_t steps = 0, int threads = 0, const std::function<bool()>& stop = {});

  NerfMappingStats stats() const;
  bool hasModel() const;
  // A model worth rendering: its occupancy grid has had its second update (train.grid_update_interval
  // steps after the first). Before it nearly every cell is still marked occupied and a render costs
  // ~5x the samples (measured at 160x120: 218 samples per ray at step 3, 30 at step 17).
  bool renderable() const;
  // Keyframe ids of the training views, in view order.
  std::vector<KeyframeId> viewKeyframes() const;
  // Frame ids (Frame::id, the runner's frame index) of the training views' images.
  std::vector<uint64_t> viewFrameIds() const;
  // Training view i (image as 8-bit RGBA at the training resolution, camera, current pose).
  nerf::TrainingView trainingView(size_t i) const;
  // Poses the trainer uses for its views (refreshed from the Map every pose_refresh_steps steps).
  std::vector<SE3> viewPoses() const;
  // The appearance (exposure, white balance) the trainer learnt for each view, in view order.
  std::vector<nerf::Appearance> viewAppearances() const;
  // Runs fn on the model under the model lock (between steps); false when there is no model yet.
  bool withModel(const std::function<void(nerf::NerfModel&)>& fn) const;
  // Continues from a saved model (a map folder's NeRF, nerf/model_io.h) with the Map's current
  // keyframes as training views; `train` false freezes it (localisation in a saved map: rendered,
  // never changed). Throws nerfslam::Error for an unreadable model. Call before keyframes arrive.
  void resume(const std::filesystem::path& model_file, bool train = true);
  bool frozen() const { return frozen_; }
  // Re-fits the scene box now (normally done when the map outgrows it); false without a model.
  bool refitNow();
  // The camera of the training views (the keyframe camera scaled by 1/downscale, undistorted).
  Camera trainingCamera() const;

 private:
  // A training view: trainer view i is views_[i].
  struct View {
    KeyframeId keyframe = -1;
    uint64_t frame = 0;  // Frame::id of its image
    SE3 pose;            // current pose
    bool valid = true;   // false: the keyframe left the map (not sampled)
    // The map points its keyframe observed when it became a view, and their keypoints (level-0
    // pixels of the keyframe camera): its sparse depth, re-read as bundle adjustment moves them.
    std::vector<PointId> point_ids;
    std::vector<Eigen::Vector2f> keypoints;
  };
  // A keyframe waiting for the model (before the box is fitted).
  struct PendingView {
    View view;
    nerf::TrainingView training;
  };

  void run();
  void drainQueue(bool wait);
  // Offers the map's keyframes that the queue dropped (those never offered, oldest first), at most
  // `max` of them; returns how many. Cheap when nothing was dropped since the last complete pass.
  size_t recoverDropped(size_t max);
  void addKeyframe(const KeyframeEvent& ev);
  void createModel();
  bool isNewView(const SE3& pose, double median_depth) const;
  // The views' surface points (the sparse depth the trainer supervises with) at their current
  // poses, with weights from each point's observations, found ratio and reprojection error.
  std::vector<std::vector<nerf::SurfacePoint>> surfacePoints(const std::vector<View>& views) const;
  void refreshPoses();
  void updateWeights();
  // The box the map needs when it needs another: grown around the map and the old box when the map
  // outgrew it (refitSceneBox), fitted to the map alone when the map is much smaller (shrunkSceneBox).
  struct NewBox {
    nerf::SceneTransform scene;
    bool shrunk = false;
  };
  std::optional<NewBox> newBox() const;
  void refit(const NewBox& box);
  void measurePsnr();
  void measureHeldout();
  void keepHeldout(const KeyframeEvent& ev);
  void stepOnce();
  // The model lock for every thread but the NeRF thread: it counts itself as waiting while it waits,
  // and the NeRF thread, which re-takes the lock after each step, lets waiters in first
  // (std::mutex is not fair: a publisher asking for the model starved for tens of seconds).
  std::unique_lock<std::mutex> lockModel() const;
  void letWaitersIn(std::unique_lock<std::mutex>& lock);  // NeRF thread, between steps
  std::vector<Eigen::Vector3d> mapPoints() const;         // positions of the sparse map's points
  std::vector<Eigen::Vector3d> viewCentres() const;       // camera centres of the views

  Map& map_;
  KeyframeBus& bus_;
  NerfMappingOptions opt_;
  std::shared_ptr<KeyframeBus::Queue> queue_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> frozen_{false};
  bool started_ = false, stopped_ = false;

  mutable std::mutex model_mutex_;             // model_, trainer_ and the views
  mutable std::atomic<int> model_waiters_{0};  // threads waiting in lockModel()
  std::unique_ptr<nerf::NerfModel> model_;
  std::unique_ptr<nerf::Trainer> trainer_;
  std::vector<View> views_;
  std::vector<PendingView> pending_;
  Camera train_camera_;
  Camera keyframe_camera_;  // the keyframes' camera (keypoints are in its pixels)
  uint64_t seen_map_version_ = 0;
  int64_t since_refit_check_ = 0;
  int64_t keyframes_seen_ = 0;
  std::set<KeyframeId> offered_;    // every keyframe addKeyframe was given (once each)
  uint64_t recovered_through_ = 0;  // the queue's drop count when a pass last found none left
  int64_t step_offset_ = 0;         // steps of trainers replaced by refits
  // Training the current field had before its trainer: a loaded model's steps, or the old field's
  // when a refit distilled it (0 when it started afresh).
  int64_t field_steps_before_ = 0;
  double last_psnr_time_ = -1e9;
  double last_heldout_time_ = -1e9;
  double start_time_ = 0;
  // The newest held-out keyframes (small images, RGB float) for the running held-out PSNR.
  struct HeldOutView {
    KeyframeId keyframe = -1;
    SE3 pose;
    cv::Mat rgb;
  };
  std::vector<HeldOutView> heldout_;
  Camera heldout_camera_;

  mutable std::mutex stats_mutex_;
  NerfMappingStats stats_;
  std::vector<std::pair<double, int64_t>> rate_window_;  // (time, samples) for the rate
};

}  // namespace nerfslam
