// ROS 1 bags (include/nerfslam/io/bag.h): the "bag" dataset kind and writeDatasetBag. The only
// translation unit of the library that includes ROS headers (librosbag_storage and the message
// headers); CMake compiles it, with NERFSLAM_HAVE_ROSBAG, only when librosbag_storage is found.
//
// Opening reads every message of the image topic once (as the video reader decodes once): the
// encoding, the size (the first image's for all), the data's length against step x height, and
// the stamps (header.stamp, strictly increasing); a CompressedImage's format is sniffed from its
// bytes (PNG, JPEG) and its header's size compared. The camera_info topic's first message gives the
// camera; the odometry and ground-truth topics are read whole, and so are /tf and /tf_static when the
// odometry or ground truth may come from tf (TfTree: only the transforms on the chain asked for are
// checked). Every error names the bag, the
// topic and the message's index on its topic. load(i) reads message i again (under a mutex: the
// bag is one file handle) and converts it.
//
// librosbag does not check a damaged bag's record offsets and lengths: a few flipped bytes can make
// it read out of bounds and crash (test/io/bag_test.cpp's damage test found several). So the bag is
// first opened and read once in a forked child process, which notes the topic and message it is
// reading in shared memory; if the child dies, the error names that message and this process never
// reads the damaged record. Opening reads the bag twice for that.
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <set>

#include <sys/mman.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fmt/format.h>
#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <spdlog/spdlog.h>
#include <tf2_msgs/TFMessage.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "../dataset_internal.h"
#include "../image_header.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/bag.h"
#include "nerfslam/io/camera_info.h"
#include "nerfslam/io/image_io.h"

namespace nerfslam {

namespace fs = std::filesystem;

namespace {

constexpr const char* kImage = "sensor_msgs/Image";
constexpr const char* kCompressed = "sensor_msgs/CompressedImage";
constexpr const char* kCameraInfo = "sensor_msgs/CameraInfo";
constexpr const char* kOdometry = "nav_msgs/Odometry";
constexpr const char* kPoseStamped = "geometry_msgs/PoseStamped";
// tf: tf2_msgs/TFMessage and tf's older tf/tfMessage are the same message (the same MD5), read as one.
constexpr const char* kTf2Message = "tf2_msgs/TFMessage";
constexpr const char* kTfMessage = "tf/tfMessage";
const std::vector<std::string> kTfTopics = {"/tf", "/tf_static"};
constexpr int kMaxSide = 16384;

// What the checking child (see the top of the file) is reading; in memory shared with the parent.
struct ReadProbe {
  int stage = 0;  // 0: the bag's index, 1: a message
  char topic[256] = {};
  uint64_t message = 0;
};
ReadProbe* g_probe = nullptr;  // set in the child only

void noteReading(const std::string& topic, size_t message) {
  if (!g_probe) return;
  g_probe->stage = 1;
  const size_t n = std::min(topic.size(), sizeof(g_probe->topic) - 1);
  std::memcpy(g_probe->topic, topic.data(), n);
  g_probe->topic[n] = '\0';
  g_probe->message = message;
}

// Seconds <-> ros::Time through the 9-decimal text (bag.h: a stamp with at most 9 decimals
// comes back as the identical double).
ros::Time toRosTime(double t, const std::string& what) {
  if (!std::isfinite(t) || t < 0.0 || t >= 4294967295.0)
    fail("{}: timestamp {} s cannot be a ROS time (0 .. 2^32 s)", what, numberForMessage(t, 9));
  const std::string s = fmt::format("{:.9f}", t);
  const size_t dot = s.find('.');
  uint32_t sec = 0, nsec = 0;
  std::from_chars(s.data(), s.data() + dot, sec);
  std::from_chars(s.data() + dot + 1, s.data() + s.size(), nsec);
  return ros::Time(sec, nsec);
}

double fromRosTime(const ros::Time& t) {
  const std::string s = fmt::format("{}.{:09d}", t.sec, t.nsec);
  double v = 0.0;
  std::from_chars(s.data(), s.data() + s.size(), v);
  return v;
}

std::string topicList(const std::map<std::string, std::string>& topics) {
  std::string s;
  for (const auto& [topic, type] : topics) s += (s.empty() ? "" : ", ") + topic + " (" + type + ")";
  return s.empty() ? "none" : s;
}

// The same construction as the TUM reader's (io/trajectory.cpp), so the same numbers give the
// identical pose.
SE3 checkedPose(double tx, double ty, double tz, double qx, double qy, double qz, double qw, const std::string& where) {
  for (double v : {tx, ty, tz, qx, qy, qz, qw})
    if (!std::isfinite(v)) fail("{}: field 'pose': a value is not finite ({})", where, numberForMessage(v, 6));
  const double n = std::sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
  if (n == 0.0) fail("{}: field 'pose.orientation': the quaternion is zero", where);
  if (std::abs(n - 1.0) > 1e-3) fail("{}: field 'pose.orientation': not a unit quaternion (norm {:.6g})", where, n);
  return SE3(Eigen::Quaterniond(qw / n, qx / n, qy / n, qz / n), Eigen::Vector3d(tx, ty, tz));
}

// Channels of a raw encoding we read; 0 for a 16-bit or float one (refused with their own
// message), -1 for anything else.
int rawChannels(const std::string& e) {
  if (e == "mono8" || e == "8UC1") return 1;
  if (e == "rgb8" || e == "bgr8" || e == "8UC3") return 3;
  if (e == "rgba8" || e == "bgra8" || e == "8UC4") return 4;
  if (e.find("16") != std::string::npos || e.find("32") != std::string::npos || e.find("64") != std::string::npos)
    return 0;
  return -1;
}

// ---- tf: the bag's transforms (/tf, /tf_static) as a tree of frames, and the pose of one frame
// in another over time.

std::string stripSlash(const std::string& frame) { return !frame.empty() && frame[0] == '/' ? frame.substr(1) : frame; }

// The transforms of a bag's tf topics, as recorded; checked only where a chain uses them, so a bad
// transform between frames nobody asked for does not refuse the bag.
class TfTree {
 public:
  // One recorded transform parent -> child.
  struct Sample {
    ros::Time stamp;
    geometry_msgs::Transform transform;
    std::string topic;
    size_t message = 0;
  };
  struct Link {
    std::string parent, child;
    bool is_static = false;
    std::vector<Sample> samples;  // in the bag's order (a static link: the last one counts)
    // Another parent, or the same child on both tf topics: named when a chain uses this link.
    std::string conflict;
  };

