// `nerfslam bag`: writes any dataset as a ROS 1 bag (include/nerfslam/io/bag.h), so bags of our
// datasets can be made without a ROS master (tests, `--dataset bag:`).
#include <memory>

#include "command.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/bag.h"
#include "nerfslam/io/dataset.h"

namespace {

struct BagArgs {
  std::string dataset;
  std::string camera;
  std::string out;
  std::string odometry;
  std::size_t max_frames = 0;
  double fps = 0;
  nerfslam::BagWriteOptions w;
  bool no_groundtruth = false;
};

nerfslam::cli::Registrar reg(
    "bag", "Write a dataset as a ROS bag (images, camera_info, ground truth, odometry) for --dataset bag:",
    [](CLI::App& sub) -> nerfslam::cli::Runner {
      auto a = std::make_shared<BagArgs>();
      sub.add_option("--dataset", a->dataset, "[kind:]PATH of the dataset to write")->required();
      sub.add_option("--out", a->out, "The bag file to write (replaced atomically)")->required();
      sub.add_option("--camera", a->camera, "Camera YAML replacing the dataset's calibration");
      sub.add_option("--fps", a->fps, "Frame rate giving the timestamps of a folder without times.txt")
          ->check(CLI::Range(0.0, 10000.0));
      sub.add_option("--max-frames", a->max_frames, "Write at most N frames (0: all)");
      sub.add_option("--encoding", a->w.encoding,
                     "Images as sensor_msgs/Image (mono8, rgb8, bgr8) or CompressedImage (png, jpeg)")
          ->check(CLI::IsMember({"mono8", "rgb8", "bgr8", "png", "jpeg"}));
      sub.add_option("--jpeg-quality", a->w.jpeg_quality, "JPEG quality (--encoding jpeg)")->check(CLI::Range(1, 100));
      sub.add_option("--odometry", a->odometry,
                     "A TUM odometry file (T_odom_base, e.g. synth's odometry.txt) written as nav_msgs/Odometry");
      sub.add_option("--odometry-as", a->w.odometry_as,
                     "How --odometry is written: topic (nav_msgs/Odometry), tf (/tf, odom -> base_link) or both")
          ->check(CLI::IsMember({"topic", "tf", "both"}));
      sub.add_option("--image-topic", a->w.image_topic, "Image topic");
      sub.add_option("--camera-info-topic", a->w.camera_info_topic, "CameraInfo topic");
      sub.add_option("--odometry-topic", a->w.odometry_topic, "Odometry topic");
      sub.add_option("--groundtruth-topic", a->w.groundtruth_topic,
                     "Ground-truth topic (geometry_msgs/PoseStamped, T_world_cam)");
      sub.add_flag("--no-groundtruth", a->no_groundtruth, "Leave the dataset's ground truth out");
      return [a]() -> int {
        if (!nerfslam::bagSupported())
          throw nerfslam::Error("bag: this nerfslam was built without ROS bag support (librosbag-storage-dev)");
        nerfslam::DatasetOptions dopt;
        if (!a->camera.empty()) dopt.camera_override = a->camera;
        dopt.fps = a->fps;
        dopt.max_frames = a->max_frames;
        const auto ds = nerfslam::openDataset(a->dataset, dopt);
        nerfslam::BagWriteOptions w = a->w;
        if (!a->odometry.empty()) w.odometry = a->odometry;
        w.groundtruth = !a->no_groundtruth;
        w.progress = true;
        nerfslam::writeDatasetBag(*ds, a->out, w);
        std::fprintf(stderr, "wrote %s: %zu frames on %s (%s)%s%s\n", a->out.c_str(), ds->size(), w.image_topic.c_str(),
                     w.encoding.c_str(), ds->hasGroundTruth() && w.groundtruth ? ", ground truth" : "",
                     w.odometry ? (", odometry as " + w.odometry_as).c_str() : "");
        return 0;
      };
    });

}  // namespace
