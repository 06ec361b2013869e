#include "nerfslam/system/map_store.h"

#include <algorithm>
#include <atomic>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iterator>
#include <map>
#include <regex>
#include <set>
#include <thread>
#include <type_traits>
#include <unordered_map>

#include <spdlog/spdlog.h>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/crc32.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/tracking/frame.h"

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "map files are written in the host's (little-endian) order");

namespace nerfslam {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr const char* kManifest = "map.json";
constexpr const char* kFormatName = "nerfslam-map";
constexpr char kKeyframesMagic[8] = {'N', 'S', 'M', 'A', 'P', 'K', 'F', '\0'};
constexpr char kPointsMagic[8] = {'N', 'S', 'M', 'A', 'P', 'P', 'T', '\0'};
constexpr uint32_t kBinaryVersion = 1;
constexpr int kDescriptorBytes = 32;

std::string hex32(uint32_t x) { return fmt::format("{:08x}", x); }

std::string genName(uint64_t generation) { return fmt::format("{:06d}", generation); }

// ---- binary encoding -------------------------------------------------------------------------

class Writer {
 public:
  template <typename T>
  void pod(T v) {
    static_assert(std::is_arithmetic_v<T>);
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof v);
    buf.append(b, sizeof v);
  }
  void bytes(const void* p, size_t n) { buf.append(static_cast<const char*>(p), n); }
  void str(const std::string& s) {
    pod<uint32_t>(static_cast<uint32_t>(s.size()));
    buf += s;
  }
  std::string buf;
};

class Reader {
 public:
  Reader(const std::string& data, std::string file) : data_(data), file_(std::move(file)) {}
  std::string context;  // e.g. "keyframe 3 (id 12)": prefixes field names in errors

  template <typename T>
  T pod(const char* field) {
    need(sizeof(T), field);
    T v;
    std::memcpy(&v, data_.data() + pos_, sizeof v);
    pos_ += sizeof v;
    return v;
  }
  void bytes(void* dst, size_t n, const char* field) {
    need(n, field);
    std::memcpy(dst, data_.data() + pos_, n);
    pos_ += n;
  }
  std::string str(const char* field, size_t max_len = 4096) {
    const uint32_t n = pod<uint32_t>(field);
    if (n > max_len) bad(field, fmt::format("string of {} bytes (at most {})", n, max_len));
    need(n, field);
    std::string s = data_.substr(pos_, n);
    pos_ += n;
    return s;
  }
  // A count of records of at least `min_record_bytes` each: must fit in what is left of the file.
  uint64_t count(uint64_t n, size_t min_record_bytes, const char* field) {
    if (min_record_bytes > 0 && n > remaining() / min_record_bytes)
      bad(field, fmt::format("{} records do not fit in the {} bytes left (truncated or corrupted)", n, remaining()));
    return n;
  }
  size_t remaining() const { return data_.size() - pos_; }
  [[noreturn]] void bad(const char* field, const std::string& what) const {
    throw fieldError(file_, context.empty() ? std::string(field) : context + "." + field, what);
  }

 private:
  void need(size_t n, const char* field) const {
    if (remaining() < n)
      bad(field,
          fmt::format("the file ends at byte {}, {} more bytes needed (truncated)", data_.size(), n - remaining()));
  }
  const std::string& data_;
  std::string file_;
  size_t pos_ = 0;
};

// ---- files -----------------------------------------------------------------------------------

std::string readFileBytes(const fs::path& path, const std::string& what) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail("{}: missing ({})", path.string(), what);
  std::ifstream in(path, std::ios::binary);
  if (!in) fail("{}: cannot open for reading ({})", path.string(), what);
  std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) fail("{}: read error", path.string());
  return s;
}

// CRC-32 and size of a file read in chunks (NeRF models can be large).
std::pair<uint64_t, uint32_t> fileSizeCrc(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail("{}: cannot open for reading", path.string());
  std::vector<char> buf(1 << 20);
  uint64_t size = 0;
  uint32_t crc = 0;
  while (in) {
    in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    const std::streamsize n = in.gcount();
    if (n <= 0) break;
    crc = crc32(buf.data(), static_cast<size_t>(n), crc);
    size += static_cast<uint64_t>(n);
  }
  if (in.bad()) fail("{}: read error", path.string());
  return {size, crc};
}

struct FileEntry {
  std::string name;  // relative to the map folder, '/' separated
  std::string role;  // camera config keyframes points image nerf
  uint64_t size = 0;
  uint32_t crc = 0;
  // Images: the keyframe and a checksum of the decoded pixels (reuse across generations).
  int64_t keyframe = -1;
  uint32_t pixels_crc = 0;
  int width = 0, height = 0, channels = 0;
};

json toJson(const FileEntry& f) {
  json j{{"name", f.name}, {"role", f.role}, {"size", f.size}, {"crc32", hex32(f.crc)}};
  if (f.role == "image") {
    j["keyframe"] = f.keyframe;
    j["pixels_crc32"] = hex32(f.pixels_crc);
    j["width"] = f.width;
    j["height"] = f.height;
    j["channels"] = f.channels;
  }
  return j;
}

