#include "nerfslam/nerf/voxel_map.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include <fmt/format.h>
#include <octomap/OcTree.h>
#include <Eigen/Eigenvalues>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/nerf/trainer.h"

namespace nerfslam::nerf {
namespace fs = std::filesystem;

namespace {

double logit(double p) { return std::log(p / (1 - p)); }

// OctoMap's keys: voxel index i (floor(coord / resolution)) is key i + 32768, a uint16.
constexpr int kOctomapKeyOffset = 32768;

double bytesPerVoxel(int threads) {
  // density (float), log-odds (float), state (byte), per-thread hits, misses, last view and views while
  // carving (4 x u32), the speckle pass's visited flag (byte)
  return 4.0 + 4.0 + 1.0 + 1.0 + 16.0 * double(std::max(1, threads));
}

}  // namespace

void validate(const VoxelMapOptions& o) {
  if (!(o.resolution > 0) || !std::isfinite(o.resolution))
    fail("occupancy: resolution must be > 0 (is {})", o.resolution);
  if (!(o.occupied_opacity > 0 && o.occupied_opacity < 1))
    fail("occupancy: occupied_opacity must be in (0, 1) (is {})", o.occupied_opacity);
  if (!(o.stop_transmittance > 0 && o.stop_transmittance < 1))
    fail("occupancy: stop_transmittance must be in (0, 1) (is {})", o.stop_transmittance);
  if (o.thickness_voxels < 0) fail("occupancy: thickness_voxels must be >= 0");
  if (o.min_cluster_voxels < 1) fail("occupancy: min_cluster_voxels must be >= 1");
  if (o.samples_per_axis < 1 || o.samples_per_axis > 8) fail("occupancy: samples_per_axis must be in [1, 8]");
  if (o.pixel_stride < 1) fail("occupancy: pixel_stride must be >= 1");
  if (o.min_hit_views < 1) fail("occupancy: min_hit_views must be >= 1");
  if (!(o.prob_hit > 0.5 && o.prob_hit < 1)) fail("occupancy: prob_hit must be in (0.5, 1)");
  if (!(o.prob_miss > 0 && o.prob_miss < 0.5)) fail("occupancy: prob_miss must be in (0, 0.5)");
  if (!(o.clamp_min > 0 && o.clamp_min < 0.5 && o.clamp_max > 0.5 && o.clamp_max < 1))
    fail("occupancy: clamp_min must be in (0, 0.5) and clamp_max in (0.5, 1)");
  if (!(o.max_memory_mb > 0)) fail("occupancy: max_memory_mb must be > 0");
  if (o.threads < 1) fail("occupancy: threads must be >= 1");
}

DensitySource fieldDensitySource(const NerfModel& model, const Sim3& T_out_world) {
  if (!model.field || !model.grid) fail("occupancy: the model has no field");
  if (model.training_steps == 0) fail("occupancy: the model was never trained (0 steps): an empty model");
  // p_nerf = A p_out + b, with A = nerf_scale / s * R^T.
  const Sim3 T_world_out = T_out_world.inverse();
  const Eigen::Matrix3d A = model.scene.scale * T_world_out.scale() * T_world_out.rotation().toRotationMatrix();
  const Eigen::Vector3d b = model.scene.scale * T_world_out.translation() + model.scene.offset;
  const float sigma_scale = float(model.scene.scale * T_world_out.scale());  // d(nerf length) / d(out length)
  const Eigen::Matrix3f Af = A.cast<float>();
  const Eigen::Vector3f bf = b.cast<float>();
  const Eigen::Vector3f lo = model.scene.aabbMin(), hi = model.scene.aabbMax();
  DensitySource s;
  const NerfModel* m = &model;
  s.density = [m, Af, bf, sigma_scale](const float* xyz, size_t n, float* sigma) {
    std::vector<float> p(3 * n), q(3 * n);
    for (size_t i = 0; i < n; ++i) {
      const Eigen::Vector3f v = Af * Eigen::Vector3f(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]) + bf;
      p[3 * i] = v.x();
      p[3 * i + 1] = v.y();
      p[3 * i + 2] = v.z();
    }
    m->toFieldCoords(p.data(), n, q.data());
    m->field->queryDensity(q.data(), n, sigma);
    for (size_t i = 0; i < n; ++i) sigma[i] = std::isfinite(sigma[i]) ? sigma[i] * sigma_scale : 0.f;
  };
  s.may_be_dense = [m, Af, bf, lo, hi](const Eigen::Vector3f& p_out) {
    const Eigen::Vector3f p = Af * p_out + bf;
    if ((p.array() < lo.array()).any() || (p.array() > hi.array()).any()) return false;
    return m->grid->occupied(p, m->grid->mipFromPos(p));
  };
  // The bounds: where the occupied cells of cascade 0 (the unit cube the scene is normalised into) are,
  // robustly: from the 0.5th to the 99.5th percentile of their coordinates along each axis, widened by
  // 5 % of that extent, so a few floaters far out do not multiply the map's size.
  const int R = OccupancyGrid::kRes;
  std::vector<int64_t> hist[3];
  for (auto& h : hist) h.assign(size_t(R), 0);
  int64_t total = 0;
  for (int z = 0; z < R; ++z)
    for (int y = 0; y < R; ++y)
      for (int x = 0; x < R; ++x)
        if (model.grid->occupiedCell(0, x, y, z)) {
          ++hist[0][size_t(x)];
          ++hist[1][size_t(y)];
          ++hist[2][size_t(z)];
          ++total;
        }
  if (total == 0) fail("occupancy: the model's occupancy grid has no occupied cell: an empty model");
  Eigen::Vector3d cmin, cmax;
  for (int a = 0; a < 3; ++a) {
    int64_t acc = 0;
    int lo_cell = 0, hi_cell = R - 1;
    for (int i = 0; i < R; ++i) {
      acc += hist[a][size_t(i)];
      if (acc * 200 <= total) lo_cell = i + 1;
    }
    acc = 0;
    for (int i = R - 1; i >= 0; --i) {
      acc += hist[a][size_t(i)];
      if (acc * 200 <= total) hi_cell = i - 1;
    }
    if (hi_cell < lo_cell) lo_cell = hi_cell = (lo_cell + hi_cell) / 2;
    const double pad = 0.05 * (hi_cell + 1 - lo_cell);
    cmin[a] = std::max(0.0, lo_cell - pad);
    cmax[a] = std::min(double(R), hi_cell + 1 + pad);
  }
  const Eigen::Matrix3d Ainv = A.inverse();
  const double h = OccupancyGrid::cellSize(0);
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3d corner(c & 1 ? cmax.x() : cmin.x(), c & 2 ? cmax.y() : cmin.y(), c & 4 ? cmax.z() : cmin.z());
    s.bounds.extend(Ainv * (corner * h - b));
  }
  return s;
}

