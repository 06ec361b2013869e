#pragma once
// NeRF training (instant-ngp recipe on CPU threads).
//
// One step: each of T threads draws rays (random view, random pixel, jittered inside the pixel) from
// its own RNG stream (seeded from the seed and the thread index) until its share of
// samples_per_step is filled, marches them through the occupancy grid, runs the field forward on all
// its samples at once, composites each ray against its background (views with alpha: a random colour;
// views without alpha: the model's learned background, background.h, created by the first such view
// when TrainOptions::learned_background is set) and back-propagates the Huber loss into its own
// Gradients (and the background's); field.step() then merges the threads' gradients in thread order
// and applies Adam (the background: its own Adam, same learning rate). Results are deterministic for a seed and a
// thread count. The occupancy grid is refreshed every grid_update_interval steps (see TrainOptions). A non-finite loss,
// or non-finite MLP weights after an update (checked every step; the hash grid is checked before each snapshot, so a
// snapshot is never broken), rolls the parameters and the grid back to the last snapshot (taken every snapshot_interval
// steps) and restarts Adam's moments; the step is reported as a rollback.
#include <cstdint>
#include <memory>
#include <random>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/nerf/appearance.h"
#include "nerfslam/nerf/depth_triangles.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/nerf_options.h"
#include "nerfslam/nerf/pose_refine.h"

namespace nerfslam::nerf {

// A point of the scene that a view sees (e.g. a sparse map point its keyframe observes): world
// position and a confidence weight in (0, 1]. It supervises the depth of the view's ray through it.
struct SurfacePoint {
  Eigen::Vector3f position = Eigen::Vector3f::Zero();
  float weight = 1.f;
};

// A posed image. image: RGB or RGBA channel order (not OpenCV's BGR), CV_8UC3/4 (0..255) or
// CV_32FC3/4 (0..1). With alpha (any pixel's below 255), the target colour is composited over the
// ray's random background; without, the view is opaque (a real camera: the learned background).
struct TrainingView {
  cv::Mat image;
  Camera camera;
  SE3 T_world_cam;
  std::vector<SurfacePoint> points;  // optional sparse depth (TrainOptions::depth_*)
};

// Validates a view (image type, size vs camera, finite pose, positive focal length) and throws an
// Error naming `source` otherwise.
void validateView(const TrainingView& view, const std::string& source);

// A view from an image as OpenCV decodes it (8-bit BGR or BGRA, e.g. DatasetFrame::image with
// ImageMode::kUnchanged), resized by 1/downscale (area averaging on premultiplied alpha, so edges do
// not pick up the colour of transparent pixels) with the camera scaled to match. The image is 8-bit
// RGB or RGBA (rounded after the resize).
TrainingView makeTrainingView(const cv::Mat& bgr_or_bgra, const Camera& camera, const SE3& T_world_cam,
                              double downscale = 1.0, const std::string& source = "image");
// Surface points from a depth image (CV_32FC1 z-depth in world units, the camera's size; 0 or
// non-finite: no depth): the pixels of a regular grid, as sparse as it takes to keep at most
// max_points, back-projected through the camera (its distortion included) to world positions, each
// of weight 1. What `nerfslam train` gives views whose transforms.json frame has a depth image.
// Throws an Error naming `source` when the size differs from the camera's.
std::vector<SurfacePoint> surfacePointsFromDepth(const cv::Mat& depth, const Camera& camera, const SE3& T_world_cam,
                                                 size_t max_points, const std::string& source = "depth");
// The view's image as float RGB composited over `background` (what a render is compared with).
cv::Mat compositeOver(const TrainingView& view, const float background[3]);

struct StageTimes {
  double march = 0, field_forward = 0, composite = 0, field_backward = 0, optimizer = 0, grid_update = 0;
  StageTimes& operator+=(const StageTimes& o) {
    march += o.march;
    field_forward += o.field_forward;
    composite += o.composite;
    field_backward += o.field_backward;
    optimizer += o.optimizer;
    grid_update += o.grid_update;
    return *this;
  }
};

struct StepStats {
  double loss = 0;             // mean Huber loss per ray (sum over channels)
  double depth_loss = 0;       // mean line-of-sight loss of the depth-supervised rays
  double distortion_loss = 0;  // mean distortion loss per ray (unweighted; 0 when distortion_weight is 0)
  int64_t depth_rays = 0;      // rays drawn through surface points
  int64_t rays = 0;
  int64_t samples = 0;             // marched samples (the field's density for each)
  int64_t samples_composited = 0;  // of those, before their ray's transmittance fell below 1e-4 (colour,
                                   // and backward where their loss gradient is not zero)
  bool rolled_back = false;
  StageTimes times;  // seconds of wall time for this step, per stage
};

// The share of a training's budget used after `steps` steps and `seconds`: the larger of
// steps / step_budget and seconds / second_budget over the budgets that are set (> 0), since the
// training stops at whichever it reaches first; 0 when neither is set.
double budgetProgress(int64_t steps, int64_t step_budget, double seconds, double second_budget);

class Trainer {
 public:
  Trainer(NerfModel& model, std::vector<TrainingView> views, const TrainOptions& options);
  ~Trainer();