template <typename T>
T jsonField(const json& j, const char* key, const std::string& file, const std::string& path) {
  if (!j.is_object() || !j.contains(key)) throw fieldError(file, path, "missing");
  try {
    return j.at(key).get<T>();
  } catch (const json::exception&) {
    throw fieldError(file, path, "unexpected value " + j.at(key).dump());
  }
}

uint32_t parseHex32(const std::string& s, const std::string& file, const std::string& path) {
  if (s.size() != 8 || s.find_first_not_of("0123456789abcdef") != std::string::npos)
    throw fieldError(file, path, "expected 8 lowercase hex digits, got '" + s + "'");
  return static_cast<uint32_t>(std::stoul(s, nullptr, 16));
}

// A file name from the manifest: relative, inside the folder.
void checkRelativeName(const std::string& name, const std::string& file, const std::string& path) {
  const fs::path p(name);
  bool ok = !name.empty() && p.is_relative();
  for (const auto& part : p) ok = ok && part != ".." && part != ".";
  if (!ok) throw fieldError(file, path, "'" + name + "' is not a file inside the map folder");
}

struct Manifest {
  json j;
  uint64_t generation = 0;
  std::vector<FileEntry> files;
  const FileEntry* find(const std::string& role) const {
    for (const auto& f : files)
      if (f.role == role) return &f;
    return nullptr;
  }
  const FileEntry* findName(const std::string& name) const {
    for (const auto& f : files)
      if (f.name == name) return &f;
    return nullptr;
  }
};

json parseManifestJson(const fs::path& dir) {
  const fs::path path = dir / kManifest;
  std::error_code ec;
  if (!fs::exists(dir, ec)) fail("{}: map folder not found", dir.string());
  if (!fs::exists(path, ec))
    fail("{}: missing: {} is not a map folder (or its first save never finished)", path.string(), dir.string());
  const std::string text = readFileBytes(path, "the map manifest");
  try {
    return json::parse(text);
  } catch (const json::exception& e) {
    fail("{}: not valid JSON (truncated or corrupted): {}", path.string(), e.what());
  }
}

// Format and version only (also used before saving over a folder).
void checkFormat(const json& j, const std::string& file) {
  const auto format = jsonField<std::string>(j, "format", file, "format");
  if (format != kFormatName)
    throw fieldError(file, "format", fmt::format("'{}' is not a nerfslam map (expected '{}')", format, kFormatName));
  const auto version = jsonField<int64_t>(j, "format_version", file, "format_version");
  if (version != kMapFormatVersion)
    throw fieldError(file, "format_version",
                     fmt::format("the map has format version {}, this nerfslam reads and writes version {}{}", version,
                                 kMapFormatVersion,
                                 version < kMapFormatVersion ? " (an older map: rebuild it with this version)"
                                                             : " (a newer map: use a newer nerfslam)"));
}

Manifest readManifest(const fs::path& dir) {
  const std::string file = (dir / kManifest).string();
  Manifest m;
  m.j = parseManifestJson(dir);
  checkFormat(m.j, file);
  m.generation = jsonField<uint64_t>(m.j, "generation", file, "generation");
  if (!m.j.contains("files") || !m.j["files"].is_array()) throw fieldError(file, "files", "missing (a list of files)");
  std::set<std::string> names;
  for (size_t i = 0; i < m.j["files"].size(); ++i) {
    const json& e = m.j["files"][i];
    const std::string p = fmt::format("files[{}]", i);
    FileEntry f;
    f.name = jsonField<std::string>(e, "name", file, p + ".name");
    checkRelativeName(f.name, file, p + ".name");
    if (!names.insert(f.name).second) throw fieldError(file, p + ".name", "'" + f.name + "' listed twice");
    f.role = jsonField<std::string>(e, "role", file, p + ".role");
    f.size = jsonField<uint64_t>(e, "size", file, p + ".size");
    f.crc = parseHex32(jsonField<std::string>(e, "crc32", file, p + ".crc32"), file, p + ".crc32");
    if (f.role == "image") {
      f.keyframe = jsonField<int64_t>(e, "keyframe", file, p + ".keyframe");
      f.pixels_crc =
          parseHex32(jsonField<std::string>(e, "pixels_crc32", file, p + ".pixels_crc32"), file, p + ".pixels_crc32");
      f.width = jsonField<int>(e, "width", file, p + ".width");
      f.height = jsonField<int>(e, "height", file, p + ".height");
      f.channels = jsonField<int>(e, "channels", file, p + ".channels");
    } else if (f.role != "camera" && f.role != "config" && f.role != "keyframes" && f.role != "points" &&
               f.role != "nerf") {
      throw fieldError(file, p + ".role", "unknown role '" + f.role + "'");
    }
    m.files.push_back(std::move(f));
  }
  for (const char* role : {"camera", "config", "keyframes", "points"})
    if (!m.find(role)) throw fieldError(file, "files", fmt::format("no {} file listed", role));
  return m;
}

// The file's bytes after checking presence, size and checksum against the manifest.
std::string readVerified(const fs::path& dir, const FileEntry& f) {
  const fs::path path = dir / f.name;
  std::error_code ec;
  if (!fs::exists(path, ec))
    fail("{}: missing: {} lists it as the map's {} file (the map folder is incomplete)", path.string(), kManifest,
         f.role);
  std::string data = readFileBytes(path, f.role + " file");
  if (data.size() != f.size)
    throw fieldError(path.string(), "size",
                     fmt::format("{} bytes, {} lists {} (truncated or modified)", data.size(), kManifest, f.size));
  const uint32_t crc = crc32(data);
  if (crc != f.crc)
    throw fieldError(
        path.string(), "crc32",
        fmt::format("checksum {} differs from {}'s {}: the file is corrupted", hex32(crc), kManifest, hex32(f.crc)));
  return data;
}

