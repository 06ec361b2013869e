// ROS bags as datasets (`bag:FILE`, src/io/bag/dataset_bag.cpp): what a bag holds comes back
// (encodings, camera_info, odometry, ground truth, topic detection) and every bad input is an Error
// naming the bag, the topic and the message. The bags are written here with rosbag::Bag directly,
// so they can be wrong in every way a recorder could make them.
#include <gtest/gtest.h>

#if NERFSLAM_HAVE_ROSBAG

#include <fstream>
#include <random>

#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#if __has_include(<tf/tfMessage.h>)
#include <tf/tfMessage.h>
#endif
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/bag.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/trajectory.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

constexpr int kW = 64, kH = 48;

cv::Mat colourFrame(int i, int w = kW, int h = kH) {
  cv::Mat g = test::noiseImage(w, h, 7 + i), bgr;
  cv::cvtColor(g, bgr, cv::COLOR_GRAY2BGR);
  bgr.forEach<cv::Vec3b>([&](cv::Vec3b& p, const int* pos) { p[2] = static_cast<uint8_t>(pos[1] * 3 + i); });
  return bgr;
}

sensor_msgs::Image rawImage(const cv::Mat& bgr, const std::string& encoding, double t) {
  sensor_msgs::Image m;
  m.header.stamp = ros::Time(t);
  m.header.frame_id = "cam";
  m.width = static_cast<uint32_t>(bgr.cols);
  m.height = static_cast<uint32_t>(bgr.rows);
  m.encoding = encoding;
  cv::Mat img = bgr;
  if (encoding == "mono8") cv::cvtColor(bgr, img, cv::COLOR_BGR2GRAY);
  if (encoding == "rgb8") cv::cvtColor(bgr, img, cv::COLOR_BGR2RGB);
  m.step = static_cast<uint32_t>(img.cols * img.channels());
  m.data.assign(img.data, img.data + img.total() * img.channels());
  return m;
}

sensor_msgs::CameraInfo info(int w = kW, int h = kH) {
  sensor_msgs::CameraInfo c;
  c.width = w;
  c.height = h;
  c.distortion_model = "plumb_bob";
  c.D = {0.01, -0.002, 0, 0, 0};
  c.K = {50, 0, 31.5, 0, 51, 23.5, 0, 0, 1};
  return c;
}

// A bag of n frames on /cam/image_raw with camera_info; `edit` may change message i before it is written.
struct BagSpec {
  int frames = 5;
  std::string encoding = "bgr8";
  bool camera_info = true;
  std::function<void(int, sensor_msgs::Image&)> edit;
};

fs::path writeBag(const fs::path& path, const BagSpec& s) {
  rosbag::Bag b(path.string(), rosbag::bagmode::Write);
  for (int i = 0; i < s.frames; ++i) {
    const double t = 1.0 + 0.1 * i;
    sensor_msgs::Image m = rawImage(colourFrame(i), s.encoding, t);
    if (s.edit) s.edit(i, m);
    b.write("/cam/image_raw", ros::Time(t), m);
    if (s.camera_info) {
      sensor_msgs::CameraInfo c = info();
      c.header = m.header;
      b.write("/cam/camera_info", ros::Time(t), c);
    }
  }
  return path;
}

// A stamp as the bag reader gives it back: ros::Time(t) keeps whole nanoseconds.
double fromRosTimeForTest(double t) {
  const ros::Time r(t);
  return std::stod(fmt::format("{}.{:09d}", r.sec, r.nsec));
}

std::unique_ptr<Dataset> open(const fs::path& bag, DatasetOptions o = {}) {
  return openDataset("bag:" + bag.string(), o);
}

// Every raw encoding we accept gives the frame back: colour exactly, grey as OpenCV converts it.
TEST(BagDataset, RawEncodingsCameraInfoAndStamps) {
  test::TempDir dir;
  for (const std::string enc : {"bgr8", "rgb8", "mono8"}) {
    const auto ds = open(writeBag(dir / (enc + ".bag"), {5, enc}));
    EXPECT_EQ(ds->kind(), "bag");
    ASSERT_EQ(ds->size(), 5u);
    EXPECT_EQ(ds->camera().width, kW);
    EXPECT_EQ(ds->camera().fx, 50.0);
    EXPECT_EQ(ds->camera().fy, 51.0);
    EXPECT_EQ(ds->camera().distortion_model, DistortionModel::kRadTan);
    EXPECT_FALSE(ds->hasGroundTruth());
    EXPECT_FALSE(ds->odometry().has_value());
    for (size_t i = 0; i < ds->size(); ++i) {
      EXPECT_EQ(ds->timestamp(i), 1.0 + 0.1 * static_cast<double>(i)) << enc << " " << i;
      cv::Mat grey;
      cv::cvtColor(colourFrame(static_cast<int>(i)), grey, cv::COLOR_BGR2GRAY);
      EXPECT_EQ(cv::norm(ds->load(i, ImageMode::kGray).image, grey, cv::NORM_INF), 0.0) << enc << " " << i;
      if (enc != "mono8")
        EXPECT_EQ(cv::norm(ds->load(i, ImageMode::kColor).image, colourFrame(static_cast<int>(i)), cv::NORM_INF), 0.0)
            << enc;
    }
    EXPECT_NE(ds->imagePath(3).find("/cam/image_raw#3"), std::string::npos);
  }
}

