#include "nerfslam/system/run_outputs.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"
#include "nerfslam/core/statistics.h"
#include "nerfslam/eval/image_metrics.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/nerf/export.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/nerf/voxel_map.h"
#include "nerfslam/render/preview.h"
#include "nerfslam/render/trajectory_plot.h"
#include "nerfslam/system/flythrough.h"

namespace nerfslam {
namespace {

namespace fs = std::filesystem;

// Points of the NeRF cloud drawn in map_preview.png: where the render is opaque and its depth certain
// (standard deviation along the ray at most this fraction of the distance, or, for a model whose
// depth is still uncertain, the better half of the cloud).
constexpr float kSurfaceOpacity = 0.95f;
constexpr float kSurfaceUncertainty = 0.05f;

void writePng(const fs::path& path, const cv::Mat& bgr) { writeImageAtomic(path, bgr); }

double mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? 0.0 : s / double(v.size());
}

// n indices spread evenly over [0, size).
std::vector<size_t> spread(size_t size, int n) {
  std::vector<size_t> out;
  if (size == 0 || n <= 0) return out;
  const size_t k = std::min(size, size_t(n));
  for (size_t i = 0; i < k; ++i) out.push_back((2 * i + 1) * size / (2 * k));
  return out;
}

// depth.txt of a TUM-layout dataset (our synthetic sequences, TUM RGB-D): timestamp -> image.
// Absent or unreadable: empty (depth evaluation is skipped and the report says why).
std::map<double, fs::path> depthIndex(const Dataset& ds, std::string* why) {
  std::map<double, fs::path> idx;
  if (ds.kind() != "tum") {
    *why = "the dataset has no depth ground truth";
    return idx;
  }
  const fs::path file = ds.root() / "depth.txt";
  InputFile f;
  try {
    f = openInputFile(file);
  } catch (const Error& e) {
    *why = e.what();
    return idx;
  }
  std::istream& in = f.stream;
  std::string line;
  int lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    double t;
    std::string rel;
    if (!(ls >> t >> rel) || !std::isfinite(t)) {
      *why = fmt::format("{}:{}: expected \"timestamp path\"", file.string(), lineno);
      return {};
    }
    idx[t] = ds.root() / rel;
  }
  return idx;
}

std::optional<fs::path> nearestDepth(const std::map<double, fs::path>& idx, double t) {
  if (idx.empty()) return std::nullopt;
  auto it = idx.lower_bound(t);
  std::optional<std::pair<double, fs::path>> best;
  for (auto cand : {it, it == idx.begin() ? idx.end() : std::prev(it)}) {
    if (cand == idx.end()) continue;
    if (!best || std::abs(cand->first - t) < std::abs(best->first - t)) best = *cand;
  }
  if (!best || std::abs(best->first - t) > 0.02) return std::nullopt;
  return best->second;
}

// The image as the NeRF saw its keyframes: BGR, downscaled to the training camera.
cv::Mat toTrainingSize(const cv::Mat& image, const Camera& train) {
  cv::Mat bgr = image;
  if (bgr.channels() == 1) cv::cvtColor(bgr, bgr, cv::COLOR_GRAY2BGR);
  if (bgr.channels() == 4) cv::cvtColor(bgr, bgr, cv::COLOR_BGRA2BGR);
  if (bgr.cols != train.width || bgr.rows != train.height)
    cv::resize(bgr, bgr, cv::Size(train.width, train.height), 0, 0, cv::INTER_AREA);
  return bgr;
}

struct ViewEval {
  double psnr = 0, ssim = 0;
  double depth_vs_points = -1;  // median |NeRF depth - point depth| / point depth (-1: no point in view)
  cv::Mat side_by_side;         // render | real
  cv::Mat depth;                // NeRF z-depth (map units)
};