void verifyLarge(const fs::path& dir, const FileEntry& f) {
  const fs::path path = dir / f.name;
  std::error_code ec;
  if (!fs::exists(path, ec))
    fail("{}: missing: {} lists it as the map's {} file (the map folder is incomplete)", path.string(), kManifest,
         f.role);
  const auto [size, crc] = fileSizeCrc(path);
  if (size != f.size)
    throw fieldError(path.string(), "size",
                     fmt::format("{} bytes, {} lists {} (truncated or modified)", size, kManifest, f.size));
  if (crc != f.crc)
    throw fieldError(
        path.string(), "crc32",
        fmt::format("checksum {} differs from {}'s {}: the file is corrupted", hex32(crc), kManifest, hex32(f.crc)));
}

// Writes `data` atomically and returns its entry.
FileEntry writeEntry(const fs::path& dir, const std::string& name, const std::string& role, const std::string& data) {
  writeStringAtomic(dir / name, data);
  FileEntry f;
  f.name = name;
  f.role = role;
  f.size = data.size();
  f.crc = crc32(data);
  return f;
}

// ---- options as YAML ---------------------------------------------------------------------------

struct YamlWriter {
  std::string* out;
  int indent = 0;

  static std::string comment(const char* doc) {
    std::string s(doc);
    std::replace(s.begin(), s.end(), '\n', ' ');
    return s;
  }
  template <typename T, typename C>
  void operator()(const char* name, const T& field, const char* doc, const C&) {
    (*this)(name, field, doc);
  }
  template <typename T>
  void operator()(const char* name, const T& field, const char* doc) {
    const std::string pad(static_cast<size_t>(indent), ' ');
    if constexpr (options_detail::kIsLeaf<T>) {
      *out += pad + name + ": " + options_detail::formatValue(field) + "  # " + comment(doc) + "\n";
    } else {
      *out += pad + name + ":  # " + comment(doc) + "\n";
      YamlWriter sub{out, indent + 2};
      const_cast<T&>(field).visit(sub);
    }
  }
};

std::string optionsYaml(const SystemOptions& options) {
  std::string out = "# nerfslam SystemOptions (loads with `nerfslam run --config FILE`)\n";
  YamlWriter w{&out, 0};
  const_cast<SystemOptions&>(options).visit(w);
  return out;
}

// ---- images -----------------------------------------------------------------------------------

// The image a keyframe is rebuilt from: the BGR input when kept, else pyramid level 0.
const cv::Mat& keyframeImage(const Keyframe& kf) {
  if (!kf.frame->colour.empty()) return kf.frame->colour;
  if (kf.frame->pyramid.empty()) fail("keyframe {}: its frame has no image", kf.id);
  return kf.frame->pyramid[0];
}

uint32_t pixelsCrc(const cv::Mat& img) {
  uint32_t crc = 0;
  const size_t row = static_cast<size_t>(img.cols) * img.elemSize();
  for (int y = 0; y < img.rows; ++y) crc = crc32(img.ptr(y), row, crc);
  return crc;
}

// ---- keyframes and points ----------------------------------------------------------------------

struct KeyframeRecord {
  Keyframe kf;  // frame not set yet
  uint64_t frame_id = 0;
  double timestamp = 0;
  std::string image;
  int width = 0, height = 0, channels = 0;
  uint32_t pixels_crc = 0;
  std::vector<cv::KeyPoint> keypoints;
  std::vector<Eigen::Vector2d> undistorted;
  cv::Mat descriptors;
};

std::string encodeKeyframes(const std::vector<Keyframe>& kfs, const std::vector<FileEntry>& images) {
  Writer w;
  w.bytes(kKeyframesMagic, 8);
  w.pod<uint32_t>(kBinaryVersion);
  w.pod<uint64_t>(kfs.size());
  for (size_t k = 0; k < kfs.size(); ++k) {
    const Keyframe& kf = kfs[k];
    const Frame& f = *kf.frame;
    w.pod<int64_t>(kf.id);
    w.pod<uint64_t>(f.id);
    w.pod<double>(f.timestamp);
    w.pod<uint8_t>(kf.fixed ? 1 : 0);
    const Eigen::Quaterniond& q = kf.T_world_cam.rotation();
    const Eigen::Vector3d& t = kf.T_world_cam.translation();
    for (double x : {q.x(), q.y(), q.z(), q.w(), t.x(), t.y(), t.z()}) w.pod<double>(x);
    const FileEntry& img = images[k];
    w.str(img.name);
    w.pod<int32_t>(img.width);
    w.pod<int32_t>(img.height);
    w.pod<int32_t>(img.channels);
    w.pod<uint32_t>(img.pixels_crc);
    const size_t n = f.keypoints.size();
    if (kf.points.size() != n || f.undistorted.size() != n || f.descriptors.rows != static_cast<int>(n) ||
        (n > 0 && (f.descriptors.cols != kDescriptorBytes || f.descriptors.type() != CV_8U)))
      fail("keyframe {}: inconsistent frame ({} keypoints, {} slots, {} undistorted, {}x{} descriptors)", kf.id, n,
           kf.points.size(), f.undistorted.size(), f.descriptors.rows, f.descriptors.cols);
    w.pod<uint32_t>(static_cast<uint32_t>(n));
    for (size_t i = 0; i < n; ++i) {
      const cv::KeyPoint& p = f.keypoints[i];
      w.pod<float>(p.pt.x);
      w.pod<float>(p.pt.y);
      w.pod<float>(p.size);
      w.pod<float>(p.angle);
      w.pod<float>(p.response);
      w.pod<int32_t>(p.octave);
      w.pod<int32_t>(p.class_id);
      w.pod<double>(f.undistorted[i].x());
      w.pod<double>(f.undistorted[i].y());
      w.pod<int64_t>(kf.points[i]);
    }
    for (size_t i = 0; i < n; ++i) w.bytes(f.descriptors.ptr(static_cast<int>(i)), kDescriptorBytes);
  }
  return w.buf;
}