// writeDatasetBag of an image folder with ground truth and odometry, read back: identical stamps,
// pixels (raw and PNG-compressed), poses and odometry samples.
TEST(BagDataset, WrittenDatasetReadsBackExactly) {
  test::TempDir dir;
  fs::create_directories(dir / "seq");
  std::string times, gt, odo = "# odometry\n";
  for (int i = 0; i < 6; ++i) {
    ASSERT_TRUE(cv::imwrite((dir / "seq" / fmt::format("{:03d}.png", i)).string(), colourFrame(i)));
    times += fmt::format("{:.6f}\n", 0.033333 * i);
    gt += fmt::format("{:.6f} {} 0.5 -1 0 0 0.0998334166 0.995004165\n", 0.033333 * i, 0.1 * i);
  }
  for (int k = 0; k < 20; ++k)
    odo += fmt::format("{:.9f} {:.17g} 0.25 0 0 0 0.0499791693 0.998750260\n", 0.01 * k, 0.03 * k);
  test::writeText(dir / "seq" / "times.txt", times);
  test::writeText(dir / "odo.txt", odo);
  test::writeText(dir / "gt.txt", gt);
  const Camera cam = Camera::pinhole(kW, kH, 50, 50, 31.5, 23.5);
  saveCameraYaml(cam, dir / "seq" / "camera.yaml");
  const auto folder = openDataset("folder:" + (dir / "seq").string());
  for (const std::string enc : {"mono8", "png"}) {
    BagWriteOptions w;
    w.encoding = enc;
    w.odometry = dir / "odo.txt";
    const fs::path bag = dir / (enc + ".bag");
    writeDatasetBag(*folder, bag, w);
    EXPECT_FALSE(fs::exists(bag.string() + ".part"));
    const auto ds = open(bag);
    ASSERT_EQ(ds->size(), folder->size());
    EXPECT_EQ(ds->camera().fx, cam.fx);
    EXPECT_EQ(ds->camera().cx, cam.cx);
    EXPECT_EQ(ds->camera().distortion_model, DistortionModel::kNone);
    for (size_t i = 0; i < ds->size(); ++i) {
      EXPECT_EQ(ds->timestamp(i), folder->timestamp(i)) << i;  // the same double
      EXPECT_EQ(cv::norm(ds->load(i).image, folder->load(i).image, cv::NORM_INF), 0.0) << enc << " " << i;
    }
    ASSERT_TRUE(ds->odometry().has_value());
    const Trajectory file = readTumTrajectory(dir / "odo.txt");
    const Trajectory bag_odo = ds->odometry()->T_odom_base;
    ASSERT_EQ(bag_odo.size(), file.size());
    for (size_t k = 0; k < file.size(); ++k) {
      EXPECT_EQ(bag_odo[k].timestamp, file[k].timestamp) << k;
      EXPECT_EQ(bag_odo[k].pose.translation(), file[k].pose.translation()) << k;
      EXPECT_EQ(bag_odo[k].pose.rotation().coeffs(), file[k].pose.rotation().coeffs()) << k;
    }
  }
  // The odometry written as tf (odom -> base_link on /tf) reads back as the identical samples; written
  // both ways, the topic is used.
  for (const std::string as : {"tf", "both"}) {
    BagWriteOptions w;
    w.encoding = "mono8";
    w.odometry = dir / "odo.txt";
    w.odometry_as = as;
    writeDatasetBag(*folder, dir / (as + ".bag"), w);
    const auto ds = open(dir / (as + ".bag"));
    ASSERT_TRUE(ds->odometry().has_value()) << as;
    EXPECT_EQ(ds->odometry()->from, as == "tf" ? "tf" : "topic");
    const Trajectory file = readTumTrajectory(dir / "odo.txt");
    const Trajectory bag_odo = ds->odometry()->T_odom_base;
    ASSERT_EQ(bag_odo.size(), file.size()) << as;
    for (size_t k = 0; k < file.size(); ++k) {
      EXPECT_EQ(bag_odo[k].timestamp, file[k].timestamp) << as << " " << k;
      EXPECT_EQ(bag_odo[k].pose.translation(), file[k].pose.translation()) << as << " " << k;
      EXPECT_EQ(bag_odo[k].pose.rotation().coeffs(), file[k].pose.rotation().coeffs()) << as << " " << k;
    }
  }
  {
    BagWriteOptions w;
    w.odometry = dir / "odo.txt";
    w.odometry_as = "wheels";
    const std::string e = test::errorOf([&] { writeDatasetBag(*folder, dir / "x.bag", w); });
    EXPECT_NE(e.find("field 'odometry_as': 'wheels'"), std::string::npos) << e;
  }
  // A dataset with ground truth: TUM layout (rgb.txt + groundtruth.txt).
  std::string rgb;
  for (int i = 0; i < 6; ++i) rgb += fmt::format("{:.6f} {:03d}.png\n", 0.033333 * i, i);
  test::writeText(dir / "seq" / "rgb.txt", rgb);
  fs::copy_file(dir / "gt.txt", dir / "seq" / "groundtruth.txt");
  const auto tum = openDataset("tum:" + (dir / "seq").string());
  ASSERT_TRUE(tum->hasGroundTruth());
  writeDatasetBag(*tum, dir / "gt.bag", {});
  const auto ds = open(dir / "gt.bag");
  ASSERT_TRUE(ds->hasGroundTruth());
  for (size_t i = 0; i < ds->size(); ++i) {
    ASSERT_TRUE(ds->groundTruth(i).has_value());
    EXPECT_LT((ds->groundTruth(i)->translation() - tum->groundTruth(i)->translation()).norm(), 1e-12);
    EXPECT_LT(ds->groundTruth(i)->rotation().angularDistance(tum->groundTruth(i)->rotation()), 1e-12);
  }
  // --camera wins over the bag's camera_info.
  const Camera other = Camera::pinhole(kW, kH, 70, 70, 32, 24);
  saveCameraYaml(other, dir / "other.yaml");
  DatasetOptions o;
  o.camera_override = dir / "other.yaml";
  EXPECT_EQ(open(dir / "gt.bag", o)->camera().fx, 70.0);
}

