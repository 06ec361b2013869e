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
