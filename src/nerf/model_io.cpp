#include "nerfslam/nerf/model_io.h"

#include <array>
#include <cmath>
#include <cstring>
#include <limits>

#include <nlohmann/json.hpp>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/crc32.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"
#include "nerfslam/nerf/hash_grid.h"

namespace nerfslam::nerf {
namespace {

constexpr char kMagic[8] = {'N', 'E', 'R', 'F', 'S', 'L', 'A', 'M'};
constexpr uint32_t kByteOrderMark = 0x01020304u;
// The JSON header of a model is a few KB (the field's configuration, the scene box, the arrays' names
// and sizes).
constexpr uint64_t kMaxModelHeaderBytes = 16 << 20;

// Visitors over option structs (FieldConfig, AdamOptions) to and from JSON.
struct ToJson {
  nlohmann::json& j;
  template <class T, class C>
  void operator()(const char* name, T& value, const char*, const C&) {
    j[name] = value;
  }
  template <class T>
  void operator()(const char* name, T& value, const char*) {
    if constexpr (std::is_arithmetic_v<T> || std::is_same_v<T, std::string>) {
      j[name] = value;
    } else {
      nlohmann::json sub = nlohmann::json::object();
      ToJson w{sub};
      value.visit(w);
      j[name] = sub;
    }
  }
};

struct FromJson {
  const nlohmann::json& j;
  std::string file;
  template <class T, class C>
  void operator()(const char* name, T& value, const char* doc, const C&) {
    (*this)(name, value, doc);
  }
  template <class T>
  void operator()(const char* name, T& value, const char*) {
    if (!j.contains(name)) throw fieldError(file, std::string("header.") + name, "missing");
    if constexpr (std::is_arithmetic_v<T> || std::is_same_v<T, std::string>) {
      value = j.at(name).get<T>();
    } else {
      FromJson r{j.at(name), file};
      value.visit(r);
    }
  }
};

class CrcWriter {
 public:
  explicit CrcWriter(std::ostream& os) : os_(os) {}
  void write(const void* data, size_t n) {
    // Large arrays in chunks so the stream and the CRC work on cache-sized pieces.
    const char* p = static_cast<const char*>(data);
    while (n > 0) {
      const size_t k = std::min<size_t>(n, 1 << 20);
      os_.write(p, std::streamsize(k));
      crc_ = crc32(p, k, crc_);
      p += k;
      n -= k;
    }
  }
  template <class T>
  void pod(const T& v) {
    write(&v, sizeof(T));
  }
  uint32_t crc() const { return crc_; }

