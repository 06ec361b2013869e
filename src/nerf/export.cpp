#include "nerfslam/nerf/export.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <type_traits>
#include <unordered_map>

#include <fmt/format.h>
#include <pcl/common/io.h>
#include <pcl/conversions.h>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/nerf/renderer.h"
#include "nerfslam/nerf/trainer.h"

namespace nerfslam::nerf {
namespace {

// Field evaluation of many NeRF-space points over threads.
void densities(const NerfModel& m, const std::vector<float>& xyz, std::vector<float>& sigma, int threads) {
  const size_t n = xyz.size() / 3;
  sigma.resize(n);
  parallelRun(threads, [&](int t) {
    const size_t b = n * size_t(t) / size_t(threads), e = n * size_t(t + 1) / size_t(threads);
    if (e <= b) return;
    std::vector<float> q(3 * (e - b));
    m.toFieldCoords(xyz.data() + 3 * b, e - b, q.data());
    m.field->queryDensity(q.data(), e - b, sigma.data() + b);
  });
}

// Colours at NeRF-space points seen along per-point directions (dirs may be a single direction repeated).
void colours(const NerfModel& m, const std::vector<float>& xyz, const std::vector<float>& dirs, std::vector<float>& rgb,
             int threads) {
  const size_t n = xyz.size() / 3;
  rgb.resize(3 * n);
  parallelRun(threads, [&](int t) {
    const size_t b = n * size_t(t) / size_t(threads), e = n * size_t(t + 1) / size_t(threads);
    if (e <= b) return;
    std::vector<float> q(3 * (e - b)), s(e - b);
    m.toFieldCoords(xyz.data() + 3 * b, e - b, q.data());
    m.field->query(q.data(), dirs.data() + 3 * b, e - b, s.data(), rgb.data() + 3 * b);
  });
}

pcl::PointXYZRGB makePoint(const NerfModel& m, const float* p_nerf, const float* rgb) {
  const Eigen::Vector3d w = m.scene.toWorld(Eigen::Vector3d(p_nerf[0], p_nerf[1], p_nerf[2]));
  pcl::PointXYZRGB pt;
  pt.x = float(w.x());
  pt.y = float(w.y());
  pt.z = float(w.z());
  pt.r = uint8_t(std::clamp(rgb[0], 0.f, 1.f) * 255.f + 0.5f);
  pt.g = uint8_t(std::clamp(rgb[1], 0.f, 1.f) * 255.f + 0.5f);
  pt.b = uint8_t(std::clamp(rgb[2], 0.f, 1.f) * 255.f + 0.5f);
  return pt;
}

void checkOptions(const ExportOptions& o) {
  if (!(o.density_threshold > 0) || !std::isfinite(o.density_threshold)) fail("export: density threshold must be > 0");
  if (o.subdivision < 1 || o.subdivision > 8) fail("export: subdivision must be in [1, 8]");
  if (o.threads < 1) fail("export: threads must be >= 1");
  if (o.pixel_stride < 1) fail("export: pixel stride must be >= 1");
}

}  // namespace

pcl::PointCloud<pcl::PointXYZRGB> densityPointCloud(const NerfModel& model, const ExportOptions& opt) {
  checkOptions(opt);
  const int S = opt.subdivision, R = OccupancyGrid::kRes;
  const float h = OccupancyGrid::cellSize(0) / float(S);
  std::vector<float> xyz;
  for (int z = 0; z < R; ++z)
    for (int y = 0; y < R; ++y)
      for (int x = 0; x < R; ++x) {
        if (!model.grid->occupiedCell(0, x, y, z)) continue;
        const Eigen::Vector3f lo = model.grid->cellCenter(0, x, y, z) - Eigen::Vector3f::Constant(0.5f * S * h);
        for (int k = 0; k < S; ++k)
          for (int j = 0; j < S; ++j)
            for (int i = 0; i < S; ++i)
              xyz.insert(xyz.end(), {lo.x() + (i + 0.5f) * h, lo.y() + (j + 0.5f) * h, lo.z() + (k + 0.5f) * h});
      }
  std::vector<float> sigma;
  densities(model, xyz, sigma, opt.threads);
  std::vector<float> keep;
  for (size_t i = 0; i < sigma.size(); ++i)
    if (sigma[i] > opt.density_threshold)
      keep.insert(keep.end(), xyz.begin() + long(3 * i), xyz.begin() + long(3 * i + 3));
  const size_t n = keep.size() / 3;
  std::vector<float> mean(3 * n, 0.f), rgb;
  const float axes[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
  for (const auto& a : axes) {
    std::vector<float> dirs(3 * n);
    for (size_t i = 0; i < n; ++i) std::copy(a, a + 3, dirs.begin() + long(3 * i));
    colours(model, keep, dirs, rgb, opt.threads);
    for (size_t i = 0; i < 3 * n; ++i) mean[i] += rgb[i] / 6.f;
  }
  pcl::PointCloud<pcl::PointXYZRGB> cloud;
  cloud.reserve(n);
  for (size_t i = 0; i < n; ++i) cloud.push_back(makePoint(model, keep.data() + 3 * i, mean.data() + 3 * i));
  return cloud;
}

pcl::PointCloud<pcl::PointXYZRGB> depthPointCloud(const NerfModel& model, const std::vector<PosedCamera>& views,
                                                  const ExportOptions& opt, std::vector<DepthPointQuality>* quality) {
  checkOptions(opt);
  pcl::PointCloud<pcl::PointXYZRGB> cloud;
  if (quality) quality->clear();
  RenderOptions ro;
  ro.threads = opt.threads;
  ro.normals = false;
  ro.min_opacity = opt.min_opacity;
  for (const auto& v : views) {
    const RenderResult r = renderView(model, v.camera, v.T_world_cam, ro);
    for (int y = 0; y < v.camera.height; y += opt.pixel_stride)
      for (int x = 0; x < v.camera.width; x += opt.pixel_stride) {
        const float d = r.depth.at<float>(y, x);
        if (!(d > 0.f)) continue;
        const Eigen::Vector3d p_cam = v.camera.unproject(Eigen::Vector2d(x, y)) * double(d);  // z = d
        const Eigen::Vector3d w = v.T_world_cam * p_cam;
        const cv::Vec3f c = r.rgb.at<cv::Vec3f>(y, x);
        pcl::PointXYZRGB pt;
        pt.x = float(w.x());
        pt.y = float(w.y());
        pt.z = float(w.z());
        pt.r = uint8_t(std::clamp(c[0], 0.f, 1.f) * 255.f + 0.5f);
        pt.g = uint8_t(std::clamp(c[1], 0.f, 1.f) * 255.f + 0.5f);
        pt.b = uint8_t(std::clamp(c[2], 0.f, 1.f) * 255.f + 0.5f);
        cloud.push_back(pt);
        if (quality)
          quality->push_back({r.opacity.at<float>(y, x), float(r.uncertainty.at<float>(y, x) / p_cam.norm())});
      }
  }
  return cloud;
}

pcl::PolygonMesh extractMesh(const NerfModel& model, const ExportOptions& opt, MeshStats* stats) {
  checkOptions(opt);
  const int S = opt.subdivision, R = OccupancyGrid::kRes;
  const int N = R * S;             // cells per axis
  const int V = N + 1;             // vertices per axis
  const float h = 1.f / float(N);  // cascade 0 spans [0,1]^3
  auto vid = [V](int x, int y, int z) { return size_t(x) + size_t(V) * (size_t(y) + size_t(V) * size_t(z)); };
  // Vertices of every grid cube inside an occupied occupancy cell (plus a one-cell margin, so the
  // surface closes where density falls off just outside an occupied cell).
  std::vector<uint8_t> need(size_t(V) * V * V, 0), cube(size_t(N) * N * N, 0);
  for (int z = 0; z < R; ++z)
    for (int y = 0; y < R; ++y)
      for (int x = 0; x < R; ++x) {
        if (!model.grid->occupiedCell(0, x, y, z)) continue;
        for (int k = std::max(0, z * S - 1); k < std::min(N, (z + 1) * S + 1); ++k)
          for (int j = std::max(0, y * S - 1); j < std::min(N, (y + 1) * S + 1); ++j)
            for (int i = std::max(0, x * S - 1); i < std::min(N, (x + 1) * S + 1); ++i) {
              cube[size_t(i) + size_t(N) * (size_t(j) + size_t(N) * size_t(k))] = 1;
              for (int c = 0; c < 8; ++c) need[vid(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1))] = 1;
            }
      }
  std::vector<float> xyz;
  std::vector<size_t> ids;
  for (int z = 0; z < V; ++z)
    for (int y = 0; y < V; ++y)
      for (int x = 0; x < V; ++x)
        if (need[vid(x, y, z)]) {
          ids.push_back(vid(x, y, z));
          xyz.insert(xyz.end(), {x * h, y * h, z * h});
        }
  std::vector<float> sig;
  densities(model, xyz, sig, opt.threads);
  std::vector<float> field(need.size(), 0.f);
  for (size_t i = 0; i < ids.size(); ++i) field[ids[i]] = std::isfinite(sig[i]) ? sig[i] : 0.f;
  need.clear();
  need.shrink_to_fit();

  // Six tetrahedra around the diagonal 0-7 (corner c = x + 2y + 4z).
  static const int kTets[6][4] = {{0, 1, 3, 7}, {0, 3, 2, 7}, {0, 2, 6, 7}, {0, 6, 4, 7}, {0, 4, 5, 7}, {0, 5, 1, 7}};
  // Triangles the marching below makes at `iso` (a tetrahedron with one corner apart gives one, two
  // and two give a quad: two), without making them.
  auto countTriangles = [&](float iso) {
    size_t count = 0;
    for (int k = 0; k < N; ++k)
      for (int j = 0; j < N; ++j)
        for (int i = 0; i < N; ++i) {
          if (!cube[size_t(i) + size_t(N) * (size_t(j) + size_t(N) * size_t(k))]) continue;
          int inside = 0;
          for (int c = 0; c < 8; ++c)
            inside |= int(field[vid(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1))] > iso) << c;
          if (inside == 0 || inside == 255) continue;
          for (const auto& tet : kTets) {
            int ni = 0;
            for (int q = 0; q < 4; ++q) ni += (inside >> tet[q]) & 1;
            count += ni == 0 || ni == 4 ? 0 : ni == 2 ? 2 : 1;
          }
        }
    return count;
  };
  float iso = float(opt.density_threshold);
  const size_t requested = opt.max_triangles > 0 || stats ? countTriangles(iso) : 0;
  for (size_t n = requested; opt.max_triangles > 0 && n > opt.max_triangles && iso < 1e30f; n = countTriangles(iso))
    iso *= 1.25f;
  if (stats) *stats = {double(iso), requested};
  std::unordered_map<uint64_t, uint32_t> edge_vertex;
  std::vector<float> verts;  // NeRF space
  std::vector<uint32_t> tris;
  auto vertexOn = [&](size_t a, size_t b, const Eigen::Vector3f& pa, const Eigen::Vector3f& pb) -> uint32_t {
    const uint64_t key = a < b ? (uint64_t(a) << 32 | b) : (uint64_t(b) << 32 | a);
    auto it = edge_vertex.find(key);
    if (it != edge_vertex.end()) return it->second;
    const float fa = field[a], fb = field[b];
    const float t = std::clamp((iso - fa) / (fb - fa), 0.f, 1.f);
    const Eigen::Vector3f p = pa + t * (pb - pa);
    const uint32_t idx = uint32_t(verts.size() / 3);
    verts.insert(verts.end(), {p.x(), p.y(), p.z()});
    edge_vertex.emplace(key, idx);
    return idx;
  };
  for (int k = 0; k < N; ++k)
    for (int j = 0; j < N; ++j)
      for (int i = 0; i < N; ++i) {
        if (!cube[size_t(i) + size_t(N) * (size_t(j) + size_t(N) * size_t(k))]) continue;
        size_t cid[8];
        Eigen::Vector3f cp[8];
        bool any_in = false, any_out = false;
        for (int c = 0; c < 8; ++c) {
          const int x = i + (c & 1), y = j + ((c >> 1) & 1), z = k + ((c >> 2) & 1);
          cid[c] = vid(x, y, z);
          cp[c] = Eigen::Vector3f(x * h, y * h, z * h);
          (field[cid[c]] > iso ? any_in : any_out) = true;
        }
        if (!any_in || !any_out) continue;
        for (const auto& tet : kTets) {
          int in[4], out[4], ni = 0, no = 0;
          for (int q = 0; q < 4; ++q) (field[cid[tet[q]]] > iso ? in[ni++] : out[no++]) = tet[q];
          if (ni == 0 || no == 0) continue;
          std::vector<uint32_t> poly;
          if (ni == 1 || no == 1) {
            const bool lone_in = ni == 1;
            const int lone = lone_in ? in[0] : out[0];
            const int* others = lone_in ? out : in;
            for (int q = 0; q < 3; ++q) poly.push_back(vertexOn(cid[lone], cid[others[q]], cp[lone], cp[others[q]]));
          } else {  // 2 in, 2 out: a quad in cyclic order
            poly.push_back(vertexOn(cid[in[0]], cid[out[0]], cp[in[0]], cp[out[0]]));
            poly.push_back(vertexOn(cid[in[0]], cid[out[1]], cp[in[0]], cp[out[1]]));
            poly.push_back(vertexOn(cid[in[1]], cid[out[1]], cp[in[1]], cp[out[1]]));
            poly.push_back(vertexOn(cid[in[1]], cid[out[0]], cp[in[1]], cp[out[0]]));
          }
          // Outward = from the inside corners towards the outside corners.
          Eigen::Vector3f ci = Eigen::Vector3f::Zero(), co = Eigen::Vector3f::Zero();
          for (int q = 0; q < ni; ++q) ci += cp[in[q]] / float(ni);
          for (int q = 0; q < no; ++q) co += cp[out[q]] / float(no);
          auto P = [&](uint32_t v) { return Eigen::Vector3f(verts[3 * v], verts[3 * v + 1], verts[3 * v + 2]); };
          for (size_t q = 1; q + 1 < poly.size(); ++q) {
            uint32_t a = poly[0], b = poly[q], c = poly[q + 1];
            const Eigen::Vector3f nrm = (P(b) - P(a)).cross(P(c) - P(a));
            if (nrm.dot(co - ci) < 0) std::swap(b, c);
            if (a == b || b == c || a == c) continue;
            tris.insert(tris.end(), {a, b, c});
          }
        }
      }
  // Vertex normals (area-weighted) for the colour lookup direction.
  const size_t nv = verts.size() / 3;
  std::vector<float> normals(3 * nv, 0.f);
  for (size_t t = 0; t < tris.size(); t += 3) {
    const Eigen::Vector3f a(&verts[3 * tris[t]]), b(&verts[3 * tris[t + 1]]), c(&verts[3 * tris[t + 2]]);
    const Eigen::Vector3f n = (b - a).cross(c - a);
    for (int q = 0; q < 3; ++q)
      for (int d = 0; d < 3; ++d) normals[3 * tris[t + q] + d] += n[d];
  }
  std::vector<float> dirs(3 * nv);
  for (size_t v = 0; v < nv; ++v) {
    Eigen::Vector3f n(&normals[3 * v]);
    n = n.norm() > 0 ? Eigen::Vector3f(-n.normalized()) : Eigen::Vector3f(0, 0, -1);
    std::copy(n.data(), n.data() + 3, dirs.begin() + long(3 * v));
  }
  std::vector<float> rgb;
  colours(model, verts, dirs, rgb, opt.threads);
  pcl::PointCloud<pcl::PointXYZRGB> cloud;
  cloud.reserve(nv);
  for (size_t v = 0; v < nv; ++v) cloud.push_back(makePoint(model, &verts[3 * v], &rgb[3 * v]));
  pcl::PolygonMesh mesh;
  pcl::toPCLPointCloud2(cloud, mesh.cloud);
  mesh.polygons.resize(tris.size() / 3);
  for (size_t t = 0; t < tris.size() / 3; ++t)
    mesh.polygons[t].vertices = {pcl::index_t(tris[3 * t]), pcl::index_t(tris[3 * t + 1]),
                                 pcl::index_t(tris[3 * t + 2])};
  return mesh;
}

