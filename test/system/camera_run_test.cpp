// `run --dataset camera:DEVICE` end to end, through the injected capture source (RunOptions::
// open_stream; there is no camera on the test machines): a video file played through VideoCapture,
// or a synthetic source of a dataset's frames. Every frame that reaches tracking is recorded in
// OUT/frames, and that folder replays to the same trajectory, bit for bit, in the same (lockstep)
// mode; with --realtime the oldest waiting frame is dropped and only the tracked frames are recorded;
// --max-frames and a stop request end the run with its outputs; a device that is not there, or that
// stops delivering, is an error naming it.
#include <gtest/gtest.h>

#include <csignal>
#include <fstream>
#include <sstream>
#include <thread>

#include <fmt/format.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "nerfslam/core/input_file.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/core/stop_signal.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/frame_stream.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/runner.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

// A dataset's colour frames as a live source, at its timestamps; `period_ms` > 0 delivers one frame
// per period (a camera's rate), 0 as fast as asked. After `fail_after` frames it fails as a device
// that stops delivering; `on_frame` runs as each frame is delivered.
class DatasetStream : public FrameStream {
 public:
  DatasetStream(std::shared_ptr<const Dataset> ds, double period_ms = 0, size_t fail_after = SIZE_MAX,
                std::function<void(size_t)> on_frame = {})
      : ds_(std::move(ds)), period_ms_(period_ms), fail_after_(fail_after), on_frame_(std::move(on_frame)) {}
  std::string name() const override { return "synthetic-camera"; }
  bool read(StreamFrame& f, std::string& why) override {
    if (next_ >= fail_after_) {
      why = "synthetic-camera: the camera stopped delivering frames";
      return false;
    }
    if (next_ >= ds_->size()) return false;
    if (period_ms_ > 0) std::this_thread::sleep_for(std::chrono::microseconds(static_cast<int>(period_ms_ * 1000)));
    const DatasetFrame d = ds_->load(next_, ImageMode::kColor);
    f.timestamp = d.timestamp;
    f.image = d.image;
    if (on_frame_) on_frame_(next_);
    ++next_;
    return true;
  }

 private:
  std::shared_ptr<const Dataset> ds_;
  double period_ms_;
  size_t fail_after_;
  std::function<void(size_t)> on_frame_;
  size_t next_ = 0;
};

struct Sequence {
  test::TempDir dir;
  std::shared_ptr<const Dataset> ds;
  fs::path camera;
};

// The synthetic room, 320x240.
std::unique_ptr<Sequence> room(int frames) {
  auto s = std::make_unique<Sequence>();
  SynthOptions so;
  so.scene = "room";
  so.frames = frames;
  so.width = 320;
  so.height = 240;
  so.textures = "procedural";
  writeSynthSequence(so, s->dir / "seq");
  s->ds = openDataset("tum:" + (s->dir / "seq").string());
  s->camera = s->dir / "seq" / "camera.yaml";
  return s;
}

RunOptions options(const std::string& dataset, const fs::path& out, const fs::path& camera) {
  RunOptions ro;
  ro.dataset = dataset;
  ro.camera = camera;
  ro.config = test::sourceDir() / "config" / "system" / "synthetic.yaml";
  ro.out = out;
  ro.progress = false;
  ro.nerf = false;
  ro.save_default_map = false;
  return ro;
}

size_t lines(const std::string& s) { return static_cast<size_t>(std::count(s.begin(), s.end(), '\n')); }