bool VoxelMap::voxelAt(const Eigen::Vector3d& p, Eigen::Vector3i* v) const {
  const Eigen::Vector3d g = p / resolution - origin.cast<double>();
  const Eigen::Vector3i i(int(std::floor(g.x())), int(std::floor(g.y())), int(std::floor(g.z())));
  if ((i.array() < 0).any() || (i.array() >= dims.array()).any()) return false;
  *v = i;
  return true;
}

uint8_t VoxelMap::stateAt(const Eigen::Vector3d& p) const {
  Eigen::Vector3i v;
  if (!voxelAt(p, &v)) return kUnknown;
  return state[index(v.x(), v.y(), v.z())];
}

size_t VoxelMap::count(State s) const { return size_t(std::count(state.begin(), state.end(), uint8_t(s))); }

namespace {
struct MapSize {
  Eigen::Vector3d lo, n;
  double voxels = 0, bytes = 0;
  bool fits = false;
};
MapSize mapSize(const Eigen::AlignedBox3d& bounds, const VoxelMapOptions& o) {
  if (bounds.isEmpty() || !bounds.min().allFinite() || !bounds.max().allFinite())
    fail("occupancy: the region to map is empty");
  MapSize s;
  s.lo = (bounds.min() / o.resolution).array().floor();
  const Eigen::Vector3d hi = (bounds.max() / o.resolution).array().ceil();
  s.n = (hi - s.lo).cwiseMax(1.0);
  s.voxels = s.n.x() * s.n.y() * s.n.z();
  s.bytes = s.voxels * bytesPerVoxel(o.threads);
  s.fits = s.bytes <= o.max_memory_mb * 1e6 && s.n.maxCoeff() < 65536;
  return s;
}
}  // namespace

size_t voxelMapBytes(const Eigen::AlignedBox3d& bounds, const VoxelMapOptions& o, Eigen::Vector3i* dims_out,
                     Eigen::Vector3i* origin_out) {
  validate(o);
  const MapSize s = mapSize(bounds, o);
  const Eigen::Vector3d& n = s.n;
  if (!s.fits)
    fail(
        "occupancy: at resolution {} the map of {:.3g} x {:.3g} x {:.3g} units would have {:.0f} x {:.0f} x {:.0f} = "
        "{:.3g} voxels and need {:.3g} MB, more than the {} MB allowed (max_memory_mb; at most 65535 voxels a side)",
        o.resolution, bounds.sizes().x(), bounds.sizes().y(), bounds.sizes().z(), n.x(), n.y(), n.z(), s.voxels,
        s.bytes / 1e6, o.max_memory_mb);
  const Eigen::Vector3d hi = s.lo + n;
  if ((s.lo.array() < -kOctomapKeyOffset).any() || (hi.array() > kOctomapKeyOffset - 1).any())
    fail("occupancy: at resolution {} the map reaches more than 32768 voxels from the origin (OctoMap's key range)",
         o.resolution);
  if (dims_out) *dims_out = n.cast<int>();
  if (origin_out) *origin_out = s.lo.cast<int>();
  return size_t(s.bytes);
}

