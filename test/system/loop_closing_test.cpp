// Loop closing (mapping/loop_closing.h) on a synthetic loop rendered at test time: the room's
// `loop` trajectory, two identical laps of 120 frames at 320x240 with sensor noise. One test, so
// that the sequence is rendered once and each system runs once (about 30 s on a loaded 2-core
// machine):
//   1. the system with loop closing off (the ATE to beat), then a LoopClosing on its final map,
//      fed its keyframes in order: the loop it finds joins two keyframes that are truly at the
//      same place, and its correction cuts the ATE of the keyframes up to the loop's;
//   2. `runSlam` with the defaults (loop closing on): every revisit closed, the ATE at most a third
//      of the run without it, the report's loop_closures and loop_closing_ms.
#include <gtest/gtest.h>

#include <fstream>
#include <map>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/mapping/loop_closing.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/runner.h"
#include "nerfslam/system/slam_system.h"
#include "nerfslam/tracking/vocabulary.h"
#include "test_support.h"

namespace nerfslam {
namespace {

constexpr int kLaps = 2;
constexpr int kFramesPerLap = 120;

// ATE (rmse after a Sim(3) alignment) in % of the ground truth's path.
double atePercent(const Dataset& ds, const Trajectory& est) {
  Trajectory ref;
  for (std::size_t i = 0; i < ds.size(); ++i)
    if (auto gt = ds.groundTruth(i)) ref.push_back({ds.timestamp(i), *gt});
  TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-3;
  return evaluateTrajectory(ref, est, eo).ape_rmse_percent;
}

TEST(LoopClosing, RoomTwoLapsEveryRevisitClosedAndAteCutByThree) {
  test::TempDir dir;
  SynthOptions so;
  so.scene = "room";
  so.trajectory = "loop";
  so.laps = kLaps;
  so.frames = kLaps * kFramesPerLap + 1;
  so.width = 320;
  so.height = 240;
  so.noise_sigma = 2.0;
  const std::filesystem::path seq = dir.path() / "seq";
  writeSynthSequence(so, seq);
  const auto ds = openDataset("tum:" + seq.string());
  ASSERT_EQ(ds->size(), std::size_t(so.frames));

  // 1. Without loop closing.
  SystemOptions off;
  off.nerf.enabled = false;
  off.loop_closing.enabled = false;
  SlamSystem slam(ds->camera(), off);
  EXPECT_EQ(slam.loopClosing(), nullptr);
  for (std::size_t i = 0; i < ds->size(); ++i) {
    const DatasetFrame f = ds->load(i);
    slam.trackFrame(f.image, f.timestamp, i);
    slam.waitMappingIdle();
  }
  slam.finish(false);
  const Trajectory traj_off = slam.trajectory();
  ASSERT_EQ(traj_off.size(), ds->size());
  const double ate_off = atePercent(*ds, traj_off);

  // The loop closer on that map, its keyframes in order: the first loop it accepts.
  auto voc = std::make_shared<const Vocabulary>(loadVocabulary(vocabularyPath("")));
  LoopClosing lc(slam.map(), nullptr, voc, LoopClosingOptions{});
  std::optional<LoopCandidate> loop;
  std::size_t fed = 0;
  for (KeyframeId id : slam.map().keyframeIds()) {
    ++fed;
    loop = lc.detect(id);
    if (loop) break;
  }
  ASSERT_TRUE(loop.has_value()) << "no loop among " << fed << " keyframes";
  EXPECT_EQ(lc.database().size(), fed);
  const auto cur = slam.map().keyframe(loop->current);
  const auto old = slam.map().keyframe(loop->loop);
  ASSERT_TRUE(cur && old);
  // A true revisit: the two frames are near each other in the ground truth, and the Sim(3)'s rotation
  // is their true relative rotation (measured: frames 99 and 3, 1.19 m apart).
  const SE3 gt_cur = *ds->groundTruth(cur->frameId()), gt_old = *ds->groundTruth(old->frameId());
  EXPECT_GT(cur->frameId(), old->frameId() + 30);
  EXPECT_LT((gt_cur.translation() - gt_old.translation()).norm(), 2.0)
      << "frames " << cur->frameId() << " and " << old->frameId();
  const Eigen::Quaterniond q_true = gt_cur.rotation().inverse() * gt_old.rotation();
  const double rot_err_deg = q_true.angularDistance(loop->S_cur_loop.rotation()) * 180.0 / M_PI;
  EXPECT_LT(rot_err_deg, 3.0);
  EXPECT_GE(loop->sim3_inliers, LoopClosingOptions{}.min_sim3_inliers);
  EXPECT_GE(static_cast<int>(loop->matches.size()), LoopClosingOptions{}.min_projection_matches);
  // The correction moves the keyframes: their ATE falls.
  const Trajectory kf_before = slam.keyframeTrajectory();
  LoopClosureRecord rec;
  ASSERT_TRUE(lc.correct(*loop, &rec));
  EXPECT_EQ(lc.corrections(), 1u);
  EXPECT_GT(rec.fused_points, 0);
  EXPECT_GT(rec.correction_m, 0.0);
  const Trajectory kf_after = slam.keyframeTrajectory();
  const double kf_ate_before = atePercent(*ds, kf_before), kf_ate_after = atePercent(*ds, kf_after);
  // The loop's own part: the keyframes up to the current one (the later ones, made without loop
  // closing, keep drifting after it).
  const auto upTo = [&](const Trajectory& t) {
    Trajectory out;
    for (const auto& p : t)
      if (p.timestamp <= cur->timestamp() + 1e-6) out.push_back(p);
    return out;
  };
  const double lap_ate_before = atePercent(*ds, upTo(kf_before)), lap_ate_after = atePercent(*ds, upTo(kf_after));
  std::printf("keyframes up to the current one: %.3f %% -> %.3f %%\n", lap_ate_before, lap_ate_after);
  std::printf(
      "without loop closing: ATE %.3f %%; keyframes %.3f %% -> %.3f %% after the correction of keyframe %ld "
      "(frame %lu) with %ld (frame %lu), scale %.3f, rotation error %.2f deg\n",
      ate_off, kf_ate_before, kf_ate_after, long(loop->current), (unsigned long)cur->frameId(), long(loop->loop),
      (unsigned long)old->frameId(), rec.sim3_scale, rot_err_deg);
  // The part the loop constrains is corrected (measured: 2.35 % -> 1.48 %). Over all keyframes it
  // is not (5.09 % -> 5.63 %): the second lap, made without loop closing, keeps shrinking after the
  // loop's keyframe (the scale halves at each lap's fast turn, docs/benchmarks.md); before the
  // pyramid levels' keypoints were placed at their true scale it happened to fall, 4.28 % -> 1.99 %.
  EXPECT_LT(lap_ate_after, lap_ate_before);
  uint64_t seen = 0;
  std::map<KeyframeId, Sim3> delta;
  ASSERT_TRUE(lc.correctionsSince(&seen, &delta));
  EXPECT_EQ(seen, 1u);
  EXPECT_EQ(delta.size(), slam.map().numKeyframes());
  EXPECT_FALSE(lc.correctionsSince(&seen, &delta));

  // 2. The run with the defaults: loop closing on its own thread.
  RunOptions ro;
  ro.dataset = "tum:" + seq.string();
  ro.out = dir.path() / "out";
  ro.progress = false;
  ro.nerf = false;
  const RunResult r = runSlam(ro);
  ASSERT_EQ(r.exit_code, 0);
  const nlohmann::json& rep = r.report;
  EXPECT_EQ(rep.at("frames_tracked").get<int>(), so.frames) << rep.dump(2);
  ASSERT_TRUE(rep.at("loop_closing").get<bool>());
  const auto& closures = rep.at("loop_closures");
  EXPECT_GE(closures.size(), std::size_t(kLaps - 1)) << rep.dump(2);
  for (const auto& c : closures) {
    EXPECT_GT(c.at("frame").get<int>(), c.at("loop_frame").get<int>());
    EXPECT_GT(c.at("sim3_scale").get<double>(), 0.0);
    EXPECT_GE(c.at("correction_translation").get<double>(), 0.0);
    EXPECT_GE(c.at("correction_rotation_deg").get<double>(), 0.0);
    EXPECT_GT(c.at("keyframe").get<int>(), c.at("loop_keyframe").get<int>());
  }
  EXPECT_EQ(rep.at("loop_closing_ms").at("correction").at("count").get<std::size_t>(), closures.size());
  EXPECT_GT(rep.at("loop_closing_ms").at("detection").at("count").get<int>(), 10);
  EXPECT_EQ(rep.at("loop_corrections_applied_by_tracking").get<std::size_t>(), closures.size());
  // A global BA in the background after each closure (loop_closing.global_ba, on by default; its
  // thread and its write are tested in test/mapping/loop_closing_test.cpp): the last one is written
  // (the offline run waits for it), and it lowers the reprojection error.
  const auto& gbas = rep.at("global_bas");
  ASSERT_EQ(gbas.size(), closures.size()) << rep.dump(2);
  EXPECT_FALSE(gbas.back().at("stopped").get<bool>());
  EXPECT_LT(gbas.back().at("rmse_after_px").get<double>(), gbas.back().at("rmse_before_px").get<double>());
  EXPECT_GE(rep.at("global_ba_ms").at("count").get<std::size_t>(), 1u);
  const double ate_on = rep.at("ate_percent_of_path").get<double>();
  // The poses as tracked, before the corrections (drawn beside the estimate in trajectory.png).
  const double ate_tracked = rep.at("ate_percent_of_path_as_tracked").get<double>();
  std::printf("as tracked, before the loop corrections: ATE %.3f %%\n", ate_tracked);
  EXPECT_GT(ate_tracked, ate_on);
  EXPECT_TRUE(std::filesystem::exists(ro.out / "trajectory.png"));
  std::printf("loop closing on: %zu closures, ATE %.3f %% (off: %.3f %%)\n", closures.size(), ate_on, ate_off);
  EXPECT_LE(ate_on, ate_off / 3.0);
  EXPECT_LT(ate_on, 1.0);
}

// A vocabulary file that is missing or not a vocabulary: the system refuses to start, naming the file.
TEST(LoopClosing, BadVocabularyFileIsNamed) {
  test::TempDir dir;
  SystemOptions o;
  o.nerf.enabled = false;
  o.loop_closing.vocabulary = (dir.path() / "missing.voc").string();
  const Camera cam = Camera::pinhole(320, 240, 260, 260, 160, 120);
  std::string err = test::errorOf([&] { SlamSystem s(cam, o); });
  EXPECT_NE(err.find("missing.voc"), std::string::npos) << err;
  const auto junk = dir.path() / "junk.voc";
  std::ofstream(junk) << "NSVOCAB";
  o.loop_closing.vocabulary = junk.string();
  err = test::errorOf([&] { SlamSystem s(cam, o); });
  EXPECT_NE(err.find("junk.voc"), std::string::npos) << err;
  o.loop_closing.enabled = false;  // read also when off: relocalisation queries the keyframe database
  err = test::errorOf([&] { SlamSystem s(cam, o); });
  EXPECT_NE(err.find("junk.voc"), std::string::npos) << err;
  o.loop_closing.vocabulary.clear();
  SlamSystem s(cam, o);
  EXPECT_EQ(s.loopClosing(), nullptr);
  EXPECT_EQ(s.places().size(), 0u);
}

}  // namespace
}  // namespace nerfslam
