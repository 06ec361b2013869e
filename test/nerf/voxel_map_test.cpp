// The occupancy maps of voxel_map.h against analytic densities (a solid box and a solid sphere seen
// by a ring of cameras): every voxel's class checked against the exact geometry; OctoMap round trips;
// the 2D grid; bad input.
#include "nerfslam/nerf/voxel_map.h"

#include <cmath>
#include <filesystem>
#include <memory>

#include <gtest/gtest.h>
#include <octomap/OcTree.h>

#include "nerfslam/core/error.h"
#include "nerfslam/nerf/model_io.h"
#include "sphere_views.h"
#include "test_support.h"

namespace nerfslam::nerf {
namespace {
namespace fs = std::filesystem;

// Solids on a floor slab: a box [-0.5, 0.5]^2 x [0, 1], a sphere of radius 0.4 at (1.4, 0, 0.5), and
// the floor z in [-0.2, 0]. Signed distance (approximately, for the box) to the union.
const Eigen::Vector3d kBoxLo(-0.5, -0.5, 0), kBoxHi(0.5, 0.5, 1.0), kSphere(1.4, 0, 0.5);
constexpr double kSphereR = 0.4;

double boxDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  const Eigen::Vector3d c = 0.5 * (lo + hi), h = 0.5 * (hi - lo);
  const Eigen::Vector3d q = (p - c).cwiseAbs() - h;
  return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
}
double sceneDistance(const Eigen::Vector3d& p) {
  const double floor = boxDistance(p, {-3, -3, -0.2}, {4, 3, 0});
  return std::min({boxDistance(p, kBoxLo, kBoxHi), (p - kSphere).norm() - kSphereR, floor});
}

DensitySource analyticSource() {
  DensitySource s;
  s.density = [](const float* xyz, size_t n, float* sigma) {
    for (size_t i = 0; i < n; ++i)
      sigma[i] = sceneDistance(Eigen::Vector3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2])) <= 0 ? 1000.f : 0.f;
  };
  s.bounds = Eigen::AlignedBox3d(Eigen::Vector3d(-1.5, -1.5, -0.3), Eigen::Vector3d(2.5, 1.5, 1.6));
  return s;
}

SE3 lookAtTarget(const Eigen::Vector3d& eye, const Eigen::Vector3d& target) {
  const Eigen::Vector3d z = (target - eye).normalized();
  Eigen::Vector3d x = z.cross(Eigen::Vector3d::UnitZ());
  x.normalize();
  const Eigen::Vector3d y = z.cross(x);
  Eigen::Matrix3d R;
  R << x, y, z;
  return SE3(R, eye);
}

// Two rings of cameras (heights 0.6 and 1.4) at 1.2 m around the objects' centre, looking at it.
std::vector<PosedCamera> ringViews() {
  std::vector<PosedCamera> v;
  const Camera cam = Camera::pinhole(64, 48, 40, 40, 31.5, 23.5);
  const Eigen::Vector3d c(0.45, 0, 0.5);
  for (int ring = 0; ring < 2; ++ring)
    for (int i = 0; i < 12; ++i) {
      const double a = 2 * M_PI * (i + 0.5 * ring) / 12;
      const Eigen::Vector3d eye =
          c + Eigen::Vector3d(1.3 * std::cos(a) + 0.6 * std::cos(a), 1.3 * std::sin(a), ring == 0 ? 0.1 : 0.9);
      v.push_back({cam, lookAtTarget(eye, c)});
    }
  return v;
}

VoxelMapOptions smallOptions() {
  VoxelMapOptions o;
  o.resolution = 0.1;
  o.pixel_stride = 1;
  o.threads = 2;
  return o;
}

