// `nerfslam render-preview`: draw point clouds, trajectories and keyframe frustums to a PNG, headless.
#include <memory>

#include <yaml-cpp/yaml.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "command.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/parse.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/io/ply_header.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/grid_preview.h"
#include "nerfslam/render/preview.h"

namespace {

struct PreviewArgs {
  std::vector<std::string> points;
  std::vector<std::string> trajectories;
  std::vector<std::string> keyframes;
  std::string view;
  std::string up = "0,0,1";
  std::string size = "1280x960";
  std::string out;
  std::string grid;
  nerfslam::PreviewOptions opts;
};

// The grid's frame in the map frame from NAME.meta.yaml beside NAME.yaml (T_map_grid, written by
// `export --format grid` and `run`); identity when there is none. Also the units it names.
nerfslam::SE3 gridFrame(const std::filesystem::path& yaml, std::string* units) {
  using namespace nerfslam;
  std::filesystem::path meta = yaml;
  meta.replace_extension(".meta.yaml");
  *units = "m";
  if (!std::filesystem::exists(meta)) return SE3();
  YAML::Node n;
  try {
    n = YAML::LoadFile(meta.string());
  } catch (const YAML::Exception& e) {
    fail("{}: not valid YAML ({})", meta.string(), e.what());
  }
  if (n["units"] && n["units"].as<std::string>() == "map") {
    *units = "map units";
    if (n["metres_per_unit"] && !n["metres_per_unit"].IsNull()) {
      try {
        *units = fmt::format("map units (1 = {:.3g} m)", n["metres_per_unit"].as<double>());
      } catch (const YAML::Exception&) {
        fail("{}: field 'metres_per_unit' is not a number", meta.string());
      }
    }
  }
  if (!n["T_map_grid"]) return SE3();
  if (!n["T_map_grid"].IsSequence() || n["T_map_grid"].size() != 16)
    fail("{}: field 'T_map_grid' must be 16 numbers (a row-major 4x4 matrix)", meta.string());
  Eigen::Matrix4d T;
  for (int i = 0; i < 16; ++i) {
    try {
      T(i / 4, i % 4) = n["T_map_grid"][i].as<double>();
    } catch (const YAML::Exception&) {
      fail("{}: field 'T_map_grid' must be 16 numbers", meta.string());
    }
  }
  if (!T.allFinite()) fail("{}: field 'T_map_grid' is not finite", meta.string());
  return SE3::fromMatrix(T);
}

const char* kPalette[] = {"red", "green", "blue", "yellow", "magenta", "cyan", "orange", "white"};

// --trajectory FILE[:COLOUR] (the i-th): the file and its colour (the palette's i-th without one; a
// file whose own name has a colon is taken whole when it exists).
std::pair<std::string, std::string> trajectoryArgument(const std::string& arg, size_t i) {
  std::string file = arg, color = kPalette[i % 8];
  const auto colon = file.rfind(':');
  if (colon != std::string::npos && colon + 1 < file.size() && !std::filesystem::exists(file)) {
    color = file.substr(colon + 1);
    file = file.substr(0, colon);
  }
  return {file, color};
}

nerfslam::cli::Registrar reg(
    "render-preview", "Draw point clouds, trajectories and keyframes to a PNG (headless, OSMesa)",
    [](CLI::App& sub) -> nerfslam::cli::Runner {
      auto a = std::make_shared<PreviewArgs>();
      sub.add_option("--points", a->points, "PLY point cloud (sparse or dense; repeatable)");
      sub.add_option("--trajectory", a->trajectories,
                     "Trajectory file (TUM/KITTI/EuRoC), optionally FILE:COLOR with a colour name or #rrggbb "
                     "(repeatable)");
      sub.add_option("--keyframes", a->keyframes, "Keyframe poses (TUM format) drawn as frustums (repeatable)");
      sub.add_option("--view", a->view, "Viewpoint \"eye=x,y,z,target=x,y,z\" (default: fit everything)");
      sub.add_option("--up", a->up, "World up direction x,y,z")->capture_default_str();
      sub.add_option("--size", a->size, "Image size WxH")->capture_default_str();
      sub.add_option("--point-size", a->opts.point_size, "Point size in pixels")->capture_default_str();
      sub.add_option("--frustum-size", a->opts.frustum_size, "Frustum depth in metres (0: automatic)");
      sub.add_option("--grid", a->grid,
                     "A 2D occupancy grid (map_server NAME.yaml, as `export --format grid` and `run` write it) drawn "
                     "top-down with the trajectories and keyframes on it, instead of the 3D view");
      sub.add_option("--out", a->out, "Output PNG")->required();
      return [a]() -> int {
        using namespace nerfslam;
        if (!a->grid.empty()) {
          if (!a->points.empty()) fail("--grid draws the grid top-down; --points are not drawn on it");
          const NavGrid grid = loadMapServer(a->grid);
          std::string units;
          const SE3 T_map_grid = gridFrame(a->grid, &units);
          std::vector<GridTrajectory> trs;
          for (size_t i = 0; i < a->trajectories.size(); ++i) {
            const auto [file, color] = trajectoryArgument(a->trajectories[i], i);
            GridTrajectory t;
            t.color = parseColor(color);
            for (const auto& e : readTrajectory(file)) t.positions.push_back(e.pose.translation());
            trs.push_back(std::move(t));
          }
          for (const auto& k : a->keyframes) {
            GridTrajectory t;
            t.color = parseColor("blue");
            t.dots = true;
            for (const auto& e : readTumTrajectory(k)) t.positions.push_back(e.pose.translation());
            trs.push_back(std::move(t));
          }
          int w = 0, h = 0;
          parseImageSize(a->size, "--size", 16, &w, &h);
          const cv::Mat img = drawNavGrid(grid, T_map_grid, trs, std::max(w, h), units);
          writeImageAtomic(a->out, img);
          spdlog::info("render-preview: wrote {} ({}x{}, the grid {}x{})", a->out, img.cols, img.rows, grid.width,
                       grid.height);
          return 0;
        }
        PreviewOptions o = a->opts;
        parseImageSize(a->size, "--size", 16, &o.width, &o.height);
        const auto up = parseNumberList(a->up, "--up");
        if (up.size() != 3 || Eigen::Vector3d(up[0], up[1], up[2]).norm() < 1e-9)
          fail("--up '{}': need a non-zero x,y,z", a->up);
        o.up = Eigen::Vector3d(up[0], up[1], up[2]);
        if (!a->view.empty()) {
          Eigen::Vector3d eye, target;
          parseView(a->view, &eye, &target);
          o.eye = eye;
          o.target = target;
        }
        PreviewScene scene;
        for (const auto& p : a->points) {
          checkPlyFile(p);  // counts the header declares against the file's size, before PCL allocates them
          scene.clouds.push_back(loadPointCloudPly(p));
        }
        for (size_t i = 0; i < a->trajectories.size(); ++i) {
          const auto [file, color] = trajectoryArgument(a->trajectories[i], i);
          PreviewTrajectory t;
          t.color = parseColor(color);
          t.label = std::filesystem::path(file).filename().string();
          for (const auto& e : readTrajectory(file)) t.poses.push_back(e.pose);
          scene.trajectories.push_back(std::move(t));
        }
        for (const auto& k : a->keyframes)
          for (const auto& e : readTumTrajectory(k)) scene.keyframes.push_back(e.pose);
        const cv::Mat img = renderPreview(scene, o);
        writeImageAtomic(a->out, img);
        spdlog::info("render-preview: wrote {} ({}x{})", a->out, img.cols, img.rows);
        return 0;
      };
    });

}  // namespace