  StepStats step();
  int64_t steps() const { return step_; }
  int64_t rollbacks() const { return rollbacks_; }
  double learningRate() const;
  // How much of its budget the training has used, in [0, 1] (clamped; see budgetProgress): from it,
  // learningRate() applies TrainOptions::lr_tail. Never called: no tail.
  void setBudgetProgress(double fraction);
  const StageTimes& totalTimes() const { return total_; }
  // Takes a snapshot now (the trainer also does every snapshot_interval steps).
  void snapshot();
  // Forces one occupancy-grid update now (with warm-up semantics when still in warm-up).
  void updateGrid();

  // Online training (the SLAM NeRF thread): views are added and re-posed between steps, from the
  // thread that calls step().
  // Validates and adds a view; returns its index.
  size_t addView(TrainingView view);
  size_t numViews() const { return views_.size(); }
  // Changes the number of training threads (e.g. more once tracking has finished). Deterministic
  // for a seed and the same sequence of thread counts.
  void setThreads(int n);
  // Changes TrainOptions::samples_per_step from the next step on (256 .. 2^22).
  void setSamplesPerStep(int n);
  const Camera& viewCamera(size_t i) const { return views_.at(i).camera; }
  const SE3& viewPose(size_t i) const { return views_.at(i).T_world_cam; }
  // View i as given (image rebuilt as 8-bit RGBA from the trainer's compact copy).
  TrainingView view(size_t i) const;
  // Throws nerfslam::Error for an unknown index or a non-finite pose.
  void setViewPose(size_t i, const SE3& T_world_cam);
  // Replaces view i's surface points (they move with bundle adjustment). Points that are not finite
  // or have a weight outside (0, 1] are dropped.
  void setViewPoints(size_t i, std::vector<SurfacePoint> points);
  size_t numViewPoints(size_t i) const { return views_.at(i).points.size(); }
  // The learned per-view appearance (identity for views with alpha and when TrainOptions::appearance
  // is off); setViewAppearance carries one over (e.g. across a box re-fit).
  const Appearance& viewAppearance(size_t i) const { return appearance_.at(i); }
  void setViewAppearance(size_t i, const Appearance& a);
  // appearanceNear (appearance.h) over the training views: for a frame rendered at `pose`.
  Appearance appearanceNear(const SE3& pose) const;
  // Pose refinement (TrainOptions::pose_refinement, pose_refine.h): viewPose(i) is the pose the view
  // was given (its anchor; setViewPose re-anchors it and keeps the correction), refinedViewPose(i)
  // the one its rays are drawn from. trainer_poses.cpp.
  SE3 refinedViewPose(size_t i) const;
  const PoseCorrection& viewPoseCorrection(size_t i) const { return pose_corr_.at(i); }
  void setViewPoseCorrection(size_t i, const PoseCorrection& c);
  struct PoseRefinementStats {
    int views = 0;               // views with surface points that project at both poses
    double median_shift_px = 0;  // over those views, of each view's median reprojection shift
    double max_shift_px = 0;     // of the same
    int64_t resets = 0;          // corrections reset as diverged (pose_max_*)
    int64_t steps = 0;           // steps that refined poses
  };
  // How far the refinement moved the views: their surface points' reprojections, anchor vs refined.
  PoseRefinementStats poseRefinementStats() const;
  // Relative probability of drawing each view's rays (one finite weight >= 0 per view, not all
  // zero); empty: uniform. Views added later get weight 1 until the next call.
  void setViewWeights(std::vector<double> weights);
  // Per view: the mean Huber loss per ray of the last step that drew rays from it (exponentially
  // smoothed over steps, factor 0.5), or -1 before any ray was drawn from it.
  const std::vector<double>& viewLoss() const { return view_loss_; }