VoxelMapper::VoxelMapper(const VoxelMapOptions& options, const Eigen::AlignedBox3d& bounds) : options_(options) {
  voxelMapBytes(bounds, options_, &map_.dims, &map_.origin);
  map_.resolution = options_.resolution;
  map_.log_odds.assign(map_.size(), 0.f);
  map_.state.assign(map_.size(), VoxelMap::kUnknown);
  density_.assign(map_.size(), 0.f);
}

size_t VoxelMapper::updateDensity(const DensitySource& source, int64_t budget) {
  if (!source.density) fail("occupancy: the density source has no density function");
  const size_t total = map_.size();
  const size_t n = budget < 0 ? total : std::min(total, size_t(budget));
  if (n == 0) return 0;
  const int S = options_.samples_per_axis;
  const int T = options_.threads;
  const size_t start = budget < 0 ? 0 : cursor_;
  const VoxelMap& m = map_;
  parallelRun(T, [&](int t) {
    const size_t b = n * size_t(t) / size_t(T), e = n * size_t(t + 1) / size_t(T);
    constexpr size_t kBatch = 2048;
    std::vector<float> pts, sig;
    std::vector<size_t> owner;
    for (size_t c = b; c < e; c += kBatch) {
      pts.clear();
      owner.clear();
      const size_t ce = std::min(e, c + kBatch);
      for (size_t k = c; k < ce; ++k) {
        const size_t idx = (start + k) % total;
        density_[idx] = 0.f;
        const int x = int(idx % size_t(m.dims.x())), y = int(idx / size_t(m.dims.x()) % size_t(m.dims.y())),
                  z = int(idx / (size_t(m.dims.x()) * size_t(m.dims.y())));
        const Eigen::Vector3d lo = m.resolution * (m.origin.cast<double>() + Eigen::Vector3d(x, y, z));
        for (int kz = 0; kz < S; ++kz)
          for (int ky = 0; ky < S; ++ky)
            for (int kx = 0; kx < S; ++kx) {
              const Eigen::Vector3f p =
                  (lo + m.resolution / S * Eigen::Vector3d(kx + 0.5, ky + 0.5, kz + 0.5)).cast<float>();
              if (source.may_be_dense && !source.may_be_dense(p)) continue;
              pts.insert(pts.end(), {p.x(), p.y(), p.z()});
              owner.push_back(idx);
            }
      }
      if (owner.empty()) continue;
      sig.resize(owner.size());
      source.density(pts.data(), owner.size(), sig.data());
      for (size_t i = 0; i < owner.size(); ++i)
        if (std::isfinite(sig[i])) density_[owner[i]] = std::max(density_[owner[i]], sig[i]);
    }
  });
  cursor_ = (start + n) % total;
  return n;
}

