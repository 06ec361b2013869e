#include "nerfslam/system/map_folder.h"

#include <algorithm>
#include <charconv>
#include <ctime>
#include <fstream>
#include <iterator>
#include <regex>
#include <set>
#include <utility>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/crc32.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"

namespace nerfslam {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr const char* kManifest = kMapManifestName;
constexpr const char* kFormatName = kMapFormatName;

std::string hex32(uint32_t x) { return fmt::format("{:08x}", x); }

// ---- files -----------------------------------------------------------------------------------

std::string readFileBytes(const fs::path& path, const std::string& what) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail("{}: missing ({})", path.string(), what);
  return readInputFile(path, what);
}

// CRC-32 and size of a file read in chunks (NeRF models can be large).
std::pair<uint64_t, uint32_t> fileSizeCrc(const fs::path& path) {
  InputFile f = openInputFile(path);
  std::istream& in = f.stream;
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
  checkReadable(in, path);
  return {size, crc};
}

// ---- the manifest ----------------------------------------------------------------------------

json toJson(const MapFileEntry& f) {
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
    throw fieldError(file, path, "expected 8 lowercase hex digits, got '" + cutForMessage(s) + "'");
  return static_cast<uint32_t>(std::stoul(s, nullptr, 16));
}

// A file name from the manifest: relative, inside the folder.
void checkRelativeName(const std::string& name, const std::string& file, const std::string& path) {
  const fs::path p(name);
  bool ok = !name.empty() && p.is_relative();
  for (const auto& part : p) ok = ok && part != ".." && part != ".";
  if (!ok) throw fieldError(file, path, "'" + name + "' is not a file inside the map folder");
}

json parseManifestJson(const fs::path& dir) {
  const fs::path path = dir / kManifest;
  std::error_code ec;
  if (!fs::exists(dir, ec)) fail("{}: map folder not found", dir.string());
  if (!fs::exists(path, ec))
    fail("{}: missing: {} is not a map folder (or its first save never finished)", path.string(), dir.string());
  const std::string text = readFileBytes(path, "map manifest");
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
    throw fieldError(file, "format",
                     fmt::format("'{}' is not a nerfslam map (expected '{}')", cutForMessage(format), kFormatName));
  const auto version = jsonField<int64_t>(j, "format_version", file, "format_version");
  if (version != kMapFormatVersion)
    throw fieldError(file, "format_version",
                     fmt::format("the map has format version {}, this nerfslam reads and writes version {}{}", version,
                                 kMapFormatVersion,
                                 version < kMapFormatVersion ? " (an older map: rebuild it with this version)"
                                                             : " (a newer map: use a newer nerfslam)"));
}

// Entry `i` of the manifest's "files" list; `names` holds the names of the entries before it.
MapFileEntry readEntry(const json& e, size_t i, const std::string& file, std::set<std::string>& names) {
  const std::string p = fmt::format("files[{}]", i);
  MapFileEntry f;
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
  return f;
}

void checkEntry(const fs::path& path, const MapFileEntry& f, uint64_t size, uint32_t crc) {
  if (size != f.size)
    throw fieldError(path.string(), "size",
                     fmt::format("{} bytes, {} lists {} (truncated or modified)", size, kManifest, f.size));
  if (crc != f.crc)
    throw fieldError(
        path.string(), "crc32",
        fmt::format("checksum {} differs from {}'s {}: the file is corrupted", hex32(crc), kManifest, hex32(f.crc)));
}

void checkPresent(const fs::path& path, const MapFileEntry& f) {
  std::error_code ec;
  if (!fs::exists(path, ec))
    fail("{}: missing: {} lists it as the map's {} file (the map folder is incomplete)", path.string(), kManifest,
         f.role);
}

// ---- generations -----------------------------------------------------------------------------

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

const MapFileEntry* MapManifest::find(const std::string& role) const {
  for (const auto& f : files)
    if (f.role == role) return &f;
  return nullptr;
}

const MapFileEntry* MapManifest::findName(const std::string& name) const {
  for (const auto& f : files)
    if (f.name == name) return &f;
  return nullptr;
}

std::string mapGenerationName(uint64_t generation) { return fmt::format("{:06d}", generation); }

MapManifest readMapManifest(const fs::path& dir) {
  const std::string file = (dir / kManifest).string();
  MapManifest m;
  m.j = parseManifestJson(dir);
  checkFormat(m.j, file);
  m.generation = jsonField<uint64_t>(m.j, "generation", file, "generation");
  if (!m.j.contains("files") || !m.j["files"].is_array()) throw fieldError(file, "files", "missing (a list of files)");
  std::set<std::string> names;
  for (size_t i = 0; i < m.j["files"].size(); ++i) {
    m.files.push_back(readEntry(m.j["files"][i], i, file, names));
  }
  for (const char* role : {"camera", "config", "keyframes", "points"})
    if (!m.find(role)) throw fieldError(file, "files", fmt::format("no {} file listed", role));
  return m;
}

std::string readMapFile(const fs::path& dir, const MapFileEntry& f) {
  const fs::path path = dir / f.name;
  checkPresent(path, f);
  // The size first: a file that is not what the manifest lists is not read into memory.
  std::error_code ec;
  const uintmax_t on_disk = fs::file_size(path, ec);
  if (!ec && on_disk != f.size) checkEntry(path, f, on_disk, f.crc);
  std::string data = readFileBytes(path, f.role + " file");
  checkEntry(path, f, data.size(), crc32(data));
  return data;
}

void verifyMapFile(const fs::path& dir, const MapFileEntry& f) {
  const fs::path path = dir / f.name;
  checkPresent(path, f);
  const auto [size, crc] = fileSizeCrc(path);
  checkEntry(path, f, size, crc);
}

MapFileEntry writeMapFile(const fs::path& dir, const std::string& name, const std::string& role,
                          const std::string& data) {
  writeStringAtomic(dir / name, data);
  MapFileEntry f;
  f.name = name;
  f.role = role;
  f.size = data.size();
  f.crc = crc32(data);
  return f;
}

MapFileEntry mapFileEntry(const fs::path& dir, const std::string& name, const std::string& role) {
  MapFileEntry f;
  f.name = name;
  f.role = role;
  std::tie(f.size, f.crc) = fileSizeCrc(dir / name);
  return f;
}

MapGeneration nextMapGeneration(const fs::path& dir) {
  MapGeneration next;
  const fs::path manifest_path = dir / kManifest;
  if (!fs::exists(manifest_path)) return next;
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
    next.previous = readMapManifest(dir);
    next.number = next.previous->generation + 1;
  } catch (const Error& e) {
    spdlog::warn("{}: the previous map is unreadable ({}); saving a new one", dir.string(), e.what());
    next.number = largestGenerationInNames(dir) + 1;
  }
  return next;
}

void commitMapManifest(const fs::path& dir, uint64_t generation, json fields, const std::vector<MapFileEntry>& files) {
  json manifest = std::move(fields);
  manifest["format"] = kFormatName;
  manifest["format_version"] = kMapFormatVersion;
  manifest["generation"] = generation;
  manifest["created_utc"] = utcNow();
  manifest["files"] = json::array();
  std::set<std::string> keep{kManifest};
  for (const MapFileEntry& f : files) {
    manifest["files"].push_back(toJson(f));
    keep.insert(f.name);
  }
  // The commit point: before this rename the previous map is the folder's map, after it this one.
  writeStringAtomic(dir / kManifest, manifest.dump(1) + "\n");
  removeUnreferenced(dir, keep);
}

}  // namespace nerfslam