 private:
  std::ostream& os_;
  uint32_t crc_ = 0;
};

struct ArrayRef {
  std::string name;
  std::string type;  // "f32" or "u32"
  void* data;
  size_t count;
};

std::vector<ArrayRef> collectArrays(NerfModel& m, bool optimizer) {
  std::vector<ArrayRef> arrays;
  for (auto& a : m.field->parameters()) arrays.push_back({a.name, "f32", a.data, a.size});
  if (m.background)
    arrays.push_back({"background.logits", "f32", m.background->logits().data(), m.background->numParameters()});
  if (optimizer) {
    for (auto& a : m.field->optimizerMoments()) arrays.push_back({a.name, "f32", a.data, a.size});
    for (auto& a : m.field->optimizerCounters()) arrays.push_back({a.name, "u32", a.data, a.size});
    if (m.background) {
      Background& b = *m.background;
      arrays.push_back({"adam.m.background", "f32", b.adamM().data(), b.adamM().size()});
      arrays.push_back({"adam.v.background", "f32", b.adamV().data(), b.adamV().size()});
      arrays.push_back({"adam.background_steps", "u32", b.adamSteps().data(), b.adamSteps().size()});
    }
  }
  return arrays;
}

}  // namespace

NerfModel NerfModel::create(FieldConfig config, const SceneTransform& scene, uint64_t seed) {
  scene.validate("scene");
  if (config.finest_resolution == FieldConfig().finest_resolution) config.finest_resolution = 2048.0 * scene.aabb_scale;
  NerfModel m;
  m.field_config = config;
  m.scene = scene;
  m.field = std::make_unique<RadianceField>(config, seed);
  m.grid = std::make_unique<OccupancyGrid>(OccupancyGrid::cascadesForAabbScale(scene.aabb_scale));
  m.grid->fill(0.f);  // values 0 (the first update sets them) but every cell marked occupied
  return m;
}

void NerfModel::toFieldCoords(const float* p, size_t n, float* q) const {
  const float s = fieldCoordScale();
  const float lo = float(0.5 - 0.5 * scene.aabb_scale);
  for (size_t i = 0; i < 3 * n; ++i) q[i] = (p[i] - lo) * s;
}

void saveModel(NerfModel& model, const std::filesystem::path& path, const SaveOptions& options) {
  if (!model.field || !model.grid) fail("{}: cannot save an empty model", path.string());
  const auto arrays = collectArrays(model, options.include_optimizer);
  for (const auto& a : arrays) {
    if (a.type != "f32") continue;
    const float* f = static_cast<const float*>(a.data);
    for (size_t i = 0; i < a.count; ++i)
      if (!std::isfinite(f[i]))
        fail("{}: refusing to save a diverged model: parameter array '{}' has a non-finite value at {}", path.string(),
             a.name, i);
  }
  nlohmann::json h;
  nlohmann::json fc = nlohmann::json::object();
  ToJson w{fc};
  model.field_config.visit(w);
  h["field_config"] = fc;
  h["scene"] = {{"scale", model.scene.scale},
                {"offset", {model.scene.offset.x(), model.scene.offset.y(), model.scene.offset.z()}},
                {"aabb_scale", model.scene.aabb_scale},
                {"cone_angle", model.scene.cone_angle},
                {"max_step", model.scene.max_step}};
  h["grid"] = {{"cascades", model.grid->cascades()},
               {"resolution", OccupancyGrid::kRes},
               {"threshold", model.grid->threshold()}};
  h["training_steps"] = model.training_steps;
  if (model.background) {
    const Eigen::Matrix3f& f = model.background->frame();
    std::vector<float> frame;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) frame.push_back(f(r, c));
    h["background"] = {{"rows", model.background->rows()}, {"frame", frame}};
  }
  nlohmann::json list = nlohmann::json::array();
  for (const auto& a : arrays) list.push_back({{"name", a.name}, {"type", a.type}, {"count", a.count}});
  list.push_back({{"name", "occupancy.values"}, {"type", "f32"}, {"count", model.grid->values().size()}});
  h["arrays"] = list;
  const std::string header = h.dump();

  writeFileAtomic(path, [&](std::ostream& os) {
    CrcWriter cw(os);
    cw.write(kMagic, sizeof(kMagic));
    // Without a background the file is a version-1 file (what earlier builds read and wrote).
    cw.pod(model.background ? kModelFormatVersion : uint32_t(1));
    cw.pod(kByteOrderMark);
    cw.pod(uint64_t(header.size()));
    cw.write(header.data(), header.size());
    for (const auto& a : arrays) cw.write(a.data, a.count * 4);
    cw.write(model.grid->values().data(), model.grid->values().size() * 4);
    const uint32_t crc = cw.crc();
    os.write(reinterpret_cast<const char*>(&crc), 4);
  });
}

