// image_folder_publisher: plays any dataset nerfslam reads (image folder, TUM, EuRoC, KITTI,
// transforms.json, Middlebury, Strecha, New Tsukuba) as a ROS camera: image + camera_info, and the
// ground truth on tf and ground_truth_path. Topics and parameters: docs/ros.md
// ("image_folder_publisher"). A bad parameter or an unreadable dataset is a ROS_FATAL naming the
// reason (exit status 1); a frame that cannot be decoded is reported and skipped; a restarted master
// is detected and the topics registered with it again (master_watch.h).
#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>
#include <string>

#include <geometry_msgs/PoseStamped.h>
#include <image_transport/camera_common.h>
#include <image_transport/image_transport.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <tf2_ros/transform_broadcaster.h>

#include "nerfslam/core/error.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam_ros/conversions.h"
#include "nerfslam_ros/master_watch.h"

namespace {

// After the last frame with ~exit_when_done: time for roscpp to send what is queued.
constexpr double kExitLingerSeconds = 1.0;
// With ~wait_for_subscribers: the longest wait for camera_info connections once the image has its.
constexpr double kInfoWaitSeconds = 5.0;

// How many subscribers the master lists for `topic` (0 when the master cannot be asked).
uint32_t registeredSubscribers(const std::string& topic) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  if (!ros::master::execute("getSystemState", args, result, payload, false) ||
      payload.getType() != XmlRpc::XmlRpcValue::TypeArray || payload.size() < 2)
    return 0;
  XmlRpc::XmlRpcValue& subs = payload[1];
  for (int i = 0; i < subs.size(); ++i) {
    if (subs[i].getType() != XmlRpc::XmlRpcValue::TypeArray || subs[i].size() < 2) continue;
    if (subs[i][0].getType() == XmlRpc::XmlRpcValue::TypeString && std::string(subs[i][0]) == topic)
      return static_cast<uint32_t>(subs[i][1].size());
  }
  return 0;
}

struct Params {
  std::string dataset;
  std::string camera;
  double rate = 0.0;
  double speed = 1.0;
  bool loop = false;
  std::string frame_id = "camera_optical_frame";
  int start = 0;
  int max_frames = 0;
  bool color = false;
  bool use_dataset_stamps = false;
  bool publish_ground_truth = false;
  std::string gt_parent_frame = "world";
  std::string gt_child_frame = "camera_ground_truth";
  bool wait_for_subscribers = false;
  int min_subscribers = 1;
  bool exit_when_done = false;
};

const char* const kKnownParams[] = {"dataset",
                                    "camera",
                                    "rate",
                                    "speed",
                                    "loop",
                                    "frame_id",
                                    "start",
                                    "max_frames",
                                    "color",
                                    "use_dataset_stamps",
                                    "publish_ground_truth",
                                    "gt_parent_frame",
                                    "gt_child_frame",
                                    "wait_for_subscribers",
                                    "min_subscribers",
                                    "exit_when_done"};

Params readParams(const ros::NodeHandle& pnh) {
  Params p;
  pnh.param("dataset", p.dataset, p.dataset);
  pnh.param("camera", p.camera, p.camera);
  pnh.param("rate", p.rate, p.rate);
  pnh.param("speed", p.speed, p.speed);
  pnh.param("loop", p.loop, p.loop);
  pnh.param("frame_id", p.frame_id, p.frame_id);
  pnh.param("start", p.start, p.start);
  pnh.param("max_frames", p.max_frames, p.max_frames);
  pnh.param("color", p.color, p.color);
  pnh.param("use_dataset_stamps", p.use_dataset_stamps, p.use_dataset_stamps);
  pnh.param("publish_ground_truth", p.publish_ground_truth, p.publish_ground_truth);
  pnh.param("gt_parent_frame", p.gt_parent_frame, p.gt_parent_frame);
  pnh.param("gt_child_frame", p.gt_child_frame, p.gt_child_frame);
  pnh.param("wait_for_subscribers", p.wait_for_subscribers, p.wait_for_subscribers);
  pnh.param("min_subscribers", p.min_subscribers, p.min_subscribers);
  pnh.param("exit_when_done", p.exit_when_done, p.exit_when_done);

  // Parameters under ~ that we do not know are most likely typos: say so.
  std::vector<std::string> names;
  if (ros::param::getParamNames(names)) {
    const std::string prefix = pnh.getNamespace() + "/";
    for (const auto& n : names) {
      if (n.rfind(prefix, 0) != 0) continue;
      const std::string key = n.substr(prefix.size());
      if (std::find(std::begin(kKnownParams), std::end(kKnownParams), key) == std::end(kKnownParams))
        ROS_WARN("unknown parameter ~%s is ignored (see the parameter list in docs/ros.md)", key.c_str());
    }
  }
  return p;
}

