#pragma once
// SIMD-target helpers shared by the nerf kernels, their tests and benchmarks.
#include <cstdint>
#include <string>
#include <vector>

#include <hwy/targets.h>

namespace nerfslam::nerf {

// Name of the Highway target the nerf kernels currently dispatch to (e.g. "AVX3", "AVX2").
const char* activeSimdTarget();

// Targets compiled into the kernels and supported by this CPU, best first.
inline std::vector<int64_t> availableSimdTargets() { return hwy::SupportedAndGeneratedTargets(); }

// Runs fn(name) once per available target with the dispatch forced to that target, then restores
// normal dispatch (also when fn throws).
template <class Fn>
void forEachSimdTarget(Fn&& fn) {
  struct Restore {
    ~Restore() { hwy::SetSupportedTargetsForTest(0); }
  } restore;
  for (int64_t t : availableSimdTargets()) {
    hwy::SetSupportedTargetsForTest(t);
    fn(std::string(hwy::TargetName(t)));
  }
}

// Peak-FMA probe: `iters` iterations of 8 independent vector FMA chains on the dispatched target.
// Returns the FLOPs performed (2 per lane per FMA); time it to get GFLOP/s.
double fmaPeakLoop(uint64_t iters);

}  // namespace nerfslam::nerf