// The render at `pose` with the appearance `app` (appearance.h: a held-out frame gets its nearest
// training view's), scored against the real image, and its depth against the map points `points`
// (those of the nearest training view) that project into it.
ViewEval evaluateView(const nerf::NerfModel& model, const Camera& cam, const SE3& pose, const nerf::Appearance& app,
                      const std::vector<nerf::SurfacePoint>& points, const cv::Mat& real_bgr, int threads) {
  nerf::RenderOptions ro;
  ro.threads = threads;
  ro.normals = false;
  ro.background = {0.0, 0.0, 0.0};
  const nerf::RenderResult r = nerf::renderView(model, cam, pose, ro);
  cv::Mat rgb_real, f_real;
  cv::cvtColor(real_bgr, rgb_real, cv::COLOR_BGR2RGB);
  rgb_real.convertTo(f_real, CV_32F, 1.0 / 255.0);
  const cv::Mat pred = cv::min(cv::max(app.apply(r.rgb), 0.0), 1.0);
  ViewEval e;
  e.psnr = psnr(pred, f_real, 1.0);
  e.ssim = ssim(pred, f_real, 1.0);
  cv::hconcat(nerf::toBgr8(pred), real_bgr, e.side_by_side);
  e.depth = r.depth;
  std::vector<double> rel;
  const SE3 T_cam_world = pose.inverse();
  for (const nerf::SurfacePoint& p : points) {
    const Eigen::Vector3d pc = T_cam_world * p.position.cast<double>();
    Eigen::Vector2d uv;
    if (!cam.projectInImage(pc, &uv)) continue;
    const float d = r.depth.at<float>(int(uv.y()), int(uv.x()));
    if (d > 0) rel.push_back(std::abs(d - pc.z()) / pc.z());
  }
  if (!rel.empty()) e.depth_vs_points = median(rel);
  return e;
}

// Up direction of the content: cameras are usually held upright, so the mean of their -y axes.
Eigen::Vector3d upFromCameras(const std::vector<SE3>& poses) {
  Eigen::Vector3d up = Eigen::Vector3d::Zero();
  for (const auto& T : poses) up -= T.rotation().toRotationMatrix().col(1);
  if (up.norm() < 1e-9) return Eigen::Vector3d::UnitZ();
  return up.normalized();
}

std::vector<SE3> posesOf(const Trajectory& traj) {
  std::vector<SE3> poses;
  for (const auto& e : traj) poses.push_back(e.pose);
  return poses;
}

// map_preview.png: with a NeRF, its surface (`dense`) and the trajectory from a viewpoint that shows
// the scene (overviewViewpoint); without, the sparse points, keyframes and trajectory from
// the automatic view. Empty when there is nothing to draw.
cv::Mat mapPreview(const SlamSystem& slam, const Trajectory& traj, const PreviewCloud& dense) {
  PreviewScene scene;
  PreviewOptions po;
  const std::vector<SE3> poses = posesOf(traj);
  po.up = upFromCameras(poses);
  if (!poses.empty()) scene.trajectories.push_back({poses, {0, 0, 255}, "estimated trajectory"});
  if (!dense.points.empty() && !poses.empty()) {
    scene.clouds.push_back(dense);
    const Overview ov = overviewViewpoint(dense.points, poses, po);
    po.eye = ov.eye;
    po.target = ov.target;
    po.up = ov.up;
    po.max_height = ov.max_height;
    po.line_width = 3;
    po.point_size = 3;
    cv::Mat img = renderPreview(scene, po);
    const std::string caption = dense.label + (ov.max_height ? ", cut away above the cameras" : "");
    cv::putText(img, caption, {12, img.rows - 14}, cv::FONT_HERSHEY_SIMPLEX, 0.55, cv::Scalar(235, 235, 235), 1,
                cv::LINE_AA);
    return img;
  }
  PreviewCloud sparse;
  sparse.label = "sparse map";
  for (const auto& p : slam.map().points()) sparse.points.push_back(p.position.cast<float>());
  if (!sparse.points.empty()) scene.clouds.push_back(std::move(sparse));
  for (const auto& kf : slam.map().keyframes()) scene.keyframes.push_back(kf.T_world_cam);
  if (scene.clouds.empty() && scene.trajectories.empty()) return {};
  return renderPreview(scene, po);
}