TEST(VoxelMap, AnalyticBoxAndSphereVoxelsAreClassifiedByTheGeometry) {
  const auto views = ringViews();
  const VoxelMapOptions o = smallOptions();
  const VoxelMap m = buildVoxelMap(analyticSource(), views, o);
  const double half_diag = 0.5 * std::sqrt(3.0) * o.resolution;
  size_t occupied = 0, touching = 0, free = 0, surface = 0, surface_found = 0;
  for (int z = 0; z < m.dims.z(); ++z)
    for (int y = 0; y < m.dims.y(); ++y)
      for (int x = 0; x < m.dims.x(); ++x) {
        const Eigen::Vector3d c = m.center(x, y, z);
        const double d = sceneDistance(c);
        const uint8_t s = m.state[m.index(x, y, z)];
        // Occupied voxels touch a solid, or are at most thickness_voxels behind one along a ray that
        // grazed it; free ones have their centre outside every solid.
        if (s == VoxelMap::kOccupied) {
          ++occupied;
          touching += d <= half_diag + 1e-9;
          EXPECT_LE(d, half_diag + o.thickness_voxels * o.resolution + 1e-9) << c.transpose();
        } else if (s == VoxelMap::kFree) {
          ++free;
          EXPECT_GT(d, 0.0) << c.transpose();
        }
        // The side and top surfaces of the box and the sphere's upper half face the cameras.
        const bool box_face = std::abs(boxDistance(c, kBoxLo, kBoxHi)) < 0.5 * o.resolution && c.z() > 0.15;
        const bool sphere_face = std::abs((c - kSphere).norm() - kSphereR) < 0.5 * o.resolution && c.z() > 0.6;
        if ((box_face || sphere_face) && c.x() < 1.0 + 0.8 * (c.z() > 0.95)) {  // not hidden between the two
          ++surface;
          surface_found += s == VoxelMap::kOccupied;
        }
      }
  EXPECT_GT(occupied, 200u);
  EXPECT_GE(double(touching) / double(occupied), 0.95) << touching << " of " << occupied;
  EXPECT_GT(free, 5000u);
  ASSERT_GT(surface, 100u);
  EXPECT_GE(double(surface_found) / double(surface), 0.9) << surface_found << " of " << surface;
  // Deep inside the box no ray arrives: unknown; in front of it (between the cameras and it): free.
  EXPECT_EQ(m.stateAt({0, 0, 0.5}), VoxelMap::kUnknown);
  EXPECT_EQ(m.stateAt({-0.9, 0.05, 0.55}), VoxelMap::kFree);
  EXPECT_EQ(m.stateAt({-0.45, 0.05, 0.55}), VoxelMap::kOccupied);  // the box's -x face
  EXPECT_EQ(m.stateAt({1.4, 0.05, 0.85}), VoxelMap::kOccupied);    // the sphere's top
}

// A floater: a dense 6 cm cube inside one voxel (centre (-0.95, 0.05, 0.55), between the box and the
// cameras on the -x side). Every ray into that voxel stops there, so it is a one-voxel occupied
// cluster (no voxel behind it with thickness_voxels 0): kept when min_cluster_voxels is 1, dropped
// to unknown (no ray crossed it) when it is 2, and nothing of the box, the sphere or the floor goes
// with it but their own one-voxel slivers.
TEST(VoxelMap, OccupiedClustersSmallerThanMinClusterVoxelsAreDropped) {
  const Eigen::Vector3d speck(-0.95, 0.05, 0.55);
  DensitySource src = analyticSource();
  const auto solid = src.density;
  src.density = [solid, speck](const float* xyz, size_t n, float* sigma) {
    solid(xyz, n, sigma);
    for (size_t i = 0; i < n; ++i)
      if ((Eigen::Vector3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]) - speck).cwiseAbs().maxCoeff() <= 0.03)
        sigma[i] = 1000.f;
  };
  VoxelMapOptions o = smallOptions();
  o.pixel_stride = 2;
  o.thickness_voxels = 0;
  o.min_cluster_voxels = 1;
  const auto views = ringViews();
  const VoxelMap kept = buildVoxelMap(src, views, o);
  o.min_cluster_voxels = 2;
  const VoxelMap dropped = buildVoxelMap(src, views, o);
  ASSERT_EQ(kept.dims, dropped.dims);
  EXPECT_EQ(kept.stateAt(speck), VoxelMap::kOccupied);
  EXPECT_EQ(dropped.stateAt(speck), VoxelMap::kUnknown);
  size_t occupied = 0, removed = 0;
  for (size_t i = 0; i < kept.size(); ++i) {
    if (dropped.state[i] == VoxelMap::kOccupied) {
      EXPECT_EQ(kept.state[i], VoxelMap::kOccupied) << i;
    }
    if (kept.state[i] != VoxelMap::kOccupied) continue;
    ++occupied;
    removed += dropped.state[i] != VoxelMap::kOccupied;
  }
  EXPECT_GT(occupied, 200u);
  EXPECT_GE(removed, 1u);
  EXPECT_LE(double(removed), 0.02 * double(occupied)) << removed << " of " << occupied;
  EXPECT_EQ(dropped.stateAt({-0.45, 0.05, 0.55}), VoxelMap::kOccupied);  // the box's -x face stays
  EXPECT_EQ(dropped.stateAt({1.4, 0.05, 0.85}), VoxelMap::kOccupied);    // the sphere's top stays
  o.min_cluster_voxels = 0;
  EXPECT_NE(test::errorOf([&] { validate(o); }).find("min_cluster_voxels"), std::string::npos);
}

