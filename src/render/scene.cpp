#include "nerfslam/render/scene.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <map>

#include <spdlog/spdlog.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace fs = std::filesystem;
using Eigen::Vector3d;

uint64_t mixSeed(uint64_t a, uint64_t b, uint64_t salt) {
  uint64_t z = a * 0x9E3779B97F4A7C15ull + b + salt;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

namespace {

uint64_t mix(uint64_t a, uint64_t b) { return mixSeed(a, b, 0x632BE59BD9B4E019ull); }

// Directional "sun" shading baked into vertex colours so faces of a box differ in brightness.
float shade(const Vector3d& n) {
  const Vector3d L = Vector3d(0.4, 0.3, 0.86).normalized();
  return static_cast<float>(0.62 + 0.38 * std::max(0.0, n.normalized().dot(L)));
}

class Builder {
 public:
  Builder(uint64_t seed, const std::vector<cv::Mat>* textures) : rng_(seed), textures_(textures) {}

  // Quad p0 p1 p2 p3 (in order around the edge). `tile` metres per texture repeat.
  void quad(int tex, const Vector3d& p0, const Vector3d& p1, const Vector3d& p2, const Vector3d& p3, double tile,
            const Vector3d& normal) {
    Mesh& m = meshFor(tex);
    const float s = shade(normal);
    // One texture repeat spans `tile` metres horizontally and keeps the image's aspect ratio.
    const cv::Mat& img = textures_->at(tex);
    const double aspect = static_cast<double>(img.cols) / img.rows;
    const double su = (p1 - p0).norm() / tile, sv = (p3 - p0).norm() / tile * aspect;
    const double ou = rng_.uniform(0.0, 1.0), ov = rng_.uniform(0.0, 1.0);
    const uint32_t base = static_cast<uint32_t>(m.vertices.size());
    const std::array<Vector3d, 4> P = {p0, p1, p2, p3};
    const std::array<std::array<double, 2>, 4> UV = {{{0, 0}, {su, 0}, {su, sv}, {0, sv}}};
    for (int i = 0; i < 4; ++i) {
      Vertex v;
      v.x = static_cast<float>(P[i].x());
      v.y = static_cast<float>(P[i].y());
      v.z = static_cast<float>(P[i].z());
      v.u = static_cast<float>(UV[i][0] + ou);
      v.v = static_cast<float>(UV[i][1] + ov);
      v.r = v.g = v.b = s;
      m.vertices.push_back(v);
    }
    for (uint32_t k : {0u, 1u, 2u, 0u, 2u, 3u}) m.indices.push_back(base + k);
  }

  // Axis-aligned box; `inward` flips normals (for rooms). Bottom face skipped when on the floor.
  void box(int tex, const Vector3d& lo, const Vector3d& hi, double tile, bool bottom = false) {
    const double x0 = lo.x(), y0 = lo.y(), z0 = lo.z(), x1 = hi.x(), y1 = hi.y(), z1 = hi.z();
    quad(tex, {x0, y0, z1}, {x1, y0, z1}, {x1, y1, z1}, {x0, y1, z1}, tile, {0, 0, 1});
    if (bottom) quad(tex, {x0, y0, z0}, {x1, y0, z0}, {x1, y1, z0}, {x0, y1, z0}, tile, {0, 0, -1});
    quad(tex, {x0, y0, z0}, {x1, y0, z0}, {x1, y0, z1}, {x0, y0, z1}, tile, {0, -1, 0});
    quad(tex, {x1, y1, z0}, {x0, y1, z0}, {x0, y1, z1}, {x1, y1, z1}, tile, {0, 1, 0});
    quad(tex, {x0, y1, z0}, {x0, y0, z0}, {x0, y0, z1}, {x0, y1, z1}, tile, {-1, 0, 0});
    quad(tex, {x1, y0, z0}, {x1, y1, z0}, {x1, y1, z1}, {x1, y0, z1}, tile, {1, 0, 0});
  }

  // Room shell seen from inside: floor, ceiling, four walls, each with its own texture.
  void roomShell(const Vector3d& lo, const Vector3d& hi, int floor_tex, int ceil_tex, const std::array<int, 4>& wall,
                 double tile) {
    const double x0 = lo.x(), y0 = lo.y(), z0 = lo.z(), x1 = hi.x(), y1 = hi.y(), z1 = hi.z();
    quad(floor_tex, {x0, y0, z0}, {x1, y0, z0}, {x1, y1, z0}, {x0, y1, z0}, tile, {0, 0, 1});
    quad(ceil_tex, {x0, y0, z1}, {x1, y0, z1}, {x1, y1, z1}, {x0, y1, z1}, tile, {0, 0, -1});
    quad(wall[0], {x0, y0, z0}, {x1, y0, z0}, {x1, y0, z1}, {x0, y0, z1}, tile, {0, 1, 0});
    quad(wall[1], {x1, y0, z0}, {x1, y1, z0}, {x1, y1, z1}, {x1, y0, z1}, tile, {-1, 0, 0});
    quad(wall[2], {x1, y1, z0}, {x0, y1, z0}, {x0, y1, z1}, {x1, y1, z1}, tile, {0, -1, 0});
    quad(wall[3], {x0, y1, z0}, {x0, y0, z0}, {x0, y0, z1}, {x0, y1, z1}, tile, {1, 0, 0});
  }

  // Vertical prism with `sides` faces around (cx, cy) from z0 to z1, plus a top cap.
  void prism(int tex, double cx, double cy, double radius, double z0, double z1, int sides, double tile) {
    for (int i = 0; i < sides; ++i) {
      const double a0 = 2 * M_PI * i / sides, a1 = 2 * M_PI * (i + 1) / sides;
      const Vector3d p0(cx + radius * std::cos(a0), cy + radius * std::sin(a0), z0);
      const Vector3d p1(cx + radius * std::cos(a1), cy + radius * std::sin(a1), z0);
      const double am = 0.5 * (a0 + a1);
      quad(tex, p0, p1, {p1.x(), p1.y(), z1}, {p0.x(), p0.y(), z1}, tile, {std::cos(am), std::sin(am), 0});
    }
    Mesh& m = meshFor(tex);
    const uint32_t c = static_cast<uint32_t>(m.vertices.size());
    Vertex vc;
    vc.x = static_cast<float>(cx);
    vc.y = static_cast<float>(cy);
    vc.z = static_cast<float>(z1);
    vc.r = vc.g = vc.b = shade({0, 0, 1});
    m.vertices.push_back(vc);
    for (int i = 0; i <= sides; ++i) {
      const double a = 2 * M_PI * i / sides;
      Vertex v = vc;
      v.x = static_cast<float>(cx + radius * std::cos(a));
      v.y = static_cast<float>(cy + radius * std::sin(a));
      v.u = static_cast<float>(0.5 + 0.5 * radius * std::cos(a) / tile);
      v.v = static_cast<float>(0.5 + 0.5 * radius * std::sin(a) / tile);
      m.vertices.push_back(v);
    }
    m.vertices[c].u = m.vertices[c].v = 0.5f;
    for (int i = 0; i < sides; ++i) {
      m.indices.push_back(c);
      m.indices.push_back(c + 1 + i);
      m.indices.push_back(c + 2 + i);
    }
  }

  // A table: top slab and four legs.
  void table(int top_tex, int leg_tex, const Eigen::Vector2d& centre, double sx, double sy, double height) {
    const double t = 0.04, leg = 0.05;
    box(top_tex, {centre.x() - sx / 2, centre.y() - sy / 2, height - t},
        {centre.x() + sx / 2, centre.y() + sy / 2, height}, 0.6, true);
    for (int i = 0; i < 4; ++i) {
      const double lx = centre.x() + (i % 2 ? 1 : -1) * (sx / 2 - 0.08);
      const double ly = centre.y() + (i / 2 ? 1 : -1) * (sy / 2 - 0.08);
      box(leg_tex, {lx - leg / 2, ly - leg / 2, 0}, {lx + leg / 2, ly + leg / 2, height - t}, 0.3);
    }
  }

  std::vector<Mesh> take() {
    std::vector<Mesh> out;
    for (auto& [tex, m] : meshes_) out.push_back(std::move(m));
    return out;
  }

 private:
  Mesh& meshFor(int tex) {
    Mesh& m = meshes_[tex];
    m.texture = tex;
    return m;
  }
  std::map<int, Mesh> meshes_;
  cv::RNG rng_;
  const std::vector<cv::Mat>* textures_;
};

fs::path defaultDataDir(const fs::path& given) {
  if (!given.empty()) return given;
  if (const char* env = std::getenv("NERFSLAM_DATA_DIR"); env && *env) return fs::path(env);
#ifdef NERFSLAM_SOURCE_DIR
  return fs::path(NERFSLAM_SOURCE_DIR) / ".." / "shared" / "data";
#else
  return {};
#endif
}

// Photos from the shared data, in a fixed order (sorted names) so the choice is deterministic.
std::vector<fs::path> findPhotos(const fs::path& dir) {
  std::vector<fs::path> out;
  const std::vector<std::pair<std::string, int>> sources = {{"strecha_fountain-P11/images", 11},
                                                            {"new_tsukuba_150", 6},
                                                            {"opencv_chessboard", 6},
                                                            {"middlebury_templeRing", 2}};
  std::error_code ec;
  for (const auto& [sub, max_n] : sources) {
    const fs::path d = dir / sub;
    if (!fs::is_directory(d, ec)) continue;
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(d, ec)) {
      const std::string ext = e.path().extension().string();
      if (ext == ".png" || ext == ".jpg" || ext == ".JPG" || ext == ".jpeg" || ext == ".ppm") files.push_back(e.path());
    }
    std::sort(files.begin(), files.end());
    // Spread the picks over the sequence (consecutive frames look alike).
    const int n = std::min<int>(max_n, static_cast<int>(files.size()));
    for (int i = 0; i < n; ++i) out.push_back(files[(files.size() * i) / n]);
  }
  return out;
}

}  // namespace