// Returns an empty string when the parameters are valid, else the reason.
std::string validate(const Params& p) {
  if (p.dataset.empty()) return "parameter ~dataset is required (\"[kind:]PATH\")";
  if (!std::isfinite(p.rate) || p.rate < 0.0) return "parameter ~rate must be >= 0 (0 = dataset timestamps)";
  if (!std::isfinite(p.speed) || p.speed <= 0.0) return "parameter ~speed must be > 0";
  if (p.min_subscribers < 1) return "parameter ~min_subscribers must be >= 1";
  if (p.start < 0) return "parameter ~start must be >= 0";
  if (p.max_frames < 0) return "parameter ~max_frames must be >= 0 (0 = all)";
  if (p.frame_id.empty()) return "parameter ~frame_id must not be empty";
  if (p.publish_ground_truth && (p.gt_parent_frame.empty() || p.gt_child_frame.empty()))
    return "parameters ~gt_parent_frame and ~gt_child_frame must not be empty";
  if (p.publish_ground_truth && p.gt_parent_frame == p.gt_child_frame)
    return "parameters ~gt_parent_frame and ~gt_child_frame must differ";
  if (p.use_dataset_stamps && p.loop)
    return "parameters ~use_dataset_stamps and ~loop cannot be combined (stamps would go back in time)";
  return "";
}

void printParams(const Params& p) {
  ROS_INFO("image_folder_publisher parameters:");
  ROS_INFO("  ~dataset              = %s", p.dataset.c_str());
  ROS_INFO("  ~camera               = %s", p.camera.empty() ? "(dataset calibration)" : p.camera.c_str());
  ROS_INFO("  ~rate                 = %g%s", p.rate, p.rate == 0.0 ? " (dataset timestamps)" : " Hz");
  ROS_INFO("  ~speed                = %g", p.speed);
  ROS_INFO("  ~loop                 = %s", p.loop ? "true" : "false");
  ROS_INFO("  ~frame_id             = %s", p.frame_id.c_str());
  ROS_INFO("  ~start                = %d", p.start);
  ROS_INFO("  ~max_frames           = %d%s", p.max_frames, p.max_frames == 0 ? " (all)" : "");
  ROS_INFO("  ~color                = %s", p.color ? "true (bgr8)" : "false (mono8)");
  ROS_INFO("  ~use_dataset_stamps   = %s", p.use_dataset_stamps ? "true" : "false");
  ROS_INFO("  ~publish_ground_truth = %s", p.publish_ground_truth ? "true" : "false");
  ROS_INFO("  ~gt_parent_frame      = %s", p.gt_parent_frame.c_str());
  ROS_INFO("  ~gt_child_frame       = %s", p.gt_child_frame.c_str());
  ROS_INFO("  ~wait_for_subscribers = %s", p.wait_for_subscribers ? "true" : "false");
  ROS_INFO("  ~min_subscribers      = %d", p.min_subscribers);
  ROS_INFO("  ~exit_when_done       = %s", p.exit_when_done ? "true" : "false");
}

// The topics the dataset is played on.
struct Outputs {
  image_transport::Publisher image;
  ros::Publisher info, path;
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf;
  nav_msgs::Path gt_path;
};

// The dataset, or null after a ROS_FATAL saying why.
std::unique_ptr<nerfslam::Dataset> openDataset(const Params& p) {
  nerfslam::DatasetOptions opts;
  if (!p.camera.empty()) opts.camera_override = p.camera;
  // Frames are published every 1/~rate s: a folder without times.txt gets those times.
  if (p.rate > 0) opts.fps = p.rate;
  opts.fps_option = "~rate";
  opts.camera_option = "~camera";
  opts.start = static_cast<size_t>(p.start);
  opts.max_frames = static_cast<size_t>(p.max_frames);
  std::unique_ptr<nerfslam::Dataset> ds;
  try {
    ds = nerfslam::openDataset(p.dataset, opts);
  } catch (const std::exception& e) {
    ROS_FATAL("cannot open dataset '%s': %s", p.dataset.c_str(), e.what());
    return nullptr;
  }
  if (ds->size() == 0) {
    ROS_FATAL("dataset '%s' has no frames after ~start=%d", p.dataset.c_str(), p.start);
    return nullptr;
  }
  ROS_INFO("dataset: %s (%s), %zu frames, %s ground truth; camera %s", ds->root().c_str(), ds->kind().c_str(),
           ds->size(), ds->hasGroundTruth() ? "with" : "without", ds->camera().describe().c_str());
  if (p.publish_ground_truth && !ds->hasGroundTruth())
    ROS_WARN("~publish_ground_truth is set but the dataset has no ground truth: nothing will be published on tf");
  return ds;
}

