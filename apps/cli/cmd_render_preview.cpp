// `nerfslam render-preview`: draw point clouds, trajectories and keyframe frustums to a PNG, headless.
#include <memory>

#include <spdlog/spdlog.h>

#include "command.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/parse.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/io/ply_header.h"
#include "nerfslam/io/trajectory.h"
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
  nerfslam::PreviewOptions opts;
};

const char* kPalette[] = {"red", "green", "blue", "yellow", "magenta", "cyan", "orange", "white"};

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
      sub.add_option("--out", a->out, "Output PNG")->required();
      return [a]() -> int {
        using namespace nerfslam;
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
          std::string file = a->trajectories[i];
          std::string color = kPalette[i % 8];
          const auto colon = file.rfind(':');
          if (colon != std::string::npos && colon + 1 < file.size() && !std::filesystem::exists(file)) {
            color = file.substr(colon + 1);
            file = file.substr(0, colon);
          }
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
