#pragma once
// Helpers shared by the rostest gtest nodes (test/ros/*_test.cpp).
#include <gtest/gtest.h>

#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <cv_bridge/cv_bridge.h>
#include <diagnostic_msgs/DiagnosticArray.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/Image.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/system/nerf_mapping.h"
#include "test_support.h"

namespace nerfslam::rostest_util {

// Waits until pred() holds or `seconds` of wall time pass; returns pred().
template <class Pred>
bool waitFor(double seconds, Pred pred) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(seconds);
  while (ros::ok() && ros::WallTime::now() < deadline) {
    if (pred()) return true;
    ros::WallDuration(0.05).sleep();
  }
  return pred();
}

// Pearson correlation of the grey levels of two RGB images (0 when either is flat).
inline double correlation(const cv::Mat& a_rgb, const cv::Mat& b_rgb) {
  cv::Mat a, b;
  cv::cvtColor(a_rgb, a, cv::COLOR_RGB2GRAY);
  cv::cvtColor(b_rgb, b, cv::COLOR_RGB2GRAY);
  a.convertTo(a, CV_64F);
  b.convertTo(b, CV_64F);
  a -= cv::mean(a)[0];
  b -= cv::mean(b)[0];
  const double den = std::sqrt(a.dot(a) * b.dot(b));
  return den > 0 ? a.dot(b) / den : 0.0;
}

// Joins a thread when the scope ends (also when an ASSERT returns early).
struct Joiner {
  std::thread& t;
  ~Joiner() {
    if (t.joinable()) t.join();
  }
};

// The synthetic room of the ROS tests (320x240, procedural textures) rendered by `nerfslam synth`
// into `dir`/room and opened from its frame 1 (frame 0 is at t = 0, a "no stamp" stamp; play it with
// image_folder_publisher's `_start:=1`), with its ground truth. `dataset` is null after a failure,
// which is reported.
struct SyntheticRoom {
  std::filesystem::path dir;
  std::unique_ptr<Dataset> dataset;
  Trajectory ground_truth;
};
inline SyntheticRoom renderSyntheticRoom(const std::filesystem::path& dir, int frames) {
  SyntheticRoom room;
  room.dir = dir / "room";
  const auto synth = test::runCli("synth --scene room --frames " + std::to_string(frames + 1) +
                                  " --size 320x240 --textures procedural --out '" + room.dir.string() + "'");
  if (synth.exit_code != 0) {
    ADD_FAILURE() << synth.output;
    return room;
  }
  DatasetOptions opts;
  opts.start = 1;
  room.dataset = openDataset(room.dir.string(), opts);
  for (size_t i = 0; i < room.dataset->size(); ++i)
    room.ground_truth.push_back({room.dataset->timestamp(i), *room.dataset->groundTruth(i)});
  return room;
}

// The size of the views a node's NeRF renders (its training resolution, NerfMappingOptions' default
// downscale: the nodes use the default).
inline cv::Size nerfTrainingSize(const Camera& cam) {
  const double downscale = NerfMappingOptions{}.downscale;
  return {std::max(1, int(std::lround(cam.width / downscale))), std::max(1, int(std::lround(cam.height / downscale)))};
}

// Records the images published on `topic` (as RGB, by stamp) from its construction on.
class InputImages {
 public:
  InputImages(ros::NodeHandle& nh, const std::string& topic) {
    sub_ = nh.subscribe<sensor_msgs::Image>(topic, 200, [this](const sensor_msgs::ImageConstPtr& m) {
      cv::Mat rgb;
      try {
        rgb = cv_bridge::toCvCopy(m, "rgb8")->image;
      } catch (const std::exception&) {
        return;
      }
      std::lock_guard<std::mutex> lock(mutex_);
      images_[m->header.stamp.toSec()] = rgb;
    });
  }
  std::map<double, cv::Mat> snapshot() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return images_;
  }

 private:
  mutable std::mutex mutex_;
  std::map<double, cv::Mat> images_;
  ros::Subscriber sub_;
};