  TfTree(const rosbag::Bag& bag, const fs::path& file, const std::map<std::string, std::string>& topics) : file_(file) {
    for (const std::string& topic : kTfTopics) {
      auto it = topics.find(topic);
      if (it == topics.end()) continue;
      if (it->second != kTf2Message && it->second != kTfMessage) {
        spdlog::warn("{}: topic '{}' is a {}, not a {} or {}: not read as tf", file_.string(), topic, it->second,
                     kTf2Message, kTfMessage);
        continue;
      }
      topics_.push_back(topic);
      read(bag, topic, topic == "/tf_static");
    }
  }

  bool empty() const { return topics_.empty(); }
  bool hasFrame(const std::string& f) const { return frames_.count(f) > 0; }
  std::string topicsText() const { return fmt::format("{}", fmt::join(topics_, ", ")); }

  // The pose of `child` in `parent` (T_parent_child) at the stamps of the chain's moving transforms
  // (where they overlap; a moving link between its samples is interpolated as tf2 does). `what` names
  // the use ("odometry", "ground truth") and `option` the flag choosing the frames, for messages.
  // Throws an Error naming the bag, the tf topic, the message and the frames for a frame the tf does
  // not have, a broken chain, a frame with two parents, stamps going back, a non-finite value or a
  // non-unit quaternion.
  Trajectory chain(const std::string& parent, const std::string& child, const std::string& what,
                   const std::string& option) const {
    const std::string pair = fmt::format("'{}' -> '{}'", parent, child);
    for (const std::string& f : {parent, child})
      if (!hasFrame(f))
        fail("{}: {} {} ({}): the bag's tf ({}) has no frame '{}'; its frames: {}", file_.string(), what, pair, option,
             topicsText(), cutForMessage(f), frameList());
    if (parent == child) fail("{}: {} {} ({}): the two frames are the same", file_.string(), what, pair, option);
    // Each frame up to its root; the chain meets where they first share a frame.
    const std::vector<std::string> up_child = ancestors(child, what, pair), up_parent = ancestors(parent, what, pair);
    std::string meet;
    for (const std::string& f : up_child)
      if (std::find(up_parent.begin(), up_parent.end(), f) != up_parent.end()) {
        meet = f;
        break;
      }
    if (meet.empty())
      fail(
          "{}: {} {} ({}): the chain is broken: no transforms link the two frames in the bag's tf ({}); '{}' goes up "
          "to {}, '{}' up to {}",
          file_.string(), what, pair, option, topicsText(), child, path(up_child), parent, path(up_parent));
    // The links from the meeting frame down to each end, checked.
    std::vector<const Link*> to_child, to_parent;
    for (size_t k = 0; up_child[k] != meet; ++k) to_child.push_back(&checkedLink(up_child[k]));
    for (size_t k = 0; up_parent[k] != meet; ++k) to_parent.push_back(&checkedLink(up_parent[k]));

    std::vector<const Link*> moving;
    for (const auto* chain : {&to_child, &to_parent})
      for (const Link* l : *chain)
        if (!l->is_static) moving.push_back(l);
    if (moving.empty())
      fail("{}: {} {} ({}): every transform between the two frames is static (/tf_static): no motion over time",
           file_.string(), what, pair, option);
    // The stamps: the moving links' own, where all of them have samples.
    double begin = -std::numeric_limits<double>::infinity(), end = std::numeric_limits<double>::infinity();
    std::vector<double> stamps;
    for (const Link* l : moving) {
      const std::vector<TimedPose>& poses = posesOf(*l);
      begin = std::max(begin, poses.front().t);
      end = std::min(end, poses.back().t);
      for (const TimedPose& p : poses) stamps.push_back(p.t);
    }
    std::sort(stamps.begin(), stamps.end());
    stamps.erase(std::unique(stamps.begin(), stamps.end()), stamps.end());
    Trajectory out;
    for (double t : stamps) {
      if (t < begin || t > end) continue;
      // T_meet_child and T_meet_parent: the links' poses multiplied from the meeting frame down (none
      // on a side: the meeting frame is that end itself, and nothing is multiplied, so a single
      // moving link parent -> child gives its recorded poses unchanged).
      auto down = [&](const std::vector<const Link*>& links) -> std::optional<SE3> {
        std::optional<SE3> T;
        for (auto it = links.rbegin(); it != links.rend(); ++it) {
          const SE3 P = poseAt(**it, t);
          T = T ? *T * P : P;
        }
        return T;
      };
      const std::optional<SE3> T_meet_child = down(to_child), T_meet_parent = down(to_parent);
      SE3 T = T_meet_child ? *T_meet_child : SE3();
      if (T_meet_parent) T = T_meet_parent->inverse() * T;
      out.push_back({t, T});
    }
    if (out.size() < 2)
      fail("{}: {} {} ({}): the moving transforms of the chain overlap in {} stamp(s), at least 2 needed",
           file_.string(), what, pair, option, out.size());
    return out;
  }

 private:
  struct TimedPose {
    double t;
    SE3 pose;
  };

