#pragma once
// What `nerfslam run` writes beside the sparse results once the NeRF map is trained, and the
// pictures a user looks at first:
//   nerf/model.nerf            the NeRF model (nerf/model_io.h), in the SLAM map's frame and scale
//   nerf_cloud.ply, .pcd       dense coloured cloud: back-projected NeRF depth renders of keyframes
//   mesh.ply                   marching-tetrahedra isosurface of the NeRF density
//   nerf/heldout/<frame>.png   NeRF render | real image, for tracked frames the NeRF did not train on
//   nerf/keyframes/<id>.png    the same for a few keyframes (training views)
//   nerf/flythrough.mp4        renders along the estimated trajectory (or nerf/flythrough/NNNNNN.png)
//   map_preview.png            the NeRF's surface and the trajectory (no NeRF: the sparse map)
//   trajectory.png             top view with axes: the estimate, Sim(3)-aligned on the ground truth if any
// and the report fields nerf_* (see README). Every file is written atomically, each write checked, and
// listed in the report's "outputs" once written (addRunOutput).
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

// Renders the held-out frames and keyframes, measures PSNR (and, with `gt_alignment` and depth
// ground truth from the dataset, the NeRF depth error), writes the model, clouds, mesh and
// renders and the fly-through (nerf_flythrough, or nerf_flythrough_error), and adds the nerf_* fields
// to `report`. `trajectory` is the final estimate (SlamSystem::trajectory()). `dense`, when given,
// receives the NeRF's surface for the preview: the cloud's points where the render is opaque and its
// depth certain.
void writeNerfOutputs(SlamSystem& slam, const Dataset& dataset, const Trajectory& trajectory,
                      const std::optional<Sim3>& gt_alignment, const std::filesystem::path& out,
                      const NerfEvalOptions& options, nlohmann::json& report, PreviewCloud* dense = nullptr);

// Appends `name` (relative to the run's folder; a folder ends in '/') to report["outputs"]: what the
// run wrote, in the order written. An output that was not written (a full disk, a NeRF that never
// initialised, a signal that skipped it) is not listed, even where an older run left a file of that
// name.
void addRunOutput(nlohmann::json& report, const std::string& name);

// map_preview.png: the NeRF surface `dense` (when not empty) and the trajectory from a viewpoint that
// shows the scene, else the sparse points, keyframes and trajectory; and trajectory.png, a top view
// with axes: with `ground_truth` and `gt_alignment` the aligned estimate on it in metres, titled with
// the report's ate_rmse_m, ate_percent_of_path and path_length_m, else the estimate in map units.
// After a loop closure (with ground truth) the plot also shows the poses as tracked, before the
// corrections (aligned on their own), and the report gets ate_percent_of_path_as_tracked.
void writeRunPreviews(const SlamSystem& slam, const Trajectory& trajectory, const Trajectory& ground_truth,
                      const std::optional<Sim3>& gt_alignment, const PreviewCloud& dense, nlohmann::json& report,
                      const std::filesystem::path& out);

}  // namespace nerfslam