constexpr size_t kKeypointBytes = 5 * 4 + 2 * 4 + 2 * 8 + 8 + kDescriptorBytes;

// Magic and version at the start of our binary files; wrong ones are errors naming the field.
void readHeader(Reader& r, const char* magic_expected, const char* what) {
  char magic[8];
  r.bytes(magic, 8, "magic");
  if (std::memcmp(magic, magic_expected, 8) != 0) r.bad("magic", fmt::format("not a nerfslam {} file", what));
  const uint32_t version = r.pod<uint32_t>("version");
  if (version != kBinaryVersion)
    r.bad("version", fmt::format("{} file version {}, this nerfslam reads {}", what, version, kBinaryVersion));
}

std::vector<KeyframeRecord> decodeKeyframes(const std::string& data, const std::string& file) {
  Reader r(data, file);
  readHeader(r, kKeyframesMagic, "keyframes");
  const uint64_t n = r.count(r.pod<uint64_t>("count"), 8 + 8 + 8 + 1 + 56 + 4 + 16 + 4, "count");
  std::vector<KeyframeRecord> out(n);
  for (uint64_t k = 0; k < n; ++k) {
    KeyframeRecord& rec = out[k];
    r.context = fmt::format("keyframe[{}]", k);
    rec.kf.id = r.pod<int64_t>("id");
    r.context = fmt::format("keyframe[{}] (id {})", k, rec.kf.id);
    rec.frame_id = r.pod<uint64_t>("frame_id");
    rec.timestamp = r.pod<double>("timestamp");
    rec.kf.fixed = r.pod<uint8_t>("fixed") != 0;
    double v[7];
    for (double& x : v) x = r.pod<double>("pose");
    const Eigen::Quaterniond q(v[3], v[0], v[1], v[2]);
    const Eigen::Vector3d t(v[4], v[5], v[6]);
    if (!q.coeffs().allFinite() || !t.allFinite() || std::abs(q.norm() - 1.0) > 1e-6)
      r.bad("pose", "not a finite rigid pose");
    rec.kf.T_world_cam = SE3(q, t);
    rec.image = r.str("image");
    rec.width = r.pod<int32_t>("image_width");
    rec.height = r.pod<int32_t>("image_height");
    rec.channels = r.pod<int32_t>("image_channels");
    rec.pixels_crc = r.pod<uint32_t>("image_pixels_crc32");
    const uint32_t nk =
        static_cast<uint32_t>(r.count(r.pod<uint32_t>("num_keypoints"), kKeypointBytes, "num_keypoints"));
    rec.keypoints.resize(nk);
    rec.undistorted.resize(nk);
    rec.kf.points.resize(nk);
    for (uint32_t i = 0; i < nk; ++i) {
      cv::KeyPoint& p = rec.keypoints[i];
      p.pt.x = r.pod<float>("keypoints.x");
      p.pt.y = r.pod<float>("keypoints.y");
      p.size = r.pod<float>("keypoints.size");
      p.angle = r.pod<float>("keypoints.angle");
      p.response = r.pod<float>("keypoints.response");
      p.octave = r.pod<int32_t>("keypoints.octave");
      p.class_id = r.pod<int32_t>("keypoints.class_id");
      const double ux = r.pod<double>("keypoints.undistorted_x");
      const double uy = r.pod<double>("keypoints.undistorted_y");
      rec.undistorted[i] = Eigen::Vector2d(ux, uy);
      rec.kf.points[i] = r.pod<int64_t>("keypoints.point");
      if (!std::isfinite(p.pt.x) || !std::isfinite(p.pt.y) || p.octave < 0 || p.octave > 64)
        r.bad("keypoints",
              fmt::format("keypoint {} is invalid (position {}, {}, octave {})", i, p.pt.x, p.pt.y, p.octave));
    }
    rec.descriptors.create(static_cast<int>(nk), kDescriptorBytes, CV_8U);
    for (uint32_t i = 0; i < nk; ++i)
      r.bytes(rec.descriptors.ptr(static_cast<int>(i)), kDescriptorBytes, "descriptors");
  }
  r.context.clear();
  if (r.remaining() != 0) r.bad("count", fmt::format("{} bytes after the last keyframe", r.remaining()));
  return out;
}