namespace {

// Little-endian bytes of a float or an integer (the PLY and PCD files below are little-endian).
template <class T>
void putLe(std::string& out, T v) {
  static_assert(std::is_trivially_copyable_v<T>);
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  if constexpr (sizeof(T) > 1) {
    const uint16_t probe = 1;
    if (*reinterpret_cast<const uint8_t*>(&probe) == 0) std::reverse(b, b + sizeof(T));
  }
  out.append(b, sizeof(T));
}

// The vertices of a binary PLY: x y z as float, red green blue as uchar (15 bytes each).
void putVertex(std::string& out, float x, float y, float z, uint8_t r, uint8_t g, uint8_t b) {
  putLe(out, x);
  putLe(out, y);
  putLe(out, z);
  out.push_back(char(r));
  out.push_back(char(g));
  out.push_back(char(b));
}

constexpr const char* kVertexProperties =
    "property float x\nproperty float y\nproperty float z\n"
    "property uchar red\nproperty uchar green\nproperty uchar blue\n";

// Written in memory, then by writeStringAtomic, whose every write is checked: a full disk is an Error
// naming the file and leaves no cut-off file (PCL's writers return success without checking theirs).
void writeCloudPly(const pcl::PointCloud<pcl::PointXYZRGB>& cloud, const std::filesystem::path& path) {
  std::string out = fmt::format(
      "ply\nformat binary_little_endian 1.0\ncomment nerfslam NeRF point cloud (world coordinates)\n"
      "element vertex {}\n{}end_header\n",
      cloud.size(), kVertexProperties);
  out.reserve(out.size() + 15 * cloud.size());
  for (const auto& p : cloud.points) putVertex(out, p.x, p.y, p.z, p.r, p.g, p.b);
  writeStringAtomic(path, out);
}

// PCD v0.7 as PCL writes it for PointXYZRGB: x y z rgb, rgb a float holding 0x00RRGGBB (PCL matches
// fields by type too, so rgb stays TYPE F to load back into a PointXYZRGB).
void writeCloudPcd(const pcl::PointCloud<pcl::PointXYZRGB>& cloud, const std::filesystem::path& path) {
  std::string out = fmt::format(
      "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\n"
      "COUNT 1 1 1 1\nWIDTH {}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {}\nDATA binary\n",
      cloud.size(), cloud.size());
  out.reserve(out.size() + 16 * cloud.size());
  for (const auto& p : cloud.points) {
    putLe(out, p.x);
    putLe(out, p.y);
    putLe(out, p.z);
    putLe(out, uint32_t(p.r) << 16 | uint32_t(p.g) << 8 | uint32_t(p.b));
  }
  writeStringAtomic(path, out);
}

}  // namespace