// Topics: detected when there is one, chosen by name among several, and a named topic that is not
// there is an error listing the bag's topics.
TEST(BagDataset, TopicsDetectedChosenOrRefused) {
  test::TempDir dir;
  {
    rosbag::Bag b((dir / "two.bag").string(), rosbag::bagmode::Write);
    for (int i = 0; i < 3; ++i) {
      const double t = 1 + i;
      b.write("/left/image_raw", ros::Time(t), rawImage(colourFrame(i), "mono8", t));
      b.write("/right/image_raw", ros::Time(t), rawImage(colourFrame(i + 10), "mono8", t));
      for (const char* ns : {"/left", "/right"}) {
        sensor_msgs::CameraInfo c = info();
        if (std::string(ns) == "/right") c.K[0] = 60;
        c.header.stamp = ros::Time(t);
        b.write(std::string(ns) + "/camera_info", ros::Time(t), c);
      }
    }
  }
  const fs::path two = dir / "two.bag";
  std::string e = test::errorOf([&] { open(two); });
  EXPECT_NE(e.find("several image topics"), std::string::npos) << e;
  EXPECT_NE(e.find("--image-topic"), std::string::npos) << e;
  EXPECT_NE(e.find(two.string()), std::string::npos) << e;
  DatasetOptions o;
  o.image_topic = "/right/image_raw";
  EXPECT_EQ(open(two, o)->camera().fx, 60.0);  // its namespace's camera_info
  o.image_topic = "/left/image_raw";
  EXPECT_EQ(open(two, o)->camera().fx, 50.0);
  o.image_topic = "/nope";
  e = test::errorOf([&] { open(two, o); });
  EXPECT_NE(e.find("no topic '/nope'"), std::string::npos) << e;
  EXPECT_NE(e.find("/left/image_raw (sensor_msgs/Image)"), std::string::npos) << e;
  o.image_topic = "/left/camera_info";
  e = test::errorOf([&] { open(two, o); });
  EXPECT_NE(e.find("is a sensor_msgs/CameraInfo"), std::string::npos) << e;
  o.image_topic = "/left/image_raw";
  o.odometry_topic = "/odom";
  e = test::errorOf([&] { open(two, o); });
  EXPECT_NE(e.find("no topic '/odom' (--odometry-topic)"), std::string::npos) << e;
  o.odometry_topic.clear();
  o.groundtruth_topic = "/gt";
  e = test::errorOf([&] { open(two, o); });
  EXPECT_NE(e.find("no topic '/gt' (--groundtruth-topic)"), std::string::npos) << e;
}