// The poses as tracked, before the loop closer corrected the map (FrameRecord::T_world_cam), with
// their own Sim(3) alignment to the ground truth: when a loop was closed and there is ground truth.
struct AsTracked {
  Trajectory trajectory;
  TrajectoryReport eval;
};
std::optional<AsTracked> asTrackedEval(const SlamSystem& slam, const Trajectory& gt) {
  if (gt.empty() || !slam.loopClosing() || slam.loopClosing()->closures().empty()) return std::nullopt;
  AsTracked a;
  for (const FrameRecord& r : slam.records())
    if (r.tracked) a.trajectory.push_back({r.timestamp, r.T_world_cam});
  if (a.trajectory.size() < 3) return std::nullopt;
  TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-3;
  a.eval = evaluateTrajectory(gt, a.trajectory, eo);
  return a;
}

// trajectory.png: a top view with axes; with ground truth the Sim(3)-aligned estimate on it in metres
// and the ATE in the title (and, after a loop closure, the poses as tracked before the corrections,
// aligned on their own), otherwise the estimate alone in map units.
TrajectoryPlot trajectoryPlot(const Trajectory& traj, const Trajectory& gt, const std::optional<Sim3>& align,
                              const nlohmann::json& rep, const std::optional<AsTracked>& as_tracked) {
  auto positions = [](const Trajectory& t, const Sim3& s) {
    std::vector<Eigen::Vector3d> p;
    for (const auto& e : t) p.push_back(s * e.pose.translation());
    return p;
  };
  const cv::Vec3b est_color{180, 119, 31};
  TrajectoryPlotOptions o;
  std::vector<PlotSeries> series;
  if (!gt.empty() && align) {
    o.up = upFromCameras(posesOf(gt));
    series.push_back({positions(gt, Sim3()), {150, 150, 150}, "ground truth"});
    if (as_tracked)
      series.push_back(
          {positions(as_tracked->trajectory, as_tracked->eval.alignment),
           {60, 60, 220},
           fmt::format("as tracked, before the loop corrections (ATE {:.3g} %)", as_tracked->eval.ape_rmse_percent)});
    series.push_back({positions(traj, *align), est_color, "estimate"});
    o.title = rep.contains("ate_rmse_m")
                  ? fmt::format("ATE RMSE {:.3g} m = {:.3g} % of the {:.3g} m path ({} frames, Sim(3)-aligned)",
                                rep["ate_rmse_m"].get<double>(), rep.value("ate_percent_of_path", 0.0),
                                rep.value("path_length_m", 0.0), rep.value("ate_matched", 0))
                  : "estimate against ground truth";
  } else {
    series.push_back({positions(traj, Sim3()), est_color, "estimate"});
    o.up = upFromCameras(posesOf(traj));
    o.unit = "map units";
    o.title = "estimated trajectory (no ground truth: map units, the scale is unknown)";
  }
  return plotTrajectories(series, o);
}