cv::Mat proceduralTexture(int size, uint64_t seed, int style) {
  if (size < 16 || size > 8192) fail("procedural texture size {} outside 16..8192", size);
  cv::RNG rng(mix(seed, 0x7e57u + style));
  // Multi-octave value noise: random grids upsampled bicubically, amplitude halving per octave.
  cv::Mat noise = cv::Mat::zeros(size, size, CV_32F);
  double amp = 1.0, total = 0.0;
  const double aspect = style == 1 ? 6.0 : 1.0;  // style 1: stretched, wood-like grain
  for (int cells = 3; cells <= size / 2; cells *= 2) {
    cv::Mat grid(cells, std::max(2, static_cast<int>(cells / aspect)), CV_32F);
    rng.fill(grid, cv::RNG::UNIFORM, 0.f, 1.f);
    cv::Mat up;
    cv::resize(grid, up, cv::Size(size, size), 0, 0, cv::INTER_CUBIC);
    noise += amp * up;
    total += amp;
    amp *= 0.62;
  }
  noise /= total;
  cv::normalize(noise, noise, 0.0, 1.0, cv::NORM_MINMAX);
  // Colour ramp between two random colours.
  const cv::Vec3f c0(rng.uniform(0.05f, 0.5f), rng.uniform(0.05f, 0.5f), rng.uniform(0.05f, 0.5f));
  const cv::Vec3f c1(rng.uniform(0.5f, 1.f), rng.uniform(0.5f, 1.f), rng.uniform(0.5f, 1.f));
  cv::Mat img(size, size, CV_8UC3);
  for (int y = 0; y < size; ++y) {
    const float* n = noise.ptr<float>(y);
    cv::Vec3b* o = img.ptr<cv::Vec3b>(y);
    for (int x = 0; x < size; ++x) {
      const cv::Vec3f c = c0 + (c1 - c0) * n[x];
      o[x] = cv::Vec3b(cv::saturate_cast<uchar>(255 * c[0]), cv::saturate_cast<uchar>(255 * c[1]),
                       cv::saturate_cast<uchar>(255 * c[2]));
    }
  }
  auto randColor = [&]() { return cv::Scalar(rng.uniform(0, 256), rng.uniform(0, 256), rng.uniform(0, 256)); };
  auto randPt = [&]() { return cv::Point(rng.uniform(0, size), rng.uniform(0, size)); };
  const double s = size / 512.0;
  if (style == 2) {  // tiles: grout lines
    const int step = std::max(8, size / 8);
    for (int p = 0; p < size; p += step) {
      cv::line(img, {p, 0}, {p, size - 1}, cv::Scalar(40, 40, 40), std::max(1, static_cast<int>(3 * s)));
      cv::line(img, {0, p}, {size - 1, p}, cv::Scalar(40, 40, 40), std::max(1, static_cast<int>(3 * s)));
    }
  }
  // Random shapes: filled and outlined rectangles, circles, polygons.
  const int shapes = style == 1 ? 25 : 60;
  for (int i = 0; i < shapes; ++i) {
    const cv::Point c = randPt();
    const int r = std::max(2, static_cast<int>(rng.uniform(4.0, 40.0) * s));
    const int thick = rng.uniform(0, 3) == 0 ? cv::FILLED : std::max(1, static_cast<int>(rng.uniform(1, 4) * s));
    switch (rng.uniform(0, 3)) {
      case 0:
        cv::rectangle(img, c, c + cv::Point(r, static_cast<int>(r * rng.uniform(0.4, 1.6))), randColor(), thick,
                      cv::LINE_AA);
        break;
      case 1:
        cv::circle(img, c, r, randColor(), thick, cv::LINE_AA);
        break;
      default: {
        std::vector<cv::Point> poly;
        const int k = rng.uniform(3, 6);
        for (int j = 0; j < k; ++j) {
          const double a = 2 * M_PI * j / k + rng.uniform(-0.3, 0.3);
          poly.push_back(c + cv::Point(static_cast<int>(r * std::cos(a)), static_cast<int>(r * std::sin(a))));
        }
        if (thick == cv::FILLED)
          cv::fillConvexPoly(img, poly, randColor(), cv::LINE_AA);
        else
          cv::polylines(img, poly, true, randColor(), thick, cv::LINE_AA);
      }
    }
  }
  // Text-like strokes: random letters and scribbles.
  static const char kChars[] = "ABCDEFGHJKLMNPQRSTUVWXYZ0123456789#&%@";
  const int words = style == 1 ? 10 : 30;
  for (int i = 0; i < words; ++i) {
    std::string w;
    const int len = rng.uniform(2, 7);
    for (int j = 0; j < len; ++j) w += kChars[rng.uniform(0, static_cast<int>(sizeof kChars) - 1)];
    cv::putText(img, w, randPt(), rng.uniform(0, 8), rng.uniform(0.4, 1.3) * s, randColor(),
                std::max(1, static_cast<int>(rng.uniform(1, 3) * s)), cv::LINE_AA);
  }
  for (int i = 0; i < 15; ++i) {
    std::vector<cv::Point> pts{randPt()};
    for (int j = 0; j < 5; ++j)
      pts.push_back(pts.back() + cv::Point(static_cast<int>(rng.uniform(-30.0, 30.0) * s),
                                           static_cast<int>(rng.uniform(-30.0, 30.0) * s)));
    cv::polylines(img, pts, false, randColor(), std::max(1, static_cast<int>(2 * s)), cv::LINE_AA);
  }
  return img;
}