// Each bad image stream: an Error naming the bag, the topic and the message index.
TEST(BagDataset, BadImageMessagesNameBagTopicAndMessage) {
  test::TempDir dir;
  const auto expectError = [&](const std::string& name, const BagSpec& spec, const std::vector<std::string>& parts) {
    const fs::path bag = writeBag(dir / (name + ".bag"), spec);
    const std::string e = test::errorOf([&] {
      const auto ds = open(bag);
      for (size_t i = 0; i < ds->size(); ++i) ds->load(i);
    });
    EXPECT_NE(e.find(bag.string()), std::string::npos) << name << ": " << e;
    for (const auto& p : parts) EXPECT_NE(e.find(p), std::string::npos) << name << ": " << e;
  };
  expectError("yuv", {4, "yuv422"}, {"topic '/cam/image_raw', message 0", "unsupported encoding 'yuv422'"});
  expectError("mono16", {4, "bgr8", true, [](int, sensor_msgs::Image& m) { m.encoding = "mono16"; }},
              {"message 0", "16-bit"});
  expectError("16uc1", {4, "bgr8", true, [](int i, sensor_msgs::Image& m) { m.encoding = i == 2 ? "16UC1" : "bgr8"; }},
              {"message 2", "16-bit"});
  expectError("resize",
              {5, "mono8", true,
               [](int i, sensor_msgs::Image& m) {
                 if (i == 3) m = rawImage(colourFrame(3, 32, 24), "mono8", m.header.stamp.toSec());
               }},
              {"message 3", "32x24", "changes mid-bag"});
  expectError("back",
              {5, "mono8", true,
               [](int i, sensor_msgs::Image& m) {
                 if (i == 2) m.header.stamp = ros::Time(1.05);
               }},
              {"message 2", "stamps go back", "header.stamp"});
  expectError("short",
              {3, "bgr8", true,
               [](int i, sensor_msgs::Image& m) {
                 if (i == 1) m.data.resize(m.data.size() / 2);
               }},
              {"message 1", "field 'data'"});
  expectError("step", {3, "bgr8", true, [](int, sensor_msgs::Image& m) { m.step = 10; }}, {"message 0", "'step'"});
  expectError("nocam", {3, "mono8", false}, {"no sensor_msgs/CameraInfo topic", "--camera"});
  // camera_info that does not match the images.
  {
    rosbag::Bag b((dir / "camsize.bag").string(), rosbag::bagmode::Write);
    b.write("/cam/image_raw", ros::Time(1), rawImage(colourFrame(0), "mono8", 1));
    b.write("/cam/camera_info", ros::Time(1), info(640, 480));
  }
  std::string e = test::errorOf([&] { open(dir / "camsize.bag"); });
  EXPECT_NE(e.find("/cam/camera_info', message 0"), std::string::npos) << e;
  EXPECT_NE(e.find("camera is 640x480"), std::string::npos) << e;
  // No image topic at all.
  {
    rosbag::Bag b((dir / "noimage.bag").string(), rosbag::bagmode::Write);
    b.write("/cam/camera_info", ros::Time(1), info());
  }
  e = test::errorOf([&] { open(dir / "noimage.bag"); });
  EXPECT_NE(e.find("no sensor_msgs/Image or sensor_msgs/CompressedImage topic"), std::string::npos) << e;
  EXPECT_NE(e.find("/cam/camera_info (sensor_msgs/CameraInfo)"), std::string::npos) << e;
}

// Compressed images: decoded as the files would be; a corrupt one is named at load, 16-bit refused.
TEST(BagDataset, CompressedImagesAndTheirFaults) {
  test::TempDir dir;
  {
    rosbag::Bag b((dir / "c.bag").string(), rosbag::bagmode::Write);
    for (int i = 0; i < 3; ++i) {
      sensor_msgs::CompressedImage m;
      m.header.stamp = ros::Time(1 + i);
      m.format = "png";
      cv::imencode(".png", colourFrame(i), m.data);
      if (i == 2) m.data.resize(m.data.size() - 30);  // cut off: no IEND
      b.write("/cam/image_raw/compressed", ros::Time(1 + i), m);
      b.write("/cam/camera_info", ros::Time(1 + i), info());
    }
  }
  const auto ds = open(dir / "c.bag");
  ASSERT_EQ(ds->size(), 3u);
  EXPECT_EQ(cv::norm(ds->load(1, ImageMode::kColor).image, colourFrame(1), cv::NORM_INF), 0.0);
  const std::string e = test::errorOf([&] { ds->load(2); });
  EXPECT_NE(e.find("topic '/cam/image_raw/compressed', message 2"), std::string::npos) << e;
  {
    rosbag::Bag b((dir / "c16.bag").string(), rosbag::bagmode::Write);
    sensor_msgs::CompressedImage m;
    m.header.stamp = ros::Time(1);
    m.format = "16UC1; png compressed";
    cv::imencode(".png", cv::Mat(kH, kW, CV_16UC1, cv::Scalar(1000)), m.data);
    b.write("/depth/compressed", ros::Time(1), m);
  }
  const std::string e16 = test::errorOf([&] { open(dir / "c16.bag"); });
  EXPECT_NE(e16.find("16-bit"), std::string::npos) << e16;
  EXPECT_NE(e16.find("message 0"), std::string::npos) << e16;
}

