// ROS 1 bags (include/nerfslam/io/bag.h): the "bag" dataset kind and writeDatasetBag. The only
// translation unit of the library that includes ROS headers (librosbag_storage and the message
// headers); CMake compiles it, with NERFSLAM_HAVE_ROSBAG, only when librosbag_storage is found.
//
// Opening reads every message of the image topic once (as the video reader decodes once): the
// encoding, the size (the first image's for all), the data's length against step x height, and
// the stamps (header.stamp, strictly increasing); a CompressedImage's format is sniffed from its
// bytes (PNG, JPEG) and its header's size compared. The camera_info topic's first message gives the
// camera; the odometry and ground-truth topics are read whole. Every error names the bag, the
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
#include <map>
#include <mutex>
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

    std::string odo_topic = opts.odometry_topic;
    if (!odo_topic.empty()) {
      requireTopic(topics, odo_topic, {kOdometry}, "--odometry-topic");
    } else {
      std::vector<std::string> found;
      for (const auto& [t, type] : topics)
        if (type == kOdometry && t != opts.groundtruth_topic && t != "/groundtruth") found.push_back(t);
      if (found.size() == 1) odo_topic = found[0];
      if (found.size() > 1)
        spdlog::warn("{}: several nav_msgs/Odometry topics ({}): no odometry used; choose one with --odometry-topic",
                     file_.string(), fmt::join(found, ", "));
    }
    if (!odo_topic.empty()) readOdometry(odo_topic);

    std::string gt_topic = opts.groundtruth_topic;
    if (!gt_topic.empty())
      requireTopic(topics, gt_topic, {kPoseStamped, kOdometry}, "--groundtruth-topic");
    else if (topics.count("/groundtruth") &&
             (topics.at("/groundtruth") == kPoseStamped || topics.at("/groundtruth") == kOdometry))
      gt_topic = "/groundtruth";
    if (!gt_topic.empty()) readGroundTruth(gt_topic);

    spdlog::info("opened bag {}: {} frames on '{}' ({}), {}x{}, {:.3f} .. {:.3f} s; odometry {}; ground truth {}",
                 file_.string(), frames_.size(), image_topic_, compressed_ ? "compressed" : "raw", width_, height_,
                 frames_.front().t, frames_.back().t,
                 odometry_ ? fmt::format("'{}' ({} samples)", odo_topic, odometry_->T_odom_base.size()) : "none",
                 has_gt_ ? "'" + gt_topic + "'" : "none");
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

  void readGroundTruth(const std::string& topic) {
    std::vector<io_detail::TimedPose> gt;
    for (const auto& e : readPoses(topic)) gt.push_back({e.timestamp, e.pose});
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
    for (size_t k = 0; k < odo.size(); ++k) {
      const std::vector<double>& v = odo[k];
      nav_msgs::Odometry m;
      m.header.seq = static_cast<uint32_t>(k);
      m.header.stamp = toRosTime(v[0], fmt::format("{}: sample {}", o.odometry->string(), k));
      m.header.frame_id = o.odom_frame;
      m.child_frame_id = o.base_frame;
      m.pose.pose.position.x = v[1];
      m.pose.pose.position.y = v[2];
      m.pose.pose.position.z = v[3];
      m.pose.pose.orientation.x = v[4];
      m.pose.pose.orientation.y = v[5];
      m.pose.pose.orientation.z = v[6];
      m.pose.pose.orientation.w = v[7];
      bag.write(o.odometry_topic, bagTime(m.header.stamp), m);
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