TEST(VoxelMap, IncrementalBudgetedUpdatesConvergeToTheFullExtraction) {
  const auto views = ringViews();
  VoxelMapOptions o = smallOptions();
  o.pixel_stride = 4;
  const DensitySource src = analyticSource();
  const VoxelMap full = buildVoxelMap(src, views, o);
  VoxelMapper inc(o, voxelMapBounds(src, views, o.resolution));
  const size_t budget = full.size() / 7 + 1;
  size_t done = 0;
  for (int k = 0; k < 7; ++k) {
    done += inc.updateDensity(src, int64_t(budget));
    inc.carve(views);  // the map is usable after every step
  }
  EXPECT_GE(done, full.size());
  EXPECT_EQ(inc.map().state, full.state);
  EXPECT_EQ(inc.map().log_odds, full.log_odds);
}

TEST(VoxelMap, OctomapFilesRoundTripThroughLiboctomap) {
  const test::TempDir tmp;
  VoxelMapOptions o = smallOptions();
  o.pixel_stride = 4;
  const VoxelMap m = buildVoxelMap(analyticSource(), ringViews(), o);
  writeOctomapFiles(m, tmp / "map.bt", 0, "analytic");
  saveOctomap(m, tmp / "map.ot");
  ASSERT_TRUE(fs::exists(tmp / "map.meta.yaml"));
  octomap::OcTree bt(0.1);
  ASSERT_TRUE(bt.readBinary((tmp / "map.bt").string()));
  std::unique_ptr<octomap::AbstractOcTree> abstract(octomap::AbstractOcTree::read((tmp / "map.ot").string()));
  ASSERT_TRUE(abstract);
  auto* ot = dynamic_cast<octomap::OcTree*>(abstract.get());
  ASSERT_NE(ot, nullptr);
  EXPECT_DOUBLE_EQ(bt.getResolution(), 0.1);
  EXPECT_DOUBLE_EQ(ot->getResolution(), 0.1);
  size_t checked = 0;
  for (int z = 0; z < m.dims.z(); ++z)
    for (int y = 0; y < m.dims.y(); ++y)
      for (int x = 0; x < m.dims.x(); ++x) {
        const Eigen::Vector3d c = m.center(x, y, z);
        const uint8_t s = m.state[m.index(x, y, z)];
        const octomap::OcTreeNode* nb = bt.search(c.x(), c.y(), c.z());
        const octomap::OcTreeNode* no = ot->search(c.x(), c.y(), c.z());
        if (s == VoxelMap::kUnknown) {
          EXPECT_EQ(nb, nullptr);
          EXPECT_EQ(no, nullptr);
          continue;
        }
        ASSERT_NE(nb, nullptr) << c.transpose();
        ASSERT_NE(no, nullptr) << c.transpose();
        EXPECT_EQ(bt.isNodeOccupied(nb), s == VoxelMap::kOccupied);
        EXPECT_EQ(ot->isNodeOccupied(no), s == VoxelMap::kOccupied);
        const float L = m.log_odds[m.index(x, y, z)];
        const float expected = s == VoxelMap::kFree ? std::min(L, -1e-3f) : L;
        // The .ot file keeps the log-odds (a pruned node stands for eight equal children).
        EXPECT_NEAR(no->getLogOdds(), expected, 1e-5);
        ++checked;
      }
  EXPECT_GT(checked, 1000u);
}

