// Video files as datasets (`video:FILE`, src/io/reader_video.cpp): frames and container timestamps
// read back from a lossless video, random access, and the bad inputs.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/dataset.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

// Writes `frames` (BGR) at `fps` losslessly: FFV1 in Matroska, else HuffYUV in AVI. Returns the
// file, or an empty path when OpenCV here has neither.
fs::path writeLosslessVideo(const fs::path& dir, const std::vector<cv::Mat>& frames, double fps) {
  for (const auto& [fourcc, name] : {std::pair{"FFV1", "v.mkv"}, std::pair{"HFYU", "v.avi"}}) {
    const fs::path p = dir / name;
    cv::VideoWriter w(p.string(), cv::CAP_FFMPEG, cv::VideoWriter::fourcc(fourcc[0], fourcc[1], fourcc[2], fourcc[3]),
                      fps, frames.front().size());
    if (!w.isOpened()) continue;
    for (const auto& f : frames) w.write(f);
    w.release();
    return p;
  }
  return {};
}

std::vector<cv::Mat> noiseFrames(int n, int w, int h) {
  std::vector<cv::Mat> out;
  for (int i = 0; i < n; ++i) {
    cv::Mat g = test::noiseImage(w, h, 100 + i), bgr;
    cv::cvtColor(g, bgr, cv::COLOR_GRAY2BGR);
    out.push_back(bgr);
  }
  return out;
}

void writeCameraFile(const fs::path& p, int w, int h) {
  Camera c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = 100;
  c.cx = (w - 1) / 2.0;
  c.cy = (h - 1) / 2.0;
  saveCameraYaml(c, p);
}

TEST(VideoDataset, LosslessVideoReadsBackTheFramesAndStamps) {
  test::TempDir tmp;
  const auto frames = noiseFrames(6, 64, 48);
  const fs::path video = writeLosslessVideo(tmp.path(), frames, 30);
  if (video.empty()) GTEST_SKIP() << "OpenCV here has no lossless video codec (FFV1, HuffYUV)";
  writeCameraFile(tmp / "cam.yaml", 64, 48);
  DatasetOptions o;
  o.camera_override = tmp / "cam.yaml";
  auto ds = openDataset("video:" + video.string(), o);
  EXPECT_EQ(ds->kind(), "video");
  ASSERT_EQ(ds->size(), 6u);
  EXPECT_FALSE(ds->hasGroundTruth());
  for (size_t i = 0; i < 6; ++i) EXPECT_NEAR(ds->timestamp(i), i / 30.0, 1e-3) << i;  // ms in Matroska
  // Sequential, then back and forth: every frame exactly as written.
  for (size_t i : {0, 1, 2, 3, 4, 5, 2, 0, 5}) {
    const DatasetFrame f = ds->load(i, ImageMode::kColor);
    EXPECT_EQ(cv::norm(f.image, frames[i], cv::NORM_INF), 0.0) << i;
    EXPECT_EQ(ds->load(i, ImageMode::kGray).image.type(), CV_8UC1);
  }
  // Detected from the extension; start / stride / max_frames.
  o.start = 1;
  o.stride = 2;
  auto sub = openDataset(video.string(), o);
  ASSERT_EQ(sub->size(), 3u);
  EXPECT_NEAR(sub->timestamp(1), 3 / 30.0, 1e-3);
  EXPECT_EQ(cv::norm(sub->load(2, ImageMode::kColor).image, frames[5], cv::NORM_INF), 0.0);
}

TEST(VideoDataset, BadVideosAreClearErrors) {
  test::TempDir tmp;
  writeCameraFile(tmp / "cam.yaml", 64, 48);
  DatasetOptions o;
  o.camera_override = tmp / "cam.yaml";
  test::writeText(tmp / "text.mp4", "this is not a video\n");
  std::string e = test::errorOf([&] { openDataset("video:" + (tmp / "text.mp4").string(), o); });
  EXPECT_NE(e.find("text.mp4"), std::string::npos) << e;
  EXPECT_TRUE(e.find("cannot open the video") != std::string::npos ||
              e.find("no frame could be decoded") != std::string::npos)
      << e;
  e = test::errorOf([&] { openDataset("video:" + (tmp / "missing.mkv").string(), o); });
  EXPECT_NE(e.find("missing.mkv: dataset path not found"), std::string::npos) << e;
  const fs::path video = writeLosslessVideo(tmp.path(), noiseFrames(3, 64, 48), 30);
  if (video.empty()) GTEST_SKIP() << "OpenCV here has no lossless video codec (FFV1, HuffYUV)";
  e = test::errorOf([&] { openDataset("video:" + video.string(), DatasetOptions{}); });
  EXPECT_NE(e.find("a video has no camera calibration; give a camera YAML (--camera)"), std::string::npos) << e;
  writeCameraFile(tmp / "cam80.yaml", 80, 60);
  o.camera_override = tmp / "cam80.yaml";
  e = test::errorOf([&] { openDataset("video:" + video.string(), o); });
  EXPECT_NE(e.find("cam80.yaml: camera is 80x60 but the video's frames are 64x48"), std::string::npos) << e;
  e = test::errorOf([&] { openDataset("video:" + tmp.path().string(), o); });
  EXPECT_NE(e.find("is a directory, not a video file"), std::string::npos) << e;
}

}  // namespace
}  // namespace nerfslam