std::string encodePoints(const std::vector<MapPoint>& points) {
  Writer w;
  w.bytes(kPointsMagic, 8);
  w.pod<uint32_t>(kBinaryVersion);
  w.pod<uint64_t>(points.size());
  for (const MapPoint& p : points) {
    w.pod<int64_t>(p.id);
    for (int i = 0; i < 3; ++i) w.pod<double>(p.position[i]);
    for (int i = 0; i < 3; ++i) w.pod<double>(p.normal[i]);
    w.pod<int64_t>(p.first_keyframe);
    w.pod<int32_t>(p.visible);
    w.pod<int32_t>(p.found);
    const size_t dn = p.descriptor.empty() ? 0 : p.descriptor.total() * p.descriptor.elemSize();
    if (dn != 0 && (!p.descriptor.isContinuous() || p.descriptor.depth() != CV_8U))
      fail("map point {}: descriptor is not a continuous 8-bit row", p.id);
    w.pod<uint32_t>(static_cast<uint32_t>(dn));
    if (dn) w.bytes(p.descriptor.data, dn);
    w.pod<uint32_t>(static_cast<uint32_t>(p.observations.size()));
    for (const auto& [kid, idx] : p.observations) {
      w.pod<int64_t>(kid);
      w.pod<int32_t>(idx);
    }
  }
  return w.buf;
}

std::vector<MapPoint> decodePoints(const std::string& data, const std::string& file) {
  Reader r(data, file);
  readHeader(r, kPointsMagic, "map points");
  const uint64_t n = r.count(r.pod<uint64_t>("count"), 8 + 48 + 8 + 8 + 4 + 4, "count");
  std::vector<MapPoint> out(n);
  for (uint64_t k = 0; k < n; ++k) {
    MapPoint& p = out[k];
    r.context = fmt::format("point[{}]", k);
    p.id = r.pod<int64_t>("id");
    r.context = fmt::format("point[{}] (id {})", k, p.id);
    for (int i = 0; i < 3; ++i) p.position[i] = r.pod<double>("position");
    for (int i = 0; i < 3; ++i) p.normal[i] = r.pod<double>("normal");
    if (!p.position.allFinite()) r.bad("position", "not finite");
    p.first_keyframe = r.pod<int64_t>("first_keyframe");
    p.visible = r.pod<int32_t>("visible");
    p.found = r.pod<int32_t>("found");
    const uint32_t dn = r.pod<uint32_t>("descriptor_bytes");
    if (dn != 0 && dn != static_cast<uint32_t>(kDescriptorBytes))
      r.bad("descriptor_bytes", fmt::format("{} (expected 0 or {})", dn, kDescriptorBytes));
    if (dn) {
      p.descriptor.create(1, static_cast<int>(dn), CV_8U);
      r.bytes(p.descriptor.data, dn, "descriptor");
    }
    const uint64_t nobs = r.count(r.pod<uint32_t>("num_observations"), 12, "num_observations");
    for (uint64_t i = 0; i < nobs; ++i) {
      const int64_t kid = r.pod<int64_t>("observations.keyframe");
      const int32_t idx = r.pod<int32_t>("observations.keypoint");
      if (!p.observations.emplace(kid, idx).second) r.bad("observations", fmt::format("keyframe {} listed twice", kid));
    }
  }
  r.context.clear();
  if (r.remaining() != 0) r.bad("count", fmt::format("{} bytes after the last point", r.remaining()));
  return out;
}

bool sameFeatures(const Frame& f, const KeyframeRecord& rec) {
  if (f.keypoints.size() != rec.keypoints.size() || f.descriptors.rows != rec.descriptors.rows) return false;
  for (size_t i = 0; i < f.keypoints.size(); ++i) {
    const cv::KeyPoint &a = f.keypoints[i], &b = rec.keypoints[i];
    if (a.pt != b.pt || a.octave != b.octave || a.angle != b.angle || a.size != b.size) return false;
  }
  for (int i = 0; i < f.descriptors.rows; ++i)
    if (std::memcmp(f.descriptors.ptr(i), rec.descriptors.ptr(i), kDescriptorBytes) != 0) return false;
  return true;
}

// Rebuilds the keyframe's Frame from its image (pyramid and everything else by extractFrame), then
// installs the stored features so the saved associations hold whatever extraction gives today.
std::shared_ptr<const Frame> rebuildFrame(const KeyframeRecord& rec, const cv::Mat& image, const Camera& camera,
                                          const FeatureOptions& features, const std::string& file, bool* identical) {
  Frame f = extractFrame(image, camera, features, rec.frame_id, rec.timestamp);
  *identical = sameFeatures(f, rec);
  if (!*identical) {
    f.keypoints = rec.keypoints;
    f.descriptors = rec.descriptors;
    f.undistorted = rec.undistorted;
    for (size_t i = 0; i < f.keypoints.size(); ++i) {
      const cv::KeyPoint& k = f.keypoints[i];
      if (k.octave >= static_cast<int>(f.pyramid.size()))
        throw fieldError(file, fmt::format("keyframe (id {}).keypoints[{}].octave", rec.kf.id, i),
                         fmt::format("pyramid level {}, but the stored image gives {} levels with the map's "
                                     "tracking.features options",
                                     k.octave, f.pyramid.size()));
    }
    f.buildGrid();
  }
  return std::make_shared<const Frame>(std::move(f));
}