// Odometry and ground-truth topics with bad poses or stamps going back.
TEST(BagDataset, BadOdometryAndGroundTruthMessages) {
  test::TempDir dir;
  const auto odoBag = [&](const std::string& name, const std::function<void(int, nav_msgs::Odometry&)>& edit) {
    const fs::path p = writeBag(dir / (name + ".bag"), {3, "mono8"});
    rosbag::Bag b(p.string(), rosbag::bagmode::Append);
    for (int k = 0; k < 5; ++k) {
      nav_msgs::Odometry m;
      m.header.stamp = ros::Time(1.0 + 0.05 * k);
      m.pose.pose.position.x = 0.1 * k;
      m.pose.pose.orientation.w = 1;
      edit(k, m);
      b.write("/odom", ros::Time(1.0 + 0.05 * k), m);
    }
    return p;
  };
  const fs::path good = odoBag("good", [](int, nav_msgs::Odometry&) {});
  ASSERT_TRUE(open(good)->odometry().has_value());
  EXPECT_EQ(open(good)->odometry()->T_odom_base.size(), 5u);
  EXPECT_EQ(open(good)->odometry()->source, good.string() + ":/odom");
  std::string e = test::errorOf([&] {
    open(odoBag("nan", [](int k, nav_msgs::Odometry& m) {
      if (k == 3) m.pose.pose.position.y = std::nan("");
    }));
  });
  EXPECT_NE(e.find("topic '/odom', message 3"), std::string::npos) << e;
  EXPECT_NE(e.find("not finite"), std::string::npos) << e;
  e = test::errorOf([&] {
    open(odoBag("quat", [](int k, nav_msgs::Odometry& m) {
      if (k == 1) m.pose.pose.orientation.w = 2;
    }));
  });
  EXPECT_NE(e.find("message 1"), std::string::npos) << e;
  EXPECT_NE(e.find("unit quaternion"), std::string::npos) << e;
  e = test::errorOf([&] {
    open(odoBag("oback", [](int k, nav_msgs::Odometry& m) {
      if (k == 4) m.header.stamp = ros::Time(1.01);
    }));
  });
  EXPECT_NE(e.find("topic '/odom', message 4"), std::string::npos) << e;
  EXPECT_NE(e.find("stamps go back"), std::string::npos) << e;
  // Ground truth going back.
  const fs::path gtb = writeBag(dir / "gt.bag", {3, "mono8"});
  {
    rosbag::Bag b(gtb.string(), rosbag::bagmode::Append);
    for (int k = 0; k < 3; ++k) {
      geometry_msgs::PoseStamped p;
      p.header.stamp = ros::Time(k == 2 ? 0.5 : 1.0 + 0.1 * k);
      p.pose.orientation.w = 1;
      b.write("/groundtruth", ros::Time(1.0 + 0.1 * k), p);
    }
  }
  e = test::errorOf([&] { open(gtb); });
  EXPECT_NE(e.find("topic '/groundtruth', message 2"), std::string::npos) << e;
}

// ---- Odometry (and ground truth) from tf.

geometry_msgs::TransformStamped transform(const std::string& parent, const std::string& child, double t, const SE3& T) {
  geometry_msgs::TransformStamped ts;
  ts.header.stamp = ros::Time(t);
  ts.header.frame_id = parent;
  ts.child_frame_id = child;
  ts.transform.translation.x = T.translation().x();
  ts.transform.translation.y = T.translation().y();
  ts.transform.translation.z = T.translation().z();
  ts.transform.rotation.x = T.rotation().x();
  ts.transform.rotation.y = T.rotation().y();
  ts.transform.rotation.z = T.rotation().z();
  ts.transform.rotation.w = T.rotation().w();
  return ts;
}

// The robot's motion: odom -> base_footprint at time t.
SE3 footprintAt(double t) {
  return SE3(Eigen::Quaterniond(Eigen::AngleAxisd(0.3 * t, Eigen::Vector3d::UnitZ())),
             Eigen::Vector3d(0.5 * t, 0.1 * t * t, 0));
}
// base_footprint -> base_link (static): up and a little tilted.
const SE3 kFootprintToBase(Eigen::Quaterniond(Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitY())),
                           Eigen::Vector3d(0.02, 0, 0.1));

// A bag of 3 frames (1.0 .. 1.2 s) with REP-105 tf: /tf odom -> base_footprint every 0.05 s from 0.95 s
// (`edit` may change each), map -> odom, and /tf_static base_footprint -> base_link and base_link ->
// camera (in one message, as static_transform_publisher batches).
fs::path writeTfBag(const fs::path& path, const std::function<void(int, geometry_msgs::TransformStamped&)>& edit = {},
                    bool with_static = true) {
  writeBag(path, {3, "mono8"});
  rosbag::Bag b(path.string(), rosbag::bagmode::Append);
  if (with_static) {
    tf2_msgs::TFMessage s;
    s.transforms.push_back(transform("base_footprint", "base_link", 0.0, kFootprintToBase));
    s.transforms.push_back(transform("base_link", "camera", 0.0, SE3(Eigen::Quaterniond::Identity(), {0.1, 0, 0.3})));
    b.write("/tf_static", ros::Time(0.5), s);
  }
  for (int k = 0; k < 8; ++k) {
    const double t = 0.95 + 0.05 * k;
    tf2_msgs::TFMessage m;
    m.transforms.push_back(transform("map", "odom", t, SE3(Eigen::Quaterniond::Identity(), {1, 2, 0})));
    m.transforms.push_back(transform("/odom", "base_footprint", t, footprintAt(t)));  // a leading '/' is tf1's
    if (edit) edit(k, m.transforms.back());
    b.write("/tf", ros::Time(t), m);
  }
  return path;
}