const std::vector<std::string>& sceneNames() {
  static const std::vector<std::string> names = {"room", "turntable", "plane", "corridor"};
  return names;
}

namespace {

void validateSynthSceneOptions(const SynthSceneOptions& opts) {
  const auto& names = sceneNames();
  if (std::find(names.begin(), names.end(), opts.name) == names.end()) {
    std::string list;
    for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
    fail("unknown scene '{}' (valid scenes: {})", opts.name, list);
  }
  if (opts.textures != "auto" && opts.textures != "procedural" && opts.textures != "photo")
    fail("unknown texture source '{}' (valid: auto, procedural, photo)", opts.textures);
  if (opts.texture_size < 16 || opts.texture_size > 8192) fail("texture size {} outside 16..8192", opts.texture_size);
}

// The scene's textures, added to Scene::textures in the order asked for. Texture k: a photo (when
// available and allowed), blended with procedural detail so nothing is flat, or procedural alone.
// The photo order is shuffled by the seed.
class TextureSource {
 public:
  TextureSource(const SynthSceneOptions& opts, Scene& sc) : opts_(opts), sc_(sc) {
    if (opts.textures != "procedural") {
      const fs::path dir = defaultDataDir(opts.data_dir);
      photos_ = findPhotos(dir);
      if (photos_.empty() && opts.textures == "photo")
        fail(
            "no photos for textures found under '{}' (need strecha_fountain-P11, new_tsukuba_150 or "
            "opencv_chessboard); use textures=procedural",
            dir.string());
    }
    cv::RNG prng(mix(opts.seed, 99));
    order_.resize(photos_.size());
    for (size_t i = 0; i < order_.size(); ++i) order_[i] = i;
    for (size_t i = order_.size(); i > 1; --i) std::swap(order_[i - 1], order_[prng.uniform(0, static_cast<int>(i))]);
  }

