// `nerfslam run`: monocular SLAM over a dataset (see include/nerfslam/system/runner.h).
#include <memory>

#include "command.h"
#include "nerfslam/system/runner.h"

namespace {

struct RunArgs {
  std::string dataset;
  std::string camera;
  std::string config;
  std::string out;
  std::size_t max_frames = 0;
  bool realtime = false;
};

nerfslam::cli::Registrar reg(
    "run", "Run monocular SLAM over a dataset; writes trajectory, keyframes, map points and report.json",
    [](CLI::App& sub) -> nerfslam::cli::Runner {
      auto a = std::make_shared<RunArgs>();
      sub.add_option("--dataset", a->dataset,
                     "[kind:]PATH (kinds: folder tum euroc kitti transforms middlebury strecha tsukuba)")
          ->required();
      sub.add_option("--camera", a->camera, "Camera YAML replacing the dataset's calibration");
      sub.add_option("--config", a->config, "Options YAML (see `nerfslam options`)");
      sub.add_option("--out", a->out, "Output directory")->required();
      sub.add_option("--max-frames", a->max_frames, "Use at most N frames (0: all)");
      sub.add_flag("--realtime", a->realtime,
                   "Play frames at their timestamps, dropping what tracking can't keep up with");
      return [a]() -> int {
        nerfslam::RunOptions o;
        o.dataset = a->dataset;
        if (!a->camera.empty()) o.camera = a->camera;
        if (!a->config.empty()) o.config = a->config;
        o.out = a->out;
        o.max_frames = a->max_frames;
        o.realtime = a->realtime;
        const nerfslam::RunResult r = nerfslam::runSlam(o);
        return r.exit_code;
      };
    });

}  // namespace