// odom -> base_link chained through base_footprint (moving) and base_footprint -> base_link (static):
// found by REP-105's names, at the moving transform's stamps, the product of the two.
TEST(BagDataset, OdometryFromTfChainsThroughStaticTransforms) {
  test::TempDir dir;
  const fs::path bag = writeTfBag(dir / "tf.bag");
  const auto ds = open(bag);
  ASSERT_TRUE(ds->odometry().has_value());
  EXPECT_EQ(ds->odometry()->from, "tf");
  EXPECT_EQ(ds->odometry()->source, bag.string() + ":tf odom -> base_link");
  const Trajectory odo = ds->odometry()->T_odom_base;  // odometry() returns a copy
  ASSERT_EQ(odo.size(), 8u);
  for (size_t k = 0; k < odo.size(); ++k) {
    const double t = fromRosTimeForTest(0.95 + 0.05 * static_cast<double>(k));
    EXPECT_EQ(odo[k].timestamp, t) << k;
    const SE3 expected = footprintAt(0.95 + 0.05 * static_cast<double>(k)) * kFootprintToBase;
    EXPECT_LT((odo[k].pose.translation() - expected.translation()).norm(), 1e-12) << k;
    EXPECT_LT(odo[k].pose.rotation().angularDistance(expected.rotation()), 1e-12) << k;
  }
  // Frames named: a single moving transform comes back exactly as recorded (odom -> base_footprint),
  // and a chain up and down the tree (base_footprint -> camera, both below odom) works too.
  DatasetOptions o;
  o.odom_frame = "odom";
  o.base_frame = "base_footprint";
  const auto raw = open(bag, o);
  for (size_t k = 0; k < 8; ++k) {
    const SE3 T = footprintAt(0.95 + 0.05 * static_cast<double>(k));
    EXPECT_EQ(raw->odometry()->T_odom_base[k].pose.translation(), T.translation()) << k;
    EXPECT_LT((raw->odometry()->T_odom_base[k].pose.rotation().coeffs() - T.rotation().coeffs()).norm(), 1e-15) << k;
  }
  o.odom_frame = "map";
  o.base_frame = "camera";
  const auto cam = open(bag, o);
  const SE3 expected = SE3(Eigen::Quaterniond::Identity(), {1, 2, 0}) * footprintAt(1.0) * kFootprintToBase *
                       SE3(Eigen::Quaterniond::Identity(), {0.1, 0, 0.3});
  EXPECT_LT((cam->odometry()->T_odom_base[1].pose.translation() - expected.translation()).norm(), 1e-12);
  // Ground truth from tf frames: the camera's pose in map at the frames' stamps (1.0, 1.1, 1.2 s).
  DatasetOptions g;
  g.groundtruth_parent_frame = "map";
  g.groundtruth_child_frame = "camera";
  const auto gt = open(bag, g);
  ASSERT_TRUE(gt->hasGroundTruth());
  EXPECT_LT((gt->groundTruth(0)->translation() - expected.translation()).norm(), 1e-9);
}

// Two moving transforms in the chain, at different stamps: the pose at every stamp of either, where
// both have samples; each link interpolated between its own samples (translation linearly, rotation
// by slerp), as tf2 does.
TEST(BagDataset, OdometryFromTfInterpolatesMovingLinksAtEachOthersStamps) {
  test::TempDir dir;
  const fs::path bag = writeTfBag(dir / "two.bag", {}, false);
  {
    rosbag::Bag b(bag.string(), rosbag::bagmode::Append);
    for (int k = 0; k < 4; ++k) {  // base_footprint -> base_link moving too, at 1.02, 1.12, ...
      const double t = 1.02 + 0.1 * k;
      tf2_msgs::TFMessage m;
      m.transforms.push_back(
          transform("base_footprint", "base_link", t, SE3(Eigen::Quaterniond::Identity(), {0, 0, t})));
      b.write("/tf", ros::Time(t), m);
    }
  }
  const auto ds = open(bag);
  const Trajectory odo = ds->odometry()->T_odom_base;  // odometry() returns a copy
  // Stamps of either link within 1.02 .. 1.30 s: 1.05, 1.10, ..., 1.30 (6) and 1.02, 1.12, 1.22 (3;
  // 1.32 is past odom -> base_footprint's last).
  ASSERT_EQ(odo.size(), 9u);
  EXPECT_EQ(odo.front().timestamp, fromRosTimeForTest(1.02));
  // At 1.02 s: odom -> base_footprint between its samples at 1.00 and 1.05.
  const SE3 a = footprintAt(1.0), b = footprintAt(1.05);
  const double s =
      (fromRosTimeForTest(1.02) - fromRosTimeForTest(1.0)) / (fromRosTimeForTest(1.05) - fromRosTimeForTest(1.0));
  const SE3 fp(a.rotation().slerp(s, b.rotation()), (1 - s) * a.translation() + s * b.translation());
  const SE3 expected = fp * SE3(Eigen::Quaterniond::Identity(), {0, 0, 1.02});
  EXPECT_LT((odo.front().pose.translation() - expected.translation()).norm(), 1e-9);
  EXPECT_LT(odo.front().pose.rotation().angularDistance(expected.rotation()), 1e-9);
}

// tf's older message type, tf/tfMessage (the same fields and MD5), is read the same way.
TEST(BagDataset, OdometryFromTf1Messages) {
#if __has_include(<tf/tfMessage.h>)
  test::TempDir dir;
  const fs::path bag = writeBag(dir / "tf1.bag", {3, "mono8"});
  {
    rosbag::Bag b(bag.string(), rosbag::bagmode::Append);
    for (int k = 0; k < 5; ++k) {
      tf::tfMessage m;
      m.transforms.push_back(transform("odom", "base_link", 1.0 + 0.1 * k, footprintAt(1.0 + 0.1 * k)));
      b.write("/tf", ros::Time(1.0 + 0.1 * k), m);
    }
  }
  const auto ds = open(bag);
  ASSERT_TRUE(ds->odometry().has_value());
  EXPECT_EQ(ds->odometry()->T_odom_base.size(), 5u);
  EXPECT_EQ(ds->odometry()->from, "tf");
#else
  GTEST_SKIP() << "no tf/tfMessage.h here (libtf-dev)";
#endif
}