  // A new texture of procedural `style` (proceduralTexture); its index in Scene::textures.
  int operator()(int style, bool allow_photo) {
    const uint64_t tseed = mix(opts_.seed, sc_.textures.size() + 1);
    cv::Mat tex = proceduralTexture(opts_.texture_size, tseed, style);
    if (allow_photo && !photos_.empty()) {
      const fs::path& p = photos_[order_[next_photo_++ % order_.size()]];
      cv::Mat photo = cv::imread(p.string(), cv::IMREAD_COLOR);
      if (!photo.empty()) {
        cv::resize(photo, photo,
                   cv::Size(opts_.texture_size * photo.cols / std::max(1, photo.rows), opts_.texture_size), 0, 0,
                   cv::INTER_AREA);
        cv::Mat proc;
        cv::resize(tex, proc, photo.size(), 0, 0, cv::INTER_LINEAR);
        cv::addWeighted(photo, 0.72, proc, 0.28, 0.0, tex);
        sc_.photographic = true;
      } else {
        spdlog::warn("texture photo '{}' unreadable; using a procedural texture", p.string());
      }
    }
    sc_.textures.push_back(tex);
    return static_cast<int>(sc_.textures.size()) - 1;
  }

 private:
  const SynthSceneOptions& opts_;
  Scene& sc_;
  std::vector<fs::path> photos_;
  std::vector<size_t> order_;
  size_t next_photo_ = 0;
};

// The scenes' geometry, textures (asked for in a fixed order: it fixes their seeds and photos),
// landmarks and camera region.

// A furnished room: table, boxes, a shelf and a cabinet; the camera looks outwards from the middle.
void buildRoom(Builder& b, TextureSource& texture, Scene& sc) {
  const Vector3d lo(-3, -2.5, 0), hi(3, 2.5, 2.8);
  const int floor_t = texture(2, false), ceil_t = texture(0, true);
  const std::array<int, 4> walls = {texture(0, true), texture(0, true), texture(0, true), texture(0, true)};
  b.roomShell(lo, hi, floor_t, ceil_t, walls, 1.4);
  const int wood = texture(1, false), box_a = texture(0, true), box_b = texture(0, true), box_c = texture(0, false);
  b.table(wood, wood, {0.4, 1.7}, 1.4, 0.8, 0.75);
  b.box(box_a, {1.9, -2.1, 0}, {2.5, -1.5, 0.6}, 0.6);
  b.box(box_b, {2.2, 1.6, 0}, {2.7, 2.0, 0.9}, 0.6);
  b.box(box_c, {-2.4, 1.6, 0}, {-1.6, 2.1, 0.5}, 0.6);
  b.box(box_a, {-2.2, 1.7, 0.5}, {-1.8, 2.0, 0.8}, 0.5);
  b.box(box_b, {-0.1, 1.5, 0.75}, {0.25, 1.8, 1.0}, 0.4);  // on the table
  b.box(wood, {-3.0, -1.2, 0}, {-2.55, 0.6, 2.0}, 0.8);    // shelf against the -x wall
  b.box(box_c, {-0.8, -2.5, 0}, {0.4, -2.2, 1.1}, 0.7);    // cabinet against the -y wall
  sc.landmarks = {{"box_a_top_corner", {1.9, -2.1, 0.6}},
                  {"box_b_top_corner", {2.2, 1.6, 0.9}},
                  {"table_box_top_corner", {-0.1, 1.5, 1.0}},
                  {"shelf_top_corner", {-2.55, -1.2, 2.0}}};
  sc.bbox_min = lo;
  sc.bbox_max = hi;
  sc.camera_min = {-1.3, -1.1, 1.2};
  sc.camera_max = {1.3, 1.0, 1.75};
  sc.focus = {0, 0, 1.2};
  sc.anchor = {0, 0, 1.5};
  sc.look_outward = true;
  sc.loop_height = 1.5;
}

// A table with objects in a larger room; the camera goes around them.
void buildTurntable(Builder& b, TextureSource& texture, Scene& sc) {
  const Vector3d lo(-4, -4, 0), hi(4, 4, 3);
  const int floor_t = texture(2, false), ceil_t = texture(0, true);
  const std::array<int, 4> walls = {texture(0, true), texture(0, true), texture(0, true), texture(0, true)};
  b.roomShell(lo, hi, floor_t, ceil_t, walls, 1.5);
  const int wood = texture(1, false), obj_a = texture(0, true), obj_b = texture(0, false);
  b.table(wood, wood, {0, 0}, 1.0, 1.0, 0.7);
  b.box(obj_a, {-0.25, -0.2, 0.7}, {0.15, 0.2, 0.95}, 0.3);
  b.box(obj_b, {-0.15, -0.1, 0.95}, {0.05, 0.1, 1.1}, 0.25);
  b.prism(obj_b, 0.25, 0.15, 0.08, 0.7, 1.05, 10, 0.3);
  sc.landmarks = {{"object_top_corner", {-0.15, -0.1, 1.1}}, {"object_base_corner", {0.15, 0.2, 0.95}}};
  sc.bbox_min = lo;
  sc.bbox_max = hi;
  sc.camera_min = {-1.6, -1.6, 1.1};
  sc.camera_max = {1.6, 1.6, 1.7};
  sc.focus = {0, 0, 0.9};
  sc.anchor = {0, -1.4, 1.4};
  sc.handheld_sweep = 1.2;
  sc.look_outward = false;
  sc.loop_height = 1.4;
}

// One textured wall, seen from the front.
void buildPlane(Builder& b, TextureSource& texture, Scene& sc) {
  const int t = texture(0, true);
  b.quad(t, {-3, 2, -0.5}, {3, 2, -0.5}, {3, 2, 3.5}, {-3, 2, 3.5}, 1.2, {0, -1, 0});
  sc.bbox_min = {-3, 2, -0.5};
  sc.bbox_max = {3, 2, 3.5};
  sc.camera_min = {-0.6, -0.4, 1.2};
  sc.camera_max = {0.6, 1.0, 1.8};  // forward motion approaches the plane up to 1 m
  sc.focus = {0, 2, 1.5};
  sc.anchor = {0, -0.1, 1.5};
  sc.handheld_sweep = 0.3;
  sc.look_outward = false;
  sc.loop_height = 1.5;
  sc.landmarks = {{"plane_centre", {0, 2, 1.5}}};
}

// Corridor centreline (x = +-5, y = +-3), corners rounded with radius 0.6.
std::vector<Eigen::Vector2d> corridorLoopPath() {
  std::vector<Eigen::Vector2d> path;
  const double X = 5.0, Y = 3.0, r = 0.6;
  const std::array<Eigen::Vector2d, 4> corners = {Eigen::Vector2d(X, -Y), Eigen::Vector2d(X, Y), Eigen::Vector2d(-X, Y),
                                                  Eigen::Vector2d(-X, -Y)};
  for (int c = 0; c < 4; ++c) {
    // Arc centre inside the corner; CCW travel turns from (c - 1) * 90 deg to c * 90 deg.
    const Eigen::Vector2d ctr = corners[c] - r * corners[c].cwiseSign();
    for (int k = 0; k <= 6; ++k) {
      const double a = (c - 1) * M_PI / 2 + k * (M_PI / 2) / 6.0;
      path.push_back(ctr + r * Eigen::Vector2d(std::cos(a), std::sin(a)));
    }
  }
  return path;
}

// A ring corridor between the outer walls and an inner block, walked around.
void buildCorridor(Builder& b, TextureSource& texture, Scene& sc) {
  const Vector3d lo(-6, -4, 0), hi(6, 4, 2.5);
  const int floor_t = texture(2, false), ceil_t = texture(0, false);
  std::array<int, 4> outer, inner;
  for (auto& t : outer) t = texture(0, true);
  for (auto& t : inner) t = texture(0, true);
  b.roomShell(lo, hi, floor_t, ceil_t, outer, 1.3);
  // Inner block (outward-facing walls; its top is hidden by the ceiling).
  b.box(inner[0], {-4, -2, 0}, {0, 2, 2.5}, 1.3);
  b.box(inner[1], {0, -2, 0}, {4, 2, 2.5}, 1.3);
  const int crate = texture(0, false), crate2 = texture(0, true);
  b.box(crate, {-5.9, -3.9, 0}, {-5.4, -3.4, 0.6}, 0.5);
  b.box(crate2, {5.3, 3.3, 0}, {5.9, 3.9, 0.8}, 0.5);
  b.box(inner[2], {1.0, -3.95, 0}, {1.8, -3.6, 1.2}, 0.6);
  b.box(inner[3], {-2.0, 3.6, 0}, {-1.2, 3.95, 1.0}, 0.6);
  sc.landmarks = {{"crate_top_corner", {-5.4, -3.4, 0.6}}, {"block_corner", {4, 2, 2.5}}};
  sc.bbox_min = lo;
  sc.bbox_max = hi;
  sc.camera_min = {-5.5, -3.5, 1.2};
  sc.camera_max = {5.5, 3.5, 1.7};
  sc.focus = {0, 0, 1.25};
  sc.anchor = {5, 0, 1.5};
  sc.look_outward = true;
  sc.loop_height = 1.5;
  sc.loop_path = corridorLoopPath();
}

}  // namespace

Scene makeScene(const SynthSceneOptions& opts) {
  validateSynthSceneOptions(opts);
  Scene sc;
  sc.name = opts.name;
  TextureSource texture(opts, sc);
  Builder b(mix(opts.seed, 7), &sc.textures);
  if (opts.name == "room")
    buildRoom(b, texture, sc);
  else if (opts.name == "turntable")
    buildTurntable(b, texture, sc);
  else if (opts.name == "plane")
    buildPlane(b, texture, sc);
  else
    buildCorridor(b, texture, sc);
  sc.meshes = b.take();
  return sc;
}

void uploadScene(const Scene& scene, Renderer& renderer) {
  renderer.clearMeshes();
  std::vector<int> ids;
  for (const auto& t : scene.textures) ids.push_back(renderer.addTexture(t));
  for (Mesh m : scene.meshes) {
    if (m.texture >= 0) m.texture = ids.at(m.texture);
    renderer.addMesh(m);
  }
}

}  // namespace nerfslam
