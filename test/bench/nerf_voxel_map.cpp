// The occupancy maps of a run (nerf/voxel_map.h) against the synthetic scene's exact geometry, beside
// the sparse-points-only baseline, and what they cost:
//
//   bench_nerf_voxel_map --run OUT --dataset SEQ [--resolution 0.05] [--threads 2] [--band 0.1,1.5]
//                        [--pixel-stride 16] [--budget-fraction 0.0625] [--pairs 20]
//
// OUT is a `nerfslam run` output folder (nerf/model.nerf, keyframes.txt, trajectory.txt,
// map_points.ply) over SEQ, a `nerfslam synth` sequence (groundtruth.txt, camera.yaml; the scene is
// named by SEQ/synth.json or --scene). The run's map is aligned to the ground truth (Sim(3) of
// trajectory.txt onto groundtruth.txt) and extracted in the ground truth's frame, so lengths are
// metres. The ground truth is the scene's geometry (render/scene.h: its triangles, exact), voxelised
// at the same resolution on the same voxels: a voxel is occupied when a triangle crosses it.
//
// Figures (voxel tolerance 0 and 1: a voxel within one voxel of the other map's counts):
//   occupied precision   our occupied voxels that are ground-truth occupied
//   occupied recall      ground-truth surface voxels the keyframes see (the first occupied voxel
//                        along their rays, at their ground-truth poses) that we mark occupied
//   free accuracy        voxels the keyframes' ground-truth rays cross before their surface that we
//                        mark free (unknown counts as wrong), and the share of our free voxels that
//                        are ground-truth occupied
//   2D grid              IoU of the occupied cells against the ground truth's (the same band above
//                        z = 0 projected); shortest-path existence (4-connected free cells) between
//                        --pairs random free ground-truth cells: ours agrees when it has a path
//                        whenever the ground truth has one
//   timing               the full extraction (density and rays), an incremental update (density of
//                        --budget-fraction of the voxels, then the rays), wall time, median of 3
// Diagnostics: --surface-errors 1 (where the NeRF puts the surfaces: along the keyframes' true rays, the
// depth where its transmittance falls to 0.5 against the scene's triangles, by orientation, signed along
// the normal; the first occupied voxel along the rays against the ground truth's; the log-odds of our
// true and false occupied voxels; --dump FILE writes the rays), --true-floor 1 (the 2D grid on z = 0
// instead of the floor found), --column x,y (one column's voxels and its 2D cell), --fp 1, --histogram 1,
// --ascii 1; the extraction's options --opacity, --thickness, --stop, --min-views, --samples,
// --min-cluster.
// The baseline: the same, from the sparse map points only (a voxel with a point is occupied; the
// rays from each keyframe to the points in its view, short of the point, are free), as an OctoMap
// built from a sparse SLAM's points would be.
// Without --run the benchmark says what it needs and exits 0 (it is not part of CTest).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <fstream>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/camera.h"
#include "nerfslam/core/parse.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/voxel_map.h"
#include "nerfslam/render/preview.h"
#include "nerfslam/render/scene.h"