// The NeRF thread's figures in report.json.
void reportNerfStats(const NerfMappingStats& st, nlohmann::json& rep) {
  rep["nerf_steps"] = st.steps;
  rep["nerf_samples"] = st.samples;
  rep["nerf_samples_composited"] = st.samples_composited;
  rep["nerf_rays"] = st.rays;
  rep["nerf_depth_rays"] = st.depth_rays;
  rep["nerf_train_seconds"] = st.train_seconds;
  rep["nerf_samples_per_second"] = st.train_seconds > 0 ? double(st.samples) / st.train_seconds : 0.0;
  rep["nerf_rollbacks"] = st.rollbacks;
  rep["nerf_learning_rate_last"] = st.learning_rate;
  rep["nerf_psnr_heldout_running"] = st.psnr_heldout;
  nlohmann::json curve = nlohmann::json::array();
  for (const auto& p : st.psnr_history)
    curve.push_back(
        {{"seconds", p.seconds}, {"steps", p.steps}, {"psnr_recent", p.psnr_recent}, {"psnr_heldout", p.psnr_heldout}});
  rep["nerf_psnr_over_time"] = curve;
  rep["nerf_time_s"] = {{"march", st.times.march},         {"field_forward", st.times.field_forward},
                        {"composite", st.times.composite}, {"field_backward", st.times.field_backward},
                        {"optimizer", st.times.optimizer}, {"grid_update", st.times.grid_update},
                        {"refresh", st.refresh_seconds},   {"refit", st.refit_seconds}};
  rep["nerf_refits"] = st.refits;
  rep["nerf_views"] = st.views;
  rep["nerf_keyframes_dropped"] = st.keyframes_dropped;
  rep["nerf_keyframes_recovered"] = st.keyframes_recovered;
  rep["nerf_keyframes_skipped"] = st.keyframes_skipped;
  rep["nerf_keyframes_held_out"] = st.keyframes_held_out;
  if (st.pose_refinement.steps > 0)
    rep["nerf_pose_refinement"] = {{"steps", st.pose_refinement.steps},
                                   {"resets", st.pose_refinement.resets},
                                   {"views_measured", st.pose_refinement.views},
                                   {"median_shift_px", st.pose_refinement.median_shift_px},
                                   {"max_shift_px", st.pose_refinement.max_shift_px}};
}

// Median |s * depth - gt| / gt of a render against the dataset's depth image nearest `timestamp`
// (s: the ground-truth alignment's scale); none without a depth image or valid pixels.
std::optional<double> depthErrorAgainstGroundTruth(const std::map<double, fs::path>& depth_idx, double timestamp,
                                                   const cv::Mat& depth, const Camera& cam, double s) {
  const auto dp = nearestDepth(depth_idx, timestamp);
  if (!dp) return std::nullopt;
  cv::Mat gt16 = readImage(*dp, ImageMode::kUnchanged);
  if (gt16.type() != CV_16UC1) throw fieldError(dp->string(), "image", "depth must be 16-bit single channel");
  cv::Mat gt;
  gt16.convertTo(gt, CV_32F, 1.0 / 5000.0);
  cv::resize(gt, gt, cv::Size(cam.width, cam.height), 0, 0, cv::INTER_NEAREST);
  return depthMedianAbsRel(depth, gt, s);
}