  void read(const rosbag::Bag& bag, const std::string& topic, bool is_static) {
    try {
      rosbag::View view(bag, rosbag::TopicQuery(topic));
      size_t k = 0;
      for (const rosbag::MessageInstance& m : view) {
        noteReading(topic, k);
        const std::string where = fmt::format("{}: topic '{}', message {}", file_.string(), topic, k);
        const auto p = m.instantiate<tf2_msgs::TFMessage>();
        if (!p) fail("{}: the message is not a {} (its type: {})", where, kTf2Message, m.getDataType());
        for (const geometry_msgs::TransformStamped& ts : p->transforms) {
          const std::string parent = stripSlash(ts.header.frame_id), child = stripSlash(ts.child_frame_id);
          if (parent.empty() || child.empty()) continue;  // tf2 ignores these too
          frames_.insert(parent);
          frames_.insert(child);
          Link& l = links_[child];
          if (l.samples.empty()) {
            l.parent = parent;
            l.child = child;
            l.is_static = is_static;
          } else if (l.conflict.empty() && (l.parent != parent || l.is_static != is_static)) {
            const Sample& first = l.samples.front();
            l.conflict = l.parent != parent
                             ? fmt::format(
                                   "frame '{}' has two parents, '{}' (topic '{}', message {}) and '{}' (topic "
                                   "'{}', message {})",
                                   child, l.parent, first.topic, first.message, parent, topic, k)
                             : fmt::format("the transform '{}' -> '{}' is on both '{}' and '{}'", parent, child,
                                           first.topic, topic);
          }
          if (l.parent == parent && l.is_static == is_static)
            l.samples.push_back({ts.header.stamp, ts.transform, topic, k});
        }
        ++k;
      }
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      fail("{}: topic '{}': the bag cannot be read ({})", file_.string(), topic, e.what());
    }
  }

  // `frame` and its parents up to the root; a link on the way that is recorded with two parents is
  // an error (`what` and `pair` name the chain asked for).
  std::vector<std::string> ancestors(const std::string& frame, const std::string& what, const std::string& pair) const {
    std::vector<std::string> up{frame};
    for (auto it = links_.find(frame); it != links_.end(); it = links_.find(it->second.parent)) {
      if (!it->second.conflict.empty())
        fail("{}: {} {}: {} in the bag's tf", file_.string(), what, pair, it->second.conflict);
      if (std::find(up.begin(), up.end(), it->second.parent) != up.end())
        fail("{}: the bag's tf ({}) has a loop: {} -> '{}'", file_.string(), topicsText(), path(up), it->second.parent);
      up.push_back(it->second.parent);
    }
    return up;
  }

  static std::string path(const std::vector<std::string>& frames) {
    std::string s;
    for (const auto& f : frames) s += (s.empty() ? "'" : " -> '") + f + "'";
    return s + (frames.size() == 1 ? " (no parent)" : "");
  }

  std::string frameList() const {
    std::string s;
    size_t n = 0;
    for (const auto& f : frames_) {
      if (++n > 30) return s + fmt::format(", ... ({} frames)", frames_.size());
      s += (s.empty() ? "" : ", ") + f;
    }
    return s.empty() ? "none" : s;
  }

  // The link from `child` to its parent, its samples checked (once): finite values, unit
  // quaternions, stamps that do not go back (a repeated stamp is dropped, as tf2 does).
  const Link& checkedLink(const std::string& child) const {
    const Link& l = links_.at(child);  // its conflicts: ancestors() named them
    posesOf(l);
    return l;
  }

  const std::vector<TimedPose>& posesOf(const Link& l) const {
    auto it = poses_.find(&l);
    if (it != poses_.end()) return it->second;
    std::vector<TimedPose> poses;
    size_t repeated = 0;
    const std::string& child = l.child;
    for (const Sample& s : l.samples) {
      const std::string where = fmt::format("{}: topic '{}', message {}, transform '{}' -> '{}'", file_.string(),
                                            s.topic, s.message, l.parent, child);
      if (s.stamp.nsec >= 1000000000u) fail("{}: field 'header.stamp': nsec {} >= 1e9", where, s.stamp.nsec);
      const double t = fromRosTime(s.stamp);
      const geometry_msgs::Transform& tr = s.transform;
      SE3 pose;
      try {
        pose = checkedPose(tr.translation.x, tr.translation.y, tr.translation.z, tr.rotation.x, tr.rotation.y,
                           tr.rotation.z, tr.rotation.w, where);
      } catch (const Error& e) {
        // checkedPose names the Odometry message's fields; a transform's are translation and rotation.
        std::string m = e.what();
        for (const auto& [from, to] :
             {std::pair<std::string, std::string>{"'pose.orientation'", "'transform.rotation'"},
              {"'pose'", "'transform'"}})
          if (auto p = m.find(from); p != std::string::npos) m.replace(p, from.size(), to);
        throw Error(m);
      }
      if (l.is_static) {
        poses = {{t, pose}};  // the last one published counts
        continue;
      }
      if (!poses.empty() && t < poses.back().t)
        fail("{}: field 'header.stamp': {} s is before the previous transform's ({} s): stamps go back", where,
             numberForMessage(t, 9), numberForMessage(poses.back().t, 9));
      if (!poses.empty() && t == poses.back().t) {
        ++repeated;
        continue;
      }
      poses.push_back({t, pose});
    }
    if (repeated > 0)
      spdlog::warn("{}: tf '{}' -> '{}': {} transform(s) with the stamp of the one before ignored (as tf2 does)",
                   file_.string(), l.parent, child, repeated);
    return poses_.emplace(&l, std::move(poses)).first->second;
  }

  // A link's pose at t: a static one's always; a moving one's sample at t, or interpolated between
  // the two around it (t is within its samples: chain() takes the overlap).
  SE3 poseAt(const Link& l, double t) const {
    const std::vector<TimedPose>& p = posesOf(l);
    if (l.is_static) return p.front().pose;
    auto it = std::lower_bound(p.begin(), p.end(), t, [](const TimedPose& a, double v) { return a.t < v; });
    if (it->t == t) return it->pose;
    // As tf2 does: the translation linearly, the rotation by slerp.
    const TimedPose& a = *(it - 1);
    const double s = (t - a.t) / (it->t - a.t);
    return SE3(a.pose.rotation().slerp(s, it->pose.rotation()),
               (1.0 - s) * a.pose.translation() + s * it->pose.translation());
  }