 private:
  struct ThreadState;
  struct ImageData {
    std::vector<uint8_t> rgba;  // 8-bit RGBA, row-major
    int width, height;
    bool has_alpha;
  };
  struct StepPlan;
  struct RayPicker;
  void rollback();
  bool learnsAppearance(size_t view) const;
  bool refinesPosesThisStep() const;
  void preparePoses(bool refine);
  void stepPoses(const std::vector<double>& grad, const std::vector<int>& rays);
  void stepAppearance();
  std::vector<Eigen::Vector3f> surfacePointsNerf() const;
  std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>> freeSpaceSegments() const;
  static ImageData toImageData(const cv::Mat& image);
  void densityBatch(const float* xyz, int n, float* sigma);
  // The stages of step() (trainer.cpp).
  void trainThread(ThreadState& ts, const StepPlan& plan);
  int marchChunk(ThreadState& ts, const StepPlan& plan, RayPicker& pick, int total, int* attempts, bool* full);
  void forwardChunk(ThreadState& ts, int used);
  void compositeChunk(ThreadState& ts, const StepPlan& plan);
  float throughSurfacePoint(size_t view, std::mt19937_64& rng, int* px, int* py, float* ju, float* jv,
                            float* weight) const;
  double gatherThreads(StepStats* stats);
  bool applyGradients(int64_t rays, StepStats* stats);

  NerfModel& model_;
  std::vector<TrainingView> views_;
  std::vector<ImageData> images_;
  std::vector<DepthTriangles> triangles_;  // per view, over its surface points (depth_triangle_share)
  std::vector<double> view_weights_;       // empty: uniform
  std::vector<double> view_loss_;
  std::vector<Appearance> appearance_;
  AppearanceOptimizer appearance_opt_;
  std::vector<PoseCorrection> pose_corr_;
  PoseOptimizer pose_opt_;
  std::vector<SE3> step_poses_;       // the poses this step's rays are drawn from (refined)
  std::vector<float> level_weights_;  // BARF's window over the hash levels for this step
  int64_t pose_steps_ = 0, pose_resets_ = 0;
  std::vector<PoseCorrection> snap_pose_corr_;
  TrainOptions opt_;
  std::vector<std::unique_ptr<ThreadState>> threads_;
  int64_t step_ = 0;
  double budget_progress_ = 0;  // setBudgetProgress()
  int64_t rollbacks_ = 0;
  StageTimes total_;
  // Divergence snapshot.
  std::vector<std::vector<float>> snap_params_;
  std::vector<float> snap_grid_;
  std::vector<float> snap_background_;  // the learned background's logits
  float snap_threshold_ = 0;
  int64_t snap_step_ = -1;
};

// Runs fn(thread_index) on n threads (the calling thread runs index 0) and waits.
void parallelRun(int n, const std::function<void(int)>& fn);

}  // namespace nerfslam::nerf
