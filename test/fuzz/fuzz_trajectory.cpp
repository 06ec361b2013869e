// libFuzzer target for io/trajectory.h: every reader (auto-detected, TUM, KITTI with and without a
// times file, EuRoC) on the same input. Sections (fuzz_common.h): trajectory file, KITTI times file.
// A trajectory that reads as TUM must also survive writeTumTrajectory -> readTumTrajectory.
#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include "fuzz_common.h"
#include "nerfslam/io/trajectory.h"

using namespace nerfslam;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::quietLogs();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto dir = fuzz::scratchDir();
  fuzz::writeSections(dir, {"traj.txt", "times.txt"}, data, size);
  const auto traj = dir / "traj.txt";
  const auto times = dir / "times.txt";
  const bool has_times = std::filesystem::exists(times);
  fuzz::expectOnlyError([&] { readTrajectory(traj); });
  fuzz::expectOnlyError([&] { readKittiTrajectory(traj); });
  if (has_times) fuzz::expectOnlyError([&] { readKittiTrajectory(traj, times); });
  fuzz::expectOnlyError([&] { readEurocTrajectory(traj); });
  Trajectory tum;
  try {
    tum = readTumTrajectory(traj);
  } catch (const Error&) {
    return 0;
  }
  const auto out = dir / "written.txt";
  writeTumTrajectory(out, tum);
  const Trajectory back = readTumTrajectory(out);
  if (back.size() != tum.size()) {
    std::fprintf(stderr, "TUM round trip changed the entry count: %zu -> %zu\n", tum.size(), back.size());
    std::abort();
  }
  return 0;
}