// An Odometry topic wins over tf unless frames are named; naming both is refused.
TEST(BagDataset, OdometryTopicWinsOverTfUnlessFramesAreNamed) {
  test::TempDir dir;
  const fs::path bag = writeTfBag(dir / "both.bag");
  {
    rosbag::Bag b(bag.string(), rosbag::bagmode::Append);
    for (int k = 0; k < 4; ++k) {
      nav_msgs::Odometry m;
      m.header.stamp = ros::Time(1.0 + 0.1 * k);
      m.pose.pose.orientation.w = 1;
      b.write("/wheel", ros::Time(1.0 + 0.1 * k), m);
    }
  }
  EXPECT_EQ(open(bag)->odometry()->from, "topic");
  EXPECT_EQ(open(bag)->odometry()->T_odom_base.size(), 4u);
  DatasetOptions o;
  o.odom_frame = "odom";
  o.base_frame = "base_link";
  EXPECT_EQ(open(bag, o)->odometry()->from, "tf");
  o.odometry_topic = "/wheel";
  const std::string e = test::errorOf([&] { open(bag, o); });
  EXPECT_NE(e.find("--odometry-topic '/wheel' and --odometry-frames both given"), std::string::npos) << e;
  // A bag without odom or base_link in its tf and without an Odometry topic: no odometry.
  DatasetOptions none;
  EXPECT_FALSE(open(writeBag(dir / "plain.bag", {3, "mono8"}), none)->odometry().has_value());
}

// Bad tf: an Error naming the bag, the topic, the message and the frames.
TEST(BagDataset, BadTfIsRefusedNamingBagTopicMessageAndFrames) {
  test::TempDir dir;
  const auto refused = [&](const fs::path& bag, DatasetOptions o, const std::vector<std::string>& parts) {
    const std::string e = test::errorOf([&] { open(bag, o); });
    EXPECT_NE(e.find(bag.string()), std::string::npos) << e;
    for (const auto& p : parts) EXPECT_NE(e.find(p), std::string::npos) << "'" << p << "' not in: " << e;
  };
  DatasetOptions named;
  named.odom_frame = "odom";
  named.base_frame = "base_link";
  // Frames the tf does not have.
  DatasetOptions missing = named;
  missing.base_frame = "base_nope";
  refused(writeTfBag(dir / "ok.bag"), missing,
          {"odometry 'odom' -> 'base_nope' (--odometry-frames)", "no frame 'base_nope'", "/tf, /tf_static",
           "base_footprint"});
  // A broken chain: without /tf_static nothing links base_link to odom... base_link is not there at
  // all; with base_link published under another root, the chain is broken.
  {
    const fs::path bag = writeTfBag(dir / "broken.bag", {}, false);
    rosbag::Bag b(bag.string(), rosbag::bagmode::Append);
    tf2_msgs::TFMessage s;
    s.transforms.push_back(transform("robot_root", "base_link", 0, SE3()));
    b.write("/tf_static", ros::Time(0.5), s);
  }
  refused(dir / "broken.bag", {},
          {"odometry 'odom' -> 'base_link'", "the chain is broken", "'base_link' -> 'robot_root'", "'odom' -> 'map'"});
  // Stamps going back on the moving transform.
  refused(writeTfBag(dir / "back.bag",
                     [](int k, geometry_msgs::TransformStamped& ts) {
                       if (k == 5) ts.header.stamp = ros::Time(1.0);
                     }),
          named, {"topic '/tf', message 5, transform 'odom' -> 'base_footprint'", "stamps go back", "header.stamp"});
  // A non-finite value and a quaternion that is not a unit one.
  refused(writeTfBag(dir / "nan.bag",
                     [](int k, geometry_msgs::TransformStamped& ts) {
                       if (k == 2) ts.transform.translation.y = std::nan("");
                     }),
          named, {"topic '/tf', message 2, transform 'odom' -> 'base_footprint'", "field 'transform'", "not finite"});
  refused(writeTfBag(dir / "quat.bag",
                     [](int k, geometry_msgs::TransformStamped& ts) {
                       if (k == 3) ts.transform.rotation.w = 3;
                     }),
          named, {"message 3, transform 'odom' -> 'base_footprint'", "'transform.rotation'", "not a unit quaternion"});
  // base_link with two parents (a second tree claims it).
  {
    const fs::path bag = writeTfBag(dir / "parents.bag");
    rosbag::Bag b(bag.string(), rosbag::bagmode::Append);
    tf2_msgs::TFMessage m;
    m.transforms.push_back(transform("other", "base_link", 1.1, SE3()));
    b.write("/tf", ros::Time(1.1), m);
  }
  refused(dir / "parents.bag", named, {"frame 'base_link' has two parents", "'base_footprint' (topic '/tf_static'"});
  // Frames named in a bag without tf; the chain only static.
  refused(writeBag(dir / "notf.bag", {3, "mono8"}), named, {"--odometry-frames odom,base_link", "no tf topic"});
  DatasetOptions fixed = named;
  fixed.odom_frame = "base_footprint";
  refused(dir / "ok.bag", fixed, {"'base_footprint' -> 'base_link'", "static"});
  // A transform that is bad but not on the chain asked for does not refuse the bag.
  {
    const fs::path bag = writeTfBag(dir / "elsewhere.bag");
    rosbag::Bag b(bag.string(), rosbag::bagmode::Append);
    tf2_msgs::TFMessage m;
    m.transforms.push_back(transform("base_link", "lidar", 1.1, SE3()));
    m.transforms.back().transform.rotation.w = 5;
    b.write("/tf", ros::Time(1.1), m);
  }
  EXPECT_EQ(open(dir / "elsewhere.bag", named)->odometry()->T_odom_base.size(), 8u);
}