  fs::path file_;
  std::vector<std::string> topics_;
  std::set<std::string> frames_;
  std::map<std::string, Link> links_;  // by child frame
  mutable std::map<const Link*, std::vector<TimedPose>> poses_;
};

class BagDataset : public Dataset {
 public:
  BagDataset(fs::path file, const DatasetOptions& opts) : file_(std::move(file)) {
    if (opts.stride == 0) fail("dataset options: field 'stride': must be >= 1");
    try {
      bag_.open(file_.string(), rosbag::bagmode::Read);
    } catch (const std::exception& e) {
      fail("{}: not a readable ROS bag ({})", file_.string(), e.what());
    }
    std::map<std::string, std::string> topics;  // topic -> datatype
    try {
      rosbag::View all(bag_);
      for (const rosbag::ConnectionInfo* c : all.getConnections()) topics[c->topic] = c->datatype;
    } catch (const std::exception& e) {
      fail("{}: cannot read the bag's index ({})", file_.string(), e.what());
    }
    image_topic_ = chooseImageTopic(topics, opts.image_topic);
    compressed_ = topics.at(image_topic_) == kCompressed;
    readImageHeaders(opts);

    std::string camera_source;
    if (opts.camera_override) {
      camera_ = loadCameraYaml(*opts.camera_override);
      camera_source = opts.camera_override->string();
    } else {
      const std::string topic = chooseCameraInfoTopic(topics, opts);
      camera_source = fmt::format("{}: topic '{}', message 0", file_.string(), topic);
      camera_ = readCamera(topic, camera_source);
    }
    if (camera_.width != width_ || camera_.height != height_)
      fail("{}: camera is {}x{} but the images on topic '{}' of {} are {}x{}", camera_source, camera_.width,
           camera_.height, image_topic_, file_.string(), width_, height_);
    camera_.validate(camera_source);

    // Odometry: a nav_msgs/Odometry topic (named, or the only one), else tf (the frames named, or
    // REP-105's odom and base_link when the tf has both). Named frames win over a detected topic.
    const bool frames_named = !opts.odom_frame.empty() || !opts.base_frame.empty();
    if (frames_named && !opts.odometry_topic.empty())
      fail("{}: --odometry-topic '{}' and --odometry-frames both given: the odometry comes from one of them",
           file_.string(), cutForMessage(opts.odometry_topic));
    std::string odo_topic = opts.odometry_topic;
    bool ambiguous = false;
    if (!odo_topic.empty()) {
      requireTopic(topics, odo_topic, {kOdometry}, "--odometry-topic");
    } else if (!frames_named) {
      std::vector<std::string> found;
      for (const auto& [t, type] : topics)
        if (type == kOdometry && t != opts.groundtruth_topic && t != "/groundtruth") found.push_back(t);
      if (found.size() == 1) odo_topic = found[0];
      if (found.size() > 1) {
        ambiguous = true;
        spdlog::warn(
            "{}: several nav_msgs/Odometry topics ({}): no odometry used; choose one with --odometry-topic (or tf "
            "frames with --odometry-frames)",
            file_.string(), fmt::join(found, ", "));
      }
    }
    // The tf, read when it may be used.
    const bool gt_frames = !opts.groundtruth_parent_frame.empty() || !opts.groundtruth_child_frame.empty();
    std::optional<TfTree> tf_tree;
    if ((odo_topic.empty() && !ambiguous) || gt_frames) tf_tree.emplace(bag_, file_, topics);
    std::string odo_what = "none";
    if (!odo_topic.empty()) {
      readOdometry(odo_topic);
      odo_what = fmt::format("topic '{}' ({} samples)", odo_topic, odometry_->T_odom_base.size());
    } else if (!ambiguous) {
      const TfTree& tf = *tf_tree;
      const std::string odom = opts.odom_frame.empty() ? "odom" : opts.odom_frame;
      const std::string base = opts.base_frame.empty() ? "base_link" : opts.base_frame;
      if (frames_named && tf.empty())
        fail("{}: --odometry-frames {},{}: the bag has no tf topic (/tf, /tf_static); its topics: {}", file_.string(),
             cutForMessage(odom), cutForMessage(base), topicList(topics));
      if (frames_named || (tf.hasFrame(odom) && tf.hasFrame(base))) {
        Trajectory t = tf.chain(odom, base, "odometry", "--odometry-frames");
        odometry_ = Odometry{std::move(t), fmt::format("{}:tf {} -> {}", file_.string(), odom, base), "tf"};
        odo_what =
            fmt::format("tf '{}' -> '{}' ({}; {} samples)", odom, base, tf.topicsText(), odometry_->T_odom_base.size());
      }
    }

    // Ground truth: a topic (named, or /groundtruth), else tf frames when named (they win over
    // /groundtruth).
    if (gt_frames && (opts.groundtruth_parent_frame.empty() || opts.groundtruth_child_frame.empty()))
      fail("{}: --groundtruth-frames needs two frames, PARENT,CAMERA", file_.string());
    if (gt_frames && !opts.groundtruth_topic.empty())
      fail("{}: --groundtruth-topic '{}' and --groundtruth-frames both given: the ground truth comes from one of them",
           file_.string(), cutForMessage(opts.groundtruth_topic));
    std::string gt_topic = opts.groundtruth_topic;
    if (!gt_topic.empty())
      requireTopic(topics, gt_topic, {kPoseStamped, kOdometry}, "--groundtruth-topic");
    else if (!gt_frames && topics.count("/groundtruth") &&
             (topics.at("/groundtruth") == kPoseStamped || topics.at("/groundtruth") == kOdometry))
      gt_topic = "/groundtruth";
    std::string gt_what = "none";
    if (!gt_topic.empty()) {
      readGroundTruth(readPoses(gt_topic));
      gt_what = "topic '" + gt_topic + "'";
    } else if (gt_frames) {
      const std::string& parent = opts.groundtruth_parent_frame;
      const std::string& child = opts.groundtruth_child_frame;
      const TfTree& tf = *tf_tree;
      if (tf.empty())
        fail("{}: --groundtruth-frames {},{}: the bag has no tf topic (/tf, /tf_static); its topics: {}",
             file_.string(), cutForMessage(parent), cutForMessage(child), topicList(topics));
      readGroundTruth(tf.chain(parent, child, "ground truth", "--groundtruth-frames"));
      gt_what = fmt::format("tf '{}' -> '{}'", parent, child);
    }

    spdlog::info("opened bag {}: {} frames on '{}' ({}), {}x{}, {:.3f} .. {:.3f} s; odometry {}; ground truth {}",
                 file_.string(), frames_.size(), image_topic_, compressed_ ? "compressed" : "raw", width_, height_,
                 frames_.front().t, frames_.back().t, odo_what, has_gt_ ? gt_what : "none");
  }

