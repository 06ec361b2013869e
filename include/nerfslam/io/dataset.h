#pragma once
// Image-sequence datasets: one interface over an image folder, TUM RGB-D, EuRoC ASL, KITTI
// odometry, NeRF transforms.json, Middlebury multi-view, Strecha and New Tsukuba layouts.
//
//   auto ds = nerfslam::openDataset("euroc:/data/V1_01_easy");   // or just the path
//   for (size_t i = 0; i < ds->size(); ++i) {
//     DatasetFrame f = ds->load(i);                               // 8-bit gray by default
//     if (f.T_world_cam) ...                                      // ground truth, when there is one
//   }
//
// Conventions: poses are T_world_cam (camera-to-world, OpenCV optical axes: x right, y down,
// z forward), in metres where the dataset has a metric scale. Timestamps are seconds, strictly
// increasing. Frame indices are 0..size()-1 in the dataset's order.
//
// Opening is cheap: index files are parsed, listed image files are checked to exist (no decoding)
// and only the first image is decoded (to fix the sequence's image size and check it against the
// calibration). Errors always name the file, and the line or field where there is one:
//   - at open: missing folder/index file, no frames, a listed image that does not exist,
//     timestamps that do not strictly increase, malformed numbers, camera size != first image;
//   - at load(i): an unreadable or truncated image (PNG without IEND, JPEG without EOI) or one whose
//     size differs from the first frame's. Such a frame is not skipped silently: the caller decides
//     (catching the Error of one load() leaves the dataset usable for the other frames).
//
// Kinds and what they read (details in src/io/reader_<kind>.cpp):
//   folder      image files in natural order; times.txt / timestamps.txt or DatasetOptions::fps;
//               camera.yaml in the folder or the override
//   tum         rgb.txt, groundtruth.txt (nearest within 0.02 s); camera.yaml, the override, or the
//               Freiburg 1/2/3 calibration from the folder name
//   euroc       mav0/cam0/{data.csv,sensor.yaml}; ground truth = body pose * T_BS
//   kitti       image_0/ | image_l/ | image_2/, times.txt, calib.txt (P0/P2), poses*.txt
//   transforms  NeRF/instant-ngp transforms.json (OpenGL poses converted to OpenCV axes)
//   middlebury  *_par.txt (x ~ K[R|t]X); only views whose image is present
//   strecha     images/ + gt_dense_cameras/*.camera (R is camera-to-world, C the centre)
//   tsukuba     New Tsukuba: images/, cam_traj_truth.txt (cm, S*M*S rotation), intrinsics.txt
//   video       a video file (OpenCV VideoCapture, FFmpeg: mp4, avi, mkv, ...), timestamps from the
//               container; the camera from the override; the file is decoded once at open (frame
//               count, stamps, every frame's size) and sequentially by load()
//   bag         a ROS 1 bag (src/io/bag/dataset_bag.cpp, built when librosbag_storage is found):
//               sensor_msgs/Image (mono8, rgb8, bgr8, rgba8, bgra8) or CompressedImage (PNG, JPEG)
//               from one image topic, the camera from a CameraInfo topic (or the override),
//               odometry (odometry()) from a nav_msgs/Odometry topic or else from tf (odom ->
//               base_link, chained), ground truth from a geometry_msgs/PoseStamped or
//               nav_msgs/Odometry topic (or tf frames named in the options) when present; every
//               image message's header (encoding, size, stamp) is checked at open
// A live camera (`camera:/dev/videoN`) is a stream, not a Dataset: io/frame_stream.h (FrameStream,
// and StreamRecording, the Dataset of the frames a run recorded from it).
// Views without capture times (transforms without "timestamp", middlebury, strecha) get
// index / 30 s (or index / DatasetOptions::fps).
#include <cstddef>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/io/trajectory.h"

namespace nerfslam {

enum class ImageMode {
  kGray,       // 8-bit single channel (CV_8UC1)
  kColor,      // 8-bit BGR (CV_8UC3)
  kUnchanged,  // as stored: keeps alpha (NeRF RGBA images are CV_8UC4, BGRA order) and bit depth
};

struct DatasetFrame {
  size_t index = 0;
  double timestamp = 0.0;          // seconds
  cv::Mat image;                   // per the ImageMode asked for
  std::optional<SE3> T_world_cam;  // ground truth, when the dataset has it for this frame
  std::string path;                // image file
};

class Dataset {
 public:
  virtual ~Dataset();

  // "folder", "tum", "euroc", "kitti", "transforms", "middlebury", "strecha", "tsukuba", "video", "bag".
  virtual std::string kind() const = 0;
  // The dataset root as given to openDataset.
  virtual const std::filesystem::path& root() const = 0;
  // The dataset's calibration, or DatasetOptions::camera_override when one was given.
  virtual const Camera& camera() const = 0;
  virtual size_t size() const = 0;
  virtual double timestamp(size_t i) const = 0;
  virtual std::string imagePath(size_t i) const = 0;
  // T_world_cam (OpenCV optical axes) of frame i, when known.
  virtual std::optional<SE3> groundTruth(size_t i) const = 0;
  virtual bool hasGroundTruth() const = 0;
  // Decodes frame i. const and free of shared state: safe to call from several threads. Throws nerfslam::Error naming
  // the file when it is missing, unreadable, truncated, or its size differs from camera(). Throws on i >= size().
  virtual DatasetFrame load(size_t i, ImageMode mode = ImageMode::kGray) const = 0;