void VoxelMapper::carve(const std::vector<PosedCamera>& views) {
  const size_t total = map_.size();
  const int T = options_.threads;
  const double res = map_.resolution;
  const float surface_sigma = float(-std::log(1.0 - options_.occupied_opacity) / res);
  const float stop_tau = float(-std::log(options_.stop_transmittance));
  const int thick = options_.thickness_voxels;
  const Eigen::Vector3i dims = map_.dims;
  std::vector<std::vector<uint32_t>> hits(static_cast<size_t>(T)), misses(static_cast<size_t>(T)),
      last_view(static_cast<size_t>(T)), hit_views(static_cast<size_t>(T));
  parallelRun(T, [&](int t) {
    auto& H = hits[size_t(t)];
    auto& M = misses[size_t(t)];
    auto& LV = last_view[size_t(t)];
    auto& HV = hit_views[size_t(t)];
    H.assign(total, 0);
    M.assign(total, 0);
    LV.assign(total, 0);
    HV.assign(total, 0);
    for (size_t vi = size_t(t); vi < views.size(); vi += size_t(T)) {
      const PosedCamera& view = views[vi];
      const Eigen::Matrix3d R = view.T_world_cam.rotation().toRotationMatrix();
      const Eigen::Vector3d o = view.T_world_cam.translation() / res - map_.origin.cast<double>();  // grid units
      const int stride = options_.pixel_stride;
      for (int v = stride / 2; v < view.camera.height; v += stride)
        for (int u = stride / 2; u < view.camera.width; u += stride) {
          const Eigen::Vector3d d = (R * view.camera.unproject(Eigen::Vector2d(u, v))).normalized();
          // Entry into [0, dims]^3.
          double t0 = 0, t1 = std::numeric_limits<double>::infinity();
          bool miss = false;
          for (int a = 0; a < 3; ++a) {
            if (std::abs(d[a]) < 1e-12) {
              if (o[a] < 0 || o[a] >= dims[a]) miss = true;
              continue;
            }
            double ta = (0 - o[a]) / d[a], tb = (dims[a] - o[a]) / d[a];
            if (ta > tb) std::swap(ta, tb);
            t0 = std::max(t0, ta);
            t1 = std::min(t1, tb);
          }
          if (miss || t0 >= t1) continue;
          double tc = t0;
          const Eigen::Vector3d p = o + (t0 + 1e-9) * d;
          Eigen::Vector3i c;
          Eigen::Vector3i step;
          Eigen::Vector3d tmax, tdelta;
          for (int a = 0; a < 3; ++a) {
            c[a] = std::clamp(int(std::floor(p[a])), 0, dims[a] - 1);
            if (d[a] > 0) {
              step[a] = 1;
              tmax[a] = (c[a] + 1 - o[a]) / d[a];
              tdelta[a] = 1 / d[a];
            } else if (d[a] < 0) {
              step[a] = -1;
              tmax[a] = (c[a] - o[a]) / d[a];
              tdelta[a] = -1 / d[a];
            } else {
              step[a] = 0;
              tmax[a] = tdelta[a] = std::numeric_limits<double>::infinity();
            }
          }
          float tau = 0;
          int behind = -1;  // voxels still to mark behind the surface; -1: before the surface
          for (;;) {
            const size_t idx = size_t(c.x()) + size_t(dims.x()) * (size_t(c.y()) + size_t(dims.y()) * size_t(c.z()));
            int a = 0;
            if (tmax[1] < tmax[a]) a = 1;
            if (tmax[2] < tmax[a]) a = 2;
            const double tn = tmax[a];
            const uint32_t view_tag = uint32_t(vi + 1);
            auto hit = [&] {
              ++H[idx];
              if (LV[idx] != view_tag) {
                LV[idx] = view_tag;
                ++HV[idx];
              }
            };
            if (behind >= 0) {
              hit();
              if (--behind < 0) break;
            } else {
              const float sigma = density_[idx];
              const float seg = float((tn - tc) * res);
              if (sigma >= surface_sigma || tau + sigma * seg > stop_tau) {
                hit();
                behind = thick;
                if (--behind < 0) break;
              } else {
                ++M[idx];
                tau += sigma * seg;
              }
            }
            tc = tn;
            c[a] += step[a];
            tmax[a] += tdelta[a];
            if (c[a] < 0 || c[a] >= dims[a]) break;
          }
        }
    }
  });
  const float lh = float(logit(options_.prob_hit)), lm = float(logit(options_.prob_miss));
  const float lmin = float(logit(options_.clamp_min)), lmax = float(logit(options_.clamp_max));
  for (size_t i = 0; i < total; ++i) {
    uint64_t h = 0, m = 0, hv = 0;
    for (int t = 0; t < T; ++t) {
      h += hits[size_t(t)][i];
      m += misses[size_t(t)][i];
      hv += hit_views[size_t(t)][i];
    }
    // A surface seen by fewer views than min_hit_views (a floater explaining one view) is no evidence.
    if (hv < uint64_t(options_.min_hit_views)) h = 0;
    if (h + m == 0) {
      map_.log_odds[i] = 0.f;
      map_.state[i] = VoxelMap::kUnknown;
      continue;
    }
    const float L = std::clamp(float(h) * lh + float(m) * lm, lmin, lmax);
    map_.log_odds[i] = L;
    map_.state[i] = L > 0 ? VoxelMap::kOccupied : VoxelMap::kFree;
  }
  if (options_.min_cluster_voxels > 1) removeSpeckles(misses);
}

void VoxelMapper::removeSpeckles(const std::vector<std::vector<uint32_t>>& misses) {
  // Occupied clusters (26-connected) smaller than min_cluster_voxels: a floater the field explains a
  // few views with, not an obstacle at this resolution. Their voxels keep only their misses.
  const size_t total = map_.size();
  const Eigen::Vector3i dims = map_.dims;
  const float lm = float(logit(options_.prob_miss)), lmin = float(logit(options_.clamp_min));
  std::vector<uint8_t> done(total, 0);
  std::vector<size_t> cluster, stack;
  for (size_t s = 0; s < total; ++s) {
    if (done[s] || map_.state[s] != VoxelMap::kOccupied) continue;
    cluster.clear();
    stack.assign(1, s);
    done[s] = 1;
    bool large = false;
    while (!stack.empty()) {
      const size_t i = stack.back();
      stack.pop_back();
      cluster.push_back(i);
      if (int(cluster.size()) >= options_.min_cluster_voxels) large = true;
      const int x = int(i % size_t(dims.x())), y = int(i / size_t(dims.x()) % size_t(dims.y())),
                z = int(i / (size_t(dims.x()) * size_t(dims.y())));
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const int nx = x + dx, ny = y + dy, nz = z + dz;
            if (nx < 0 || ny < 0 || nz < 0 || nx >= dims.x() || ny >= dims.y() || nz >= dims.z()) continue;
            const size_t j = map_.index(nx, ny, nz);
            if (done[j] || map_.state[j] != VoxelMap::kOccupied) continue;
            done[j] = 1;
            stack.push_back(j);
          }
    }
    if (large) continue;
    for (size_t i : cluster) {
      uint64_t m = 0;
      for (const auto& M : misses) m += M[i];
      map_.log_odds[i] = m ? std::max(float(m) * lm, lmin) : 0.f;
      map_.state[i] = m ? VoxelMap::kFree : VoxelMap::kUnknown;
    }
  }
}