// A lossless video through VideoCapture as the camera, lockstep: every frame recorded, at the
// container's timestamps; the recorded folder replays to the same trajectory and keyframes, byte for
// byte, and the same video read as a `video:` dataset tracks the same too.
TEST(CameraRun, VideoStreamRecordsFramesThatReplayToTheSameTrajectory) {
  const auto s = room(60);
  const fs::path video = s->dir / "room.mkv";
  {
    cv::VideoWriter w(video.string(), cv::CAP_FFMPEG, cv::VideoWriter::fourcc('F', 'F', 'V', '1'), 30,
                      cv::Size(320, 240));
    if (!w.isOpened()) GTEST_SKIP() << "OpenCV here cannot write FFV1 (lossless) video";
    for (size_t i = 0; i < s->ds->size(); ++i) w.write(s->ds->load(i, ImageMode::kColor).image);
  }
  RunOptions ro = options("camera:/dev/video7", s->dir / "cam_out", s->camera);
  std::string opened;
  ro.open_stream = [&](const std::string& device) {
    opened = device;
    return openVideoFileStream(video, false);
  };
  const RunResult rc = runSlam(ro);
  ASSERT_EQ(rc.exit_code, 0);
  EXPECT_EQ(opened, "/dev/video7");
  EXPECT_EQ(rc.report.at("dataset_kind").get<std::string>(), "camera");
  EXPECT_EQ(rc.report.at("camera").at("device").get<std::string>(), video.string());
  EXPECT_EQ(rc.report.at("camera").at("frames_read").get<int>(), 60);
  EXPECT_EQ(rc.report.at("camera").at("frames_recorded").get<int>(), 60);
  EXPECT_EQ(rc.report.at("frames").get<int>(), 60);
  EXPECT_GT(rc.report.at("frames_tracked").get<int>(), 50);
  const fs::path frames = s->dir / "cam_out" / "frames";
  EXPECT_EQ(listImages(frames).size(), 60u);
  EXPECT_EQ(lines(readInputFile(frames / "times.txt")), 60u);
  EXPECT_EQ(readInputFile(frames / "camera.yaml"), readInputFile(s->camera));
  // The timestamps are the container's (the capture clock of a file).
  DatasetOptions vo;
  vo.camera_override = s->camera;
  const auto vds = openDataset("video:" + video.string(), vo);
  const auto rec = openDataset("folder:" + frames.string());
  for (size_t i = 0; i < 60; ++i) EXPECT_EQ(rec->timestamp(i), vds->timestamp(i)) << i;

  // Replayed: the same trajectory and keyframes, byte for byte; the `video:` run too.
  const RunResult rr = runSlam(options("folder:" + frames.string(), s->dir / "replay_out", s->camera));
  ASSERT_EQ(rr.exit_code, 0);
  const std::string traj = readInputFile(s->dir / "cam_out" / "trajectory.txt");
  EXPECT_GT(lines(traj), 50u);
  EXPECT_EQ(readInputFile(s->dir / "replay_out" / "trajectory.txt"), traj);
  EXPECT_EQ(readInputFile(s->dir / "replay_out" / "keyframes.txt"),
            readInputFile(s->dir / "cam_out" / "keyframes.txt"));
  const RunResult rv = runSlam(options("video:" + video.string(), s->dir / "video_out", s->camera));
  ASSERT_EQ(rv.exit_code, 0);
  EXPECT_EQ(readInputFile(s->dir / "video_out" / "trajectory.txt"), traj);
}

// With the NeRF: the stream's colour frames are recorded, and the end-of-run outputs read their frames
// from the recording (the held-out frames rendered beside the real ones and scored).
TEST(CameraRun, NerfOutputsReadTheRecordedFrames) {
  const auto s = room(45);
  RunOptions ro = options("camera:/dev/video0", s->dir / "out", s->camera);
  SystemOptions sys;
  loadOptionsFile(*ro.config, sys);
  sys.nerf.final_train_steps = 30;
  sys.nerf.outputs.heldout_frames = 2;
  sys.nerf.outputs.keyframe_frames = 1;
  sys.nerf.outputs.flythrough_frames = 0;
  ro.system = sys;
  ro.nerf = true;
  ro.open_stream = [&](const std::string&) { return std::make_unique<DatasetStream>(s->ds); };
  const RunResult r = runSlam(ro);
  ASSERT_EQ(r.exit_code, 0) << r.report.dump(2);
  EXPECT_EQ(r.report.at("camera").at("frames_recorded").get<int>(), 45);
  EXPECT_FALSE(r.report.contains("nerf_error")) << r.report.dump(2);
  ASSERT_TRUE(r.report.contains("nerf_psnr_heldout")) << r.report.dump(2);
  EXPECT_EQ(r.report.at("nerf_psnr_heldout_frames").get<int>(), 2);
  size_t heldout = 0;
  for (const auto& e : fs::directory_iterator(s->dir / "out" / "nerf" / "heldout")) heldout += e.is_regular_file();
  EXPECT_GE(heldout, 2u);
  // Colour recorded as delivered.
  const auto rec = openDataset("folder:" + (s->dir / "out" / "frames").string());
  EXPECT_EQ(cv::norm(rec->load(7, ImageMode::kColor).image, s->ds->load(7, ImageMode::kColor).image, cv::NORM_INF),
            0.0);
}