// A process started by a test (argv[0] found on PATH), in a process group of its own, its output
// appended to `log`. Stopped (SIGINT to the group, SIGKILL after `grace` s) by stop() or the
// destructor, so that nothing it started outlives the test, also when an ASSERT returns early.
class ChildProcess {
 public:
  ChildProcess(const std::vector<std::string>& argv, const std::string& log) {
    pid_ = fork();
    if (pid_ == 0) {
      setpgid(0, 0);
      const int fd = open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (fd >= 0) {
        dup2(fd, 1);
        dup2(fd, 2);
      }
      std::vector<char*> args;
      for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
      args.push_back(nullptr);
      execvp(args[0], args.data());
      std::perror("execvp");
      _exit(127);
    }
    if (pid_ > 0) setpgid(pid_, pid_);  // also here: no race with the first kill
  }
  ~ChildProcess() { stop(); }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  pid_t pid() const { return pid_; }
  bool running() {
    if (pid_ <= 0) return false;
    int status = 0;
    if (waitpid(pid_, &status, WNOHANG) == pid_) {
      exit_status_ = status;
      pid_ = -1;
      return false;
    }
    return true;
  }
  // Sends `sig` to the whole group and waits `grace` s for the process, then SIGKILLs the group.
  // Returns the wait status (-1 when it was not running).
  int stop(int sig = SIGINT, double grace = 10.0) {
    if (pid_ <= 0) return exit_status_;
    kill(-pid_, sig);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(grace);
    while (running() && std::chrono::steady_clock::now() < deadline)
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    kill(-pid_, SIGKILL);  // what is left of the group (children of a roscore, ...)
    if (pid_ > 0) {
      int status = 0;
      waitpid(pid_, &status, 0);
      exit_status_ = status;
      pid_ = -1;
    }
    return exit_status_;
  }

 private:
  pid_t pid_ = -1;
  int exit_status_ = -1;
};

// A TCP port nobody listens on now (the kernel's choice).
inline int freePort() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = 0;
  socklen_t len = sizeof(addr);
  int port = 0;
  if (bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) == 0 &&
      getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len) == 0)
    port = ntohs(addr.sin_port);
  close(fd);
  return port;
}

// The text of a (log) file, "" when it cannot be read.
inline std::string readText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// The latest values of a node's status on /diagnostics (the status whose name contains `node`).
class DiagnosticsValues {
 public:
  DiagnosticsValues(ros::NodeHandle& nh, const std::string& node) : node_(node) {
    sub_ = nh.subscribe<diagnostic_msgs::DiagnosticArray>("/diagnostics", 100,
                                                          [this](const diagnostic_msgs::DiagnosticArrayConstPtr& m) {
                                                            std::lock_guard<std::mutex> lock(mutex_);
                                                            for (const auto& st : m->status) {
                                                              if (st.name.find(node_) == std::string::npos) continue;
                                                              for (const auto& kv : st.values)
                                                                values_[kv.key] = kv.value;
                                                              ++count_;
                                                            }
                                                          });
  }
  std::string str(const std::string& key) const {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = values_.find(key);
    return it == values_.end() ? "" : it->second;
  }
  double num(const std::string& key) const {
    const std::string v = str(key);
    return v.empty() ? 0.0 : std::atof(v.c_str());
  }
  int count() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return count_;
  }
  // nerfslam_node's refused frames (every reason), and the frames it accounted for: processed +
  // dropped + refused + tracking errors (= "frames received" once its queue is empty).
  double refused() const {
    return num("frames refused (encoding)") + num("frames refused (size)") + num("frames refused (timestamp)") +
           num("frames refused (calibration changed)");
  }
  double accounted() const {
    return num("frames processed") + num("frames dropped (queue full)") + refused() + num("tracking errors");
  }

 private:
  std::string node_;
  mutable std::mutex mutex_;
  std::map<std::string, std::string> values_;
  int count_ = 0;
  ros::Subscriber sub_;
};

// What a node logs (its messages on /rosout), to check that it said what happened.
class RosoutLog {
 public:
  RosoutLog(ros::NodeHandle& nh, const std::string& node) : node_(node) {
    sub_ = nh.subscribe<rosgraph_msgs::Log>("/rosout", 1000, [this](const rosgraph_msgs::LogConstPtr& m) {
      if (m->name != node_) return;
      std::lock_guard<std::mutex> lock(mutex_);
      lines_.push_back(m->msg);
    });
  }
  // The first message containing every one of `parts` ("" when none).
  std::string find(const std::vector<std::string>& parts) const {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& l : lines_) {
      bool all = true;
      for (const auto& p : parts) all = all && l.find(p) != std::string::npos;
      if (all) return l;
    }
    return "";
  }

 private:
  std::string node_;
  mutable std::mutex mutex_;
  std::vector<std::string> lines_;
  ros::Subscriber sub_;
};

// Percentile (0..1) of `v` (sorted in place); 0 for an empty vector.
inline double percentile(std::vector<double>& v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(std::lround(q * double(v.size() - 1))));
  return v[i];
}

// main() of a rostest gtest node: gtest, ros::init as `name`, an AsyncSpinner for the callbacks.
inline int runRosGtest(int argc, char** argv, const char* name) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, name);
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int rc = RUN_ALL_TESTS();
  spinner.stop();
  ros::shutdown();
  return rc;
}

}  // namespace nerfslam::rostest_util