Eigen::AlignedBox3d voxelMapBounds(const DensitySource& source, const std::vector<PosedCamera>& views,
                                   double resolution) {
  Eigen::AlignedBox3d b = source.bounds;
  for (const auto& v : views) b.extend(v.T_world_cam.translation());
  if (b.isEmpty()) fail("occupancy: nothing to map (no density bounds and no views)");
  b.min() -= Eigen::Vector3d::Constant(resolution);
  b.max() += Eigen::Vector3d::Constant(resolution);
  return b;
}

Eigen::AlignedBox3d observedBounds(const DensitySource& source, const std::vector<PosedCamera>& views,
                                   const VoxelMapOptions& options) {
  validate(options);
  const Eigen::AlignedBox3d all = voxelMapBounds(source, views, options.resolution);
  if (views.empty()) return all;
  VoxelMapOptions coarse = options;
  coarse.resolution = 4 * options.resolution;
  coarse.samples_per_axis = std::min(8, 2 * options.samples_per_axis);
  coarse.pixel_stride = std::max(options.pixel_stride, 8);
  // A map too large at 4x the resolution is too large at the resolution asked for: say so in its figures.
  try {
    voxelMapBytes(all, coarse);
  } catch (const Error&) {
    voxelMapBytes(all, options);
    throw;
  }
  VoxelMapper m(coarse, all);
  m.updateDensity(source, -1);
  m.carve(views);
  const VoxelMap& c = m.map();
  Eigen::AlignedBox3d seen;
  for (int z = 0; z < c.dims.z(); ++z)
    for (int y = 0; y < c.dims.y(); ++y)
      for (int x = 0; x < c.dims.x(); ++x)
        if (c.state[c.index(x, y, z)] != VoxelMap::kUnknown) {
          seen.extend(c.center(x, y, z) - Eigen::Vector3d::Constant(c.resolution));
          seen.extend(c.center(x, y, z) + Eigen::Vector3d::Constant(c.resolution));
        }
  if (seen.isEmpty()) return all;
  return seen.intersection(all);
}

VoxelMap buildVoxelMap(const DensitySource& source, const std::vector<PosedCamera>& views,
                       const VoxelMapOptions& options) {
  validate(options);
  return buildVoxelMap(source, views, options, observedBounds(source, views, options));
}

VoxelMap buildVoxelMap(const DensitySource& source, const std::vector<PosedCamera>& views,
                       const VoxelMapOptions& options, const Eigen::AlignedBox3d& bounds) {
  validate(options);
  VoxelMapper mapper(options, bounds);
  mapper.updateDensity(source, -1);
  mapper.carve(views);
  return mapper.map();
}

double fittingResolution(const DensitySource& source, const std::vector<PosedCamera>& views,
                         const VoxelMapOptions& options, int max_doublings, Eigen::AlignedBox3d* observed) {
  validate(options);
  VoxelMapOptions o = options;
  for (int k = 0; k <= max_doublings; ++k, o.resolution *= 2) {
    VoxelMapOptions coarse = o;
    coarse.resolution = 4 * o.resolution;
    if (!mapSize(voxelMapBounds(source, views, o.resolution), coarse).fits) continue;
    const Eigen::AlignedBox3d seen = observedBounds(source, views, o);
    if (!mapSize(seen, o).fits) continue;
    if (observed) *observed = seen;
    return o.resolution;
  }
  return options.resolution;  // none fits: buildVoxelMap at the resolution asked for says how large it would be
}

