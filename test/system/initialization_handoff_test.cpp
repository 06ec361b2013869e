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

TEST(InitializationHandoff, FramesBetweenTheInitialisationPairAreTrackedWithoutWaitingForMapping) {
  test::TempDir dir;
  render::SynthOptions so;
  so.scene = "room";
  so.trajectory = "handheld";
  so.frames = 70;
  render::writeSynthSequence(so, dir.path() / "seq");
  const auto ds = openDataset("tum:" + (dir.path() / "seq").string());
  SystemOptions opt;
  opt.nerf.enabled = false;
  SlamSystem sys(ds->camera(), opt);
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
  eval::TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-6;
  const auto ev = eval::evaluateTrajectory(ref, sys.trajectory(), eo);
  std::printf("initialised at frame %d from frame %llu: %d frames tracked (%d in between), ATE %.3f %% of path\n",
              init_frame, static_cast<unsigned long long>(first), tracked, retroactive, ev.ape_rmse_percent);
  EXPECT_LT(ev.ape_rmse_percent, 1.0);
}

}  // namespace
}  // namespace nerfslam
