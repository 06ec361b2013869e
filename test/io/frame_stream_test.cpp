// Live frame sources and their recording (io/frame_stream.h): camera specs, a device that is not
// there, a video file played as a camera, and a recording that reads back as the identical folder
// dataset (pixels and timestamps).
#include <gtest/gtest.h>

#include <fmt/format.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/frame_stream.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

TEST(FrameStream, CameraSpecs) {
  EXPECT_TRUE(isCameraSpec("camera:/dev/video0"));
  EXPECT_FALSE(isCameraSpec("folder:/dev/video0"));
  EXPECT_EQ(cameraDevice("camera:/dev/video2"), "/dev/video2");
  EXPECT_EQ(cameraDevice("camera:3"), "/dev/video3");
  EXPECT_NE(test::errorOf([] { cameraDevice("camera:"); }).find("no device after 'camera:'"), std::string::npos);
  // Other commands than `run` cannot read a stream: said so, not "unknown kind".
  const std::string e = test::errorOf([] { openDataset("camera:/dev/video0"); });
  EXPECT_NE(e.find("is a live camera"), std::string::npos) << e;
}

TEST(FrameStream, MissingDeviceOrFileIsNamed) {
  std::string e = test::errorOf([] { openCameraStream("/dev/video99", 640, 480); });
  EXPECT_NE(e.find("/dev/video99: no such camera device (camera:/dev/video99)"), std::string::npos) << e;
  EXPECT_NE(e.find("the video devices here:"), std::string::npos) << e;
  test::TempDir dir;
  e = test::errorOf([&] { openVideoFileStream(dir / "none.mkv", false); });
  EXPECT_NE(e.find("none.mkv: no such video file"), std::string::npos) << e;
  test::writeText(dir / "text.mkv", "not a video\n");
  e = test::errorOf([&] {
    auto s = openVideoFileStream(dir / "text.mkv", false);
    StreamFrame f;
    std::string why;
    if (s->read(f, why)) throw Error("a frame from a text file");
  });
  EXPECT_TRUE(e.empty() || e.find("text.mkv") != std::string::npos) << e;
}

// A video file through the stream: every frame, at the container's timestamps, then the end (no
// error); the same frames and stamps as the `video:` dataset reads.
TEST(FrameStream, VideoFilePlaysAsAStream) {
  test::TempDir dir;
  const fs::path video = dir / "v.mkv";
  {
    cv::VideoWriter w(video.string(), cv::CAP_FFMPEG, cv::VideoWriter::fourcc('F', 'F', 'V', '1'), 25,
                      cv::Size(64, 48));
    if (!w.isOpened()) GTEST_SKIP() << "OpenCV here cannot write FFV1 (lossless) video";
    for (int i = 0; i < 12; ++i) {
      cv::Mat g = test::noiseImage(64, 48, 3 + i), bgr;
      cv::cvtColor(g, bgr, cv::COLOR_GRAY2BGR);
      w.write(bgr);
    }
  }
  saveCameraYaml(Camera::pinhole(64, 48, 50, 50, 32, 24), dir / "cam.yaml");
  DatasetOptions o;
  o.camera_override = dir / "cam.yaml";
  const auto ds = openDataset("video:" + video.string(), o);
  auto s = openVideoFileStream(video, false);
  EXPECT_EQ(s->name(), video.string());
  StreamFrame f;
  std::string why;
  size_t n = 0;
  while (s->read(f, why)) {
    ASSERT_LT(n, ds->size());
    EXPECT_EQ(f.timestamp, ds->timestamp(n)) << n;
    EXPECT_EQ(cv::norm(f.image, ds->load(n, ImageMode::kColor).image, cv::NORM_INF), 0.0) << n;
    ++n;
  }
  EXPECT_EQ(n, 12u);
  EXPECT_TRUE(why.empty()) << why;
}