// Not a bag, a truncated bag, a directory.
TEST(BagDataset, NotABagTruncatedOrADirectory) {
  test::TempDir dir;
  test::writeText(dir / "text.bag", "this is not a bag\n");
  std::string e = test::errorOf([&] { open(dir / "text.bag"); });
  EXPECT_NE(e.find("text.bag: not a readable ROS bag"), std::string::npos) << e;
  const fs::path good = writeBag(dir / "good.bag", {4, "mono8"});
  std::string bytes;
  {
    std::ifstream f(good, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(f), {});
  }
  test::writeText(dir / "cut.bag", bytes.substr(0, bytes.size() / 2));
  e = test::errorOf([&] { open(dir / "cut.bag"); });
  EXPECT_NE(e.find("cut.bag"), std::string::npos) << e;
  EXPECT_FALSE(e.empty());
  fs::create_directories(dir / "d.bag");
  e = test::errorOf([&] { open(dir / "d.bag"); });
  EXPECT_NE(e.find("is a directory"), std::string::npos) << e;
}

// Random damage to a bag's bytes: an Error, never a crash. librosbag reads some damaged records out
// of bounds; the checking child (src/io/bag/dataset_bag.cpp) takes that crash and it is named.
TEST(BagDataset, DamagedBytesAreRefusedNeverACrash) {
  test::TempDir dir;
  const fs::path good = writeBag(dir / "good.bag", {4, "mono8"});
  std::string bytes;
  {
    std::ifstream f(good, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(f), {});
  }
  // Damage: 8 random bytes changed, 80 times (fixed seed); each bag opens and loads cleanly or is
  // refused with an Error (some of them crash librosbag in the checking child: named as such).
  std::mt19937 rng(24);
  int refused = 0, crashed = 0;
  for (int trial = 0; trial < 80; ++trial) {
    std::string b = bytes;
    for (int k = 0; k < 8; ++k) b[rng() % b.size()] = static_cast<char>(rng() & 0xff);
    const fs::path p = dir / "damaged.bag";
    test::writeText(p, b);
    try {
      const auto ds = open(p);
      for (size_t i = 0; i < ds->size(); ++i) ds->load(i);
    } catch (const Error& err) {
      ++refused;
      crashed += std::string(err.what()).find("crashed librosbag") != std::string::npos;
    }
  }
  std::printf("damaged bags refused: %d of 80 (%d crashed librosbag in the checking child)\n", refused, crashed);
  EXPECT_GT(refused, 0);
}

// The CLI: a bad bag is exit status 1 with the message, and no output folder is written.
TEST(BagDataset, RunOnABadBagExitsWithTheMessage) {
  test::TempDir dir;
  const fs::path bag = writeBag(dir / "y.bag", {3, "yuv422"});
  const auto r =
      test::runCli("run --no-nerf --dataset bag:'" + bag.string() + "' --out '" + (dir / "out").string() + "'");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("unsupported encoding 'yuv422'"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "out"));
  // A bag whose odometry has no time in common with its images: refused as `--odometry` would be.
  const fs::path far = writeBag(dir / "far.bag", {4, "mono8"});
  {
    rosbag::Bag b(far.string(), rosbag::bagmode::Append);
    for (int k = 0; k < 3; ++k) {
      nav_msgs::Odometry m;
      m.header.stamp = ros::Time(100.0 + k);
      m.pose.pose.orientation.w = 1;
      b.write("/wheel_odom", ros::Time(100.0 + k), m);
    }
  }
  const auto r2 =
      test::runCli("run --no-nerf --dataset bag:'" + far.string() + "' --out '" + (dir / "out").string() + "'");
  EXPECT_EQ(r2.exit_code, 1) << r2.output;
  EXPECT_NE(r2.output.find("far.bag:/wheel_odom: field 'timestamp': the odometry does not overlap the images"),
            std::string::npos)
      << r2.output;
  EXPECT_FALSE(fs::exists(dir / "out"));
}

}  // namespace
}  // namespace nerfslam

#else

TEST(BagDataset, NotBuilt) { GTEST_SKIP() << "built without ROS bag support (librosbag-storage-dev)"; }

#endif