  // Extras some kinds carry (std::nullopt elsewhere).
  // instant-ngp aabb_scale of a transforms.json (1 when the file omits it).
  virtual std::optional<double> aabbScale() const { return std::nullopt; }
  // A transforms.json's "scale" and "offset" (instant-ngp's: p_nerf = scale * p + offset), when it
  // gives them (`nerfslam synth` does, fitting its scene into the unit cube).
  struct NerfScene {
    double scale = 1.0;
    Eigen::Vector3d offset = Eigen::Vector3d::Zero();
  };
  virtual std::optional<NerfScene> nerfScene() const { return std::nullopt; }
  // Wheel odometry recorded with the images (a bag's nav_msgs/Odometry topic, or its tf from the odom
  // frame to the base frame): T_odom_base samples, stamps strictly increasing, where they came from
  // (for messages) and how ("topic" or "tf"), as `run --odometry FILE` would read them.
  struct Odometry {
    Trajectory T_odom_base;
    std::string source;
    std::string from = "topic";
  };
  virtual std::optional<Odometry> odometry() const { return std::nullopt; }
  // Depth of frame i in metres (z along the optical axis; CV_32FC1 of the camera's size, 0 where
  // there is none), or an empty Mat when the frame has no depth. A transforms.json frame's
  // "depth_path" (instant-ngp) or "depth_file_path" (nerfstudio), a 16-bit or float image scaled by
  // "integer_depth_scale" or "depth_unit_scale_factor" (1e-3 when neither is given: millimetres,
  // nerfstudio's default). Throws an Error naming the file when it is unreadable, of another size,
  // not single-channel, or holds negative or non-finite depths.
  virtual cv::Mat loadDepth(size_t i) const;
  // Ground truth for all frames in order (std::nullopt entries where missing).
  std::vector<std::optional<SE3>> groundTruthAll() const;
};

struct DatasetOptions {
  // Our camera YAML or a ROS camera_info YAML (loadCameraYaml); replaces the dataset's own
  // calibration. Its width/height must match the images.
  std::optional<std::filesystem::path> camera_override;
  // Frame rate giving index / fps timestamps where the layout has no times: an image folder without
  // times.txt / timestamps.txt (0: such a folder is an error), transforms.json frames without
  // "timestamp", Middlebury, Strecha, New Tsukuba (0: 30 fps for these).
  double fps = 0.0;
  // Use at most this many frames (0: all), after `start` frames skipped, taking every `stride`-th.
  size_t start = 0;
  size_t stride = 1;
  size_t max_frames = 0;
  // How the caller's user gives `fps` and `camera_override`, named by the errors that ask for them
  // (the CLI's flags; the ROS publisher's parameters are "~rate" and "~camera").
  std::string fps_option = "--fps";
  std::string camera_option = "--camera";
  // A bag's topics (kind "bag"); empty: detected. The image topic: the only sensor_msgs/Image or
  // CompressedImage topic (several: an error asking for one). camera_info: the only CameraInfo topic,
  // or IMAGE_NAMESPACE/camera_info among several (not read with camera_override). Odometry: the only
  // nav_msgs/Odometry topic (none or several: no odometry). Ground truth: a topic named /groundtruth.
  // A topic named here that the bag does not have is an error.
  std::string image_topic;
  std::string camera_info_topic;
  std::string odometry_topic;
  std::string groundtruth_topic;
  // A bag's tf (topics /tf and /tf_static, tf2_msgs/TFMessage or tf/tfMessage), used when no
  // Odometry topic was chosen or detected: the odometry is the pose of `base_frame` in `odom_frame`
  // over time, chained through the frames between them (static transforms included). Empty: REP-105's
  // odom and base_link when the bag's tf has both; named here: used even when the bag also has an
  // Odometry topic (with odometry_topic too: an error), and a frame the tf does not have is an error.
  std::string odom_frame;
  std::string base_frame;
  // Ground truth from tf, when no ground-truth topic was chosen or detected: the pose of
  // `groundtruth_child_frame` (a camera's optical frame, OpenCV axes) in `groundtruth_parent_frame`.
  // Both empty: none from tf.
  std::string groundtruth_parent_frame;
  std::string groundtruth_child_frame;
};

// All kind names: folder tum euroc kitti transforms middlebury strecha tsukuba video bag.
const std::vector<std::string>& datasetKinds();

// "[kind:]PATH" split into its parts; `kind` is empty when the spec names none (then the layout
// decides). A spec that is itself an existing path is a path, even with a ':' in it. Throws an Error
// for an unknown kind or a missing path.
struct DatasetSpec {
  std::string kind;
  std::filesystem::path path;
};
DatasetSpec parseDatasetSpec(const std::string& spec);

// spec is "[kind:]PATH"; the kind is detected from the layout when omitted. Throws
// nerfslam::Error for an unknown kind (listing the valid ones), a missing path or a bad layout.
std::unique_ptr<Dataset> openDataset(const std::string& spec, const DatasetOptions& opts = {});
std::unique_ptr<Dataset> openDataset(const std::string& kind, const std::filesystem::path& path,
                                     const DatasetOptions& opts = {});

// The kind of the layout at `path`; throws a clear error listing the kinds (and what each needs)
// when nothing matches.
std::string detectDatasetKind(const std::filesystem::path& path);

}  // namespace nerfslam