std::string utcNow() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

// Our data file names (any generation) and the temporaries writeFileAtomic leaves when killed.
const std::regex& dataFilePattern() {
  static const std::regex re(R"(^(camera|config|keyframes|points|nerf)\.\d{6,}(\.tmp\.\d+\.\d+)?\.(yaml|bin|nerf)$)");
  return re;
}
const std::regex& manifestTempPattern() {
  static const std::regex re(R"(^map\.tmp\.\d+\.\d+\.json$)");
  return re;
}
const std::regex& imagePattern() {
  static const std::regex re(R"(^kf-?\d+\.\d{6,}(\.tmp\.\d+\.\d+)?\.png$)");
  return re;
}

uint64_t largestGenerationInNames(const fs::path& dir) {
  uint64_t g = 0;
  std::error_code ec;
  static const std::regex re(R"(^[a-z]+-?\d*\.(\d{6,})\.)");
  for (const fs::path& d : {dir, dir / "images"})
    for (fs::directory_iterator it(d, ec), end; !ec && it != end; it.increment(ec)) {
      std::smatch m;
      const std::string name = it->path().filename().string();
      if (!std::regex_search(name, m, re)) continue;
      // A number too long for 64 bits is not one of our generations.
      const std::string digits = m[1].str();
      uint64_t n = 0;
      if (std::from_chars(digits.data(), digits.data() + digits.size(), n).ec == std::errc()) g = std::max(g, n);
    }
  return g;
}

// Deletes our files that `keep` does not name (previous generations, temporaries of killed saves).
void removeUnreferenced(const fs::path& dir, const std::set<std::string>& keep) {
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!it->is_regular_file() || keep.count(name)) continue;
    if (std::regex_match(name, dataFilePattern()) || std::regex_match(name, manifestTempPattern())) {
      std::error_code rec;
      fs::remove(it->path(), rec);
    }
  }
  for (fs::directory_iterator it(dir / "images", ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!it->is_regular_file() || keep.count("images/" + name)) continue;
    if (std::regex_match(name, imagePattern())) {
      std::error_code rec;
      fs::remove(it->path(), rec);
    }
  }
}

}  // namespace

void checkSameCamera(const Camera& map_camera, const Camera& camera, const std::string& source) {
  if (const auto d = calibrationDifference(map_camera, camera))
    throw fieldError(
        source, d->field,
        fmt::format("the map's camera has {0} = {1}, the camera given has {0} = {2}: the map was made with "
                    "another camera (a map is tied to its camera)",
                    d->field, d->a, d->b));
}

