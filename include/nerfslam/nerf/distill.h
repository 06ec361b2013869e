#pragma once
// Distillation: trains one NeRF model to reproduce another where they overlap, e.g. when online
// training re-fits the scene box (nerf/scene_box.h) and the old field's knowledge must carry over
// to a field in a new box rather than be dropped.
//
// Each step regresses the student's log-density and, where the teacher is dense, its colour, at
// random points of the teacher's box, every cascade alike (half uniform, half inside its occupied
// cells), with random view directions; points outside the student's box are skipped. Densities are per NeRF-space
// length, so the target is converted to the student's units: sigma_to = sigma_from * scale_from / scale_to. Below a
// floor (log 0.1) any density counts as empty space; the colour is weighted by 1 - exp(-0.01 sigma_to).
#include <cstdint>

#include "nerfslam/nerf/model_io.h"

namespace nerfslam::nerf {

struct DistillOptions {
  int steps = 300;              // optimiser steps
  int samples_per_step = 4096;  // points per step
  double lr = 1e-2;             // Adam learning rate of the student
  uint64_t seed = 0;            // the sample points are a pure function of it
};

// Trains `to` (the student) to reproduce `from` (the teacher) inside from's box (all its cascades); returns the
// mean loss per point of the last step (0 when steps is 0). Deterministic for a seed. Only `to`'s
// field changes (its occupancy grid is left as it is) and its training_steps, which count the
// distillation steps: a trained field, whose first occupancy sweep must be at full resolution.
double distill(const NerfModel& from, NerfModel& to, const DistillOptions& options);

}  // namespace nerfslam::nerf