void saveOctomap(const VoxelMap& map, const fs::path& path) {
  const std::string ext = path.extension().string();
  if (ext != ".bt" && ext != ".ot")
    fail("{}: an OctoMap file is .bt (binary) or .ot (full, with log-odds)", path.string());
  if (map.size() == 0) fail("{}: the map is empty", path.string());
  octomap::OcTree tree(map.resolution);
  tree.setClampingThresMin(0.1192);
  tree.setClampingThresMax(0.971);
  for (int z = 0; z < map.dims.z(); ++z)
    for (int y = 0; y < map.dims.y(); ++y)
      for (int x = 0; x < map.dims.x(); ++x) {
        const size_t i = map.index(x, y, z);
        if (map.state[i] == VoxelMap::kUnknown) continue;
        const octomap::OcTreeKey key(uint16_t(map.origin.x() + x + kOctomapKeyOffset),
                                     uint16_t(map.origin.y() + y + kOctomapKeyOffset),
                                     uint16_t(map.origin.z() + z + kOctomapKeyOffset));
        // An occupied voxel's log-odds is > 0 and a free one's <= 0; OctoMap's threshold is 0 (p 0.5).
        float L = map.log_odds[i];
        if (map.state[i] == VoxelMap::kFree && L > -1e-3f) L = -1e-3f;
        tree.setNodeValue(key, L, true);
      }
  tree.updateInnerOccupancy();
  writeFileAtomic(path, [&](std::ostream& os) {
    bool ok = false;
    if (ext == ".bt")
      ok = tree.writeBinary(os);
    else
      ok = tree.write(os);
    if (!ok) fail("{}: OctoMap could not write the tree", path.string());
  });
}

namespace {

// "Up" refined by the walls: the local plane normal of occupied voxels (PCA of the occupied voxels
// within 2 voxels) that are within 30 degrees of horizontal are walls and the sides of furniture, and
// "up" is perpendicular to all of them: the eigenvector of the smallest eigenvalue of their sum of
// n n^T. Taken when the walls face at least two directions (a clear eigenvalue gap) and it is within
// 15 degrees of `up`; otherwise `up` is kept.
Eigen::Vector3d refineUp(const VoxelMap& map, const std::vector<Eigen::Vector3i>& occ, const Eigen::Vector3d& up) {
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  int walls = 0;
  const double max_vertical = std::sin(30.0 * M_PI / 180.0);
  for (size_t k = 0; k < occ.size(); k += std::max<size_t>(1, occ.size() / 20000)) {
    const Eigen::Vector3i& c = occ[k];
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    int n = 0;
    for (int dz = -2; dz <= 2; ++dz)
      for (int dy = -2; dy <= 2; ++dy)
        for (int dx = -2; dx <= 2; ++dx) {
          const Eigen::Vector3i q = c + Eigen::Vector3i(dx, dy, dz);
          if ((q.array() < 0).any() || (q.array() >= map.dims.array()).any()) continue;
          if (map.state[map.index(q.x(), q.y(), q.z())] != VoxelMap::kOccupied) continue;
          const Eigen::Vector3d p = q.cast<double>();
          mean += p;
          C += p * p.transpose();
          ++n;
        }
    if (n < 8) continue;
    mean /= n;
    C = C / n - mean * mean.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
    const Eigen::Vector3d ev = es.eigenvalues();
    if (!(ev(0) < 0.2 * ev(1))) continue;  // not planar
    const Eigen::Vector3d nrm = es.eigenvectors().col(0);
    if (std::abs(nrm.dot(up)) > max_vertical) continue;  // not a wall
    M += nrm * nrm.transpose();
    ++walls;
  }
  if (walls < 50) return up;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(M);
  if (!(es.eigenvalues()(0) < 0.3 * es.eigenvalues()(1))) return up;  // walls facing one way only
  Eigen::Vector3d e = es.eigenvectors().col(0);
  if (e.dot(up) < 0) e = -e;
  return e.dot(up) > std::cos(15.0 * M_PI / 180.0) ? Eigen::Vector3d(e.normalized()) : up;
}

}  // namespace