TEST(VoxelMap, GridFromTheBandAboveTheDetectedFloor) {
  const test::TempDir tmp;
  const auto views = ringViews();
  const VoxelMap m = buildVoxelMap(analyticSource(), views, smallOptions());
  const FloorPlane f = detectFloor(m, views);
  EXPECT_GT(f.normal.z(), 0.999);
  EXPECT_NEAR(-f.offset, -0.05, 0.051);  // the top layer of floor voxels: centres at z = -0.05
  const GridProjection g = writeGridFiles(m, views, nullptr, 0.15, 0.8, tmp / "map.yaml", 1.0, "analytic");
  const NavGrid r = loadMapServer(tmp / "map.yaml");
  EXPECT_EQ(r.cells, g.grid.cells);
  // A cell at a grid-frame point (the grid frame is the output frame shifted onto the floor here).
  auto cellAt = [&](double x, double y) {
    const Eigen::Vector3d p = g.T_out_grid.inverse() * Eigen::Vector3d(x, y, 0);
    const int cx = int(std::floor((p.x() - r.origin_x) / r.resolution));
    const int cy = int(std::floor((p.y() - r.origin_y) / r.resolution));
    return r.at(cx, cy);
  };
  EXPECT_EQ(cellAt(-0.45, 0.05), NavGrid::kOccupied);  // the box's sides
  EXPECT_EQ(cellAt(0.45, 0.05), NavGrid::kOccupied);
  EXPECT_EQ(cellAt(0.05, 0.05), NavGrid::kUnknown);   // inside the box: no ray gets there
  EXPECT_EQ(cellAt(1.45, 0.35), NavGrid::kOccupied);  // the sphere's side
  EXPECT_EQ(cellAt(-1.0, 0.05), NavGrid::kFree);      // in front of the box
  EXPECT_EQ(cellAt(1.45, 0.65), NavGrid::kFree);      // beside the sphere
  // The sidecar says the scale and the band.
  const std::string meta = [&] {
    std::ifstream in(tmp / "map.meta.yaml");
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  }();
  EXPECT_NE(meta.find("units: metres"), std::string::npos);
  EXPECT_NE(meta.find("height_band: [0.15, 0.8]"), std::string::npos);
}