// --realtime with a source faster than tracking: a frame that arrives while tracking is busy drops
// the oldest waiting one; exactly the frames that reached tracking are recorded (read = tracked +
// dropped), each the source's frame at its timestamp, pixel for pixel.
TEST(CameraRun, RealtimeDropsTheOldestAndRecordsOnlyTrackedFrames) {
  const auto s = room(80);
  RunOptions ro = options("camera:0", s->dir / "out", s->camera);
  ro.realtime = true;
  ro.open_stream = [&](const std::string&) { return std::make_unique<DatasetStream>(s->ds, 1.0); };
  const RunResult r = runSlam(ro);
  ASSERT_EQ(r.exit_code, 0);
  const size_t read = r.report.at("camera").at("frames_read").get<size_t>();
  const size_t recorded = r.report.at("camera").at("frames_recorded").get<size_t>();
  const size_t dropped = r.report.at("frames_dropped").get<size_t>();
  std::printf("realtime camera: %zu frames read, %zu tracked and recorded, %zu dropped\n", read, recorded, dropped);
  EXPECT_EQ(read, 80u);
  EXPECT_GT(dropped, 0u);
  EXPECT_EQ(recorded + dropped, read);
  EXPECT_EQ(r.report.at("frames_processed").get<size_t>(), recorded);
  const auto rec = openDataset("folder:" + (s->dir / "out" / "frames").string());
  ASSERT_EQ(rec->size(), recorded);
  size_t j = 0;
  for (size_t i = 0; i < rec->size(); ++i) {
    while (j < s->ds->size() && s->ds->timestamp(j) < rec->timestamp(i)) ++j;
    ASSERT_LT(j, s->ds->size());
    EXPECT_EQ(s->ds->timestamp(j), rec->timestamp(i)) << i;
    // The source's colour frame made grey as the run makes it (OpenCV's cvtColor; a PNG decoder's
    // grey rounds differently).
    cv::Mat grey;
    cv::cvtColor(s->ds->load(j, ImageMode::kColor).image, grey, cv::COLOR_BGR2GRAY);
    EXPECT_EQ(cv::norm(rec->load(i, ImageMode::kGray).image, grey, cv::NORM_INF), 0.0) << i;
  }
  // Every tracked pose is at a recorded frame's time.
  for (const auto& e : readTumTrajectory(s->dir / "out" / "trajectory.txt")) {
    bool found = false;
    for (size_t i = 0; i < rec->size() && !found; ++i) found = rec->timestamp(i) == e.timestamp;
    EXPECT_TRUE(found) << e.timestamp;
  }
}