FloorPlane detectFloor(const VoxelMap& map, const std::vector<PosedCamera>& views) {
  Eigen::Vector3d up = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> centres;
  for (const auto& v : views) {
    up -= v.T_world_cam.rotation().toRotationMatrix().col(1);  // image y points down
    centres.push_back(v.T_world_cam.translation());
  }
  up = up.norm() > 1e-9 ? up.normalized() : Eigen::Vector3d::UnitZ();
  std::vector<Eigen::Vector3i> occ;
  std::vector<Eigen::Vector3d> pts;
  for (int z = 0; z < map.dims.z(); ++z)
    for (int y = 0; y < map.dims.y(); ++y)
      for (int x = 0; x < map.dims.x(); ++x)
        if (map.state[map.index(x, y, z)] == VoxelMap::kOccupied) {
          occ.emplace_back(x, y, z);
          pts.push_back(map.center(x, y, z));
        }
  if (pts.empty()) fail("occupancy: no occupied voxel to find the floor on (give the floor plane)");
  const double res = map.resolution;
  Eigen::Vector3d n = refineUp(map, occ, up);
  double cam_h = std::numeric_limits<double>::infinity();
  if (!centres.empty()) {
    std::vector<double> hs;
    for (const auto& c : centres) hs.push_back(n.dot(c));
    std::nth_element(hs.begin(), hs.begin() + long(hs.size() / 2), hs.end());
    cam_h = hs[hs.size() / 2];
  }
  double hmin = std::numeric_limits<double>::infinity();
  for (const auto& p : pts) hmin = std::min(hmin, n.dot(p));
  if (!(hmin < cam_h)) fail("occupancy: no occupied voxel below the cameras to find the floor on");
  // Layers of one voxel along "up", below the cameras.
  const int bins = int(std::min(1e6, std::ceil((std::min(cam_h, hmin + 1e5 * res) - hmin) / res) + 1));
  std::vector<int> hist(size_t(bins), 0);
  for (const auto& p : pts) {
    const double h = n.dot(p);
    const int b = int((h - hmin) / res);
    if (h < cam_h && b >= 0 && b < bins) ++hist[size_t(b)];
  }
  std::vector<int> nonzero;
  for (int c : hist)
    if (c > 0) nonzero.push_back(c);
  std::nth_element(nonzero.begin(), nonzero.begin() + long(nonzero.size() / 2), nonzero.end());
  const int typical = nonzero[nonzero.size() / 2];
  FloorPlane f;
  // A floor seen by the cameras: the lowest layer with at least 3x the typical layer's voxels (a floor
  // covers the area; walls and furniture add a perimeter per layer), refined by a plane fit.
  int peak = -1;
  for (int b = 0; b < bins && peak < 0; ++b)
    if (hist[size_t(b)] >= 3 * typical && hist[size_t(b)] >= 50) peak = b;
  if (peak >= 0) {
    while (peak + 1 < bins && hist[size_t(peak + 1)] > hist[size_t(peak)]) ++peak;
    const double hp = hmin + (peak + 0.5) * res;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    std::vector<Eigen::Vector3d> in;
    for (const auto& p : pts)
      if (std::abs(n.dot(p) - hp) <= 1.0 * res) {
        in.push_back(p);
        mean += p;
      }
    mean /= double(in.size());
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& p : in) C += (p - mean) * (p - mean).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
    Eigen::Vector3d nn = es.eigenvectors().col(0);
    if (nn.dot(n) < 0) nn = -nn;
    if (nn.dot(n) > std::cos(5.0 * M_PI / 180.0)) n = nn.normalized();
    f.normal = n;
    f.offset = -n.dot(mean);
    f.support = int(in.size());
    f.method = "plane";
    return f;
  }
  // No floor in view (cameras looking out level see little of it): the bottom of the walls and the
  // furniture standing on it, the lowest layer with at least a third of the typical layer's voxels.
  int b = 0;
  while (b + 1 < bins && 3 * hist[size_t(b)] < typical) ++b;
  f.normal = n;
  f.offset = -(hmin + b * res);
  f.support = hist[size_t(b)];
  f.method = "bottom of the walls";
  return f;
}

GridProjection projectToGrid(const VoxelMap& map, const FloorPlane& floor, double lo, double hi) {
  if (!(lo < hi) || !std::isfinite(lo) || !std::isfinite(hi))
    fail("occupancy: the height band must have lo < hi (is {}, {})", lo, hi);
  if (map.size() == 0) fail("occupancy: the map is empty");
  const Eigen::Vector3d n = floor.normal.normalized();
  Eigen::Vector3d ex = Eigen::Vector3d::UnitX() - n.x() * n;
  if (ex.norm() < 0.3) ex = Eigen::Vector3d::UnitY() - n.y() * n;
  ex.normalize();
  const Eigen::Vector3d ey = n.cross(ex);
  const Eigen::Vector3d p0 = -floor.offset * n;
  Eigen::Matrix3d R;
  R << ex, ey, n;
  GridProjection out;
  out.T_out_grid = SE3(R, p0);
  const double res = map.resolution;
  double xmin = 1e300, xmax = -1e300, ymin = 1e300, ymax = -1e300;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3d corner =
        res * (map.origin.cast<double>() +
               Eigen::Vector3d(c & 1 ? map.dims.x() : 0, c & 2 ? map.dims.y() : 0, c & 4 ? map.dims.z() : 0));
    const double gx = ex.dot(corner - p0), gy = ey.dot(corner - p0);
    xmin = std::min(xmin, gx);
    xmax = std::max(xmax, gx);
    ymin = std::min(ymin, gy);
    ymax = std::max(ymax, gy);
  }
  const double cx0 = std::floor(xmin / res), cy0 = std::floor(ymin / res);
  NavGrid& g = out.grid;
  g.width = int(std::ceil(xmax / res) - cx0);
  g.height = int(std::ceil(ymax / res) - cy0);
  g.resolution = res;
  g.origin_x = cx0 * res;
  g.origin_y = cy0 * res;
  g.origin_yaw = 0;
  g.cells.assign(size_t(g.width) * size_t(g.height), NavGrid::kUnknown);
  const int steps = std::max(2, int(std::ceil((hi - lo) / (0.5 * res))) + 1);
  for (int y = 0; y < g.height; ++y)
    for (int x = 0; x < g.width; ++x) {
      const Eigen::Vector3d q = p0 + (g.origin_x + (x + 0.5) * res) * ex + (g.origin_y + (y + 0.5) * res) * ey;
      bool any_free = false, any_occ = false;
      for (int k = 0; k < steps && !any_occ; ++k) {
        const double h = lo + (hi - lo) * k / (steps - 1);
        const uint8_t s = map.stateAt(q + h * n);
        any_occ = s == VoxelMap::kOccupied;
        any_free |= s == VoxelMap::kFree;
      }
      g.at(x, y) = any_occ ? NavGrid::kOccupied : any_free ? NavGrid::kFree : NavGrid::kUnknown;
    }
  return out;
}

