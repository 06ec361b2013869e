// `nerfslam run`: monocular SLAM over a dataset (see include/nerfslam/system/runner.h).
#include <memory>

#include "command.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/stop_signal.h"
#include "nerfslam/system/runner.h"

namespace {

struct RunArgs {
  std::string dataset;
  std::string camera;
  std::string config;
  std::string out;
  std::size_t max_frames = 0;
  double fps = 0;
  bool realtime = false;
  bool no_nerf = false;
  int demo_frames = 300;
  std::string map;  // saved maps (include/nerfslam/system/map_store.h)
  bool localize = false;
  bool extend = false;
  std::string save_map;
  std::string odometry;
  std::string image_topic, camera_info_topic, odometry_topic, groundtruth_topic;
  std::vector<std::string> odometry_frames, groundtruth_frames;
};

// Two frame names, "A,B" (CLI11 splits the value at the comma). No description of its own: the
// option's type name says A,B.
CLI::Validator twoFrames(const char* names) {
  return CLI::Validator(
      [names](std::string& s) -> std::string {
        if (s.empty()) return std::string("an empty frame name: expected ") + names;
        return {};
      },
      "");
}

nerfslam::cli::Registrar reg(
    "run", "Run monocular SLAM over a dataset; writes trajectory, keyframes, map points and report.json",
    [](CLI::App& sub) -> nerfslam::cli::Runner {
      auto a = std::make_shared<RunArgs>();
      sub.add_option("--dataset", a->dataset,
                     "[kind:]PATH (kinds: folder tum euroc kitti transforms middlebury strecha tsukuba video bag), "
                     "or camera:/dev/videoN (camera:N) for a live camera (needs --camera; implies --realtime; its "
                     "frames are recorded in OUT/frames, a folder dataset); without it: the demo on a synthetic room "
                     "rendered into OUT/sequence");
      sub.add_option("--demo-frames", a->demo_frames, "Frames of the demo sequence (without --dataset)")
          ->check(CLI::Range(30, 100000));
      sub.add_option("--camera", a->camera, "Camera YAML replacing the dataset's calibration");
      sub.add_option("--config", a->config, "Options YAML (see `nerfslam options`)");
      sub.add_option("--out", a->out, "Output directory")->required();
      sub.add_option("--max-frames", a->max_frames,
                     "Use at most N frames (0: all; a camera: stop once N frames reached tracking, else at Ctrl-C)");
      sub.add_option("--fps", a->fps,
                     "Frame rate giving the timestamps of a dataset without them (an image folder without "
                     "times.txt; 0: the dataset's own)")
          ->check(CLI::Range(0.0, 10000.0));
      sub.add_flag("--realtime", a->realtime,
                   "Play frames at their timestamps, dropping what tracking can't keep up with");
      sub.add_flag("--no-nerf", a->no_nerf, "Sparse SLAM only: no NeRF mapping thread");
      auto* map_opt = sub.add_option("--map", a->map,
                                     "Start from this saved map folder (with --localize or --extend; its options are "
                                     "used unless --config is given; its camera must be the dataset's)");
      auto* loc = sub.add_flag("--localize", a->localize,
                               "With --map: relocalise in the map, then track against it without changing it");
      auto* ext = sub.add_flag("--extend", a->extend, "With --map: relocalise in the map, then continue mapping");
      loc->needs(map_opt)->excludes(ext);
      ext->needs(map_opt);
      sub.add_option("--odometry", a->odometry,
                     "Wheel odometry, TUM format (timestamp tx ty tz qx qy qz qw, the base in its odom frame; the "
                     "camera's pose in the base: odometry.T_base_cam in --config): metric scale");
      sub.add_option("--image-topic", a->image_topic,
                     "bag: the sensor_msgs/Image or CompressedImage topic (default: the bag's only one)");
      sub.add_option("--camera-info-topic", a->camera_info_topic,
                     "bag: the sensor_msgs/CameraInfo topic (default: the only one, or IMAGE_NAMESPACE/camera_info; "
                     "--camera wins)");
      sub.add_option("--odometry-topic", a->odometry_topic,
                     "bag: the nav_msgs/Odometry topic used as --odometry (default: the only one; --odometry wins)");
      sub.add_option("--groundtruth-topic", a->groundtruth_topic,
                     "bag: ground truth, geometry_msgs/PoseStamped or nav_msgs/Odometry of the camera (default: "
                     "/groundtruth when present)");
      sub.add_option("--odometry-frames", a->odometry_frames,
                     "bag: the odometry from tf (/tf, /tf_static): the pose of BASE in ODOM, chained through the "
                     "frames between them (default: odom,base_link when the bag's tf has both and no "
                     "nav_msgs/Odometry topic was chosen or detected; given, it is used instead of such a topic)")
          ->delimiter(',')
          ->expected(2)
          ->check(twoFrames("ODOM,BASE"))
          ->type_name("ODOM,BASE");
      sub.add_option("--groundtruth-frames", a->groundtruth_frames,
                     "bag: ground truth from tf, the pose of CAMERA (its optical frame, OpenCV axes) in WORLD "
                     "(default: none; given, it is used instead of a /groundtruth topic)")
          ->delimiter(',')
          ->expected(2)
          ->check(twoFrames("WORLD,CAMERA"))
          ->type_name("WORLD,CAMERA");
      sub.add_option("--save-map", a->save_map,
                     "Save the map folder here at the end (default: OUT/map, except after --localize)");
      return [a]() -> int {
        nerfslam::RunOptions o;
        o.dataset = a->dataset;
        if (!a->camera.empty()) o.camera = a->camera;
        if (!a->config.empty()) o.config = a->config;
        o.out = a->out;
        o.max_frames = a->max_frames;
        o.fps = a->fps;
        o.realtime = a->realtime;
        o.nerf = !a->no_nerf;
        o.demo_frames = a->demo_frames;
        if (!a->map.empty()) {
          if (!a->localize && !a->extend) throw nerfslam::Error("run: --map needs --localize or --extend");
          o.map = a->map;
          o.map_mode = a->localize ? nerfslam::MapMode::kLocalize : nerfslam::MapMode::kExtend;
        }
        if (!a->save_map.empty()) o.save_map = a->save_map;
        if (!a->odometry.empty()) o.odometry = a->odometry;
        o.image_topic = a->image_topic;
        o.camera_info_topic = a->camera_info_topic;
        o.odometry_topic = a->odometry_topic;
        o.groundtruth_topic = a->groundtruth_topic;
        if (!a->odometry_frames.empty()) {
          o.odom_frame = a->odometry_frames.at(0);
          o.base_frame = a->odometry_frames.at(1);
        }
        if (!a->groundtruth_frames.empty()) {
          o.groundtruth_parent_frame = a->groundtruth_frames.at(0);
          o.groundtruth_child_frame = a->groundtruth_frames.at(1);
        }
        // Ctrl-C / SIGTERM: stop reading and write what exists (core/stop_signal.h).
        nerfslam::installStopHandlers();
        const nerfslam::RunResult r = nerfslam::runSlam(o);
        return r.exit_code;
      };
    });

}  // namespace