// Frames appended to a recording come back from it and from the folder as a `folder:` dataset: the
// same pixels (PNG), the same timestamps to the bit, the camera file's calibration.
TEST(FrameStream, RecordingReadsBackAsTheIdenticalFolderDataset) {
  test::TempDir dir;
  const Camera cam = Camera::pinhole(64, 48, 50.125, 50.5, 31.75, 23.5);
  saveCameraYaml(cam, dir / "cam.yaml");
  std::vector<double> stamps;
  std::vector<cv::Mat> images;
  {
    StreamRecording rec("/dev/video5", dir / "out" / "frames", cam, dir / "cam.yaml");
    EXPECT_EQ(rec.kind(), "camera");
    EXPECT_EQ(rec.root(), fs::path("/dev/video5"));
    for (int i = 0; i < 100; ++i) {
      // Stamps no short decimal text gives exactly (a monotonic clock's seconds since boot).
      stamps.push_back(12345.0 + i / 3.0 + 0.1 + 0.2);
      cv::Mat g = test::noiseImage(64, 48, 40 + i), bgr;
      cv::cvtColor(g, bgr, cv::COLOR_GRAY2BGR);
      images.push_back(bgr);
      EXPECT_EQ(rec.append(stamps.back(), bgr), static_cast<size_t>(i));
    }
    EXPECT_EQ(rec.size(), 100u);
    EXPECT_EQ(cv::norm(rec.load(57, ImageMode::kColor).image, images[57], cv::NORM_INF), 0.0);
    rec.flush();
    EXPECT_EQ(rec.timestamp(99), stamps[99]);
    EXPECT_NE(test::errorOf([&] { rec.load(100); }).find("frame index 100 out of range"), std::string::npos);
  }
  const auto folder = openDataset("folder:" + (dir / "out" / "frames").string());
  ASSERT_EQ(folder->size(), 100u);
  EXPECT_EQ(folder->camera().fx, cam.fx);
  EXPECT_EQ(folder->camera().cx, cam.cx);
  for (size_t i = 0; i < folder->size(); ++i) {
    EXPECT_EQ(folder->timestamp(i), stamps[i]) << i;
    EXPECT_EQ(cv::norm(folder->load(i, ImageMode::kColor).image, images[i], cv::NORM_INF), 0.0) << i;
  }
  // The same folder again: refused (its frames would be replayed with the next run's).
  const std::string e =
      test::errorOf([&] { StreamRecording again("/dev/video5", dir / "out" / "frames", cam, dir / "cam.yaml"); });
  EXPECT_NE(e.find("frames: the folder for the camera's frames already holds files"), std::string::npos) << e;
}

// The tracking thread's tryAppend never waits for the disk: with kMaxPending frames waiting for the
// PNG writer it records nothing (nullopt), and the frames it did record are numbered without gaps
// and replay as the folder dataset, in order.
TEST(FrameStream, RecordingThatFallsBehindDropsInsteadOfWaiting) {
  test::TempDir dir;
  const Camera cam = Camera::pinhole(1024, 1024, 800, 800, 511.5, 511.5);
  saveCameraYaml(cam, dir / "cam.yaml");
  std::vector<double> accepted;
  std::vector<int> seeds;
  size_t dropped = 0;
  {
    StreamRecording rec("/dev/video5", dir / "out" / "frames", cam, dir / "cam.yaml");
    // Noise compresses badly: each 1024x1024 PNG takes the writer milliseconds, appending takes
    // microseconds, so the backlog fills at once.
    std::vector<cv::Mat> images;
    for (int k = 0; k < 4; ++k) images.push_back(test::noiseImage(1024, 1024, 7 + k));
    for (int i = 0; i < 3 * int(StreamRecording::kMaxPending); ++i) {
      const double stamp = 100.0 + 0.04 * i;
      const auto index = rec.tryAppend(stamp, images[size_t(i % 4)]);
      if (!index) {
        ++dropped;
        continue;
      }
      EXPECT_EQ(*index, accepted.size());
      accepted.push_back(stamp);
      seeds.push_back(i % 4);
    }
    EXPECT_GT(dropped, 0u) << "the writer kept up with 192 noise frames appended in a loop";
    EXPECT_GE(accepted.size(), StreamRecording::kMaxPending);
    rec.flush();
  }
  const auto folder = openDataset("folder:" + (dir / "out" / "frames").string());
  ASSERT_EQ(folder->size(), accepted.size());
  for (size_t i = 0; i < accepted.size(); ++i) {
    EXPECT_EQ(folder->timestamp(i), accepted[i]) << i;
    EXPECT_EQ(
        cv::norm(folder->load(i, ImageMode::kGray).image, test::noiseImage(1024, 1024, 7 + seeds[i]), cv::NORM_INF),
        0.0)
        << i;
  }
}

}  // namespace
}  // namespace nerfslam