// ~wait_for_subscribers: ~min_subscribers on the image, then their camera_info connections.
void waitForSubscribers(const Params& p, const Outputs& out) {
  ROS_INFO("waiting for %d subscriber(s) on %s and %s", p.min_subscribers, out.image.getTopic().c_str(),
           out.info.getTopic().c_str());
  const auto min_subscribers = static_cast<uint32_t>(p.min_subscribers);
  while (ros::ok() && out.image.getNumSubscribers() < min_subscribers) ros::WallDuration(0.02).sleep();
  // Then the camera_info connections: a subscriber that pairs the two topics (camera subscribers
  // do) would otherwise miss the first frames when its camera_info connection completes after its
  // image connection (on a loaded machine, seconds later). As many as the master lists for
  // camera_info, but no more than the image has (subscribers of the image alone, viewers and
  // tests, do not hold it back), and at most kInfoWaitSeconds: a node killed without
  // unregistering stays listed.
  const ros::WallTime info_deadline = ros::WallTime::now() + ros::WallDuration(kInfoWaitSeconds);
  auto info_ready = [&] {
    const uint32_t wanted = std::min(registeredSubscribers(out.info.getTopic()), out.image.getNumSubscribers());
    return out.info.getNumSubscribers() >= wanted;
  };
  while (ros::ok() && !info_ready() && ros::WallTime::now() < info_deadline) ros::WallDuration(0.02).sleep();
  if (!info_ready())
    ROS_WARN("%u of the %u subscribers the master lists for %s connected within %g s; publishing anyway",
             out.info.getNumSubscribers(), registeredSubscribers(out.info.getTopic()), out.info.getTopic().c_str(),
             kInfoWaitSeconds);
}

// Publishes frame `i` (image, camera_info, ground truth) with header.seq `seq`.
void publishFrame(const Params& p, const nerfslam::Camera& camera, const nerfslam::DatasetFrame& frame, size_t i,
                  uint32_t seq, Outputs& out) {
  std_msgs::Header header;
  header.frame_id = p.frame_id;
  header.stamp = p.use_dataset_stamps ? ros::Time(frame.timestamp) : ros::Time::now();
  if (p.use_dataset_stamps && header.stamp.isZero())
    ROS_WARN_ONCE(
        "frame %zu has timestamp 0: ROS treats a zero stamp as 'no time' (tf returns the latest "
        "transform); use ~start to skip it or leave ~use_dataset_stamps off",
        i);
  header.seq = seq;
  sensor_msgs::ImagePtr img = nerfslam::rosbridge::toImageMsg(frame.image, header);
  sensor_msgs::CameraInfoPtr info =
      boost::make_shared<sensor_msgs::CameraInfo>(nerfslam::rosbridge::toCameraInfo(camera, header));
  out.image.publish(img);
  out.info.publish(info);
  if (p.publish_ground_truth && frame.T_world_cam) {
    out.tf->sendTransform(
        nerfslam::rosbridge::toTransformStamped(*frame.T_world_cam, p.gt_parent_frame, p.gt_child_frame, header.stamp));
    geometry_msgs::PoseStamped ps;
    ps.header.frame_id = p.gt_parent_frame;
    ps.header.stamp = header.stamp;
    ps.pose = nerfslam::rosbridge::toPose(*frame.T_world_cam);
    out.gt_path.poses.push_back(ps);
    out.gt_path.header.stamp = header.stamp;
    out.path.publish(out.gt_path);
  }
}

struct Playback {
  size_t published = 0, skipped = 0, slot = 0;
};

