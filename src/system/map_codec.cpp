#include "system/map_codec.h"

#include <cmath>
#include <cstring>
#include <type_traits>
#include <unordered_map>

#include <fmt/format.h>

#include "nerfslam/core/error.h"

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "map files are written in the host's (little-endian) order");

namespace nerfslam::map_detail {
namespace {

constexpr char kKeyframesMagic[8] = {'N', 'S', 'M', 'A', 'P', 'K', 'F', '\0'};
constexpr char kPointsMagic[8] = {'N', 'S', 'M', 'A', 'P', 'P', 'T', '\0'};
constexpr uint32_t kBinaryVersion = 1;

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

}  // namespace

std::string encodeKeyframes(const std::vector<Keyframe>& kfs, const std::vector<KeyframeImageRef>& images) {
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
    const KeyframeImageRef& img = images[k];
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
    rec.image.name = r.str("image");
    rec.image.width = r.pod<int32_t>("image_width");
    rec.image.height = r.pod<int32_t>("image_height");
    rec.image.channels = r.pod<int32_t>("image_channels");
    rec.image.pixels_crc = r.pod<uint32_t>("image_pixels_crc32");
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

void checkAssociations(const std::vector<KeyframeRecord>& records, const std::vector<MapPoint>& points,
                       const std::string& kf_file, const std::string& pt_file) {
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
}

}  // namespace nerfslam::map_detail