MapSaveResult saveMapFolder(const fs::path& dir, const Map& map, const Camera& camera, const SystemOptions& options,
                            const NerfModelWriter& write_nerf_model) {
  const auto t0 = std::chrono::steady_clock::now();
  camera.validate("camera");
  validateOptions(options, "options");
  ensureDirectory(dir);
  ensureDirectory(dir / "images");

  // The previous map, if any: its generation, and images that can be reused.
  std::optional<Manifest> prev;
  uint64_t generation = 1;
  const fs::path manifest_path = dir / kManifest;
  if (fs::exists(manifest_path)) {
    json j;
    bool parsed = false;
    try {
      j = parseManifestJson(dir);
      parsed = true;
    } catch (const Error&) {
    }
    if (parsed && j.is_object() && j.value("format", std::string()) == kFormatName && j.contains("format_version") &&
        j["format_version"] != kMapFormatVersion) {
      checkFormat(j, manifest_path.string());  // throws: never overwrite a map of another version
    }
    try {
      prev = readManifest(dir);
      generation = prev->generation + 1;
    } catch (const Error& e) {
      spdlog::warn("{}: the previous map is unreadable ({}); saving a new one", dir.string(), e.what());
      generation = largestGenerationInNames(dir) + 1;
    }
  }
  const std::string g = genName(generation);

  auto [kfs, points] = map.snapshot();
  MapSaveResult res;
  res.generation = generation;
  res.keyframes = kfs.size();
  res.points = points.size();

  std::vector<FileEntry> files;
  std::vector<FileEntry> images;
  images.reserve(kfs.size());
  for (const Keyframe& kf : kfs) {
    if (!kf.frame) fail("keyframe {}: no frame to save", kf.id);
    const cv::Mat& img = keyframeImage(kf);
    if (img.depth() != CV_8U || (img.channels() != 1 && img.channels() != 3))
      fail("keyframe {}: image type {} cannot be stored (8-bit grey or BGR expected)", kf.id, img.type());
    FileEntry e;
    e.role = "image";
    e.keyframe = kf.id;
    e.width = img.cols;
    e.height = img.rows;
    e.channels = img.channels();
    e.pixels_crc = pixelsCrc(img);
    const FileEntry* old = nullptr;
    if (prev)
      for (const FileEntry& f : prev->files)
        if (f.role == "image" && f.keyframe == e.keyframe && f.pixels_crc == e.pixels_crc && f.width == e.width &&
            f.height == e.height && f.channels == e.channels) {
          std::error_code ec;
          if (fs::file_size(dir / f.name, ec) == f.size && !ec) old = &f;
          break;
        }
    if (old) {
      e = *old;
      ++res.images_reused;
    } else {
      std::vector<uchar> png;
      if (!cv::imencode(".png", img, png, {cv::IMWRITE_PNG_COMPRESSION, 3}))
        fail("keyframe {}: PNG encoding failed", kf.id);
      const std::string data(png.begin(), png.end());
      e = writeEntry(dir, fmt::format("images/kf{:06d}.{}.png", kf.id, g), "image", data);
      e.keyframe = kf.id;
      e.width = img.cols;
      e.height = img.rows;
      e.channels = img.channels();
      e.pixels_crc = pixelsCrc(img);
      ++res.images_written;
    }
    images.push_back(e);
  }

  files.push_back(writeEntry(dir, "keyframes." + g + ".bin", "keyframes", encodeKeyframes(kfs, images)));
  files.push_back(writeEntry(dir, "points." + g + ".bin", "points", encodePoints(points)));
  {
    const std::string name = "camera." + g + ".yaml";
    saveCameraYaml(camera, dir / name);
    FileEntry e;
    e.name = name;
    e.role = "camera";
    std::tie(e.size, e.crc) = fileSizeCrc(dir / name);
    files.push_back(e);
  }
  files.push_back(writeEntry(dir, "config." + g + ".yaml", "config", optionsYaml(options)));
  if (write_nerf_model) {
    const std::string name = "nerf." + g + ".nerf";
    write_nerf_model(dir / name);
    if (!fs::exists(dir / name)) fail("{}: the NeRF model writer wrote nothing", (dir / name).string());
    FileEntry e;
    e.name = name;
    e.role = "nerf";
    std::tie(e.size, e.crc) = fileSizeCrc(dir / name);
    files.push_back(e);
    res.has_nerf = true;
  }
  files.insert(files.end(), images.begin(), images.end());

  json manifest;
  manifest["format"] = kFormatName;
  manifest["format_version"] = kMapFormatVersion;
  manifest["generation"] = generation;
  manifest["created_utc"] = utcNow();
  manifest["creator"] = "nerfslam (src/system/map_store.cpp)";
  manifest["keyframes"] = kfs.size();
  manifest["map_points"] = points.size();
  manifest["camera"] = camera.describe();
  manifest["nerf_model"] = res.has_nerf ? json("nerf." + g + ".nerf") : json(nullptr);
  manifest["files"] = json::array();
  std::set<std::string> keep{kManifest};
  for (const FileEntry& f : files) {
    manifest["files"].push_back(toJson(f));
    keep.insert(f.name);
    res.bytes += f.size;
  }
  // The commit point: before this rename the previous map is the folder's map, after it this one.
  writeStringAtomic(manifest_path, manifest.dump(1) + "\n");
  removeUnreferenced(dir, keep);
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  spdlog::info(
      "map saved to {} (generation {}): {} keyframes, {} points, {} images written, {} reused, {:.1f} MB, "
      "{:.2f} s",
      dir.string(), generation, res.keyframes, res.points, res.images_written, res.images_reused, res.bytes / 1e6,
      res.seconds);
  return res;
}

SystemOptions loadMapOptions(const fs::path& dir) {
  const Manifest m = readManifest(dir);
  const FileEntry& cf = *m.find("config");
  readVerified(dir, cf);
  SystemOptions o;
  loadOptionsFile(dir / cf.name, o);
  validateOptions(o, (dir / cf.name).string());
  return o;
}

