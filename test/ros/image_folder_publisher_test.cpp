// gtest node started by test/ros/image_folder_publisher.test (rostest): checks what
// image_folder_publisher publishes against the dataset read directly through nerfslam::openDataset,
// and that the node refuses bad input with a message and a non-zero exit status.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <cv_bridge/cv_bridge.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>
#include <fstream>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam_ros/conversions.h"
#include "ros_test_util.h"
#include "test_support.h"

namespace {

struct Received {
  std::mutex mutex;
  std::vector<sensor_msgs::ImageConstPtr> images;
  std::vector<ros::WallTime> image_arrival;
  std::vector<sensor_msgs::CameraInfoConstPtr> infos;
};

TEST(ImageFolderPublisher, PublishesTheDatasetWithMatchingCameraInfoAtTheRequestedRate) {
  ros::NodeHandle nh;
  ros::NodeHandle pnh("~");
  std::string spec, frame_id;
  double rate = 0;
  int start = 0, frames = 0;
  ASSERT_TRUE(pnh.getParam("dataset", spec));
  ASSERT_TRUE(pnh.getParam("rate", rate));
  ASSERT_TRUE(pnh.getParam("start", start));
  ASSERT_TRUE(pnh.getParam("frames", frames));
  ASSERT_TRUE(pnh.getParam("frame_id", frame_id));
  ASSERT_GT(rate, 0.0);
  ASSERT_GT(frames, 1);
  const std::filesystem::path root = nerfslam::parseDatasetSpec(spec).path;
  NERFSLAM_REQUIRE_PATH(root)
  nerfslam::DatasetOptions opts;
  opts.start = static_cast<size_t>(start);
  opts.max_frames = static_cast<size_t>(frames);
  const auto ds = nerfslam::openDataset(spec, opts);
  ASSERT_EQ(ds->size(), static_cast<size_t>(frames));
  const nerfslam::Camera& cam = ds->camera();

  Received rx;
  ros::Subscriber image_sub =
      nh.subscribe<sensor_msgs::Image>("image", 200, [&rx](const sensor_msgs::ImageConstPtr& m) {
        std::lock_guard<std::mutex> lock(rx.mutex);
        rx.images.push_back(m);
        rx.image_arrival.push_back(ros::WallTime::now());
      });
  ros::Subscriber info_sub =
      nh.subscribe<sensor_msgs::CameraInfo>("camera_info", 200, [&rx](const sensor_msgs::CameraInfoConstPtr& m) {
        std::lock_guard<std::mutex> lock(rx.mutex);
        rx.infos.push_back(m);
      });

  // The publisher holds its first frame until we subscribe; all frames take (frames - 1) / rate s.
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(30.0 + frames / rate);
  while (ros::ok() && ros::WallTime::now() < deadline) {
    {
      std::lock_guard<std::mutex> lock(rx.mutex);
      if (rx.images.size() >= static_cast<size_t>(frames) && rx.infos.size() >= static_cast<size_t>(frames)) break;
    }
    ros::WallDuration(0.01).sleep();
  }
  ros::WallDuration(2.0 / rate).sleep();  // anything beyond `frames` would arrive now
  std::lock_guard<std::mutex> lock(rx.mutex);
  ASSERT_EQ(rx.images.size(), static_cast<size_t>(frames)) << "images received";
  ASSERT_EQ(rx.infos.size(), static_cast<size_t>(frames)) << "camera_info received";

  for (size_t i = 0; i < rx.images.size(); ++i) {
    const auto& img = *rx.images[i];
    const auto& info = *rx.infos[i];
    SCOPED_TRACE("frame " + std::to_string(i));
    EXPECT_EQ(img.header.stamp, info.header.stamp) << "image and camera_info share the stamp";
    EXPECT_EQ(img.header.frame_id, frame_id);
    EXPECT_EQ(info.header.frame_id, frame_id);
    EXPECT_EQ(img.encoding, "mono8");
    EXPECT_EQ(static_cast<int>(img.width), cam.width);
    EXPECT_EQ(static_cast<int>(img.height), cam.height);
    EXPECT_EQ(static_cast<int>(info.width), cam.width);
    EXPECT_EQ(static_cast<int>(info.height), cam.height);
    const Eigen::Matrix3d K = cam.K();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(info.K[3 * r + c], K(r, c)) << "K(" << r << "," << c << ")";
    const nerfslam::Camera back = nerfslam::rosbridge::fromCameraInfo(info);
    EXPECT_EQ(back.distortion_model, cam.distortion_model);
    if (i > 0) {
      EXPECT_GT(img.header.stamp, rx.images[i - 1]->header.stamp) << "stamps increase";
    }
    // The pixels are the dataset's frame start + i.
    const cv::Mat expected = ds->load(i, nerfslam::ImageMode::kGray).image;
    const cv::Mat got = cv_bridge::toCvShare(rx.images[i])->image;
    ASSERT_EQ(got.size(), expected.size());
    EXPECT_EQ(cv::norm(got, expected, cv::NORM_INF), 0.0) << "pixels differ from " << ds->imagePath(i);
  }

  // Rate: the stamps and the arrival times span (frames - 1) / rate seconds.
  const double expected_span = (frames - 1) / rate;
  const double stamp_span = (rx.images.back()->header.stamp - rx.images.front()->header.stamp).toSec();
  const double arrival_span = (rx.image_arrival.back() - rx.image_arrival.front()).toSec();
  std::printf("rate check: %d frames at %.1f Hz: stamp span %.4f s, arrival span %.4f s, expected %.4f s\n", frames,
              rate, stamp_span, arrival_span, expected_span);
  EXPECT_NEAR(stamp_span, expected_span, 0.1 * expected_span);
  EXPECT_NEAR(arrival_span, expected_span, 0.1 * expected_span);
  std::vector<double> gaps;
  for (size_t i = 1; i < rx.images.size(); ++i)
    gaps.push_back((rx.images[i]->header.stamp - rx.images[i - 1]->header.stamp).toSec());
  std::nth_element(gaps.begin(), gaps.begin() + gaps.size() / 2, gaps.end());
  const double median_gap = gaps[gaps.size() / 2];
  std::printf("rate check: median stamp gap %.4f s (expected %.4f s)\n", median_gap, 1.0 / rate);
  EXPECT_NEAR(median_gap, 1.0 / rate, 0.1 / rate);
}

// Started by test/ros/image_folder_ground_truth.test: ~publish_ground_truth, ~use_dataset_stamps
// and ~color. The tf at each image stamp and the path equal the dataset's ground truth.
TEST(GroundTruth, TfAndPathEqualTheDatasetsGroundTruthAtDatasetStamps) {
  ros::NodeHandle nh;
  ros::NodeHandle pnh("~");
  std::string spec, parent, child;
  int frames = 0, start = 0;
  ASSERT_TRUE(pnh.getParam("dataset", spec));
  ASSERT_TRUE(pnh.getParam("frames", frames));
  ASSERT_TRUE(pnh.getParam("start", start));
  ASSERT_TRUE(pnh.getParam("gt_parent_frame", parent));
  ASSERT_TRUE(pnh.getParam("gt_child_frame", child));
  const std::filesystem::path root = nerfslam::parseDatasetSpec(spec).path;
  NERFSLAM_REQUIRE_PATH(root)
  nerfslam::DatasetOptions opts;
  opts.start = static_cast<size_t>(start);
  opts.max_frames = static_cast<size_t>(frames);
  const auto ds = nerfslam::openDataset(spec, opts);
  ASSERT_TRUE(ds->hasGroundTruth());

  tf2_ros::Buffer buffer(ros::Duration(600.0));
  tf2_ros::TransformListener listener(buffer, nh);
  std::mutex mutex;
  std::vector<sensor_msgs::ImageConstPtr> images;
  nav_msgs::PathConstPtr last_path;
  ros::Subscriber path_sub =
      nh.subscribe<nav_msgs::Path>("ground_truth_path", 100, [&](const nav_msgs::PathConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        last_path = m;
      });
  ros::WallDuration(0.5).sleep();  // tf and path connected before the image subscription releases the publisher
  ros::Subscriber image_sub = nh.subscribe<sensor_msgs::Image>("image", 200, [&](const sensor_msgs::ImageConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex);
    images.push_back(m);
  });
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(60.0);
  while (ros::ok() && ros::WallTime::now() < deadline) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (images.size() >= static_cast<size_t>(frames) && last_path &&
          last_path->poses.size() >= static_cast<size_t>(frames))
        break;
    }
    ros::WallDuration(0.01).sleep();
  }
  ros::WallDuration(0.5).sleep();
  std::lock_guard<std::mutex> lock(mutex);
  ASSERT_EQ(images.size(), static_cast<size_t>(frames));
  ASSERT_TRUE(last_path);
  ASSERT_EQ(last_path->poses.size(), static_cast<size_t>(frames));
  EXPECT_EQ(last_path->header.frame_id, parent);
  for (size_t i = 0; i < images.size(); ++i) {
    SCOPED_TRACE("frame " + std::to_string(i));
    const auto& img = *images[i];
    EXPECT_EQ(img.header.stamp, ros::Time(ds->timestamp(i))) << "dataset stamps";
    EXPECT_EQ(img.encoding, "bgr8");
    const cv::Mat expected = ds->load(i, nerfslam::ImageMode::kColor).image;
    EXPECT_EQ(cv::norm(cv_bridge::toCvShare(images[i])->image, expected, cv::NORM_INF), 0.0);
    const nerfslam::SE3 gt = *ds->groundTruth(i);
    geometry_msgs::TransformStamped ts;
    try {
      ts = buffer.lookupTransform(parent, child, img.header.stamp);
    } catch (const tf2::TransformException& e) {
      ADD_FAILURE() << "no tf at the image stamp: " << e.what();
      continue;
    }
    const nerfslam::SE3 T = nerfslam::rosbridge::fromTransform(ts.transform);
    EXPECT_LT((T.translation() - gt.translation()).norm(), 1e-9);
    EXPECT_LT(T.rotation().angularDistance(gt.rotation()), 1e-9);
    const nerfslam::SE3 P = nerfslam::rosbridge::fromPose(last_path->poses[i].pose);
    EXPECT_LT((P.translation() - gt.translation()).norm(), 1e-9);
    EXPECT_LT(P.rotation().angularDistance(gt.rotation()), 1e-9);
    EXPECT_EQ(last_path->poses[i].header.stamp, img.header.stamp);
  }
}