  std::string kind() const override { return "bag"; }
  const fs::path& root() const override { return file_; }
  const Camera& camera() const override { return camera_; }
  size_t size() const override { return frames_.size(); }
  double timestamp(size_t i) const override { return at(i).t; }
  std::string imagePath(size_t i) const override {
    return fmt::format("{}:{}#{}", file_.string(), image_topic_, at(i).message);
  }
  std::optional<SE3> groundTruth(size_t i) const override { return at(i).gt; }
  bool hasGroundTruth() const override { return has_gt_; }
  std::optional<Odometry> odometry() const override { return odometry_; }

  DatasetFrame load(size_t i, ImageMode mode) const override {
    const Frame& fr = at(i);
    DatasetFrame f;
    f.index = i;
    f.timestamp = fr.t;
    f.T_world_cam = fr.gt;
    f.path = imagePath(i);
    const std::string where = fmt::format("{}: topic '{}', message {}", file_.string(), image_topic_, fr.message);
    if (compressed_) {
      sensor_msgs::CompressedImage::ConstPtr m;
      {
        std::lock_guard<std::mutex> lk(mutex_);
        m = instantiate<sensor_msgs::CompressedImage>(fr.instance, where);
      }
      f.image = decodeImage(m->data, mode, where);
    } else {
      sensor_msgs::Image::ConstPtr m;
      {
        std::lock_guard<std::mutex> lk(mutex_);
        m = instantiate<sensor_msgs::Image>(fr.instance, where);
      }
      checkRaw(*m, where);
      f.image = convertRaw(*m, mode);
    }
    if (f.image.cols != camera_.width || f.image.rows != camera_.height)
      fail("{}: the image is {}x{} but the bag's images (and camera) are {}x{}", where, f.image.cols, f.image.rows,
           camera_.width, camera_.height);
    return f;
  }

 private:
  struct Frame {
    rosbag::MessageInstance instance;
    size_t message = 0;  // index on the image topic
    double t = 0.0;
    std::optional<SE3> gt;
  };

  const Frame& at(size_t i) const {
    if (i >= frames_.size())
      fail("bag dataset {}: frame index {} out of range (size {})", file_.string(), i, frames_.size());
    return frames_[i];
  }

  template <class T>
  boost::shared_ptr<T> instantiate(const rosbag::MessageInstance& m, const std::string& where) const {
    boost::shared_ptr<T> p;
    try {
      p = m.instantiate<T>();
    } catch (const std::exception& e) {
      fail("{}: the message cannot be read ({})", where, e.what());
    }
    if (!p)
      fail("{}: the message is not a {} (its type: {}, MD5 {})", where, ros::message_traits::DataType<T>::value(),
           m.getDataType(), m.getMD5Sum());
    return p;
  }

  void requireTopic(const std::map<std::string, std::string>& topics, const std::string& topic,
                    const std::vector<std::string>& types, const std::string& option) const {
    auto it = topics.find(topic);
    if (it == topics.end())
      fail("{}: no topic '{}' ({}); the bag's topics: {}", file_.string(), cutForMessage(topic), option,
           topicList(topics));
    if (std::find(types.begin(), types.end(), it->second) == types.end())
      fail("{}: topic '{}' ({}) is a {}, not a {}", file_.string(), topic, option, it->second,
           fmt::join(types, " or "));
  }

  std::string chooseImageTopic(const std::map<std::string, std::string>& topics, const std::string& wanted) const {
    if (!wanted.empty()) {
      requireTopic(topics, wanted, {kImage, kCompressed}, "--image-topic");
      return wanted;
    }
    std::vector<std::string> found;
    for (const auto& [t, type] : topics)
      if (type == kImage || type == kCompressed) found.push_back(t);
    if (found.empty())
      fail("{}: no sensor_msgs/Image or sensor_msgs/CompressedImage topic; the bag's topics: {}", file_.string(),
           topicList(topics));
    if (found.size() > 1)
      fail("{}: several image topics ({}): choose one with --image-topic", file_.string(), fmt::join(found, ", "));
    return found[0];
  }

  std::string chooseCameraInfoTopic(const std::map<std::string, std::string>& topics,
                                    const DatasetOptions& opts) const {
    if (!opts.camera_info_topic.empty()) {
      requireTopic(topics, opts.camera_info_topic, {kCameraInfo}, "--camera-info-topic");
      return opts.camera_info_topic;
    }
    std::vector<std::string> found;
    for (const auto& [t, type] : topics)
      if (type == kCameraInfo) found.push_back(t);
    if (found.size() == 1) return found[0];
    const std::string ns = image_topic_.substr(0, image_topic_.rfind('/'));
    if (std::find(found.begin(), found.end(), ns + "/camera_info") != found.end()) return ns + "/camera_info";
    if (found.empty())
      fail("{}: no sensor_msgs/CameraInfo topic: give a camera YAML ({})", file_.string(), opts.camera_option);
    fail("{}: several camera_info topics ({}): choose one with --camera-info-topic (or give {})", file_.string(),
         fmt::join(found, ", "), opts.camera_option);
  }