void savePointCloud(const pcl::PointCloud<pcl::PointXYZRGB>& cloud, const std::filesystem::path& path) {
  const std::string ext = path.extension().string();
  if (ext != ".ply" && ext != ".pcd") fail("{}: point clouds are written as .ply or .pcd", path.string());
  if (cloud.empty()) fail("{}: the point cloud is empty (nothing above the density threshold)", path.string());
  if (ext == ".ply")
    writeCloudPly(cloud, path);
  else
    writeCloudPcd(cloud, path);
}

void saveMesh(const pcl::PolygonMesh& mesh, const std::filesystem::path& path) {
  if (mesh.polygons.empty()) fail("{}: the mesh is empty (no surface at the density threshold)", path.string());
  // Vertices with colours (extractMesh's), or positions only.
  const bool colours = std::any_of(mesh.cloud.fields.begin(), mesh.cloud.fields.end(),
                                   [](const pcl::PCLPointField& f) { return f.name == "rgb" || f.name == "rgba"; });
  pcl::PointCloud<pcl::PointXYZRGB> v;
  if (colours) {
    pcl::fromPCLPointCloud2(mesh.cloud, v);
  } else {
    pcl::PointCloud<pcl::PointXYZ> xyz;
    pcl::fromPCLPointCloud2(mesh.cloud, xyz);
    pcl::copyPointCloud(xyz, v);
  }
  std::string out = fmt::format(
      "ply\nformat binary_little_endian 1.0\ncomment nerfslam NeRF mesh (world coordinates)\n"
      "element vertex {}\n{}element face {}\nproperty list uchar int vertex_indices\nend_header\n",
      v.size(), colours ? kVertexProperties : "property float x\nproperty float y\nproperty float z\n",
      mesh.polygons.size());
  out.reserve(out.size() + 15 * v.size() + 13 * mesh.polygons.size());
  for (const auto& p : v.points) {
    if (colours) {
      putVertex(out, p.x, p.y, p.z, p.r, p.g, p.b);
    } else {
      putLe(out, p.x);
      putLe(out, p.y);
      putLe(out, p.z);
    }
  }
  for (size_t f = 0; f < mesh.polygons.size(); ++f) {
    const auto& idx = mesh.polygons[f].vertices;
    if (idx.size() > 255)
      fail("{}: face {} has {} vertices (at most 255 in this format)", path.string(), f, idx.size());
    out.push_back(char(idx.size()));
    for (const auto i : idx) {
      if (i < 0 || size_t(i) >= v.size())
        fail("{}: face {} names vertex {} of {}", path.string(), f, static_cast<long long>(i), v.size());
      putLe(out, int32_t(i));
    }
  }
  writeStringAtomic(path, out);
}

}  // namespace nerfslam::nerf
