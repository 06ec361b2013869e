#pragma once
// Helpers shared by the rostest gtest nodes (test/ros/*_test.cpp).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <string>
#include <thread>

#include <cv_bridge/cv_bridge.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/system/nerf_mapping.h"

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