  // Encoding, size and data length of a raw image message.
  void checkRaw(const sensor_msgs::Image& m, const std::string& where) const {
    const int ch = rawChannels(m.encoding);
    if (ch == 0)
      fail("{}: encoding '{}': 16-bit and floating-point images are not supported (mono8, rgb8, bgr8, rgba8, bgra8)",
           where, cutForMessage(m.encoding));
    if (ch < 0)
      fail("{}: unsupported encoding '{}' (mono8, rgb8, bgr8, rgba8, bgra8, or a sensor_msgs/CompressedImage)", where,
           cutForMessage(m.encoding));
    if (m.width == 0 || m.height == 0 || m.width > kMaxSide || m.height > kMaxSide)
      fail("{}: image size {}x{} is empty or larger than {} a side", where, m.width, m.height, kMaxSide);
    const uint64_t row = uint64_t{m.width} * ch;
    if (m.step < row) fail("{}: field 'step': {} is less than width x channels ({})", where, m.step, row);
    const uint64_t need = uint64_t{m.step} * (m.height - 1) + row;
    if (m.data.size() < need)
      fail("{}: field 'data': {} bytes, the image needs {} (step {}, height {})", where, m.data.size(), need, m.step,
           m.height);
  }

  static cv::Mat convertRaw(const sensor_msgs::Image& m, ImageMode mode) {
    const int ch = rawChannels(m.encoding);
    const cv::Mat view(static_cast<int>(m.height), static_cast<int>(m.width), CV_8UC(ch),
                       const_cast<uint8_t*>(m.data.data()), m.step);
    const bool rgb = m.encoding == "rgb8" || m.encoding == "rgba8";
    cv::Mat out;
    if (ch == 1) {
      if (mode == ImageMode::kColor)
        cv::cvtColor(view, out, cv::COLOR_GRAY2BGR);
      else
        out = view.clone();
    } else if (ch == 3) {
      if (mode == ImageMode::kGray)
        cv::cvtColor(view, out, rgb ? cv::COLOR_RGB2GRAY : cv::COLOR_BGR2GRAY);
      else if (rgb)
        cv::cvtColor(view, out, cv::COLOR_RGB2BGR);
      else
        out = view.clone();
    } else {
      if (mode == ImageMode::kGray)
        cv::cvtColor(view, out, rgb ? cv::COLOR_RGBA2GRAY : cv::COLOR_BGRA2GRAY);
      else if (mode == ImageMode::kColor)
        cv::cvtColor(view, out, rgb ? cv::COLOR_RGBA2BGR : cv::COLOR_BGRA2BGR);
      else if (rgb)
        cv::cvtColor(view, out, cv::COLOR_RGBA2BGRA);
      else
        out = view.clone();
    }
    return out;
  }

  // Reads every image message once: encoding, size, data, stamps (see the file's comment).
  void readImageHeaders(const DatasetOptions& opts) {
    std::vector<Frame> all;
    double prev = 0.0;
    try {
      rosbag::View view(bag_, rosbag::TopicQuery(image_topic_));
      size_t k = 0;
      for (const rosbag::MessageInstance& m : view) {
        const std::string where = fmt::format("{}: topic '{}', message {}", file_.string(), image_topic_, k);
        noteReading(image_topic_, k);
        int w = -1, h = -1;
        std_msgs::Header header;
        if (compressed_) {
          const auto p = instantiate<sensor_msgs::CompressedImage>(m, where);
          header = p->header;
          const std::string& fmt_s = p->format;
          if (fmt_s.find("16") != std::string::npos)
            fail("{}: format '{}': 16-bit images are not supported", where, cutForMessage(fmt_s));
          const auto sniff = io_detail::sniffImageHeader(p->data);
          if (!sniff ||
              (sniff->format != io_detail::ImageFormat::kPng && sniff->format != io_detail::ImageFormat::kJpeg))
            fail("{}: format '{}': the data is not a PNG or JPEG image", where, cutForMessage(fmt_s));
          w = static_cast<int>(std::clamp<int64_t>(sniff->width, -1, kMaxSide + 1));
          h = static_cast<int>(std::clamp<int64_t>(sniff->height, -1, kMaxSide + 1));
          if (w < 0 || h < 0) fail("{}: the {} header gives no image size", where, imageFormatName(sniff->format));
          if (w == 0 || h == 0 || w > kMaxSide || h > kMaxSide)
            fail("{}: image size {}x{} is empty or larger than {} a side", where, w, h, kMaxSide);
        } else {
          const auto p = instantiate<sensor_msgs::Image>(m, where);
          header = p->header;
          checkRaw(*p, where);
          w = static_cast<int>(p->width);
          h = static_cast<int>(p->height);
        }
        if (k == 0) {
          width_ = w;
          height_ = h;
        } else if (w != width_ || h != height_) {
          fail("{}: the image is {}x{}, the first one (message 0) is {}x{}: the image size changes mid-bag", where, w,
               h, width_, height_);
        }
        if (header.stamp.nsec >= 1000000000u)
          fail("{}: field 'header.stamp': nsec {} >= 1e9", where, header.stamp.nsec);
        const double t = fromRosTime(header.stamp);
        if (k > 0 && !(t > prev))
          fail("{}: field 'header.stamp': {} s is not after the previous message's ({} s): stamps go back", where,
               numberForMessage(t, 9), numberForMessage(prev, 9));
        prev = t;
        all.push_back({m, k, t, std::nullopt});
        ++k;
      }
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      fail("{}: topic '{}': the bag cannot be read ({})", file_.string(), image_topic_, e.what());
    }
    if (all.empty()) fail("{}: topic '{}' has no messages", file_.string(), image_topic_);
    for (size_t i = opts.start; i < all.size(); i += opts.stride) {
      if (opts.max_frames > 0 && frames_.size() >= opts.max_frames) break;
      frames_.push_back(all[i]);
    }
    if (frames_.empty())
      fail("bag dataset {}: no frames left after skipping the first {} of {}", file_.string(), opts.start, all.size());
  }

