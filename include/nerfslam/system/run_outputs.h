#pragma once
// What `nerfslam run` writes beside the sparse results once the NeRF map is trained, and the
// pictures a user looks at first:
//   nerf/model.nerf            the NeRF model (nerf/model_io.h), in the SLAM map's frame and scale
//   nerf_cloud.ply, .pcd       dense coloured cloud: back-projected NeRF depth renders of keyframes
//   mesh.ply                   marching-tetrahedra isosurface of the NeRF density
//   nerf/heldout/<frame>.png   NeRF render | real image, for tracked frames the NeRF did not train on
//   nerf/keyframes/<id>.png    the same for a few keyframes (training views)
//   map_preview.png            sparse points, NeRF cloud, keyframe frustums and the trajectory
//   trajectory.png             the estimate (Sim(3)-aligned) against ground truth, when present
// and the report fields nerf_* (see README). Every file is written atomically.
#include <filesystem>
#include <optional>
#include <vector>

#include <nlohmann/json.hpp>

#include "nerfslam/core/pose.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/preview.h"
#include "nerfslam/system/slam_system.h"

namespace nerfslam {

struct NerfEvalOptions {
  int heldout_frames = 8;   // tracked frames the NeRF did not train on, rendered and compared (evenly spread)
  int keyframe_frames = 4;  // training views rendered and compared
  int cloud_views = 8;      // training views back-projected into nerf_cloud
  int threads = 2;
  // Write nerf/model.nerf and the training statistics only: no renders, cloud or mesh (a run
  // stopped a second time, core/stop_signal.h).
  bool model_only = false;
};

// Renders the held-out frames and keyframes, measures PSNR (and, with `gt_alignment` and depth
// ground truth from the dataset, the NeRF depth error), writes the model, clouds, mesh and
// renders, and adds the nerf_* fields to `report`. `trajectory` is the final estimate
// (SlamSystem::trajectory()). `dense`, when given, receives the NeRF cloud for the preview.
void writeNerfOutputs(SlamSystem& slam, const Dataset& dataset, const Trajectory& trajectory,
                      const std::optional<Sim3>& gt_alignment, const std::filesystem::path& out,
                      const NerfEvalOptions& options, nlohmann::json& report, render::PreviewCloud* dense = nullptr);

// map_preview.png (sparse points, `dense` when not empty, keyframes, trajectory) and trajectory.png
// when `ground_truth` is not empty (the estimate mapped onto it by `gt_alignment`).
void writeRunPreviews(const SlamSystem& slam, const Trajectory& trajectory, const Trajectory& ground_truth,
                      const std::optional<Sim3>& gt_alignment, const render::PreviewCloud& dense,
                      const std::filesystem::path& out);

}  // namespace nerfslam