// A run maps whatever it saw at one resolution option: a street at a room's resolution would need
// gigabytes. fittingResolution doubles the resolution until the map fits its memory limit, and the
// map built at it is the one built when asked for that resolution directly.
TEST(VoxelMap, FittingResolutionCoarsensUntilTheMapFitsItsMemory) {
  VoxelMapOptions o = smallOptions();
  o.pixel_stride = 8;
  EXPECT_EQ(fittingResolution(analyticSource(), ringViews(), o), o.resolution);  // fits: unchanged
  o.resolution = 0.01;
  o.max_memory_mb = 5;
  ASSERT_FALSE(test::errorOf([&] { buildVoxelMap(analyticSource(), ringViews(), o); }).empty());
  const double r = fittingResolution(analyticSource(), ringViews(), o);
  EXPECT_GT(r, o.resolution);
  const double k = std::log2(r / o.resolution);
  EXPECT_NEAR(k, std::round(k), 1e-9);  // a power of two coarser
  VoxelMapOptions fit = o;
  fit.resolution = r;
  const VoxelMap m = buildVoxelMap(analyticSource(), ringViews(), fit);
  EXPECT_GT(m.count(VoxelMap::kOccupied), 0u);
  // The bounds it found make the same map without a second coarse pass.
  Eigen::AlignedBox3d observed;
  EXPECT_EQ(fittingResolution(analyticSource(), ringViews(), o, 8, &observed), r);
  const VoxelMap again = buildVoxelMap(analyticSource(), ringViews(), fit, observed);
  EXPECT_EQ(again.dims, m.dims);
  EXPECT_EQ(again.origin, m.origin);
  EXPECT_EQ(again.state, m.state);
  EXPECT_LE(double(m.size()) * 42, 5e6);
  // One step finer would not have fitted.
  fit.resolution = r / 2;
  EXPECT_FALSE(test::errorOf([&] { buildVoxelMap(analyticSource(), ringViews(), fit); }).empty());
  // Nothing fits within the doublings allowed: the resolution asked for, which buildVoxelMap refuses.
  o.max_memory_mb = 1e-3;
  EXPECT_EQ(fittingResolution(analyticSource(), ringViews(), o, 2), o.resolution);
}

TEST(VoxelMap, BadInputIsRefusedWithoutWritingAnything) {
  const test::TempDir tmp;
  VoxelMapOptions o = smallOptions();
  o.resolution = 0;
  EXPECT_NE(test::errorOf([&] { validate(o); }).find("resolution must be > 0"), std::string::npos);
  o.resolution = -0.05;
  EXPECT_NE(test::errorOf([&] { buildVoxelMap(analyticSource(), ringViews(), o); }).find("resolution"),
            std::string::npos);
  // So fine that the grid would not fit: refused, with the size it would have.
  o.resolution = 1e-4;
  const std::string big = test::errorOf([&] { VoxelMapper(o, analyticSource().bounds); });
  EXPECT_NE(big.find("would have 40000 x 30000 x 19000"), std::string::npos) << big;
  EXPECT_NE(big.find("MB"), std::string::npos) << big;
  // A height band with lo >= hi.
  o = smallOptions();
  o.pixel_stride = 8;
  const VoxelMap m = buildVoxelMap(analyticSource(), ringViews(), o);
  EXPECT_NE(test::errorOf([&] { projectToGrid(m, FloorPlane{}, 0.5, 0.5); }).find("lo < hi"), std::string::npos);
  EXPECT_NE(
      test::errorOf([&] { writeGridFiles(m, ringViews(), nullptr, 1.0, 0.2, tmp / "g.yaml", 0, ""); }).find("lo < hi"),
      std::string::npos);
  EXPECT_FALSE(fs::exists(tmp / "g.pgm"));
  // Unwritable output: an error naming the file, nothing left behind.
  const fs::path missing = tmp / "no_such_dir" / "map.bt";
  EXPECT_NE(test::errorOf([&] { saveOctomap(m, missing); }).find("map.bt"), std::string::npos);
  EXPECT_FALSE(fs::exists(tmp / "no_such_dir"));
  EXPECT_NE(test::errorOf([&] { saveOctomap(m, tmp / "map.txt"); }).find(".bt"), std::string::npos);
  // An untrained (empty) model.
  FieldConfig fc = sphereField();
  NerfModel empty = NerfModel::create(fc, sphereScene(), 1);
  EXPECT_NE(test::errorOf([&] { fieldDensitySource(empty); }).find("empty model"), std::string::npos);
  // A model trained a step whose grid has no occupied cell.
  empty.training_steps = 1;
  empty.grid->setValues(std::vector<float>(empty.grid->values().size(), 0.f), 1.f);
  EXPECT_NE(test::errorOf([&] { fieldDensitySource(empty); }).find("no occupied cell"), std::string::npos);
}

}  // namespace
}  // namespace nerfslam::nerf