// One pass over the dataset, each frame at its wall-clock deadline from t0: with ~rate the slots
// count across passes (a skipped frame keeps its slot); with the timestamps the clock restarts
// every pass.
void playPass(const Params& p, nerfslam::Dataset& ds, ros::WallTime t0, Outputs& out, Playback& pb) {
  const nerfslam::ImageMode mode = p.color ? nerfslam::ImageMode::kColor : nerfslam::ImageMode::kGray;
  const double t_first = ds.timestamp(0);
  for (size_t i = 0; i < ds.size() && ros::ok(); ++i) {
    nerfslam::DatasetFrame frame;
    try {
      frame = ds.load(i, mode);
    } catch (const std::exception& e) {
      ROS_ERROR("skipping frame %zu: %s", i, e.what());
      ++pb.skipped;
      ++pb.slot;
      continue;
    }
    const double offset = p.rate > 0.0 ? static_cast<double>(pb.slot) / p.rate : (frame.timestamp - t_first) / p.speed;
    ++pb.slot;
    const ros::WallDuration wait = t0 + ros::WallDuration(offset) - ros::WallTime::now();
    if (wait > ros::WallDuration(0)) wait.sleep();
    if (!ros::ok()) break;
    publishFrame(p, ds.camera(), frame, i, static_cast<uint32_t>(pb.published), out);
    ++pb.published;
    ros::spinOnce();
  }
}

int run(int argc, char** argv) {
  ros::init(argc, argv, "image_folder_publisher");
  ros::NodeHandle nh;
  ros::NodeHandle pnh("~");
  const Params p = readParams(pnh);
  printParams(p);
  if (const std::string why = validate(p); !why.empty()) {
    ROS_FATAL("%s", why.c_str());
    return 1;
  }
  const std::unique_ptr<nerfslam::Dataset> ds = openDataset(p);
  if (!ds) return 1;

  image_transport::ImageTransport it(nh);
  Outputs out;
  // The image and its camera_info on two publishers, so that ~wait_for_subscribers can wait for
  // each topic's connections. camera_info is named from the resolved image topic, as
  // image_transport's CameraPublisher does (image:=/cam/image gives /cam/camera_info).
  out.image = it.advertise("image", 10);
  out.info = nh.advertise<sensor_msgs::CameraInfo>(image_transport::getCameraInfoTopic(out.image.getTopic()), 10);
  out.gt_path.header.frame_id = p.gt_parent_frame;
  if (p.publish_ground_truth) {
    out.path = nh.advertise<nav_msgs::Path>("ground_truth_path", 1, /*latch=*/true);
    out.tf = std::make_unique<tf2_ros::TransformBroadcaster>();
  }
  // Registers the topics again with a restarted master (docs/ros.md, "Faults").
  const nerfslam::rosnode::MasterWatch master_watch;
  if (p.wait_for_subscribers) waitForSubscribers(p, out);

  ros::WallTime t0 = ros::WallTime::now();
  Playback pb;
  size_t pass = 0;
  while (ros::ok()) {
    const size_t published_before = pb.published;
    playPass(p, *ds, t0, out, pb);
    if (!ros::ok()) break;  // interrupted mid-pass
    if (pb.published == published_before) {
      ROS_FATAL("no frame of '%s' could be decoded (%zu frames, all skipped)", p.dataset.c_str(), ds->size());
      return 1;
    }
    ++pass;
    ROS_INFO("pass %zu done: %zu frames published in total, %zu skipped", pass, pb.published, pb.skipped);
    if (!p.loop) break;
    if (p.rate == 0.0) {
      // Next pass one mean frame period after the last frame.
      const double span = ds->timestamp(ds->size() - 1) - ds->timestamp(0);
      const double period = ds->size() > 1 ? span / static_cast<double>(ds->size() - 1) : 1.0 / 30.0;
      t0 += ros::WallDuration((span + period) / p.speed);
    }
    out.gt_path.poses.clear();
  }
  if (!p.exit_when_done && ros::ok()) {
    ROS_INFO("all frames published; idling until shutdown (set ~exit_when_done to exit)");
    ros::spin();
  } else if (ros::ok()) {
    // publish() only queues a message: roscpp's own thread writes it to each subscriber's socket.
    // Exiting at once loses the last frames whenever that thread has not run yet (a loaded
    // machine), and roscpp cannot say when its queues are empty: give it a second.
    ros::WallDuration(kExitLingerSeconds).sleep();
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    ROS_FATAL("image_folder_publisher: %s", e.what());
    return 1;
  }
}