void saveMapMeta(const MapMeta& m, const fs::path& path) {
  std::ostringstream s;
  s << "# nerfslam " << m.kind << " map: how to read the map beside this file\n";
  s << "kind: " << m.kind << "\n";
  s << "frame: " << m.frame << "\n";
  s << fmt::format("resolution: {:.9g}\n", m.resolution);
  if (m.metres_per_unit == 1.0) {
    s << "units: metres\n";
    s << "metres_per_unit: 1\n";
  } else if (m.metres_per_unit > 0) {
    s << "units: map  # lengths (resolution, origin, band) are in the map's units; metres = units * metres_per_unit\n";
    s << fmt::format("metres_per_unit: {:.9g}  # the scale from the ground truth\n", m.metres_per_unit);
    s << fmt::format("resolution_metres: {:.9g}\n", m.resolution * m.metres_per_unit);
  } else {
    s << "units: map  # a monocular map without a known scale: lengths are in map units\n";
    s << "metres_per_unit: null\n";
  }
  if (!m.source.empty()) s << "source: \"" << m.source << "\"\n";
  if (m.voxels) {
    const VoxelMap& v = *m.voxels;
    s << fmt::format(
        "voxels: {{dims: [{}, {}, {}], origin_index: [{}, {}, {}], occupied: {}, free: {}, unknown: {}}}\n", v.dims.x(),
        v.dims.y(), v.dims.z(), v.origin.x(), v.origin.y(), v.origin.z(), v.count(VoxelMap::kOccupied),
        v.count(VoxelMap::kFree), v.count(VoxelMap::kUnknown));
  }
  if (m.floor)
    s << fmt::format(
        "floor: {{normal: [{:.9g}, {:.9g}, {:.9g}], offset: {:.9g}, found_by: \"{}\", support_voxels: {}}}  # n.p + "
        "offset = 0\n",
        m.floor->normal.x(), m.floor->normal.y(), m.floor->normal.z(), m.floor->offset, m.floor->method,
        m.floor->support);
  if (m.grid) {
    s << fmt::format("height_band: [{:.9g}, {:.9g}]  # above the floor\n", m.band_lo, m.band_hi);
    const Eigen::Matrix4d T = m.grid->T_out_grid.matrix();
    s << "# The grid's frame (map_server's frame) in the map frame, row-major 4x4\nT_map_grid: [";
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) s << fmt::format("{:.9g}{}", T(r, c), r == 3 && c == 3 ? "]\n" : ", ");
  }
  writeStringAtomic(path, s.str());
}

fs::path metaPathFor(const fs::path& map_path) {
  fs::path p = map_path;
  p.replace_extension(".meta.yaml");
  return p;
}

void writeOctomapFiles(const VoxelMap& map, const fs::path& path, double metres_per_unit, const std::string& source) {
  saveOctomap(map, path);
  MapMeta m;
  m.kind = "octomap";
  m.resolution = map.resolution;
  m.metres_per_unit = metres_per_unit;
  m.source = source;
  m.voxels = &map;
  saveMapMeta(m, metaPathFor(path));
}

GridProjection writeGridFiles(const VoxelMap& map, const std::vector<PosedCamera>& views, const FloorPlane* floor,
                              double band_lo, double band_hi, const fs::path& yaml_path, double metres_per_unit,
                              const std::string& source) {
  if (!(band_lo < band_hi)) fail("occupancy: the height band must have lo < hi (is {}, {})", band_lo, band_hi);
  const FloorPlane f = floor ? *floor : detectFloor(map, views);
  GridProjection g = projectToGrid(map, f, band_lo, band_hi);
  saveMapServer(g.grid, yaml_path);
  MapMeta m;
  m.kind = "grid";
  m.resolution = map.resolution;
  m.metres_per_unit = metres_per_unit;
  m.source = source;
  m.grid = &g;
  m.floor = &f;
  m.band_lo = band_lo;
  m.band_hi = band_hi;
  saveMapMeta(m, metaPathFor(yaml_path));
  return g;
}

}  // namespace nerfslam::nerf