// nerf_cloud.ply/.pcd from depth renders of cloud_views training views, mesh.ply, and the surface
// drawn in map_preview.png (`dense`: opaque points whose depth is certain).
void writeCloudAndMesh(nerf::NerfModel& model, const Camera& cam, const std::vector<SE3>& view_poses,
                       const NerfEvalOptions& eo, const fs::path& out, nlohmann::json& rep, PreviewCloud* dense) {
  nerf::ExportOptions xo;
  xo.threads = eo.threads;
  std::vector<nerf::PosedCamera> views;
  for (size_t k : spread(view_poses.size(), eo.cloud_views)) views.push_back({cam, view_poses[k]});
  std::vector<nerf::DepthPointQuality> quality;
  const auto cloud = nerf::depthPointCloud(model, views, xo, &quality);
  // A field with nothing opaque yet (a NeRF that had almost no time) is a result, not a failure of
  // the outputs: no cloud or mesh file, and the report says why.
  const std::string too_little =
      fmt::format("nothing above the density threshold after {} steps", model.training_steps);
  rep["nerf_cloud_points"] = cloud.size();
  if (cloud.empty()) {
    rep["nerf_cloud_note"] = "not written: " + too_little;
    spdlog::warn("NeRF cloud not written: {}", too_little);
  } else {
    nerf::savePointCloud(cloud, out / "nerf_cloud.ply");
    addRunOutput(rep, "nerf_cloud.ply");
    nerf::savePointCloud(cloud, out / "nerf_cloud.pcd");
    addRunOutput(rep, "nerf_cloud.pcd");
  }
  if (dense) {  // the surface: opaque, with a certain depth
    dense->label = fmt::format("NeRF surface: depth renders of {} training views", views.size());
    std::vector<double> uncertainty;
    for (const auto& q : quality) uncertainty.push_back(q.relative_uncertainty);
    const double max_uncertainty = std::max<double>(kSurfaceUncertainty, median(uncertainty));
    for (size_t i = 0; i < cloud.size(); ++i) {
      if (quality[i].opacity < kSurfaceOpacity || quality[i].relative_uncertainty > max_uncertainty) continue;
      const auto& p = cloud.points[i];
      dense->points.emplace_back(p.x, p.y, p.z);
      dense->colors.emplace_back(p.b, p.g, p.r);
    }
  }
  xo.max_triangles = eo.mesh_max_triangles;
  nerf::MeshStats ms;
  const auto mesh = nerf::extractMesh(model, xo, &ms);
  rep["mesh_triangles"] = mesh.polygons.size();
  if (mesh.polygons.empty()) {
    rep["mesh_note"] = "not written: " + too_little;
    spdlog::warn("NeRF mesh not written: {}", too_little);
  } else {
    nerf::saveMesh(mesh, out / "mesh.ply");
    addRunOutput(rep, "mesh.ply");
  }
  rep["mesh_density_threshold"] = ms.density_threshold;
  rep["mesh_triangles_at_default_threshold"] = ms.triangles_at_requested_threshold;
}