  Camera readCamera(const std::string& topic, const std::string& source) const {
    try {
      rosbag::View view(bag_, rosbag::TopicQuery(topic));
      noteReading(topic, 0);
      for (const rosbag::MessageInstance& m : view)
        return cameraFromCameraInfo(*instantiate<sensor_msgs::CameraInfo>(m, source), source);
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      fail("{}: the bag cannot be read ({})", source, e.what());
    }
    fail("{}: topic '{}' has no messages: give a camera YAML (--camera)", file_.string(), topic);
  }

  // Poses of an Odometry or PoseStamped topic, stamps strictly increasing.
  Trajectory readPoses(const std::string& topic) const {
    Trajectory out;
    try {
      rosbag::View view(bag_, rosbag::TopicQuery(topic));
      size_t k = 0;
      for (const rosbag::MessageInstance& m : view) {
        noteReading(topic, k);
        const std::string where = fmt::format("{}: topic '{}', message {}", file_.string(), topic, k++);
        std_msgs::Header header;
        geometry_msgs::Pose pose;
        if (m.getDataType() == kOdometry) {
          const auto p = instantiate<nav_msgs::Odometry>(m, where);
          header = p->header;
          pose = p->pose.pose;
        } else {
          const auto p = instantiate<geometry_msgs::PoseStamped>(m, where);
          header = p->header;
          pose = p->pose;
        }
        if (header.stamp.nsec >= 1000000000u)
          fail("{}: field 'header.stamp': nsec {} >= 1e9", where, header.stamp.nsec);
        const double t = fromRosTime(header.stamp);
        if (!out.empty() && !(t > out.back().timestamp))
          fail("{}: field 'header.stamp': {} s is not after the previous message's ({} s): stamps go back", where,
               numberForMessage(t, 9), numberForMessage(out.back().timestamp, 9));
        out.push_back({t, checkedPose(pose.position.x, pose.position.y, pose.position.z, pose.orientation.x,
                                      pose.orientation.y, pose.orientation.z, pose.orientation.w, where)});
      }
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      fail("{}: topic '{}': the bag cannot be read ({})", file_.string(), topic, e.what());
    }
    return out;
  }

  void readOdometry(const std::string& topic) {
    Trajectory t = readPoses(topic);
    if (t.size() < 2)
      fail("{}: topic '{}': {} odometry message(s), at least 2 needed", file_.string(), topic, t.size());
    odometry_ = Odometry{std::move(t), fmt::format("{}:{}", file_.string(), topic)};
  }

  void readGroundTruth(const Trajectory& poses) {
    std::vector<io_detail::TimedPose> gt;
    for (const auto& e : poses) gt.push_back({e.timestamp, e.pose});
    for (Frame& f : frames_) {
      f.gt = io_detail::interpolatePose(gt, f.t, 0.02);
      has_gt_ = has_gt_ || f.gt.has_value();
    }
  }