LoadedMap loadMapFolder(const fs::path& dir, const std::optional<Camera>& expected_camera) {
  const auto t0 = std::chrono::steady_clock::now();
  const Manifest m = readManifest(dir);
  LoadedMap out;
  out.manifest = m.j;
  out.generation = m.generation;

  // Every listed file present, complete and intact before anything is parsed.
  const FileEntry& camera_file = *m.find("camera");
  const FileEntry& config_file = *m.find("config");
  readVerified(dir, camera_file);
  readVerified(dir, config_file);
  const std::string kf_data = readVerified(dir, *m.find("keyframes"));
  const std::string pt_data = readVerified(dir, *m.find("points"));
  if (const FileEntry* nf = m.find("nerf")) {
    verifyLarge(dir, *nf);
    out.nerf_model = dir / nf->name;
  }
  for (const FileEntry& f : m.files) {
    if (f.role != "image") continue;
    std::error_code ec;
    if (!fs::exists(dir / f.name, ec))
      fail("{}: missing: {} lists it as the image of keyframe {} (the map folder is incomplete)",
           (dir / f.name).string(), kManifest, f.keyframe);
  }

  out.camera = loadCameraYaml(dir / camera_file.name);
  if (expected_camera) checkSameCamera(out.camera, *expected_camera, (dir / camera_file.name).string());
  loadOptionsFile(dir / config_file.name, out.options);
  validateOptions(out.options, (dir / config_file.name).string());

  const std::string kf_file = (dir / m.find("keyframes")->name).string();
  const std::string pt_file = (dir / m.find("points")->name).string();
  std::vector<KeyframeRecord> records = decodeKeyframes(kf_data, kf_file);
  std::vector<MapPoint> points = decodePoints(pt_data, pt_file);

  // Associations: every keypoint slot and every observation must agree.
  std::unordered_map<int64_t, size_t> kf_index;
  for (size_t i = 0; i < records.size(); ++i)
    if (!kf_index.emplace(records[i].kf.id, i).second)
      throw fieldError(kf_file, fmt::format("keyframe[{}].id", i), fmt::format("id {} listed twice", records[i].kf.id));
  std::unordered_map<int64_t, const MapPoint*> point_index;
  for (size_t i = 0; i < points.size(); ++i) {
    if (!point_index.emplace(points[i].id, &points[i]).second)
      throw fieldError(pt_file, fmt::format("point[{}].id", i), fmt::format("id {} listed twice", points[i].id));
    if (points[i].observations.size() < 2)
      throw fieldError(pt_file, fmt::format("point[{}] (id {}).observations", i, points[i].id),
                       fmt::format("{} observations (a map point has at least 2)", points[i].observations.size()));
    for (const auto& [kid, idx] : points[i].observations) {
      auto it = kf_index.find(kid);
      if (it == kf_index.end())
        throw fieldError(pt_file, fmt::format("point[{}] (id {}).observations", i, points[i].id),
                         fmt::format("keyframe {} is not in {}", kid, kf_file));
      const auto& slots = records[it->second].kf.points;
      if (idx < 0 || idx >= static_cast<int>(slots.size()) || slots[idx] != points[i].id)
        throw fieldError(pt_file, fmt::format("point[{}] (id {}).observations", i, points[i].id),
                         fmt::format("keyframe {} keypoint {} does not name this point in {}", kid, idx, kf_file));
    }
  }
  for (size_t k = 0; k < records.size(); ++k) {
    const auto& rec = records[k];
    for (size_t i = 0; i < rec.kf.points.size(); ++i) {
      const int64_t pid = rec.kf.points[i];
      if (pid == kNoPoint) continue;
      auto it = point_index.find(pid);
      if (it == point_index.end() || !it->second->observations.count(rec.kf.id) ||
          it->second->observations.at(rec.kf.id) != static_cast<int>(i))
        throw fieldError(kf_file, fmt::format("keyframe[{}] (id {}).keypoints[{}].point", k, rec.kf.id, i),
                         fmt::format("map point {} {}", pid,
                                     it == point_index.end() ? "is not in " + pt_file
                                                             : "does not list this keypoint in " + pt_file));
    }
  }

  // Keyframe frames from their images, on two threads (decoding and feature extraction dominate
  // loading); the first failing keyframe in file order is reported.
  std::vector<char> identical(records.size(), 0);
  std::vector<std::exception_ptr> errors(records.size());
  std::atomic<size_t> next{0};
  auto rebuild = [&] {
    for (size_t k = next++; k < records.size(); k = next++) {
      try {
        KeyframeRecord& rec = records[k];
        const FileEntry* img = m.findName(rec.image);
        if (!img || img->role != "image")
          throw fieldError(kf_file, fmt::format("keyframe (id {}).image", rec.kf.id),
                           fmt::format("'{}' is not listed in {}", rec.image, kManifest));
        const std::string png = readVerified(dir, *img);
        const fs::path img_path = dir / img->name;
        const cv::Mat image = cv::imdecode(
            cv::Mat(1, static_cast<int>(png.size()), CV_8U, const_cast<char*>(png.data())), cv::IMREAD_UNCHANGED);
        if (image.empty()) fail("{}: not a readable PNG image", img_path.string());
        if (image.cols != rec.width || image.rows != rec.height || image.channels() != rec.channels ||
            image.depth() != CV_8U)
          throw fieldError(img_path.string(), "size",
                           fmt::format("{}x{}x{} image, the keyframe was {}x{}x{}", image.cols, image.rows,
                                       image.channels(), rec.width, rec.height, rec.channels));
        if (pixelsCrc(image) != rec.pixels_crc)
          throw fieldError(img_path.string(), "pixels", "the decoded pixels differ from the keyframe's (checksum)");
        bool same = false;
        rec.kf.frame = rebuildFrame(rec, image, out.camera, out.options.tracking.features, kf_file, &same);
        identical[k] = same;
      } catch (...) {
        errors[k] = std::current_exception();
      }
    }
  };
  {
    std::vector<std::thread> helpers;
    if (records.size() > 1 && std::thread::hardware_concurrency() > 1) helpers.emplace_back(rebuild);
    rebuild();
    for (auto& t : helpers) t.join();
  }
  std::vector<Keyframe> kfs;
  kfs.reserve(records.size());
  for (size_t k = 0; k < records.size(); ++k) {
    if (errors[k]) std::rethrow_exception(errors[k]);
    out.keyframes_rebuilt_identical += identical[k];
    kfs.push_back(std::move(records[k].kf));
  }

  out.map = std::make_unique<Map>(out.camera);
  out.map->restore(std::move(kfs), std::move(points));
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  spdlog::info("map loaded from {} (generation {}): {} keyframes ({} re-extracted identically), {} points{}, {:.2f} s",
               dir.string(), out.generation, out.map->numKeyframes(), out.keyframes_rebuilt_identical,
               out.map->numPoints(), out.nerf_model ? ", NeRF model" : "", out.seconds);
  return out;
}

}  // namespace nerfslam