// occupancy.bt/.ot (+ .meta.yaml) and map.yaml/map.pgm (+ map.meta.yaml), in the map frame, from the NeRF
// and its training views' rays. Metric (the ground truth's scale) when the run has ground truth. An
// error is reported, not fatal.
void writeOccupancyOutputs(const nerf::NerfModel& model, const Camera& cam, const std::vector<SE3>& view_poses,
                           const std::optional<Sim3>& gt_alignment, const OccupancyOutputOptions& oo, int threads,
                           const fs::path& out, nlohmann::json& rep) {
  if (!oo.enabled) return;
  try {
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<nerf::PosedCamera> views;
    for (const auto& p : view_poses) views.push_back({cam, p});
    const nerf::DensitySource src = nerf::fieldDensitySource(model);
    const double metres_per_unit = gt_alignment ? gt_alignment->scale() : 0.0;
    nerf::VoxelMapOptions vo;
    vo.threads = threads;
    vo.pixel_stride = oo.pixel_stride;
    if (metres_per_unit > 0) {
      vo.resolution = oo.resolution / metres_per_unit;
    } else {
      const auto b = nerf::voxelMapBounds(src, views, 0.0);
      vo.resolution = oo.relative_resolution * b.diagonal().norm();
    }
    // A street mapped at a room's resolution would need gigabytes: coarsen (x2 at a time) until it
    // fits in vo.max_memory_mb, and say so.
    const double requested = vo.resolution;
    Eigen::AlignedBox3d observed;  // stays empty when no resolution fits: buildVoxelMap then says why
    vo.resolution = nerf::fittingResolution(src, views, vo, 8, &observed);
    if (vo.resolution != requested)
      spdlog::warn("occupancy map: {} units per voxel would exceed {} MB for this map; written at {} ({}x coarser)",
                   requested, vo.max_memory_mb, vo.resolution, vo.resolution / requested);
    const nerf::VoxelMap map =
        observed.isEmpty() ? nerf::buildVoxelMap(src, views, vo) : nerf::buildVoxelMap(src, views, vo, observed);
    nerf::writeOctomapFiles(map, out / "occupancy.bt", metres_per_unit, "nerf/model.nerf");
    addRunOutput(rep, "occupancy.bt");
    nerf::saveOctomap(map, out / "occupancy.ot");
    addRunOutput(rep, "occupancy.ot");
    addRunOutput(rep, "occupancy.meta.yaml");
    rep["occupancy"] = {{"resolution", map.resolution},
                        {"resolution_requested", requested},
                        {"metres_per_unit", metres_per_unit > 0 ? nlohmann::json(metres_per_unit) : nlohmann::json()},
                        {"occupied", map.count(nerf::VoxelMap::kOccupied)},
                        {"free", map.count(nerf::VoxelMap::kFree)},
                        {"unknown", map.count(nerf::VoxelMap::kUnknown)}};
    const nerf::FloorPlane floor = nerf::detectFloor(map, views);
    double lo = 0, hi = 0;
    if (metres_per_unit > 0) {
      lo = oo.band_lo / metres_per_unit;
      hi = oo.band_hi / metres_per_unit;
    } else {
      std::vector<double> h;
      for (const auto& v : views) h.push_back(floor.height(v.T_world_cam.translation()));
      const double cam_h = median(h);
      if (!(cam_h > 0)) fail("the cameras are not above the floor found (median height {})", cam_h);
      lo = oo.relative_band_lo * cam_h;
      hi = oo.relative_band_hi * cam_h;
    }
    const nerf::GridProjection g =
        nerf::writeGridFiles(map, views, &floor, lo, hi, out / "map.yaml", metres_per_unit, "nerf/model.nerf");
    addRunOutput(rep, "map.yaml");
    addRunOutput(rep, "map.pgm");
    addRunOutput(rep, "map.meta.yaml");
    size_t occ = 0, fr = 0;
    for (int8_t c : g.grid.cells) {
      occ += c == NavGrid::kOccupied;
      fr += c == NavGrid::kFree;
    }
    rep["occupancy"]["grid"] = {{"width", g.grid.width},
                                {"height", g.grid.height},
                                {"occupied", occ},
                                {"free", fr},
                                {"band", {lo, hi}},
                                {"floor_support", floor.support},
                                {"floor_found_by", floor.method}};
    rep["occupancy"]["seconds"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  } catch (const std::exception& e) {
    rep["occupancy_error"] = e.what();
    spdlog::error("occupancy map: {}", e.what());
  }
}

// nerf/flythrough.mp4 and its entry in report.json (an error there is reported, not fatal).
void writeFlythroughOutput(NerfMapping& nerf, const Camera& cam, const Trajectory& traj, const NerfEvalOptions& eo,
                           const fs::path& out, nlohmann::json& rep) {
  try {
    nerf.withModel([&](nerf::NerfModel& model) {
      FlythroughOptions fo;
      fo.frames = eo.flythrough_frames;
      fo.max_seconds = eo.flythrough_seconds;
      fo.threads = eo.threads;
      const FlythroughResult f = writeFlythrough(model, cam, traj, fo, out / "nerf");
      rep["nerf_flythrough"] = {{"path", fs::relative(f.path, out).string()},
                                {"codec", f.codec},
                                {"frames", f.frames},
                                {"frames_requested", f.frames_requested},
                                {"width", f.size.width},
                                {"height", f.size.height},
                                {"fps", f.fps},
                                {"seconds", f.seconds}};
      addRunOutput(rep, fs::relative(f.path, out).string() + (f.codec == "png" ? "/" : ""));
    });
  } catch (const std::exception& e) {
    rep["nerf_flythrough_error"] = e.what();
    spdlog::error("NeRF fly-through: {}", e.what());
  }
}

}  // namespace