// --max-frames N: the run ends once N frames reached tracking. A stop request (Ctrl-C) ends it with
// its outputs and "interrupted"; the frames recorded until then replay to the same trajectory.
TEST(CameraRun, MaxFramesAndStopRequestEndTheStreamWithItsOutputs) {
  const auto s = room(60);
  RunOptions ro = options("camera:/dev/video0", s->dir / "max_out", s->camera);
  ro.max_frames = 25;
  ro.open_stream = [&](const std::string&) { return std::make_unique<DatasetStream>(s->ds); };
  const RunResult rm = runSlam(ro);
  ASSERT_EQ(rm.exit_code, 0);
  EXPECT_EQ(rm.report.at("frames").get<int>(), 25);
  EXPECT_EQ(rm.report.at("frames_processed").get<int>(), 25);
  EXPECT_EQ(listImages(s->dir / "max_out" / "frames").size(), 25u);

  resetStopRequests();
  ro.out = s->dir / "stop_out";
  ro.max_frames = 0;
  ro.open_stream = [&](const std::string&) {
    return std::make_unique<DatasetStream>(s->ds, 0, SIZE_MAX, [](size_t i) {
      if (i == 40) requestStop(SIGINT);
    });
  };
  const RunResult rs = runSlam(ro);
  resetStopRequests();
  EXPECT_EQ(rs.exit_code, 130);
  EXPECT_TRUE(rs.report.at("interrupted").get<bool>());
  EXPECT_EQ(rs.report.at("frames").get<int>(), 41);  // frame 40 was read before the request was seen
  EXPECT_EQ(rs.report.at("interrupted_at_frame").get<int>(), 41);
  EXPECT_TRUE(fs::exists(s->dir / "stop_out" / "trajectory.txt"));
  const RunResult rr =
      runSlam(options("folder:" + (s->dir / "stop_out" / "frames").string(), s->dir / "replay_out", s->camera));
  ASSERT_EQ(rr.exit_code, 0);
  EXPECT_EQ(rr.report.at("frames").get<int>(), 41);
  EXPECT_EQ(readInputFile(s->dir / "replay_out" / "trajectory.txt"),
            readInputFile(s->dir / "stop_out" / "trajectory.txt"));
}

// A device that is not there, a run without --camera, a device that stops delivering, frames of
// another size than the calibration, an output folder holding an earlier run's frames: errors naming
// the device (or the folder), a non-zero exit; what was tracked before a failure is kept.
TEST(CameraRun, DeviceProblemsAreNamed) {
  const auto s = room(30);
  test::TempDir dir;
  auto r = test::runCli("run --no-nerf --dataset camera:/dev/video99 --camera '" + s->camera.string() + "' --out '" +
                        (dir / "a").string() + "'");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("/dev/video99: no such camera device"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "a"));
  r = test::runCli("run --no-nerf --dataset camera:99 --out '" + (dir / "b").string() + "'");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("--dataset camera:99: a live camera has no calibration; give its camera YAML (--camera"),
            std::string::npos)
      << r.output;

  // Stops delivering after 20 frames: exit status 1, the failure names the device, the 20 frames are
  // recorded and the report and trajectory written.
  RunOptions ro = options("camera:/dev/video0", dir / "c", s->camera);
  ro.open_stream = [&](const std::string&) { return std::make_unique<DatasetStream>(s->ds, 0, 20); };
  RunResult rr = runSlam(ro);
  EXPECT_EQ(rr.exit_code, 1);
  EXPECT_NE(rr.report.at("failure").get<std::string>().find("synthetic-camera: the camera stopped delivering"),
            std::string::npos)
      << rr.report.dump();
  EXPECT_EQ(rr.report.at("frames").get<int>(), 20);
  EXPECT_TRUE(fs::exists(dir / "c" / "trajectory.txt"));
  EXPECT_EQ(openDataset("folder:" + (dir / "c" / "frames").string())->size(), 20u);

  // The same output folder again: its frames folder is not mixed with an earlier run's.
  const std::string e = test::errorOf([&] { runSlam(ro); });
  EXPECT_NE(e.find("frames: the folder for the camera's frames already holds files"), std::string::npos) << e;

  // Frames of another size than the camera YAML.
  ro.out = dir / "d";
  saveCameraYaml(Camera::pinhole(640, 480, 500, 500, 320, 240), dir / "vga.yaml");
  ro.camera = dir / "vga.yaml";
  rr = runSlam(ro);
  EXPECT_EQ(rr.exit_code, 1);
  EXPECT_NE(rr.report.at("failure").get<std::string>().find(
                "synthetic-camera: frame 0 is 320x240 (3 channel(s), depth 0), the camera YAML is for 640x480"),
            std::string::npos)
      << rr.report.dump();
}

}  // namespace
}  // namespace nerfslam