// Runs the publisher binary against this test's master with the given arguments.
nerfslam::test::CommandResult runPublisher(const std::string& args) {
  return nerfslam::test::runCommand("timeout 60 '" NERFSLAM_PUBLISHER_PATH "' " + args);
}

TEST(ImageFolderPublisher, MissingDatasetExitsNonZeroNamingThePath) {
  const nerfslam::test::CommandResult e =
      runPublisher("__name:=bad_dataset_publisher _dataset:=/nonexistent/nerfslam_no_such_dataset");
  EXPECT_EQ(e.exit_code, 1) << e.output;
  EXPECT_NE(e.output.find("cannot open dataset"), std::string::npos) << e.output;
  EXPECT_NE(e.output.find("/nonexistent/nerfslam_no_such_dataset"), std::string::npos) << e.output;
}

TEST(ImageFolderPublisher, BadParametersExitNonZeroNamingTheParameter) {
  const nerfslam::test::CommandResult no_dataset = runPublisher("__name:=no_dataset_publisher");
  EXPECT_EQ(no_dataset.exit_code, 1) << no_dataset.output;
  EXPECT_NE(no_dataset.output.find("~dataset is required"), std::string::npos) << no_dataset.output;

  const nerfslam::test::CommandResult bad_rate = runPublisher("__name:=bad_rate_publisher _dataset:=/tmp _rate:=-5.0");
  EXPECT_EQ(bad_rate.exit_code, 1) << bad_rate.output;
  EXPECT_NE(bad_rate.output.find("~rate must be >= 0"), std::string::npos) << bad_rate.output;

  const nerfslam::test::CommandResult bad_kind = runPublisher("__name:=bad_kind_publisher _dataset:=nosuchkind:/tmp");
  EXPECT_EQ(bad_kind.exit_code, 1) << bad_kind.output;
  EXPECT_NE(bad_kind.output.find("nosuchkind"), std::string::npos) << bad_kind.output;
}

