// The frame that initialises the map hands the two-keyframe bundle adjustment and the tracking of
// the frames between the two initialisation frames to the mapping thread, and goes on. A producer
// that never waits for mapping (a camera driver, --realtime, ROS) still gets every frame from the
// reference on tracked, with poses that agree with ground truth, once the mapping thread is done.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>

#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/slam_system.h"
#include "test_support.h"

namespace nerfslam {
namespace {

// The synthetic room seen by a hand-held camera, `frames` frames written into `dir`.
std::unique_ptr<Dataset> handheldRoom(const test::TempDir& dir, int frames) {
  SynthOptions so;
  so.scene = "room";
  so.trajectory = "handheld";
  so.frames = frames;
  writeSynthSequence(so, dir.path() / "seq");
  return openDataset("tum:" + (dir.path() / "seq").string());
}

SystemOptions noNerf() {
  SystemOptions opt;
  opt.nerf.enabled = false;
  return opt;
}

TEST(InitializationHandoff, FramesBetweenTheInitialisationPairAreTrackedWithoutWaitingForMapping) {
  test::TempDir dir;
  const auto ds = handheldRoom(dir, 70);
  SlamSystem sys(ds->camera(), noNerf());
  int init_frame = -1;
  for (size_t i = 0; i < ds->size(); ++i) {
    const DatasetFrame f = ds->load(i);
    sys.trackFrame(f.image, f.timestamp, i);  // never waits for the mapping thread
    if (init_frame < 0 && sys.initialized()) init_frame = static_cast<int>(i);
  }
  ASSERT_GE(init_frame, 2) << "initialised too early for frames in between to exist";
  ASSERT_LE(init_frame, 30);
  sys.finish();

  int tracked = 0, retroactive = 0;
  uint64_t first = ds->size();
  for (const FrameRecord& r : sys.records()) {
    if (!r.tracked) continue;
    ++tracked;
    first = std::min(first, r.index);
    retroactive += r.message == "tracked after initialisation";
  }
  // Every frame from the reference on: the reference, the frames in between, and the rest.
  EXPECT_EQ(tracked, static_cast<int>(ds->size() - first));
  EXPECT_GT(retroactive, 0);
  EXPECT_LT(first, static_cast<uint64_t>(init_frame) - 1);

  Trajectory ref;
  for (const FrameRecord& r : sys.records())
    if (const auto T = ds->groundTruth(r.index)) ref.push_back({r.timestamp, *T});
  TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-6;
  const auto ev = evaluateTrajectory(ref, sys.trajectory(), eo);
  std::printf("initialised at frame %d from frame %llu: %d frames tracked (%d in between), ATE %.3f %% of path\n",
              init_frame, static_cast<unsigned long long>(first), tracked, retroactive, ev.ape_rmse_percent);
  EXPECT_LT(ev.ape_rmse_percent, 1.0);
}

// Offline lock-step: the mapping thread has tracked the frames between the initialisation frames
// before the next frame comes, but the records take its result only in the next trackFrame()
// (pollInitialization), never in a const accessor.
TEST(SlamSystem, InitialisationResultIsTakenByTheNextFrameNotByTheAccessors) {
  test::TempDir dir;
  const auto ds = handheldRoom(dir, 40);
  SlamSystem sys(ds->camera(), noNerf());
  size_t i = 0;
  for (; i < ds->size() && !sys.initialized(); ++i) {
    const DatasetFrame f = ds->load(i);
    sys.trackFrame(f.image, f.timestamp, i);
    sys.waitMappingIdle();
  }
  ASSERT_TRUE(sys.initialized());
  ASSERT_LT(i, ds->size());
  const auto retroactive = [&sys] {
    return std::count_if(sys.records().begin(), sys.records().end(),
                         [](const FrameRecord& r) { return r.message == "tracked after initialisation"; });
  };
  // The reference frame and the initialising one.
  EXPECT_EQ(sys.trajectory().size(), 2u);
  EXPECT_EQ(retroactive(), 0);
  EXPECT_EQ(sys.trajectory().size(), 2u);
  const DatasetFrame next = ds->load(i);
  const FrameRecord rec = sys.trackFrame(next.image, next.timestamp, i);
  EXPECT_TRUE(rec.tracked);
  const auto between = retroactive();
  EXPECT_GT(between, 0);
  EXPECT_EQ(sys.trajectory().size(), 3u + static_cast<size_t>(between));
  sys.finish();
  EXPECT_EQ(retroactive(), between);
}

}  // namespace
}  // namespace nerfslam