namespace {

using namespace nerfslam;
using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

double seconds(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }
double median3(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Grid geometry shared by every voxel set below (the run's map's voxels).
struct Grid {
  Eigen::Vector3i origin, dims;
  double res = 0;
  size_t size() const { return size_t(dims.x()) * size_t(dims.y()) * size_t(dims.z()); }
  bool at(const Eigen::Vector3d& p, Eigen::Vector3i* v) const {
    const Eigen::Vector3d g = p / res - origin.cast<double>();
    const Eigen::Vector3i i(int(std::floor(g.x())), int(std::floor(g.y())), int(std::floor(g.z())));
    if ((i.array() < 0).any() || (i.array() >= dims.array()).any()) return false;
    *v = i;
    return true;
  }
  size_t index(const Eigen::Vector3i& v) const {
    return size_t(v.x()) + size_t(dims.x()) * (size_t(v.y()) + size_t(dims.y()) * size_t(v.z()));
  }
  Eigen::Vector3i coords(size_t i) const {
    return {int(i % size_t(dims.x())), int(i / size_t(dims.x()) % size_t(dims.y())),
            int(i / (size_t(dims.x()) * size_t(dims.y())))};
  }
};

// Voxels crossed by the scene's triangles: each triangle sampled on a lattice finer than a quarter
// voxel (barycentric steps), exact up to that spacing.
// Calls f(p) with the three corners of every triangle of the scene's meshes.
template <class F>
void forEachSceneTriangle(const Scene& scene, F&& f) {
  for (const Mesh& m : scene.meshes) {
    const size_t n = m.indices.empty() ? m.vertices.size() : m.indices.size();
    for (size_t k = 0; k + 2 < n; k += 3) {
      Eigen::Vector3d p[3];
      for (int j = 0; j < 3; ++j) {
        const auto& v = m.vertices[m.indices.empty() ? k + size_t(j) : m.indices[k + size_t(j)]];
        p[j] = Eigen::Vector3d(v.x, v.y, v.z);
      }
      f(p);
    }
  }
}

std::vector<uint8_t> voxeliseScene(const Scene& scene, const Grid& g) {
  std::vector<uint8_t> occ(g.size(), 0);
  forEachSceneTriangle(scene, [&](const Eigen::Vector3d* p) {
    const double len = std::max({(p[1] - p[0]).norm(), (p[2] - p[0]).norm(), (p[2] - p[1]).norm()});
    const int steps = std::max(1, int(std::ceil(len / (0.25 * g.res))));
    for (int a = 0; a <= steps; ++a)
      for (int b = 0; a + b <= steps; ++b) {
        const double u = double(a) / steps, w = double(b) / steps;
        // Every voxel whose closed box holds the point: a surface on a voxel boundary (the room's
        // walls and floor, at multiples of 5 cm) crosses the voxels on both sides.
        const Eigen::Vector3d q = p[0] + u * (p[1] - p[0]) + w * (p[2] - p[0]);
        const double eps = 1e-6 * g.res;
        for (int c = 0; c < 8; ++c) {
          const Eigen::Vector3d o((c & 1 ? eps : -eps), (c & 2 ? eps : -eps), (c & 4 ? eps : -eps));
          Eigen::Vector3i v;
          if (g.at(q + o, &v)) occ[g.index(v)] = 1;
        }
      }
  });
  return occ;
}

// Marches from `o` along unit `d` through the grid (exact traversal) calling f(index) until f returns
// false, the ray leaves the grid or `max_len` is reached.
template <class F>
void march(const Grid& g, const Eigen::Vector3d& o_world, const Eigen::Vector3d& d, double max_len, F&& f) {
  const Eigen::Vector3d o = o_world / g.res - g.origin.cast<double>();
  double t0 = 0, t1 = max_len / g.res;
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-12) {
      if (o[a] < 0 || o[a] >= g.dims[a]) return;
      continue;
    }
    double ta = -o[a] / d[a], tb = (g.dims[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  if (t0 >= t1) return;
  const Eigen::Vector3d p = o + (t0 + 1e-9) * d;
  Eigen::Vector3i c, step;
  Eigen::Vector3d tmax, tdelta;
  for (int a = 0; a < 3; ++a) {
    c[a] = std::clamp(int(std::floor(p[a])), 0, g.dims[a] - 1);
    step[a] = d[a] > 0 ? 1 : d[a] < 0 ? -1 : 0;
    tdelta[a] = step[a] ? 1 / std::abs(d[a]) : 1e300;
    tmax[a] = step[a] > 0 ? (c[a] + 1 - o[a]) / d[a] : step[a] < 0 ? (c[a] - o[a]) / d[a] : 1e300;
  }
  double t = t0;
  while (t < t1) {
    if (!f(g.index(c))) return;
    int a = 0;
    if (tmax[1] < tmax[a]) a = 1;
    if (tmax[2] < tmax[a]) a = 2;
    t = tmax[a];
    c[a] += step[a];
    tmax[a] += tdelta[a];
    if (c[a] < 0 || c[a] >= g.dims[a]) return;
  }
}

std::vector<uint8_t> dilate(const std::vector<uint8_t>& in, const Grid& g) {
  std::vector<uint8_t> out(in.size(), 0);
  for (size_t i = 0; i < in.size(); ++i) {
    if (!in[i]) continue;
    const Eigen::Vector3i c = g.coords(i);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const Eigen::Vector3i n = c + Eigen::Vector3i(dx, dy, dz);
          if ((n.array() >= 0).all() && (n.array() < g.dims.array()).all()) out[g.index(n)] = 1;
        }
  }
  return out;
}

struct Scores {
  double precision[2] = {0, 0}, recall[2] = {0, 0}, free_accuracy = 0, free_wrong = 0;
  size_t occupied = 0, free = 0;
};

// occ/free: a map's classes on the grid; gt: ground-truth occupied; seen: the keyframes' first ground-truth
// surface voxels; gt_free: voxels their rays cross before it.
Scores score(const std::vector<uint8_t>& occ, const std::vector<uint8_t>& free, const std::vector<uint8_t>& gt,
             const std::vector<uint8_t>& seen, const std::vector<uint8_t>& gt_free, const Grid& g) {
  Scores s;
  const auto gt_d = dilate(gt, g), occ_d = dilate(occ, g);
  size_t tp[2] = {0, 0}, hit[2] = {0, 0}, n_seen = 0, free_ok = 0, n_free_gt = 0, free_bad = 0;
  for (size_t i = 0; i < occ.size(); ++i) {
    s.occupied += occ[i];
    s.free += free[i];
    if (occ[i]) {
      tp[0] += gt[i];
      tp[1] += gt_d[i];
    }
    if (seen[i]) {
      ++n_seen;
      hit[0] += occ[i];
      hit[1] += occ_d[i];
    }
    if (gt_free[i]) {
      ++n_free_gt;
      free_ok += free[i];
    }
    if (free[i]) free_bad += gt[i];
  }
  for (int k = 0; k < 2; ++k) {
    s.precision[k] = s.occupied ? double(tp[k]) / double(s.occupied) : 0;
    s.recall[k] = n_seen ? double(hit[k]) / double(n_seen) : 0;
  }
  s.free_accuracy = n_free_gt ? double(free_ok) / double(n_free_gt) : 0;
  s.free_wrong = s.free ? double(free_bad) / double(s.free) : 0;
  return s;
}

// The scene's triangles with their unit normals, for exact ray casts.
struct Triangle {
  Eigen::Vector3d a, b, c, n;
};
std::vector<Triangle> sceneTriangles(const Scene& scene) {
  std::vector<Triangle> out;
  forEachSceneTriangle(scene, [&](const Eigen::Vector3d* p) {
    const Eigen::Vector3d nrm = (p[1] - p[0]).cross(p[2] - p[0]);
    if (nrm.norm() >= 1e-12) out.push_back({p[0], p[1], p[2], nrm.normalized()});
  });
  return out;
}
// The nearest triangle along the ray (Moller-Trumbore); false when none.
bool castRay(const std::vector<Triangle>& tris, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double* t_out,
             Eigen::Vector3d* n_out) {
  double best = 1e300;
  for (const Triangle& t : tris) {
    const Eigen::Vector3d e1 = t.b - t.a, e2 = t.c - t.a, pv = d.cross(e2);
    const double det = e1.dot(pv);
    if (std::abs(det) < 1e-12) continue;
    const Eigen::Vector3d tv = o - t.a;
    const double u = tv.dot(pv) / det;
    if (u < 0 || u > 1) continue;
    const Eigen::Vector3d qv = tv.cross(e1);
    const double v = d.dot(qv) / det;
    if (v < 0 || u + v > 1) continue;
    const double tt = e2.dot(qv) / det;
    if (tt > 1e-6 && tt < best) {
      best = tt;
      *n_out = t.n;
    }
  }
  *t_out = best;
  return best < 1e299;
}

// Breadth-first search over 4-connected free cells.
bool pathExists(const std::vector<int8_t>& cells, int w, int h, int a, int b) {
  if (cells[size_t(a)] != 0 || cells[size_t(b)] != 0) return false;
  std::vector<uint8_t> seen(cells.size(), 0);
  std::deque<int> q{a};
  seen[size_t(a)] = 1;
  while (!q.empty()) {
    const int c = q.front();
    q.pop_front();
    if (c == b) return true;
    const int x = c % w, y = c / w;
    const int nb[4][2] = {{x + 1, y}, {x - 1, y}, {x, y + 1}, {x, y - 1}};
    for (const auto& n : nb) {
      if (n[0] < 0 || n[1] < 0 || n[0] >= w || n[1] >= h) continue;
      const int k = n[0] + w * n[1];
      if (seen[size_t(k)] || cells[size_t(k)] != 0) continue;
      seen[size_t(k)] = 1;
      q.push_back(k);
    }
  }
  return false;
}

}  // namespace

int main(int argc, char** argv) {
  std::map<std::string, std::string> args;
  for (int i = 1; i + 1 < argc; i += 2) args[argv[i]] = argv[i + 1];
  if (!args.count("--run") || !args.count("--dataset")) {
    std::printf(
        "bench_nerf_voxel_map: needs --run OUT (a `nerfslam run` folder) and --dataset SEQ (its `nerfslam synth`\n"
        "sequence), e.g.\n"
        "  nerfslam run --out out/demo --demo-frames 300\n"
        "  bench_nerf_voxel_map --run out/demo --dataset out/demo/sequence\n");
    return 0;
  }
  try {
    const fs::path run = args["--run"], seq = args["--dataset"];
    const double res = args.count("--resolution") ? std::stod(args["--resolution"]) : 0.05;
    const int threads = args.count("--threads") ? std::stoi(args["--threads"]) : 2;
    const int stride = args.count("--pixel-stride") ? std::stoi(args["--pixel-stride"]) : 16;
    const double budget_fraction = args.count("--budget-fraction") ? std::stod(args["--budget-fraction"]) : 1 / 16.;
    const int pairs = args.count("--pairs") ? std::stoi(args["--pairs"]) : 20;
    const auto band = parseNumberList(args.count("--band") ? args["--band"] : "0.1,1.5", "--band");
    std::string scene_name = args.count("--scene") ? args["--scene"] : "room";
    if (!args.count("--scene") && fs::exists(seq / "synth.json")) {
      std::ifstream in(seq / "synth.json");
      const auto j = nlohmann::json::parse(in, nullptr, false);
      if (j.is_object() && j.contains("scene")) scene_name = j["scene"].get<std::string>();
    }

    const nerf::NerfModel model = nerf::loadModel(run / "nerf" / "model.nerf");
    const Trajectory gt = readTrajectory(seq / "groundtruth.txt");
    const Trajectory est = readTrajectory(run / "trajectory.txt");
    const Trajectory kfs = readTrajectory(run / "keyframes.txt");
    const Camera cam = loadCameraYaml(seq / "camera.yaml");
    TrajectoryEvalOptions eo;
    eo.align = "sim3";
    const TrajectoryReport rep = evaluateTrajectory(gt, est, eo);
    const Sim3 S = rep.alignment;
    std::printf("run %s: %zu keyframes, Sim(3) scale %.4f, ATE rmse %.4f m; resolution %.3f m, %d threads\n",
                run.string().c_str(), kfs.size(), S.scale(), rep.ape.rmse, res, threads);

    // Keyframes: estimated poses aligned (what the map is built from) and ground-truth poses (scoring).
    std::vector<nerf::PosedCamera> views, gt_views;
    std::vector<std::pair<SE3, SE3>> kf_pairs;
    {
      const Association as = associate(gt, kfs, 0.02);
      for (size_t k = 0; k < as.ref_index.size(); ++k) {
        views.push_back({cam, S.transformPose(kfs[as.est_index[k]].pose)});
        gt_views.push_back({cam, gt[as.ref_index[k]].pose});
      }
    }
    if (views.empty()) throw std::runtime_error("no keyframe matches a ground-truth timestamp");

    nerf::VoxelMapOptions vo;
    vo.resolution = res;
    vo.threads = threads;
    vo.pixel_stride = stride;
    if (args.count("--opacity")) vo.occupied_opacity = std::stod(args["--opacity"]);
    if (args.count("--thickness")) vo.thickness_voxels = std::stoi(args["--thickness"]);
    if (args.count("--min-cluster")) vo.min_cluster_voxels = std::stoi(args["--min-cluster"]);
    if (args.count("--stop")) vo.stop_transmittance = std::stod(args["--stop"]);
    if (args.count("--min-views")) vo.min_hit_views = std::stoi(args["--min-views"]);
    if (args.count("--samples")) vo.samples_per_axis = std::stoi(args["--samples"]);
    const nerf::DensitySource src = nerf::fieldDensitySource(model, S);
    Eigen::AlignedBox3d bounds;
    std::vector<double> t_full;
    nerf::VoxelMap map;
    std::vector<float> mapper_density;
    for (int r = 0; r < 3; ++r) {
      const auto t0 = Clock::now();
      bounds = nerf::observedBounds(src, views, vo);
      nerf::VoxelMapper mapper(vo, bounds);
      mapper.updateDensity(src, -1);
      mapper.carve(views);
      t_full.push_back(seconds(t0));
      if (r == 0) {
        map = mapper.map();
        mapper_density = mapper.density();
      }
    }
    std::vector<double> t_inc, t_inc_density;
    {
      nerf::VoxelMapper mapper(vo, bounds);
      mapper.updateDensity(src, -1);
      const auto budget = int64_t(double(mapper.map().size()) * budget_fraction);
      for (int r = 0; r < 3; ++r) {
        const auto t0 = Clock::now();
        mapper.updateDensity(src, budget);
        t_inc_density.push_back(seconds(t0));
        mapper.carve(views);
        t_inc.push_back(seconds(t0));
      }
    }
    std::printf(
        "map: %d x %d x %d voxels; full extraction %.3f s (median of 3); incremental update %.3f s "
        "(density of %.1f%% of the voxels %.3f s, then the rays of %zu keyframes)\n",
        map.dims.x(), map.dims.y(), map.dims.z(), median3(t_full), median3(t_inc), 100 * budget_fraction,
        median3(t_inc_density), views.size());

    // Ground truth on the same voxels.
    SynthSceneOptions so;
    so.name = scene_name;
    so.textures = "procedural";
    so.texture_size = 16;
    const Scene scene = makeScene(so);
    const Grid g{map.origin, map.dims, res};
    const std::vector<uint8_t> gt_occ = voxeliseScene(scene, g);
    std::vector<uint8_t> seen(g.size(), 0), gt_free(g.size(), 0);
    for (const auto& v : gt_views) {
      const Eigen::Matrix3d R = v.T_world_cam.rotationMatrix();
      for (int y = stride / 2; y < cam.height; y += stride)
        for (int x = stride / 2; x < cam.width; x += stride) {
          const Eigen::Vector3d d = (R * cam.unproject(Eigen::Vector2d(x, y))).normalized();
          march(g, v.T_world_cam.translation(), d, 1e9, [&](size_t i) {
            if (gt_occ[i]) {
              seen[i] = 1;
              return false;
            }
            gt_free[i] = 1;
            return true;
          });
        }
    }

    // Ours.
    std::vector<uint8_t> occ(g.size()), fr(g.size());
    for (size_t i = 0; i < g.size(); ++i) {
      occ[i] = map.state[i] == nerf::VoxelMap::kOccupied;
      fr[i] = map.state[i] == nerf::VoxelMap::kFree;
    }
    // The baseline from the sparse points.
    std::vector<uint8_t> b_occ(g.size(), 0), b_free(g.size(), 0);
    std::vector<Eigen::Vector3d> pts;
    for (const auto& p : loadPointCloudPly(run / "map_points.ply").points) pts.push_back(S * p.cast<double>());
    for (const auto& p : pts) {
      Eigen::Vector3i v;
      if (g.at(p, &v)) b_occ[g.index(v)] = 1;
    }
    for (const auto& v : views) {
      const SE3 Tcw = v.T_world_cam.inverse();
      for (const auto& p : pts) {
        const Eigen::Vector3d pc = Tcw * p;
        if (pc.z() <= 0) continue;
        const double u = cam.fx * pc.x() / pc.z() + cam.cx, w = cam.fy * pc.y() / pc.z() + cam.cy;
        if (u < 0 || w < 0 || u >= cam.width || w >= cam.height) continue;
        const Eigen::Vector3d o = v.T_world_cam.translation();
        const double len = (p - o).norm() - res;
        march(g, o, (p - o).normalized(), len, [&](size_t i) {
          b_free[i] = 1;
          return true;
        });
      }
    }
    for (size_t i = 0; i < g.size(); ++i)
      if (b_occ[i]) b_free[i] = 0;

    if (args.count("--fp")) {  // where our false positives are: distance (voxels) to the ground truth
      std::vector<uint8_t> ring = gt_occ;
      std::vector<int> dist(g.size(), 99);
      for (size_t i = 0; i < g.size(); ++i)
        if (gt_occ[i]) dist[i] = 0;
      for (int d = 1; d <= 6; ++d) {
        ring = dilate(ring, g);
        for (size_t i = 0; i < g.size(); ++i)
          if (ring[i] && dist[i] == 99) dist[i] = d;
      }
      std::map<int, int> h;
      for (size_t i = 0; i < g.size(); ++i)
        if (occ[i]) ++h[dist[i]];
      for (const auto& [d, c] : h) std::printf("  occupied at %2d voxels from the ground truth: %d\n", d, c);
    }

    if (args.count("--column")) {  // one column of the map: state and density by height
      const auto xy = parseNumberList(args["--column"], "--column");
      for (int z = 0; z < g.dims.z(); ++z) {
        Eigen::Vector3i v;
        const double h = (g.origin.z() + z + 0.5) * res;
        if (!g.at({xy[0], xy[1], h}, &v)) continue;
        const size_t i = g.index(v);
        std::printf("  z %.3f: ours %d (L %+.2f, sigma %.1f) gt %d seen %d gt_free %d\n", h, int(map.state[i]),
                    map.log_odds[i], mapper_density.empty() ? 0.f : mapper_density[i], int(gt_occ[i]), int(seen[i]),
                    int(gt_free[i]));
      }
    }
    if (args.count("--surface-errors")) {
      // Where the NeRF puts the surfaces: along the keyframes' ground-truth rays, the depth at which the
      // field's transmittance falls below 0.5 (fine steps) against the exact depth of the scene's
      // triangles, as a signed distance along the surface's normal (positive: behind the true
      // surface), by the surface's orientation; and where in its voxel the true surface lies.
      const std::vector<Triangle> tris = sceneTriangles(scene);
      std::string dump;  // --dump: one line per ray (class, origin, direction, true depth, ours, normal)
      std::map<std::string, std::map<int, int>> hist;
      std::map<std::string, std::vector<double>> errs;
      const double step = res / 10;
      std::vector<float> pts, sig;
      for (const auto& v : gt_views) {
        const Eigen::Matrix3d R = v.T_world_cam.rotationMatrix();
        const Eigen::Vector3d o = v.T_world_cam.translation();
        for (int y = stride / 2; y < cam.height; y += stride)
          for (int x = stride / 2; x < cam.width; x += stride) {
            const Eigen::Vector3d d = (R * cam.unproject(Eigen::Vector2d(x, y))).normalized();
            double tt = 0;
            Eigen::Vector3d n = Eigen::Vector3d::UnitZ();
            if (!castRay(tris, o, d, &tt, &n)) continue;
            const int ns = int((tt + 0.5) / step);
            pts.resize(3 * size_t(ns));
            sig.resize(size_t(ns));
            for (int k = 0; k < ns; ++k) {
              const Eigen::Vector3d p = o + (k + 0.5) * step * d;
              pts[3 * size_t(k)] = float(p.x());
              pts[3 * size_t(k) + 1] = float(p.y());
              pts[3 * size_t(k) + 2] = float(p.z());
            }
            src.density(pts.data(), size_t(ns), sig.data());
            double tau = 0, tm = -1;
            for (int k = 0; k < ns && tm < 0; ++k) {
              const double dt = sig[size_t(k)] * step;
              if (tau + dt >= std::log(2.0)) tm = (k + (std::log(2.0) - tau) / dt) * step;
              tau += dt;
            }
            const double c = std::abs(d.dot(n));
            const Eigen::Vector3d hp = o + tt * d;
            const std::string cls = std::abs(n.z()) > 0.9 ? (hp.z() < 0.05 ? "floor"
                                                             : n.z() < 0   ? "ceiling"
                                                                           : "tops")
                                                          : "walls";
            if (tm < 0) {
              ++hist[cls][999];
              continue;
            }
            const double e = (tm - tt) * c;
            errs[cls].push_back(e);
            if (args.count("--dump"))
              dump += fmt::format("{} {:.5f} {:.5f} {:.5f} {:.5f} {:.5f} {:.5f} {:.5f} {:.5f} {:.5f} {:.5f} {:.5f}\n",
                                  cls, o.x(), o.y(), o.z(), d.x(), d.y(), d.z(), tt, tm, n.x(), n.y(), n.z());
            errs["all"].push_back(e);
            ++hist[cls][int(std::floor(e / 0.01))];
            ++hist["all"][int(std::floor(e / 0.01))];
          }
      }
      if (args.count("--dump")) writeStringAtomic(args["--dump"], dump);
      for (auto& [cls, e] : errs) {
        std::sort(e.begin(), e.end());
        auto q = [&](double f) { return e[size_t(f * double(e.size() - 1))]; };
        std::printf(
            "surface error %-8s %6zu rays: median %+.4f m, 10%% %+.4f, 90%% %+.4f, |e|<1cm %.3f, no surface %d\n",
            cls.c_str(), e.size(), q(0.5), q(0.1), q(0.9),
            double(std::count_if(e.begin(), e.end(), [](double a) { return std::abs(a) < 0.01; })) / double(e.size()),
            hist[cls][999]);
        std::string line;
        for (int b = -6; b < 6; ++b) line += fmt::format(" {:+d}cm:{}", b, hist[cls][b]);
        std::printf("   %s\n", line.c_str());
      }
      // Where the current carving stops: the voxel offset, along the ray, of our first occupied voxel
      // from the first ground-truth one.
      std::map<int, int> off;
      for (const auto& v : gt_views) {
        const Eigen::Matrix3d R = v.T_world_cam.rotationMatrix();
        for (int y = stride / 2; y < cam.height; y += stride)
          for (int x = stride / 2; x < cam.width; x += stride) {
            const Eigen::Vector3d d = (R * cam.unproject(Eigen::Vector2d(x, y))).normalized();
            int k = 0, kg = -1, ko = -1;
            march(g, v.T_world_cam.translation(), d, 1e9, [&](size_t i) {
              if (kg < 0 && gt_occ[i]) kg = k;
              if (ko < 0 && map.state[i] == nerf::VoxelMap::kOccupied) ko = k;
              ++k;
              return kg < 0 || ko < 0;
            });
            ++off[kg < 0 ? 99 : ko < 0 ? 98 : std::clamp(ko - kg, -5, 5)];
          }
      }
      std::string line;
      for (const auto& [o, c] : off) line += fmt::format(" {}:{}", o, c);
      std::map<int, std::pair<int, int>> lh;  // log-odds of our occupied voxels: in the ground truth, not
      for (size_t i = 0; i < g.size(); ++i)
        if (occ[i]) (gt_occ[i] ? lh[int(map.log_odds[i] * 2)].first : lh[int(map.log_odds[i] * 2)].second)++;
      for (const auto& [l, c] : lh) std::printf("  log-odds %.1f: %d true, %d false\n", l / 2.0, c.first, c.second);
      size_t f_occ = 0, f_unk = 0, f_all = 0;
      for (size_t i = 0; i < g.size(); ++i)
        if (gt_free[i]) {
          ++f_all;
          f_occ += map.state[i] == nerf::VoxelMap::kOccupied;
          f_unk += map.state[i] == nerf::VoxelMap::kUnknown;
        }
      std::printf("ground-truth free voxels along the rays: %zu, ours occupied %zu, unknown %zu\n", f_all, f_occ,
                  f_unk);
      std::printf("first occupied voxel along the rays minus the first ground-truth one (98 none of ours):%s\n",
                  line.c_str());
    }
    const Scores ours = score(occ, fr, gt_occ, seen, gt_free, g);
    const Scores base = score(b_occ, b_free, gt_occ, seen, gt_free, g);
    std::printf("ground truth: %zu occupied voxels, %zu seen by the keyframes, %zu free along their rays\n",
                size_t(std::count(gt_occ.begin(), gt_occ.end(), 1)), size_t(std::count(seen.begin(), seen.end(), 1)),
                size_t(std::count(gt_free.begin(), gt_free.end(), 1)));
    std::printf("%-22s %10s %10s %12s %12s %10s %12s %10s\n", "3D (tolerance 0 / 1)", "occupied", "precision", "",
                "recall", "", "free acc.", "free->occ");
    for (const auto& [name, s] : {std::pair<const char*, const Scores&>{"NeRF", ours}, {"sparse points", base}})
      std::printf("%-22s %10zu %10.3f / %.3f %10.3f / %.3f %12.3f %10.4f\n", name, s.occupied, s.precision[0],
                  s.precision[1], s.recall[0], s.recall[1], s.free_accuracy, s.free_wrong);

    // 2D: our grid (the floor found in the map) and the ground truth's (z = 0), compared on the ground
    // truth's cells.
    if (args.count("--histogram")) {
      std::map<int, std::pair<int, int>> hz;
      for (size_t i = 0; i < g.size(); ++i) {
        const int z = g.coords(i).z() + g.origin.z();
        if (occ[i]) ++hz[z].first;
        if (gt_occ[i]) ++hz[z].second;
      }
      for (const auto& [z, c] : hz) std::printf("  z %6.2f: ours %6d, ground truth %6d\n", z * res, c.first, c.second);
    }
    nerf::FloorPlane floor = nerf::detectFloor(map, views);
    if (args.count("--true-floor")) floor = nerf::FloorPlane();  // z = 0: the 2D figures without the floor's error
    const nerf::GridProjection ours2d = nerf::projectToGrid(map, floor, band[0], band[1]);
    std::printf("floor found (%s): normal (%.4f, %.4f, %.4f), height %.4f m (ground truth: (0, 0, 1), 0), %d voxels\n",
                floor.method.c_str(), floor.normal.x(), floor.normal.y(), floor.normal.z(), -floor.offset,
                floor.support);
    const int W = int(std::ceil((scene.bbox_max.x() - scene.bbox_min.x()) / res)) + 2;
    const int H = int(std::ceil((scene.bbox_max.y() - scene.bbox_min.y()) / res)) + 2;
    const double x0 = scene.bbox_min.x() - res, y0 = scene.bbox_min.y() - res;
    std::vector<int8_t> gt2(size_t(W) * H, 0), our2(size_t(W) * H, -1);
    std::vector<uint8_t> observed(size_t(W) * H, 0);  // the keyframes' ground-truth rays reach the column's band
    const SE3 T_grid_out = ours2d.T_out_grid.inverse();
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const double px = x0 + (x + 0.5) * res, py = y0 + (y + 0.5) * res;
        // Ground truth: a surface in the band in this column, or outside the room (walls' far side).
        bool occ_gt =
            px < scene.bbox_min.x() || px > scene.bbox_max.x() || py < scene.bbox_min.y() || py > scene.bbox_max.y();
        for (double h = band[0]; h <= band[1] + 1e-9; h += 0.5 * res) {
          Eigen::Vector3i v;
          if (!g.at({px, py, h}, &v)) continue;
          occ_gt |= gt_occ[g.index(v)] != 0;
          observed[size_t(x + W * y)] |= seen[g.index(v)] || gt_free[g.index(v)];
        }
        gt2[size_t(x + W * y)] = occ_gt ? 100 : 0;
        const Eigen::Vector3d q = T_grid_out * Eigen::Vector3d(px, py, floor.height({px, py, 0}));
        const int cx = int(std::floor((q.x() - ours2d.grid.origin_x) / res));
        const int cy = int(std::floor((q.y() - ours2d.grid.origin_y) / res));
        if (cx >= 0 && cy >= 0 && cx < ours2d.grid.width && cy < ours2d.grid.height)
          our2[size_t(x + W * y)] = ours2d.grid.at(cx, cy);
      }
    size_t gt_occ_ours_free = 0, gt_occ_ours_unknown = 0, ours_occ_gt_free = 0;
    size_t inter = 0, uni = 0, inter_tol = 0, our_occ = 0, our_free = 0, our_unknown = 0, n_observed = 0;
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const size_t i = size_t(x + W * y);
        if (!observed[i]) continue;
        ++n_observed;
        const bool a = our2[i] == 100, b = gt2[i] == 100;
        our_occ += a;
        our_free += our2[i] == 0;
        our_unknown += our2[i] == -1;
        inter += a && b;
        uni += a || b;
        // Tolerance 1: an occupied cell of either grid within one cell of the other's counts as shared.
        auto near = [&](const std::vector<int8_t>& c) {
          for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) {
              const int nx = x + dx, ny = y + dy;
              if (nx >= 0 && ny >= 0 && nx < W && ny < H && c[size_t(nx + W * ny)] == 100) return true;
            }
          return false;
        };
        if ((a && near(gt2)) || (b && near(our2))) ++inter_tol;
        if (b && our2[i] == 0) ++gt_occ_ours_free;
        if (b && our2[i] == -1) ++gt_occ_ours_unknown;
        if (a && !b) ++ours_occ_gt_free;
      }
    std::printf(
        "2D grid, band [%.2f, %.2f] m, on the %zu of %d x %d cells the keyframes observe: %zu occupied, %zu "
        "free, %zu unknown; IoU of the occupied cells %.3f (tolerance 1 cell: %.3f)\n",
        band[0], band[1], n_observed, W, H, our_occ, our_free, our_unknown, uni ? double(inter) / double(uni) : 0.0,
        uni ? double(inter_tol) / double(uni) : 0.0);
    std::printf(
        "2D cells: ground truth occupied and ours free %zu, unknown %zu; ours occupied and ground truth free %zu\n",
        gt_occ_ours_free, gt_occ_ours_unknown, ours_occ_gt_free);
    if (args.count("--column")) {
      const auto xy = parseNumberList(args["--column"], "--column");
      const int x = int(std::floor((xy[0] - x0) / res)), y = int(std::floor((xy[1] - y0) / res));
      std::printf("column's 2D cell (%d, %d): ours %d, ground truth %d, observed %d\n", x, y, our2[size_t(x + W * y)],
                  gt2[size_t(x + W * y)], observed[size_t(x + W * y)]);
    }
    if (args.count("--ascii"))
      for (int y = H - 1; y >= 0; y -= 2) {
        for (int x = 0; x < W; ++x) {
          const int8_t a = our2[size_t(x + W * y)], b = gt2[size_t(x + W * y)];
          if (!observed[size_t(x + W * y)]) {
            std::putchar(' ');
            continue;
          }
          std::putchar(a == 100 ? (b == 100 ? '#' : 'o') : b == 100 ? (a == 0 ? 'X' : 'g') : a == 0 ? '.' : ' ');
        }
        std::putchar('\n');
      }
    std::vector<int> gt_free_cells;
    for (int i = 0; i < W * H; ++i)
      if (gt2[size_t(i)] == 0 && observed[size_t(i)]) gt_free_cells.push_back(i);
    std::mt19937 rng(7);
    int agree = 0, gt_paths = 0;
    for (int k = 0; k < pairs; ++k) {
      const int a = gt_free_cells[rng() % gt_free_cells.size()], b = gt_free_cells[rng() % gt_free_cells.size()];
      const bool pg = pathExists(gt2, W, H, a, b), po = pathExists(our2, W, H, a, b);
      gt_paths += pg;
      agree += (po == pg) || (!pg);
      std::printf("  pair %2d: (%.2f, %.2f) -> (%.2f, %.2f): ground truth %s, ours %s\n", k, x0 + (a % W + 0.5) * res,
                  y0 + (a / W + 0.5) * res, x0 + (b % W + 0.5) * res, y0 + (b / W + 0.5) * res, pg ? "path" : "none",
                  po ? "path" : "none");
    }
    std::printf(
        "paths: ours has one whenever the ground truth has one in %d of %d pairs (%d with a ground-truth path)\n",
        agree, pairs, gt_paths);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_nerf_voxel_map: %s\n", e.what());
    return 1;
  }
  return 0;
}
