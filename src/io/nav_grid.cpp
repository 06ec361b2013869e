#include "nerfslam/io/nav_grid.h"

#include <cmath>
#include <sstream>
#include <string>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"

namespace nerfslam {
namespace fs = std::filesystem;

namespace {

constexpr uint64_t kMaxYamlBytes = 1 << 20;
constexpr int kMaxSide = 1 << 16;

double yamlNumber(const YAML::Node& root, const char* key, const fs::path& path) {
  const YAML::Node n = root[key];
  if (!n) fail("{}: field '{}' is missing", path.string(), key);
  double v = 0;
  try {
    v = n.as<double>();
  } catch (const YAML::Exception&) {
    fail("{}: field '{}' is not a number", path.string(), key);
  }
  if (!std::isfinite(v)) fail("{}: field '{}' is not finite", path.string(), key);
  return v;
}

// The next whitespace-separated token of a PGM header, skipping '#' comments.
std::string pgmToken(const std::string& s, size_t& pos) {
  for (;;) {
    while (pos < s.size() && std::isspace(static_cast<unsigned char>(s[pos]))) ++pos;
    if (pos < s.size() && s[pos] == '#') {
      while (pos < s.size() && s[pos] != '\n') ++pos;
      continue;
    }
    break;
  }
  const size_t b = pos;
  while (pos < s.size() && !std::isspace(static_cast<unsigned char>(s[pos]))) ++pos;
  return s.substr(b, pos - b);
}

}  // namespace

void saveMapServer(const NavGrid& g, const fs::path& yaml_path) {
  if (g.width <= 0 || g.height <= 0 || g.cells.size() != size_t(g.width) * size_t(g.height))
    fail("{}: the grid is empty or its cells do not match its size", yaml_path.string());
  if (!(g.resolution > 0) || !std::isfinite(g.resolution))
    fail("{}: resolution must be > 0 (is {})", yaml_path.string(), g.resolution);
  if (yaml_path.extension() != ".yaml") fail("{}: a map_server map is written as NAME.yaml", yaml_path.string());
  fs::path pgm = yaml_path;
  pgm.replace_extension(".pgm");
  std::string img =
      fmt::format("P5\n# nerfslam occupancy grid, {} per cell\n{} {}\n255\n", g.resolution, g.width, g.height);
  const size_t header = img.size();
  img.resize(header + size_t(g.width) * size_t(g.height));
  for (int y = 0; y < g.height; ++y)
    for (int x = 0; x < g.width; ++x) {
      const int8_t c = g.at(x, y);
      const unsigned char v = c == NavGrid::kOccupied ? 0 : c == NavGrid::kFree ? 254 : 205;
      img[header + size_t(g.height - 1 - y) * size_t(g.width) + size_t(x)] = char(v);
    }
  writeStringAtomic(pgm, img);
  const std::string yaml = fmt::format(
      "image: {}\nresolution: {:.9g}\norigin: [{:.9g}, {:.9g}, {:.9g}]\nnegate: 0\noccupied_thresh: {}\n"
      "free_thresh: {}\n",
      pgm.filename().string(), g.resolution, g.origin_x, g.origin_y, g.origin_yaw, kMapServerOccupiedThresh,
      kMapServerFreeThresh);
  writeStringAtomic(yaml_path, yaml);
}

NavGrid loadMapServer(const fs::path& yaml_path) {
  const std::string text = readInputFile(yaml_path, "map YAML file", kMaxYamlBytes);
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    fail("{}: not valid YAML ({})", yaml_path.string(), e.what());
  }
  if (!root.IsMap()) fail("{}: not a map_server YAML file (no key: value mapping)", yaml_path.string());
  NavGrid g;
  g.resolution = yamlNumber(root, "resolution", yaml_path);
  if (!(g.resolution > 0)) fail("{}: field 'resolution' must be > 0 (is {})", yaml_path.string(), g.resolution);
  const YAML::Node origin = root["origin"];
  if (!origin || !origin.IsSequence() || origin.size() != 3)
    fail("{}: field 'origin' must be [x, y, yaw]", yaml_path.string());
  double o[3];
  for (size_t i = 0; i < 3; ++i) {
    try {
      o[i] = origin[i].as<double>();
    } catch (const YAML::Exception&) {
      fail("{}: field 'origin' must be [x, y, yaw] numbers", yaml_path.string());
    }
    if (!std::isfinite(o[i])) fail("{}: field 'origin' is not finite", yaml_path.string());
  }
  g.origin_x = o[0];
  g.origin_y = o[1];
  g.origin_yaw = o[2];
  const double occ = yamlNumber(root, "occupied_thresh", yaml_path);
  const double free = yamlNumber(root, "free_thresh", yaml_path);
  if (!(free >= 0 && free <= occ && occ <= 1))
    fail("{}: fields 'free_thresh' ({}) and 'occupied_thresh' ({}) must satisfy 0 <= free <= occupied <= 1",
         yaml_path.string(), free, occ);
  const double negate = yamlNumber(root, "negate", yaml_path);
  if (negate != 0 && negate != 1) fail("{}: field 'negate' must be 0 or 1", yaml_path.string());
  if (root["mode"] && root["mode"].as<std::string>() != "trinary")
    fail("{}: field 'mode': only map_server's default 'trinary' is read", yaml_path.string());
  if (!root["image"]) fail("{}: field 'image' is missing", yaml_path.string());
  fs::path image = root["image"].as<std::string>();
  if (image.is_relative()) image = yaml_path.parent_path() / image;
  if (image.extension() != ".pgm")
    fail("{}: field 'image': only PGM images are read ({})", yaml_path.string(), image.string());
  const std::string pgm = readInputFile(image, "map image", uint64_t(kMaxSide) * kMaxSide / 16 + 4096);
  size_t pos = 0;
  if (pgmToken(pgm, pos) != "P5") fail("{}: not a binary PGM (P5)", image.string());
  int w = 0, h = 0, maxval = 0;
  try {
    w = std::stoi(pgmToken(pgm, pos));
    h = std::stoi(pgmToken(pgm, pos));
    maxval = std::stoi(pgmToken(pgm, pos));
  } catch (const std::exception&) {
    fail("{}: malformed PGM header", image.string());
  }
  if (w <= 0 || h <= 0 || w > kMaxSide || h > kMaxSide) fail("{}: PGM size {}x{} out of range", image.string(), w, h);
  if (maxval != 255) fail("{}: only 8-bit PGM (maxval 255) is read, not maxval {}", image.string(), maxval);
  ++pos;  // the single whitespace after maxval
  if (pgm.size() < pos + size_t(w) * size_t(h))
    fail("{}: truncated: {} pixel bytes, {}x{} needs {}", image.string(), pgm.size() - std::min(pos, pgm.size()), w, h,
         size_t(w) * size_t(h));
  g.width = w;
  g.height = h;
  g.cells.assign(size_t(w) * size_t(h), NavGrid::kUnknown);
  for (int row = 0; row < h; ++row)
    for (int x = 0; x < w; ++x) {
      const double v = static_cast<unsigned char>(pgm[pos + size_t(row) * size_t(w) + size_t(x)]);
      const double p = negate == 1 ? v / 255.0 : (255.0 - v) / 255.0;
      int8_t c = NavGrid::kUnknown;
      if (p > occ)
        c = NavGrid::kOccupied;
      else if (p < free)
        c = NavGrid::kFree;
      g.at(x, h - 1 - row) = c;
    }
  return g;
}

}  // namespace nerfslam
