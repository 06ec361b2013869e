#include "nerfslam_ros/nerf_publisher.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <type_traits>
#include <vector>

#include <cv_bridge/cv_bridge.h>
#include <fmt/format.h>
#include <nav_msgs/OccupancyGrid.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/thread.h"
#include "nerfslam/nerf/export.h"
#include "nerfslam/nerf/field.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/nerf_options.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/nerf/voxel_map.h"
#include "nerfslam/system/map_store.h"
#include "nerfslam_ros/conversions.h"

namespace nerfslam::rosnode {

std::filesystem::path resolveMapDir(const std::string& dir) {
  std::error_code ec;
  const std::filesystem::path abs = std::filesystem::absolute(dir, ec);
  return ec ? std::filesystem::path(dir) : abs.lexically_normal();
}

double wallSeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// A copy of the NeRF model that the publisher thread renders, exports and saves from, so that NeRF
// training pauses only while the copy is taken (a memcpy of the parameters and the occupancy grid,
// under NerfMapping::withModel), not for a whole render. Costs one model's memory (the size of a
// saved model: ~70 MB with the default 2^19-entry hash tables); the buffers are reused.
class NerfPublisher::ModelCopy {
 public:
  // Copies the model; false when there is none yet. Returns the wait for the lock and the copy time.
  bool update(const NerfMapping& nerf, double* wait_ms, double* copy_ms) {
    const double t0 = wallSeconds();
    double t1 = t0;
    const bool ok = nerf.withModel([&](nerf::NerfModel& src) {
      t1 = wallSeconds();
      copyFrom(src);
    });
    if (!ok) return false;
    model_.field->parametersChanged();  // derived copies of the weights, outside the lock
    if (wait_ms) *wait_ms = 1e3 * (t1 - t0);
    if (copy_ms) *copy_ms = 1e3 * (wallSeconds() - t1);
    return true;
  }
  nerf::NerfModel& model() { return model_; }

 private:
  // The field's structure, from its configuration's scalar options.
  struct KeyVisitor {
    std::string key;
    template <class T, class... Rest>
    void operator()(const char* name, T& value, Rest&&...) {
      if constexpr (std::is_arithmetic_v<T>) key += std::string(name) + "=" + std::to_string(value) + ";";
    }
  };
  static std::string configKey(nerf::FieldConfig config) {
    KeyVisitor v;
    config.visit(v);
    return v.key;
  }
  void copyFrom(nerf::NerfModel& src) {
    const std::string key = configKey(src.field->config());
    auto src_params = src.field->parameters();
    bool same = model_.field && key == key_;
    std::vector<nerf::FloatArray> dst_params;
    if (same) {
      dst_params = model_.field->parameters();
      same = dst_params.size() == src_params.size();
      for (size_t i = 0; same && i < src_params.size(); ++i)
        same = dst_params[i].name == src_params[i].name && dst_params[i].size == src_params[i].size;
    }
    if (!same) {  // first copy, or another field structure (rare: allocated under the lock)
      model_.field = std::make_unique<nerf::RadianceField>(src.field->config(), 0);
      key_ = key;
      dst_params = model_.field->parameters();
    }
    for (size_t i = 0; i < src_params.size(); ++i)
      std::memcpy(dst_params[i].data, src_params[i].data, src_params[i].size * sizeof(float));
    model_.field_config = src.field_config;
    model_.scene = src.scene;
    model_.training_steps = src.training_steps;
    if (!src.background)
      model_.background.reset();
    else if (model_.background && model_.background->numParameters() == src.background->numParameters())
      *model_.background = *src.background;
    else
      model_.background = std::make_unique<nerf::Background>(*src.background);
    if (model_.grid)
      *model_.grid = *src.grid;
    else
      model_.grid = std::make_unique<nerf::OccupancyGrid>(*src.grid);
  }