void writeNerfOutputs(SlamSystem& slam, const Dataset& ds, const Trajectory& traj,
                      const std::optional<Sim3>& gt_alignment, const fs::path& out, const NerfEvalOptions& eo,
                      nlohmann::json& rep, PreviewCloud* dense) {
  NerfMapping* nerf = slam.nerf();
  if (!nerf) return;
  reportNerfStats(nerf->stats(), rep);
  if (!nerf->hasModel()) {
    rep["nerf_error"] = "no NeRF model: the map never initialised";
    return;
  }
  if (eo.model_only) {
    ensureDirectory(out / "nerf");
    nerf->withModel([&](nerf::NerfModel& model) { nerf::saveModel(model, out / "nerf" / "model.nerf"); });
    addRunOutput(rep, "nerf/model.nerf");
    return;
  }
  const Camera cam = nerf->trainingCamera();
  const std::vector<KeyframeId> view_kfs = nerf->viewKeyframes();

  // Frames: tracked poses by timestamp; keyframes by frame index.
  std::map<double, SE3> pose_at;
  for (const auto& e : traj) pose_at[e.timestamp] = e.pose;
  // Held out: tracked frames whose image the NeRF never trained on (not keyframes, or keyframes it
  // skipped as too close to an existing view), spread over the whole sequence.
  const auto view_frames = nerf->viewFrameIds();
  const std::set<uint64_t> trained(view_frames.begin(), view_frames.end());
  std::vector<const FrameRecord*> heldout;
  for (const auto& r : slam.records())
    if (r.tracked && !trained.count(r.index) && pose_at.count(r.timestamp)) heldout.push_back(&r);
  std::string depth_why;
  const auto depth_idx = depthIndex(ds, &depth_why);
  if (!gt_alignment) depth_why = "no Sim(3) alignment to ground truth";

  std::vector<double> psnr_held, ssim_held, psnr_kf, depth_rel, depth_pts;
  nlohmann::json held_list = nlohmann::json::array();
  ensureDirectory(out / "nerf" / "heldout");
  ensureDirectory(out / "nerf" / "keyframes");
  // Taken before the model lock (these lock it themselves).
  std::vector<nerf::TrainingView> kf_views;
  std::vector<KeyframeId> kf_ids;
  for (size_t k : spread(view_kfs.size(), eo.keyframe_frames)) {
    kf_views.push_back(nerf->trainingView(k));
    kf_ids.push_back(view_kfs[k]);
  }
  const std::vector<SE3> view_poses = nerf->viewPoses();
  const std::vector<nerf::Appearance> view_app = nerf->viewAppearances();
  const auto appearanceNear = [&](const SE3& pose) { return nerf::appearanceNear(view_poses, view_app, pose); };
  // The map points of the held-out frames' nearest training views (taken before the model lock).
  std::vector<std::vector<nerf::SurfacePoint>> held_points;
  const std::vector<size_t> held_pick = spread(heldout.size(), eo.heldout_frames);
  for (size_t k : held_pick)
    held_points.push_back(
        view_poses.empty() ? std::vector<nerf::SurfacePoint>{}
                           : nerf->trainingView(nerf::nearestView(view_poses, pose_at[heldout[k]->timestamp])).points);
  nerf->withModel([&](nerf::NerfModel& model) {
    for (size_t h = 0; h < held_pick.size(); ++h) {
      const FrameRecord& r = *heldout[held_pick[h]];
      const SE3 pose = pose_at[r.timestamp];
      const DatasetFrame f = ds.load(r.index, ImageMode::kColor);
      const cv::Mat real = toTrainingSize(f.image, cam);
      const ViewEval e = evaluateView(model, cam, pose, appearanceNear(pose), held_points[h], real, eo.threads);
      psnr_held.push_back(e.psnr);
      ssim_held.push_back(e.ssim);
      if (e.depth_vs_points >= 0) depth_pts.push_back(e.depth_vs_points);
      writePng(out / "nerf" / "heldout" / fmt::format("{:06d}.png", r.index), e.side_by_side);
      nlohmann::json j{{"frame", r.index}, {"psnr", e.psnr}, {"ssim", e.ssim}};
      if (gt_alignment && !depth_idx.empty()) {
        if (const auto m = depthErrorAgainstGroundTruth(depth_idx, r.timestamp, e.depth, cam, gt_alignment->scale())) {
          depth_rel.push_back(*m);
          j["depth_median_abs_rel"] = *m;
        }
      }
      held_list.push_back(j);
    }
    if (!held_pick.empty()) addRunOutput(rep, "nerf/heldout/");
    // Training views (keyframes the NeRF trained on; their keyframes may since have been culled).
    for (size_t j = 0; j < kf_views.size(); ++j) {
      const nerf::TrainingView& v = kf_views[j];
      cv::Mat bgr;
      cv::cvtColor(v.image, bgr, cv::COLOR_RGBA2BGR);
      const ViewEval e =
          evaluateView(model, cam, v.T_world_cam, appearanceNear(v.T_world_cam), v.points, bgr, eo.threads);
      psnr_kf.push_back(e.psnr);
      writePng(out / "nerf" / "keyframes" / fmt::format("{:06d}.png", kf_ids[j]), e.side_by_side);
    }
    if (!kf_views.empty()) addRunOutput(rep, "nerf/keyframes/");
    nerf::saveModel(model, out / "nerf" / "model.nerf");
    addRunOutput(rep, "nerf/model.nerf");
    writeCloudAndMesh(model, cam, view_poses, eo, out, rep, dense);
    writeOccupancyOutputs(model, cam, view_poses, gt_alignment, eo.occupancy, eo.threads, out, rep);
  });
  rep["nerf_psnr_heldout"] = mean(psnr_held);
  rep["nerf_psnr_heldout_frames"] = psnr_held.size();
  rep["nerf_ssim_heldout"] = mean(ssim_held);
  if (!depth_pts.empty()) rep["nerf_depth_vs_points_heldout"] = median(depth_pts);
  rep["nerf_psnr_keyframes"] = mean(psnr_kf);
  rep["nerf_heldout"] = held_list;
  if (!depth_rel.empty())
    rep["nerf_depth_median_abs_rel"] = median(depth_rel);
  else
    rep["nerf_depth_note"] = depth_why.empty() ? "no depth ground truth for the held-out frames" : depth_why;
  if (eo.flythrough_frames > 0 && !traj.empty()) writeFlythroughOutput(*nerf, cam, traj, eo, out, rep);
}