TEST(ImageFolderPublisher, UndecodableFrameIsReportedAndSkipped) {
  // A synthetic image folder of 4 frames whose frame 2 is a truncated PNG: the node names the file,
  // skips that frame, publishes the others and (with ~exit_when_done) exits 0.
  nerfslam::test::TempDir dir;
  cv::Mat img(48, 64, CV_8UC1);
  std::ofstream times(dir / "times.txt");
  for (int i = 0; i < 4; ++i) {
    cv::randu(img, 0, 255);
    ASSERT_TRUE(cv::imwrite((dir / ("frame" + std::to_string(i) + ".png")).string(), img));
    times << 0.1 * i << "\n";
  }
  times.close();
  nerfslam::saveCameraYaml(nerfslam::Camera::pinhole(64, 48, 60, 60, 31.5, 23.5), dir / "camera.yaml");
  const auto bad = dir / "frame2.png";
  std::filesystem::resize_file(bad, std::filesystem::file_size(bad) / 2);

  const nerfslam::test::CommandResult e = runPublisher(
      "__name:=corrupt_frame_publisher image:=corrupt/image camera_info:=corrupt/camera_info "
      "_exit_when_done:=true _rate:=50 _dataset:=folder:" +
      dir.path().string());
  EXPECT_EQ(e.exit_code, 0) << e.output;
  EXPECT_NE(e.output.find("skipping frame 2"), std::string::npos) << e.output;
  EXPECT_NE(e.output.find("frame2.png"), std::string::npos) << e.output;
  EXPECT_NE(e.output.find("3 frames published in total, 1 skipped"), std::string::npos) << e.output;
}

}  // namespace

int main(int argc, char** argv) {
  return nerfslam::rostest_util::runRosGtest(argc, argv, "image_folder_publisher_test");
}