  nerf::NerfModel model_;
  std::string key_;
};

// The occupancy maps the publisher keeps up to date (nerf/voxel_map.h): a VoxelMapper over the region
// the training views observe, refreshed by a budget of voxels per update; rebuilt when the NeRF's box
// is re-fitted (another model) or a camera leaves the mapped region.
struct NerfPublisher::Occupancy {
  std::unique_ptr<nerf::VoxelMapper> mapper;
  std::string model_key;
  Eigen::AlignedBox3d bounds;
  nerf::GridProjection grid;
  nerf::FloorPlane floor;
  double band_lo = 0, band_hi = 0;
  bool have_grid = false;
};

NerfPublisher::NerfPublisher(ros::NodeHandle pnh, NerfTopicsOptions p, bool nerf, SourceFn source, PoseFn pose)
    : pnh_(pnh),
      p_(std::move(p)),
      nerf_(nerf),
      source_(std::move(source)),
      pose_(std::move(pose)),
      model_copy_(std::make_unique<ModelCopy>()) {
  // The publisher thread's queue: the NeRF topics' renders and the map services (slow work that
  // must not delay image callbacks or tracking).
  queue_nh_ = pnh_;
  queue_nh_.setCallbackQueue(&queue_);
  save_srv_ = queue_nh_.advertiseService("save_map", &NerfPublisher::onSaveMap, this);
  if (nerf_) {
    view_pub_ = pnh_.advertise<sensor_msgs::Image>("nerf_view", 1);
    depth_pub_ = pnh_.advertise<sensor_msgs::Image>("nerf_depth", 1);
    cloud_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("nerf_cloud", 1, true);
    occupancy_pub_ = pnh_.advertise<nav_msgs::OccupancyGrid>("occupancy", 1, true);
    voxels_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("occupied_voxels", 1, true);
    save_occupancy_srv_ = queue_nh_.advertiseService("save_occupancy", &NerfPublisher::onSaveOccupancy, this);
    occupancy_ = std::make_unique<Occupancy>();
  }
}

NerfPublisher::~NerfPublisher() { stop(); }

void NerfPublisher::start() {
  if (!thread_.joinable()) thread_ = std::thread([this] { run(); });
}

void NerfPublisher::stop() {
  stopping_ = true;
  if (thread_.joinable()) thread_.join();
}

void NerfPublisher::run() {
  if (!lowerThreadPriority(p_.nerf_render_nice)) ROS_WARN("could not lower the NeRF publisher thread's priority");
  double next_view = wallSeconds() + p_.nerf_publish_period;
  double next_cloud = wallSeconds() + p_.nerf_cloud_period;
  double next_occupancy = wallSeconds() + p_.occupancy_period;
  while (!stopping_ && ros::ok()) {
    queue_.callAvailable(ros::WallDuration(0.05));
    if (!nerf_ || stopping_) continue;
    // A render longer than its period is followed by half a period of rest, so the thread never
    // renders back to back.
    double now = wallSeconds();
    if (now >= next_view) {
      publishView();
      const double end = wallSeconds();
      next_view = std::max(now + p_.nerf_publish_period, end + 0.5 * p_.nerf_publish_period);
    }
    now = wallSeconds();
    if (now >= next_cloud) {
      publishCloud();
      const double end = wallSeconds();
      next_cloud = std::max(now + p_.nerf_cloud_period, end + 0.5 * p_.nerf_cloud_period);
    }
    now = wallSeconds();
    if (p_.occupancy_period > 0 && now >= next_occupancy) {
      updateOccupancy(false);
      const double end = wallSeconds();
      next_occupancy = std::max(now + p_.occupancy_period, end + 0.5 * p_.occupancy_period);
    }
  }
}

void NerfPublisher::updateOccupancy(bool force) {
  if (!occupancy_) return;
  if (!force && occupancy_pub_.getNumSubscribers() == 0 && voxels_pub_.getNumSubscribers() == 0) return;
  const auto src = source_();
  if (!src || !src->nerf) return;
  NerfMapping& nerf = *src->nerf;
  if (!nerf.renderable()) return;
  const Camera cam = nerf.trainingCamera();
  std::vector<nerf::PosedCamera> views;
  for (const auto& pose : nerf.viewPoses()) views.push_back({cam, pose});
  if (views.size() < 2) return;
  Occupancy& o = *occupancy_;
  try {
    if (!updateModelCopy(nerf)) return;
    const double t0 = wallSeconds();
    const nerf::NerfModel& m = model_copy_->model();
    const nerf::DensitySource density = nerf::fieldDensitySource(m);
    // Another model (a box re-fit: other scene transform) or a camera outside the mapped region: rebuild.
    const std::string key = fmt::format("{} {} {} {} {}", m.scene.scale, m.scene.offset.x(), m.scene.offset.y(),
                                        m.scene.offset.z(), m.scene.aabb_scale);
    bool inside = o.mapper != nullptr;
    for (const auto& v : views) inside = inside && o.bounds.contains(v.T_world_cam.translation());
    nerf::VoxelMapOptions vo;
    vo.threads = p_.nerf_render_threads;
    vo.pixel_stride = p_.occupancy_pixel_stride;
    if (!inside || key != o.model_key) {
      vo.resolution = p_.occupancy_resolution > 0 ? p_.occupancy_resolution
                                                  : nerf::voxelMapBounds(density, views, 0.0).diagonal().norm() / 160.0;
      o.bounds = nerf::observedBounds(density, views, vo);
      o.mapper = std::make_unique<nerf::VoxelMapper>(vo, o.bounds);
      o.mapper->updateDensity(density, -1);
      o.model_key = key;
      ++occupancy_rebuilds_;
    } else {
      o.mapper->updateDensity(density,
                              std::max<int64_t>(1, int64_t(double(o.mapper->map().size()) * p_.occupancy_budget)));
    }
    o.mapper->carve(views);
    const nerf::VoxelMap& map = o.mapper->map();
    o.have_grid = false;
    try {
      o.floor = nerf::detectFloor(map, views);
      std::vector<double> h;
      for (const auto& v : views) h.push_back(o.floor.height(v.T_world_cam.translation()));
      std::nth_element(h.begin(), h.begin() + long(h.size() / 2), h.end());
      const double cam_h = h[h.size() / 2];
      if (cam_h > 0) {
        o.band_lo = p_.occupancy_band_lo * cam_h;
        o.band_hi = p_.occupancy_band_hi * cam_h;
        o.grid = nerf::projectToGrid(map, o.floor, o.band_lo, o.band_hi);
        o.have_grid = true;
      }
    } catch (const std::exception& e) {
      ROS_WARN_THROTTLE(30.0, "~occupancy: no 2D grid yet: %s", e.what());
    }
    occupancy_ms_last_ = 1e3 * (wallSeconds() - t0);
    ++occupancy_updates_;
    const std::optional<ViewPose> pose = pose_();
    const ros::Time stamp = pose ? pose->stamp : ros::Time::now();
    if (o.have_grid) {
      nav_msgs::OccupancyGrid g;
      g.header.stamp = stamp;
      g.header.frame_id = p_.map_frame;
      g.info.map_load_time = stamp;
      g.info.resolution = float(o.grid.grid.resolution);
      g.info.width = uint32_t(o.grid.grid.width);
      g.info.height = uint32_t(o.grid.grid.height);
      // The grid's origin cell corner in the map frame: the grid's frame (on the floor) moved to it.
      const Eigen::Vector3d origin = o.grid.T_out_grid * Eigen::Vector3d(o.grid.grid.origin_x, o.grid.grid.origin_y, 0);
      const Eigen::Quaterniond q = o.grid.T_out_grid.rotation();
      g.info.origin.position.x = origin.x();
      g.info.origin.position.y = origin.y();
      g.info.origin.position.z = origin.z();
      g.info.origin.orientation.x = q.x();
      g.info.origin.orientation.y = q.y();
      g.info.origin.orientation.z = q.z();
      g.info.origin.orientation.w = q.w();
      g.data.assign(o.grid.grid.cells.begin(), o.grid.grid.cells.end());
      occupancy_pub_.publish(g);
    }
    sensor_msgs::PointCloud2 cloud;
    cloud.header.stamp = stamp;
    cloud.header.frame_id = p_.map_frame;
    sensor_msgs::PointCloud2Modifier mod(cloud);
    mod.setPointCloud2FieldsByString(1, "xyz");
    mod.resize(map.count(nerf::VoxelMap::kOccupied));
    sensor_msgs::PointCloud2Iterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
    for (int k = 0; k < map.dims.z(); ++k)
      for (int j = 0; j < map.dims.y(); ++j)
        for (int i = 0; i < map.dims.x(); ++i) {
          if (map.state[map.index(i, j, k)] != nerf::VoxelMap::kOccupied) continue;
          const Eigen::Vector3d c = map.center(i, j, k);
          *x = float(c.x());
          *y = float(c.y());
          *z = float(c.z());
          ++x, ++y, ++z;
        }
    voxels_pub_.publish(cloud);
  } catch (const std::exception& e) {
    ++occupancy_errors_;
    ROS_ERROR_THROTTLE(10.0, "occupancy update failed: %s", e.what());
  }
}

bool NerfPublisher::onSaveOccupancy(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  std::string dir_param = p_.occupancy_dir;
  pnh_.getParam("occupancy_dir", dir_param);
  auto refuse = [&](const std::string& why) {
    res.success = false;
    res.message = why;
    ROS_ERROR("~save_occupancy: %s", why.c_str());
    return true;
  };
  if (dir_param.empty()) return refuse("~occupancy_dir is empty");
  const uint64_t before = occupancy_errors_;
  updateOccupancy(true);
  if (!occupancy_ || !occupancy_->mapper)
    return refuse(occupancy_errors_ > before ? "the occupancy update failed (see the log)"
                                             : "no occupancy map yet: the NeRF has no model or fewer than 2 views");
  try {
    const std::filesystem::path dir = resolveMapDir(dir_param);
    ensureDirectory(dir);
    const nerf::VoxelMap& map = occupancy_->mapper->map();
    nerf::writeOctomapFiles(map, dir / "occupancy.bt", 0, "nerfslam ROS node");
    nerf::saveOctomap(map, dir / "occupancy.ot");
    std::string grid_note = "no 2D grid (no floor found yet)";
    if (occupancy_->have_grid) {
      saveMapServer(occupancy_->grid.grid, dir / "map.yaml");
      nerf::MapMeta meta;
      meta.kind = "grid";
      meta.resolution = map.resolution;
      meta.source = "nerfslam ROS node";
      meta.grid = &occupancy_->grid;
      meta.floor = &occupancy_->floor;
      meta.band_lo = occupancy_->band_lo;
      meta.band_hi = occupancy_->band_hi;
      nerf::saveMapMeta(meta, dir / "map.meta.yaml");
      grid_note = "map.yaml + map.pgm";
    }
    res.success = true;
    res.message = fmt::format("{}: occupancy.bt, occupancy.ot, {}", dir.string(), grid_note);
    ROS_INFO("~save_occupancy: %s", res.message.c_str());
  } catch (const std::exception& e) {
    return refuse(e.what());
  }
  return true;
}

void NerfPublisher::publishView() {
  if (view_pub_.getNumSubscribers() == 0 && depth_pub_.getNumSubscribers() == 0) return;
  const auto src = source_();
  if (!src || !src->nerf) return;
  NerfMapping& nerf = *src->nerf;
  if (!nerf.renderable()) return;
  const std::optional<ViewPose> pose = pose_();
  if (!pose || pose->generation != src->generation) return;
  const Camera cam = nerf.trainingCamera();
  nerf::RenderOptions ro;
  ro.threads = p_.nerf_render_threads;
  ro.normals = false;
  ro.background = {0.0, 0.0, 0.0};
  nerf::RenderResult r;
  double t0 = 0;
  try {
    if (!updateModelCopy(nerf)) return;
    t0 = wallSeconds();
    r = nerf::renderView(model_copy_->model(), cam, pose->T_world_cam, ro);
  } catch (const std::exception& e) {
    ++render_errors_;
    ROS_ERROR_THROTTLE(10.0, "NeRF render failed: %s", e.what());
    return;
  }
  const double ms = 1e3 * (wallSeconds() - t0);
  samples_per_ray_last_ = double(r.samples) / std::max(1, cam.width * cam.height);
  occupied_last_ = model_copy_->model().grid->occupiedFraction();
  std_msgs::Header header;
  header.stamp = pose->stamp;
  header.frame_id = p_.camera_frame;
  if (view_pub_.getNumSubscribers() > 0) {
    cv::Mat rgb8;
    r.rgb.convertTo(rgb8, CV_8UC3, 255.0);  // saturating: [0,1] -> 0..255, RGB order
    view_pub_.publish(cv_bridge::CvImage(header, "rgb8", rgb8).toImageMsg());
  }
  if (depth_pub_.getNumSubscribers() > 0) {
    cv::Mat depth = r.depth.clone();
    depth.setTo(std::numeric_limits<float>::quiet_NaN(), depth <= 0.0f);  // REP 118: NaN = no depth
    depth_pub_.publish(rosbridge::toImageMsg(depth, header));
  }
  ++renders_;
  render_ms_last_ = ms;
  render_ms_sum_.store(render_ms_sum_.load() + ms);
}

void NerfPublisher::publishCloud() {
  if (cloud_pub_.getNumSubscribers() == 0) return;
  const auto src = source_();
  if (!src || !src->nerf) return;
  NerfMapping& nerf = *src->nerf;
  if (!nerf.renderable()) return;
  nerf::ExportOptions xo;
  xo.threads = p_.nerf_render_threads;
  std::vector<nerf::PosedCamera> views;
  if (p_.nerf_cloud_source == "depth") {
    // Rendered at 1/stride of the training resolution with a point per pixel: the points
    // depthPointCloud would keep with pixel_stride, for 1/stride^2 of the rays.
    const Camera train = nerf.trainingCamera();
    const int w = std::max(1, static_cast<int>(std::lround(double(train.width) / p_.nerf_cloud_stride)));
    const int hgt = std::max(1, static_cast<int>(std::lround(double(train.height) / p_.nerf_cloud_stride)));
    Camera cam = train.scaled(double(w) / train.width);
    cam.width = w;
    cam.height = hgt;
    xo.pixel_stride = 1;
    const std::vector<SE3> poses = nerf.viewPoses();
    const size_t n = std::min(poses.size(), static_cast<size_t>(p_.nerf_cloud_views));
    for (size_t i = poses.size() - n; i < poses.size(); ++i) views.push_back({cam, poses[i]});
    if (views.empty()) return;
  }
  pcl::PointCloud<pcl::PointXYZRGB> pc;
  double t0 = 0;
  try {
    if (!updateModelCopy(nerf)) return;
    t0 = wallSeconds();
    const nerf::NerfModel& m = model_copy_->model();
    pc = views.empty() ? nerf::densityPointCloud(m, xo) : nerf::depthPointCloud(m, views, xo);
  } catch (const std::exception& e) {
    ++render_errors_;
    ROS_ERROR_THROTTLE(10.0, "NeRF cloud export failed: %s", e.what());
    return;
  }
  const double ms = 1e3 * (wallSeconds() - t0);
  sensor_msgs::PointCloud2 cloud;
  const std::optional<ViewPose> pose = pose_();
  cloud.header.stamp = pose ? pose->stamp : ros::Time::now();
  cloud.header.frame_id = p_.map_frame;
  sensor_msgs::PointCloud2Modifier mod(cloud);
  mod.setPointCloud2FieldsByString(2, "xyz", "rgb");  // x y z float32, rgb packed (rviz RGB8)
  mod.resize(pc.size());
  sensor_msgs::PointCloud2Iterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
  sensor_msgs::PointCloud2Iterator<uint8_t> cr(cloud, "r"), cg(cloud, "g"), cb(cloud, "b");
  for (const auto& pt : pc.points) {
    *x = pt.x;
    *y = pt.y;
    *z = pt.z;
    *cr = pt.r;
    *cg = pt.g;
    *cb = pt.b;
    ++x, ++y, ++z, ++cr, ++cg, ++cb;
  }
  cloud_pub_.publish(cloud);
  ++clouds_;
  cloud_points_last_ = pc.size();
  cloud_ms_last_ = ms;
}

bool NerfPublisher::updateModelCopy(const NerfMapping& nerf) {
  double wait_ms = 0, copy_ms = 0;
  if (!model_copy_->update(nerf, &wait_ms, &copy_ms)) return false;
  lock_wait_ms_last_ = wait_ms;
  copy_ms_last_ = copy_ms;
  return true;
}

bool NerfPublisher::onSaveMap(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  std::string dir_param = p_.map_dir;
  pnh_.getParam("map_dir", dir_param);  // re-read: `rosparam set` before the call changes the folder
  if (dir_param.empty()) {
    ++save_failures_;
    res.success = false;
    res.message = "~map_dir is empty";
    ROS_ERROR("~save_map: %s", res.message.c_str());
    return true;
  }
  const std::filesystem::path dir = resolveMapDir(dir_param);
  std::string message;
  res.success = saveMap(dir, &message) == SaveOutcome::kSaved;
  if (res.success) {
    res.message = dir.string();  // the folder, for callers; the details in the log
    ROS_INFO("~save_map: %s", message.c_str());
  } else {
    res.message = message;
    ROS_ERROR("~save_map: %s", message.c_str());
  }
  return true;
}

NerfPublisher::SaveOutcome NerfPublisher::saveMap(const std::filesystem::path& dir, std::string* message) {
  auto refuse = [&](SaveOutcome why, const std::string& text) {
    ++save_failures_;
    *message = text;
    return why;
  };
  const auto src = source_();
  if (!src)
    return refuse(SaveOutcome::kNothingToSave,
                  "no map to save: the SLAM system has not started (no images received yet)");
  if (src->map->numKeyframes() == 0)
    return refuse(SaveOutcome::kNothingToSave,
                  "no map to save: the SLAM system has not initialised yet (no keyframes)");
  NerfModelWriter write_nerf;
  // The model is written from a copy (training pauses only for the copy, not for the disk write).
  if (NerfMapping* n = src->nerf; n && n->hasModel())
    write_nerf = [this, n](const std::filesystem::path& path) {
      if (!updateModelCopy(*n)) throw std::runtime_error("the NeRF model disappeared (reset)");
      nerf::saveModel(model_copy_->model(), path);
    };
  try {
    const std::shared_ptr<const Map> copy = src->map_to_save ? src->map_to_save() : nullptr;
    const MapSaveResult r = saveMapFolder(dir, copy ? *copy : *src->map, *src->camera, src->options, write_nerf);
    ++saves_;
    {
      std::lock_guard<std::mutex> lock(saved_mutex_);
      last_saved_ = dir.string();
    }
    char buf[512];
    std::snprintf(buf, sizeof buf,
                  " (generation %lu: %zu keyframes, %zu points, %s, %.1f MB, %zu images written, %zu reused, %.2f s)",
                  static_cast<unsigned long>(r.generation), r.keyframes, r.points,
                  r.has_nerf ? "with the NeRF model" : "no NeRF model", r.bytes / 1e6, r.images_written,
                  r.images_reused, r.seconds);
    *message = dir.string() + buf;
    return SaveOutcome::kSaved;
  } catch (const std::exception& e) {
    const std::string what = e.what();
    return refuse(SaveOutcome::kFailed, what.find(dir.string()) != std::string::npos
                                            ? "cannot save the map: " + what
                                            : "cannot save the map to " + dir.string() + ": " + what);
  }
}

void NerfPublisher::diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) const {
  s.add("nerf", nerf_ ? "on" : "off");
  if (nerf_) {
    // Only stats() here (a short lock of its own): hasModel(), trainingCamera() and viewPoses() take
    // the model lock, held across whole training steps and renders, and would stall this (the image
    // callbacks') thread.
    const auto src = source_();
    const NerfMapping* nerf = src ? src->nerf : nullptr;
    const NerfMappingStats st = nerf ? nerf->stats() : NerfMappingStats{};
    s.add("nerf model", st.views > 0 ? "yes" : "no");
    s.add("nerf steps", static_cast<int64_t>(st.steps));
    s.addf("nerf samples/s", "%.0f", st.samples_per_second);
    s.add("nerf views", st.views);
    s.addf("nerf psnr recent (dB)", "%.2f", st.psnr_recent);
    s.addf("nerf psnr held-out (dB)", "%.2f", st.psnr_heldout);
    s.add("nerf keyframes dropped", static_cast<uint64_t>(st.keyframes_dropped));
    s.add("nerf keyframes recovered", static_cast<uint64_t>(st.keyframes_recovered));
    s.add("nerf refits", static_cast<int64_t>(st.refits));
    const uint64_t renders = renders_;
    s.add("nerf renders", renders);
    s.addf("nerf render ms (last)", "%.1f", render_ms_last_.load());
    s.addf("nerf render ms (mean)", "%.1f", renders > 0 ? render_ms_sum_.load() / renders : 0.0);
    s.addf("nerf model lock wait ms (last)", "%.1f", lock_wait_ms_last_.load());
    s.addf("nerf model copy ms (last)", "%.1f", copy_ms_last_.load());
    s.addf("nerf render samples per ray (last)", "%.1f", samples_per_ray_last_.load());
    s.addf("nerf occupied fraction (last render)", "%.4f", occupied_last_.load());
    s.add("nerf clouds", static_cast<uint64_t>(clouds_));
    s.add("occupancy updates", static_cast<uint64_t>(occupancy_updates_));
    s.add("occupancy rebuilds", static_cast<uint64_t>(occupancy_rebuilds_));
    s.add("occupancy errors", static_cast<uint64_t>(occupancy_errors_));
    s.addf("occupancy ms (last)", "%.1f", occupancy_ms_last_.load());
    s.add("nerf cloud points (last)", static_cast<uint64_t>(cloud_points_last_));
    s.addf("nerf cloud ms (last)", "%.1f", cloud_ms_last_.load());
    s.add("nerf render errors", static_cast<uint64_t>(render_errors_));
  }
  s.add("map saves", static_cast<uint64_t>(saves_));
  s.add("map save failures", static_cast<uint64_t>(save_failures_));
  std::lock_guard<std::mutex> lock(saved_mutex_);
  s.add("map saved to", last_saved_);
}

std::string NerfPublisher::summary() const {
  char buf[200];
  const uint64_t renders = renders_;
  std::snprintf(buf, sizeof buf, "%lu NeRF renders (mean %.0f ms), %lu NeRF clouds, %lu map saves (%lu failed)",
                static_cast<unsigned long>(renders), renders > 0 ? render_ms_sum_.load() / renders : 0.0,
                static_cast<unsigned long>(clouds_), static_cast<unsigned long>(saves_),
                static_cast<unsigned long>(save_failures_));
  return buf;
}

}  // namespace nerfslam::rosnode