void addRunOutput(nlohmann::json& report, const std::string& name) {
  if (!report.contains("outputs")) report["outputs"] = nlohmann::json::array();
  report["outputs"].push_back(name);
}

void writeRunPreviews(const SlamSystem& slam, const Trajectory& traj, const Trajectory& gt,
                      const std::optional<Sim3>& align, const PreviewCloud& dense, nlohmann::json& rep,
                      const fs::path& out) {
  try {
    const cv::Mat preview = mapPreview(slam, traj, dense);
    if (!preview.empty()) {
      writePng(out / "map_preview.png", preview);
      addRunOutput(rep, "map_preview.png");
    }
  } catch (const std::exception& e) {
    // The map preview needs OSMesa; a machine without it still gets every other output.
    spdlog::warn("map_preview.png not written: {}", e.what());
  }
  if (traj.size() < 2) return;
  try {
    const std::optional<AsTracked> as_tracked = align ? asTrackedEval(slam, gt) : std::nullopt;
    if (as_tracked) rep["ate_percent_of_path_as_tracked"] = as_tracked->eval.ape_rmse_percent;
    writePng(out / "trajectory.png", trajectoryPlot(traj, gt, align, rep, as_tracked).image);
    addRunOutput(rep, "trajectory.png");
  } catch (const std::exception& e) {
    spdlog::warn("trajectory.png not written: {}", e.what());
  }
}

}  // namespace nerfslam
