// Distillation (nerf/distill.h): a field trained on the procedural sphere is distilled into a
// fresh field in a box twice as large (as after a scene-box re-fit); the student then gives the
// teacher's density and colour at points of the teacher's cube within a tolerance, and empty
// space stays empty. Deterministic for a seed.
#include "nerfslam/nerf/distill.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "sphere_views.h"

namespace nerfslam::nerf {
namespace {

// A teacher: the sphere (radius 0.8) in world [-1.5, 1.5]^3, trained for `steps` steps.
NerfModel trainedTeacher(int steps) {
  NerfModel m = NerfModel::create(sphereField(), sphereScene(), 1);
  std::vector<TrainingView> views;
  for (int i = 0; i < 16; ++i) views.push_back(syntheticView(i, 16, 48));
  {
    Trainer trainer(m, views, sphereTraining(2));
    for (int i = 0; i < steps; ++i) trainer.step();
  }
  return m;
}

// A fresh field in a box twice as large around the same centre (world [-3, 3]^3).
NerfModel student(uint64_t seed) {
  SceneTransform scene = sphereScene();
  scene.scale /= 2;
  return NerfModel::create(sphereField(), scene, seed);
}

// Density (student units) above which a point counts as dense: its colour is distilled with a
// weight of at least 1 - exp(-0.01 * 100) = 0.63.
constexpr double kDense = 100.0;
// Teacher densities below kEmpty are thin space: a ray crosses a whole unit cube with more than
// e^-0.5 of its light (a briefly trained teacher leaves its empty space at 0.2-1, not at
// distillation's floor of 0.1: 3 of the 20,000 points were below 0.1, then none once the occupancy
// picks changed, which made the check a coin toss); a student density below kThin there still lets
// more than e^-1 through.
constexpr double kEmpty = 0.5, kThin = 1.0;

struct Errors {
  double log_density = 0;  // median |log sigma_student - log sigma_teacher|, where the teacher is dense
  double colour = 0;       // RMS colour difference there
  double dense = 0;        // share of the points where the teacher is dense
  double empty_kept = 0;   // share of the points where the teacher is empty that the student keeps thin
  size_t empty = 0;        // points where the teacher is empty
};

// Compares the fields (densities in the student's units) at random points of the teacher's cube.
Errors compare(const NerfModel& from, const NerfModel& to) {
  const size_t n = 20000;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::normal_distribution<float> g;
  std::vector<float> p_from(3 * n), p_to(3 * n), dir(3 * n), q_from(3 * n), q_to(3 * n), sf(n), st(n), cf(3 * n),
      ct(3 * n);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d p(u(rng), u(rng), u(rng));
    const Eigen::Vector3d pt = to.scene.toNerf(from.scene.toWorld(p));
    const Eigen::Vector3f d = Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    for (int a = 0; a < 3; ++a) {
      p_from[3 * i + size_t(a)] = float(p[a]);
      p_to[3 * i + size_t(a)] = float(pt[a]);
      dir[3 * i + size_t(a)] = d[a];
    }
  }
  from.toFieldCoords(p_from.data(), n, q_from.data());
  to.toFieldCoords(p_to.data(), n, q_to.data());
  from.field->query(q_from.data(), dir.data(), n, sf.data(), cf.data());
  to.field->query(q_to.data(), dir.data(), n, st.data(), ct.data());
  const double k = from.scene.scale / to.scene.scale;
  std::vector<double> dlog;
  double se = 0;
  size_t empty = 0, kept = 0;
  for (size_t i = 0; i < n; ++i) {
    if (double(sf[i]) * k < kEmpty) {
      ++empty;
      kept += double(st[i]) < kThin;
    }
    if (double(sf[i]) * k < kDense) continue;
    dlog.push_back(std::abs(std::log(double(st[i])) - std::log(double(sf[i]) * k)));
    for (size_t c = 0; c < 3; ++c) se += std::pow(double(ct[3 * i + c]) - cf[3 * i + c], 2);
  }
  Errors e;
  e.dense = double(dlog.size()) / double(n);
  e.empty_kept = empty > 0 ? double(kept) / double(empty) : 0.0;
  e.empty = empty;
  if (dlog.empty()) return e;
  std::nth_element(dlog.begin(), dlog.begin() + long(dlog.size() / 2), dlog.end());
  e.log_density = dlog[dlog.size() / 2];
  e.colour = std::sqrt(se / double(3 * dlog.size()));
  return e;
}

TEST(Distill, StudentReproducesTheTeacherInsideItsCube) {
  const NerfModel from = trainedTeacher(200);
  NerfModel to = student(7);
  const Errors before = compare(from, to);
  DistillOptions o;
  o.steps = 300;
  const double loss = distill(from, to, o);
  const Errors after = compare(from, to);
  std::printf(
      "distill: where the teacher is dense (%.1f %% of its cube): median |d log sigma| %.3f -> %.3f, colour RMS "
      "%.4f -> %.4f; empty space (%zu points) kept thin %.1f -> %.1f %%; last loss %.4f\n",
      100 * before.dense, before.log_density, after.log_density, before.colour, after.colour, before.empty,
      100 * before.empty_kept, 100 * after.empty_kept, loss);
  ASSERT_GT(before.dense, 0.01);         // the teacher has learned a surface
  ASSERT_GT(before.empty, size_t(200));  // and thin space, enough of it for a share to mean something
  EXPECT_TRUE(std::isfinite(loss));
  EXPECT_LT(after.log_density, 0.5);
  EXPECT_LT(after.colour, 0.1);
  EXPECT_LT(after.log_density, 0.5 * before.log_density);
  EXPECT_LT(after.colour, 0.5 * before.colour);
  EXPECT_GT(after.empty_kept, 0.98);
}

// Determinism needs no converged teacher: 30 steps (200 took most of this test's minute under ASan).
TEST(Distill, IsDeterministicForASeedAndZeroStepsChangeNothing) {
  const NerfModel from = trainedTeacher(30);
  NerfModel a = student(7), b = student(7), c = student(7), fresh = student(7);
  DistillOptions o;
  o.steps = 20;
  o.seed = 9;
  EXPECT_EQ(distill(from, a, o), distill(from, b, o));
  o.steps = 0;
  EXPECT_EQ(distill(from, c, o), 0.0);
  const auto pa = a.field->parameters(), pb = b.field->parameters(), pc = c.field->parameters(),
             pf = fresh.field->parameters();
  bool same_ab = true, same_cf = true, a_changed = false;
  for (size_t i = 0; i < pa.size(); ++i)
    for (size_t j = 0; j < pa[i].size; ++j) {
      same_ab = same_ab && pa[i].data[j] == pb[i].data[j];
      same_cf = same_cf && pc[i].data[j] == pf[i].data[j];
      a_changed = a_changed || pa[i].data[j] != pf[i].data[j];
    }
  EXPECT_TRUE(same_ab) << "two distillations with one seed differ";
  EXPECT_TRUE(same_cf) << "zero steps changed the student";
  EXPECT_TRUE(a_changed) << "20 steps left the student as it was";
}

}  // namespace
}  // namespace nerfslam::nerf
