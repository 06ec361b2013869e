#pragma once
// ROS 1 bags without ROS: datasets read as `--dataset bag:FILE.bag` (io/dataset.h, kind "bag") and
// written from any dataset (`nerfslam bag`), through Debian's librosbag_storage. Only
// src/io/bag/dataset_bag.cpp includes ROS headers; it is compiled when the library is found at
// build time (bagSupported() says so), and without it both directions are an Error saying so.
//
// What writeDatasetBag writes, per frame (bag time = the frame's stamp):
//   image_topic        sensor_msgs/Image (mono8, rgb8, bgr8) or sensor_msgs/CompressedImage
//                      (png, jpeg) of the frame, header.stamp = the frame's timestamp
//   camera_info_topic  sensor_msgs/CameraInfo of the dataset's camera (plumb_bob or equidistant)
//   groundtruth_topic  geometry_msgs/PoseStamped T_world_cam (OpenCV axes), frames with ground truth
//   odometry_topic     nav_msgs/Odometry of every sample of a TUM odometry file (T_odom_base),
//                      the numbers copied as written (so the bag's odometry reads back exactly as
//                      `run --odometry FILE` reads the file)
//   /tf                with odometry_as "tf" (or "both"), the same samples as tf2_msgs/TFMessage,
//                      one transform odom_frame -> base_frame each, instead of (or beside) the topic
// Stamps are written as the 9-decimal rounding of the seconds and read back through the same
// decimal text, so a timestamp with at most 9 decimals comes back as the identical double.
// The bag is written to a temporary file beside `out` and renamed over it when complete.
#include <filesystem>
#include <optional>
#include <string>

#include "nerfslam/io/dataset.h"

namespace nerfslam {

// True when this build reads and writes bags.
bool bagSupported();

struct BagWriteOptions {
  std::string image_topic = "/camera/image_raw";
  std::string camera_info_topic = "/camera/camera_info";
  std::string groundtruth_topic = "/groundtruth";
  std::string odometry_topic = "/odom";
  // mono8, rgb8, bgr8 (sensor_msgs/Image) or png, jpeg (sensor_msgs/CompressedImage).
  std::string encoding = "bgr8";
  int jpeg_quality = 95;
  std::string camera_frame = "camera_optical_frame";
  std::string world_frame = "world";
  std::string odom_frame = "odom";
  std::string base_frame = "base_link";
  // A TUM file of T_odom_base (`nerfslam synth`'s odometry.txt); none: no odometry topic.
  std::optional<std::filesystem::path> odometry;
  // How the odometry is written: "topic" (nav_msgs/Odometry on odometry_topic), "tf" (/tf) or "both".
  std::string odometry_as = "topic";
  bool groundtruth = true;  // write the dataset's ground truth
  bool progress = false;    // a line on stderr every 100 frames
};

// Writes `ds` as a bag at `out`. Throws an Error naming the file for an unknown encoding, an
// unreadable frame or odometry file, or a write that fails (nothing is left at `out` then).
void writeDatasetBag(const Dataset& ds, const std::filesystem::path& out, const BagWriteOptions& options = {});

}  // namespace nerfslam