  fs::path file_;
  rosbag::Bag bag_;
  std::string image_topic_;
  bool compressed_ = false;
  int width_ = 0, height_ = 0;
  Camera camera_;
  std::vector<Frame> frames_;
  bool has_gt_ = false;
  std::optional<Odometry> odometry_;
  mutable std::mutex mutex_;
};

}  // namespace

namespace io_detail {

namespace {

// Reads the bag in a child process first (see the top of the file); an Error naming the message
// whose reading crashed it.
void checkBagInChild(const fs::path& file, const DatasetOptions& opts) {
  void* mem = mmap(nullptr, sizeof(ReadProbe), PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1, 0);
  if (mem == MAP_FAILED) fail("{}: cannot check the bag (mmap: {})", file.string(), std::strerror(errno));
  ReadProbe* probe = new (mem) ReadProbe();
  std::fflush(stdout);
  std::fflush(stderr);
  const pid_t pid = fork();
  if (pid < 0) {
    munmap(mem, sizeof(ReadProbe));
    fail("{}: cannot check the bag (fork: {})", file.string(), std::strerror(errno));
  }
  if (pid == 0) {
    g_probe = probe;
    spdlog::set_level(spdlog::level::off);
    try {
      BagDataset ds(file, opts);
    } catch (...) {
    }
    _exit(0);
  }
  int status = 0;
  while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  const ReadProbe seen = *probe;
  munmap(mem, sizeof(ReadProbe));
  if (WIFEXITED(status) && WEXITSTATUS(status) == 0) return;
  const std::string how = WIFSIGNALED(status) ? fmt::format("signal {}", WTERMSIG(status))
                                              : fmt::format("exit status {}", WEXITSTATUS(status));
  if (seen.stage == 0) fail("{}: the bag is damaged: reading its index crashed librosbag ({})", file.string(), how);
  fail("{}: topic '{}', message {}: the message's record is damaged: reading it crashed librosbag ({})", file.string(),
       seen.topic, seen.message, how);
}

}  // namespace

std::unique_ptr<Dataset> openBag(const fs::path& file, const DatasetOptions& opts) {
  std::error_code ec;
  if (fs::is_directory(file, ec)) fail("{}: is a directory, not a ROS bag", file.string());
  checkBagInChild(file, opts);
  return std::make_unique<BagDataset>(file, opts);
}

}  // namespace io_detail

bool bagSupported() { return true; }

void writeDatasetBag(const Dataset& ds, const fs::path& out, const BagWriteOptions& o) {
  const std::string& enc = o.encoding;
  if (o.odometry_as != "topic" && o.odometry_as != "tf" && o.odometry_as != "both")
    fail("{}: field 'odometry_as': '{}' is not one of topic, tf, both", out.string(), cutForMessage(o.odometry_as));
  const bool compressed = enc == "png" || enc == "jpeg";
  if (!compressed && enc != "mono8" && enc != "rgb8" && enc != "bgr8")
    fail("{}: field 'encoding': '{}' is not one of mono8, rgb8, bgr8, png, jpeg", out.string(), cutForMessage(enc));
  // The odometry file: checked by the TUM reader first (file and line in its errors), then its
  // numbers copied as written.
  std::vector<std::vector<double>> odo;
  if (o.odometry) {
    const Trajectory checked = readTumTrajectory(*o.odometry);
    for (const auto& line : io_detail::readDataLines(*o.odometry))
      odo.push_back(io_detail::parseNumbers(line, *o.odometry, 8, "odometry sample"));
    if (odo.size() != checked.size())
      fail("{}: the odometry lines could not be read as TUM samples", o.odometry->string());
    for (size_t k = 0; k < odo.size(); ++k) odo[k][0] = checked[k].timestamp;
  }
  fs::path tmp = out;
  tmp += ".part";
  try {
    rosbag::Bag bag;
    try {
      bag.open(tmp.string(), rosbag::bagmode::Write);
    } catch (const std::exception& e) {
      fail("{}: cannot write the bag ({})", out.string(), e.what());
    }
    const sensor_msgs::CameraInfo info0 = cameraInfoFromCamera<sensor_msgs::CameraInfo>(ds.camera());
    // rosbag refuses a message time before ros::TIME_MIN (1 ns); the header keeps the true stamp.
    auto bagTime = [](const ros::Time& t) { return std::max(t, ros::TIME_MIN); };
    const ImageMode mode = enc == "mono8" ? ImageMode::kGray : ImageMode::kColor;
    for (size_t i = 0; i < ds.size(); ++i) {
      const DatasetFrame f = ds.load(i, mode);
      std_msgs::Header header;
      header.seq = static_cast<uint32_t>(i);
      header.stamp = toRosTime(f.timestamp, fmt::format("{}: frame {}", ds.imagePath(i), i));
      header.frame_id = o.camera_frame;
      if (compressed) {
        sensor_msgs::CompressedImage m;
        m.header = header;
        m.format = enc;
        std::vector<int> params;
        if (enc == "jpeg") params = {cv::IMWRITE_JPEG_QUALITY, o.jpeg_quality};
        if (!cv::imencode(enc == "png" ? ".png" : ".jpg", f.image, m.data, params))
          fail("{}: frame {} cannot be encoded as {}", out.string(), i, enc);
        bag.write(o.image_topic, bagTime(header.stamp), m);
      } else {
        sensor_msgs::Image m;
        m.header = header;
        m.width = static_cast<uint32_t>(f.image.cols);
        m.height = static_cast<uint32_t>(f.image.rows);
        m.encoding = enc;
        m.is_bigendian = 0;
        cv::Mat img = f.image;
        if (enc == "rgb8") cv::cvtColor(f.image, img, cv::COLOR_BGR2RGB);
        if (!img.isContinuous()) img = img.clone();
        m.step = static_cast<uint32_t>(img.cols * img.channels());
        m.data.assign(img.data, img.data + img.total() * img.channels());
        bag.write(o.image_topic, bagTime(header.stamp), m);
      }
      sensor_msgs::CameraInfo info = info0;
      info.header = header;
      bag.write(o.camera_info_topic, bagTime(header.stamp), info);
      if (o.groundtruth && f.T_world_cam) {
        geometry_msgs::PoseStamped p;
        p.header = header;
        p.header.frame_id = o.world_frame;
        const SE3& T = *f.T_world_cam;
        p.pose.position.x = T.translation().x();
        p.pose.position.y = T.translation().y();
        p.pose.position.z = T.translation().z();
        p.pose.orientation.x = T.rotation().x();
        p.pose.orientation.y = T.rotation().y();
        p.pose.orientation.z = T.rotation().z();
        p.pose.orientation.w = T.rotation().w();
        bag.write(o.groundtruth_topic, bagTime(header.stamp), p);
      }
      if (o.progress && (i + 1) % 100 == 0) std::fprintf(stderr, "bag: %zu/%zu frames\n", i + 1, ds.size());
    }
    const bool odo_topic = o.odometry_as == "topic" || o.odometry_as == "both";
    const bool odo_tf = o.odometry_as == "tf" || o.odometry_as == "both";
    for (size_t k = 0; k < odo.size(); ++k) {
      const std::vector<double>& v = odo[k];
      std_msgs::Header header;
      header.seq = static_cast<uint32_t>(k);
      header.stamp = toRosTime(v[0], fmt::format("{}: sample {}", o.odometry->string(), k));
      header.frame_id = o.odom_frame;
      if (odo_topic) {
        nav_msgs::Odometry m;
        m.header = header;
        m.child_frame_id = o.base_frame;
        m.pose.pose.position.x = v[1];
        m.pose.pose.position.y = v[2];
        m.pose.pose.position.z = v[3];
        m.pose.pose.orientation.x = v[4];
        m.pose.pose.orientation.y = v[5];
        m.pose.pose.orientation.z = v[6];
        m.pose.pose.orientation.w = v[7];
        bag.write(o.odometry_topic, bagTime(header.stamp), m);
      }
      if (odo_tf) {
        geometry_msgs::TransformStamped ts;
        ts.header = header;
        ts.child_frame_id = o.base_frame;
        ts.transform.translation.x = v[1];
        ts.transform.translation.y = v[2];
        ts.transform.translation.z = v[3];
        ts.transform.rotation.x = v[4];
        ts.transform.rotation.y = v[5];
        ts.transform.rotation.z = v[6];
        ts.transform.rotation.w = v[7];
        tf2_msgs::TFMessage m;
        m.transforms.push_back(ts);
        bag.write("/tf", bagTime(header.stamp), m);
      }
    }
    bag.close();
  } catch (const Error&) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  } catch (const std::exception& e) {
    std::error_code ec;
    fs::remove(tmp, ec);
    fail("{}: writing the bag failed ({})", out.string(), e.what());
  }
  std::error_code ec;
  fs::rename(tmp, out, ec);
  if (ec) {
    fs::remove(tmp, ec);
    fail("{}: cannot move the finished bag into place ({})", out.string(), ec.message());
  }
}

}  // namespace nerfslam