NerfModel loadModel(const std::filesystem::path& path) {
  const std::string file = path.string();
  InputFile in = openInputFile(path, "NeRF model file");
  // Read in steps, each size declared by what came before checked against the file's size (or, for a
  // pipe, taken as it arrives) before anything of that size is allocated.
  std::vector<char> buf;
  auto readMore = [&](uint64_t n) {
    while (n > 0 && in.stream) {
      const size_t k = size_t(std::min<uint64_t>(n, 1 << 24));
      const size_t old = buf.size();
      buf.resize(old + k);
      in.stream.read(buf.data() + old, std::streamsize(k));
      const auto got = size_t(in.stream.gcount());
      buf.resize(old + got);
      n -= got;
      if (got < k) break;
    }
    checkReadable(in.stream, path);
  };
  constexpr size_t kFixed = 8 + 4 + 4 + 8;
  readMore(kFixed);
  if (buf.size() < kFixed || (in.size && *in.size < kFixed + 4))
    fail("{}: not a nerfslam model (file too short: {} bytes)", file, in.size.value_or(buf.size()));
  if (std::memcmp(buf.data(), kMagic, 8) != 0)
    fail("{}: not a nerfslam model (bad magic; expected \"NERFSLAM\")", file);
  uint32_t version, bom;
  uint64_t hlen;
  std::memcpy(&version, buf.data() + 8, 4);
  std::memcpy(&bom, buf.data() + 12, 4);
  std::memcpy(&hlen, buf.data() + 16, 8);
  if (bom != kByteOrderMark) fail("{}: byte order mark mismatch (file written on a big-endian machine?)", file);
  if (version != 1 && version != kModelFormatVersion)
    fail("{}: unsupported model format version {} (this build reads versions 1 to {})", file, version,
         kModelFormatVersion);
  if (in.size && hlen > *in.size - kFixed - 4)
    fail("{}: truncated model file (header of {} bytes, file {} bytes)", file, hlen, *in.size);
  if (hlen > kMaxModelHeaderBytes)
    fail("{}: corrupt model header: it declares {} bytes, more than the {} a model header may have", file, hlen,
         formatBytes(kMaxModelHeaderBytes));
  readMore(hlen);
  if (buf.size() < kFixed + hlen)
    fail("{}: truncated model file (header of {} bytes, file {} bytes)", file, hlen, buf.size());
  nlohmann::json h;
  try {
    h = nlohmann::json::parse(buf.begin() + long(kFixed), buf.begin() + long(kFixed + hlen));
  } catch (const std::exception& e) {
    fail("{}: corrupt model header: {}", file, e.what());
  }
  // Expected total size from the header, to tell truncation apart from corruption. Each array must
  // fit in what the file has after the header (a pipe: in what the format can hold).
  const uint64_t room = in.size ? *in.size - kFixed - hlen - 4 : std::numeric_limits<uint64_t>::max() / 2;
  uint64_t data_bytes = 0;
  try {
    for (const auto& a : h.at("arrays")) {
      const auto count = a.at("count").get<uint64_t>();
      if (count > (room - data_bytes) / 4)
        fail("{}: truncated model file: array {} declares {} values of 4 bytes, but only {} bytes follow", file,
             cutForMessage(a.value("name", nlohmann::json()).dump()), count, room - data_bytes);
      data_bytes += count * 4;
    }
  } catch (const nlohmann::json::exception& e) {
    fail("{}: corrupt model header: {}", file, e.what());
  }
  const uint64_t expected = kFixed + hlen + data_bytes + 4;
  if (in.size && *in.size < expected)
    fail("{}: truncated model file ({} bytes, expected {})", file, *in.size, expected);
  if (in.size && *in.size > expected) fail("{}: corrupt model file ({} trailing bytes)", file, *in.size - expected);
  if (in.size) buf.reserve(size_t(expected));
  readMore(expected - buf.size() + 1);  // one byte more: none may follow
  if (buf.size() < expected) fail("{}: truncated model file ({} bytes, expected {})", file, buf.size(), expected);
  if (buf.size() > expected) fail("{}: corrupt model file (bytes after the {} expected)", file, expected);
  const size_t size = buf.size();
  uint32_t stored;
  std::memcpy(&stored, buf.data() + size - 4, 4);
  if (crc32(buf.data(), size - 4) != stored) fail("{}: checksum mismatch: the model file is corrupted", file);

  NerfModel m;
  try {
    FromJson r{h.at("field_config"), file};
    m.field_config.visit(r);
    const auto& s = h.at("scene");
    m.scene.scale = s.at("scale").get<double>();
    const auto off = s.at("offset").get<std::vector<double>>();
    if (off.size() != 3) throw fieldError(file, "scene.offset", "must have 3 numbers");
    m.scene.offset = Eigen::Vector3d(off[0], off[1], off[2]);
    m.scene.aabb_scale = s.at("aabb_scale").get<double>();
    const int cascades = h.at("grid").at("cascades").get<int>();
    if (s.contains("cone_angle") || s.contains("max_step")) {
      m.scene.cone_angle = s.at("cone_angle").get<double>();
      m.scene.max_step = s.at("max_step").get<double>();
    } else {  // written before the march was recorded: instant-ngp's, as those builds marched
      m.scene.cone_angle = 1.0 / 256.0;
      m.scene.max_step = double(kMinStep) * double(1 << std::clamp(cascades - 1, 0, 30));
    }
    m.scene.validate(file);
    if (h.at("grid").at("resolution").get<int>() != OccupancyGrid::kRes)
      throw fieldError(file, "grid.resolution", "unsupported occupancy grid resolution");
    m.training_steps = h.at("training_steps").get<uint64_t>();
    // What the header's configuration makes is allocated below: its parameters must be among the
    // arrays the file holds (a header that asks for gigabytes in a small file is refused here).
    auto mustHold = [&](const char* field, uint64_t bytes) {
      if (bytes > data_bytes)
        throw fieldError(file, field,
                         fmt::format("declares {} of parameters, but the file's arrays hold {}", formatBytes(bytes),
                                     formatBytes(data_bytes)));
    };
    try {
      validate(m.field_config);
    } catch (const Error& e) {
      fail("{}: {}", file, e.what());
    }
    const auto levels = gridLevels(m.field_config.n_levels, m.field_config.base_resolution,
                                   m.field_config.finest_resolution, m.field_config.log2_hashmap_size);
    mustHold("header.field_config", (uint64_t(levels.back().offset) + levels.back().size) * 2 * 4);
    if (cascades < 1 || cascades > 8)
      throw fieldError(file, "grid.cascades", fmt::format("{} is not in [1, 8]", cascades));
    mustHold("grid.cascades", uint64_t(cascades) * OccupancyGrid::kCells * 4);
    int background_rows = 0;
    if (version >= 2 && h.contains("background")) {
      background_rows = h.at("background").at("rows").get<int>();
      if (background_rows < 2 || background_rows > 4096)
        throw fieldError(file, "header.background.rows", fmt::format("{} is not in [2, 4096]", background_rows));
      mustHold("header.background.rows", uint64_t(background_rows) * uint64_t(2 * background_rows) * 3 * 4);
    }
    m.field = std::make_unique<RadianceField>(m.field_config, 0);
    m.grid = std::make_unique<OccupancyGrid>(cascades);
    const float threshold = h.at("grid").at("threshold").get<float>();
    if (background_rows > 0) {
      const auto f = h.at("background").at("frame").get<std::vector<float>>();
      if (f.size() != 9) throw fieldError(file, "header.background.frame", "must have 9 numbers");
      Eigen::Matrix3f frame;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) frame(r, c) = f[size_t(3 * r + c)];
      m.background = std::make_unique<Background>(background_rows, frame);
    }

    std::vector<ArrayRef> targets = collectArrays(m, true);
    size_t pos = kFixed + hlen;
    std::vector<float> grid_values;
    for (const auto& a : h.at("arrays")) {
      const auto name = a.at("name").get<std::string>();
      const auto type = a.at("type").get<std::string>();
      const auto count = a.at("count").get<size_t>();
      const char* src = buf.data() + pos;
      pos += count * 4;
      if (name == "occupancy.values") {
        if (count != size_t(cascades) * OccupancyGrid::kCells)
          throw fieldError(file, "arrays.occupancy.values", "size does not match the grid");
        grid_values.resize(count);
        std::memcpy(grid_values.data(), src, count * 4);
        continue;
      }
      auto it = std::find_if(targets.begin(), targets.end(), [&](const ArrayRef& t) { return t.name == name; });
      if (it == targets.end()) throw fieldError(file, "arrays." + name, "unknown parameter array");
      if (it->count != count || it->type != type)
        throw fieldError(file, "arrays." + name,
                         fmt::format("has {} {} values, the field expects {} {}", count, type, it->count, it->type));
      std::memcpy(it->data, src, count * 4);
    }
    if (grid_values.empty()) throw fieldError(file, "arrays", "no occupancy grid");
    for (const auto& t : collectArrays(m, false))
      if (std::none_of(h.at("arrays").begin(), h.at("arrays").end(),
                       [&](const nlohmann::json& a) { return a.at("name").get<std::string>() == t.name; }))
        throw fieldError(file, "arrays." + t.name, "missing");
    m.field->parametersChanged();
    m.grid->setValues(std::move(grid_values), threshold);
  } catch (const nlohmann::json::exception& e) {
    fail("{}: corrupt model header: {}", file, e.what());
  }
  return m;
}

}  // namespace nerfslam::nerf
