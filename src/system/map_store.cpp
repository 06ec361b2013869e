// The map store's facade: saveMapFolder and loadMapFolder compose the folder's files and
// generations (map_folder.h), the keyframe and point binaries (map_codec.h) and the keyframe images
// and frames (map_rebuild.h).
#include "nerfslam/system/map_store.h"

#include <algorithm>
#include <chrono>
#include <map>
#include <system_error>

#include <spdlog/spdlog.h>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/system/nerf_mapping.h"
#include "nerfslam/tracking/frame.h"
#include "system/map_codec.h"
#include "system/map_rebuild.h"

namespace nerfslam {
namespace fs = std::filesystem;
using map_detail::KeyframeImageRef;
using map_detail::KeyframeRecord;
using nlohmann::json;

namespace {

// The previous generation's entry of an image with the same keyframe, size and pixels, when its
// file is still there with the listed size; else null.
const MapFileEntry* reusableImage(const fs::path& dir, const std::optional<MapManifest>& prev, const MapFileEntry& e) {
  if (!prev) return nullptr;
  for (const MapFileEntry& f : prev->files)
    if (f.role == "image" && f.keyframe == e.keyframe && f.pixels_crc == e.pixels_crc && f.width == e.width &&
        f.height == e.height && f.channels == e.channels) {
      std::error_code ec;
      if (fs::file_size(dir / f.name, ec) == f.size && !ec) return &f;
      break;
    }
  return nullptr;
}

// The image entries of `kfs` (in order) for generation `g`: reused from the previous generation
// where possible, else written as PNG files.
std::vector<MapFileEntry> saveKeyframeImages(const fs::path& dir, const std::vector<Keyframe>& kfs,
                                             const std::optional<MapManifest>& prev, const std::string& g,
                                             MapSaveResult& res) {
  std::vector<MapFileEntry> images;
  images.reserve(kfs.size());
  for (const Keyframe& kf : kfs) {
    if (!kf.frame) fail("keyframe {}: no frame to save", kf.id);
    const cv::Mat& img = map_detail::keyframeImage(kf);
    if (img.depth() != CV_8U || (img.channels() != 1 && img.channels() != 3))
      fail("keyframe {}: image type {} cannot be stored (8-bit grey or BGR expected)", kf.id, img.type());
    MapFileEntry e;
    e.role = "image";
    e.keyframe = kf.id;
    e.width = img.cols;
    e.height = img.rows;
    e.channels = img.channels();
    e.pixels_crc = map_detail::pixelsCrc(img);
    if (const MapFileEntry* old = reusableImage(dir, prev, e)) {
      e = *old;
      ++res.images_reused;
    } else {
      std::vector<uchar> png;
      if (!cv::imencode(".png", img, png, {cv::IMWRITE_PNG_COMPRESSION, 3}))
        fail("keyframe {}: PNG encoding failed", kf.id);
      const std::string data(png.begin(), png.end());
      const MapFileEntry written = writeMapFile(dir, fmt::format("images/kf{:06d}.{}.png", kf.id, g), "image", data);
      e.name = written.name;
      e.size = written.size;
      e.crc = written.crc;
      ++res.images_written;
    }
    images.push_back(e);
  }
  return images;
}

std::vector<KeyframeImageRef> imageRefs(const std::vector<MapFileEntry>& images) {
  std::vector<KeyframeImageRef> refs;
  refs.reserve(images.size());
  for (const MapFileEntry& e : images) refs.push_back({e.name, e.width, e.height, e.channels, e.pixels_crc});
  return refs;
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
  const MapGeneration next = nextMapGeneration(dir);
  const uint64_t generation = next.number;
  const std::string g = mapGenerationName(generation);

  auto [kfs, points] = map.snapshot();
  MapSaveResult res;
  res.generation = generation;
  res.keyframes = kfs.size();
  res.points = points.size();

  const std::vector<MapFileEntry> images = saveKeyframeImages(dir, kfs, next.previous, g, res);
  std::vector<MapFileEntry> files;
  files.push_back(
      writeMapFile(dir, "keyframes." + g + ".bin", "keyframes", map_detail::encodeKeyframes(kfs, imageRefs(images))));
  files.push_back(writeMapFile(dir, "points." + g + ".bin", "points", map_detail::encodePoints(points)));
  saveCameraYaml(camera, dir / ("camera." + g + ".yaml"));
  files.push_back(mapFileEntry(dir, "camera." + g + ".yaml", "camera"));
  files.push_back(
      writeMapFile(dir, "config." + g + ".yaml", "config",
                   optionsYaml(options, "nerfslam SystemOptions (loads with `nerfslam run --config FILE`)")));
  if (write_nerf_model) {
    const std::string name = "nerf." + g + ".nerf";
    write_nerf_model(dir / name);
    if (!fs::exists(dir / name)) fail("{}: the NeRF model writer wrote nothing", (dir / name).string());
    files.push_back(mapFileEntry(dir, name, "nerf"));
    res.has_nerf = true;
  }
  files.insert(files.end(), images.begin(), images.end());
  for (const MapFileEntry& f : files) res.bytes += f.size;

  json fields;
  fields["creator"] = "nerfslam (src/system/map_store.cpp)";
  fields["keyframes"] = kfs.size();
  fields["map_points"] = points.size();
  fields["camera"] = camera.describe();
  fields["nerf_model"] = res.has_nerf ? json("nerf." + g + ".nerf") : json(nullptr);
  commitMapManifest(dir, generation, std::move(fields), files);
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  spdlog::info(
      "map saved to {} (generation {}): {} keyframes, {} points, {} images written, {} reused, {:.1f} MB, "
      "{:.2f} s",
      dir.string(), generation, res.keyframes, res.points, res.images_written, res.images_reused, res.bytes / 1e6,
      res.seconds);
  return res;
}

SystemOptions loadMapOptions(const fs::path& dir) {
  const MapManifest m = readMapManifest(dir);
  const MapFileEntry& cf = *m.find("config");
  readMapFile(dir, cf);
  SystemOptions o;
  loadOptionsFile(dir / cf.name, o);
  validateOptions(o, (dir / cf.name).string());
  return o;
}

LoadedMap loadMapFolder(const fs::path& dir, const std::optional<Camera>& expected_camera) {
  const auto t0 = std::chrono::steady_clock::now();
  const MapManifest m = readMapManifest(dir);
  LoadedMap out;
  out.manifest = m.j;
  out.generation = m.generation;

  // Every listed file present, complete and intact before anything is parsed.
  const MapFileEntry& camera_file = *m.find("camera");
  const MapFileEntry& config_file = *m.find("config");
  readMapFile(dir, camera_file);
  readMapFile(dir, config_file);
  const std::string kf_data = readMapFile(dir, *m.find("keyframes"));
  const std::string pt_data = readMapFile(dir, *m.find("points"));
  if (const MapFileEntry* nf = m.find("nerf")) {
    verifyMapFile(dir, *nf);
    out.nerf_model = dir / nf->name;
  }
  for (const MapFileEntry& f : m.files) {
    if (f.role != "image") continue;
    std::error_code ec;
    if (!fs::exists(dir / f.name, ec))
      fail("{}: missing: {} lists it as the image of keyframe {} (the map folder is incomplete)",
           (dir / f.name).string(), kMapManifestName, f.keyframe);
  }

  out.camera = loadCameraYaml(dir / camera_file.name);
  if (expected_camera) checkSameCamera(out.camera, *expected_camera, (dir / camera_file.name).string());
  loadOptionsFile(dir / config_file.name, out.options);
  validateOptions(out.options, (dir / config_file.name).string());

  const std::string kf_file = (dir / m.find("keyframes")->name).string();
  const std::string pt_file = (dir / m.find("points")->name).string();
  std::vector<KeyframeRecord> records = map_detail::decodeKeyframes(kf_data, kf_file);
  std::vector<MapPoint> points = map_detail::decodePoints(pt_data, pt_file);
  map_detail::checkAssociations(records, points, kf_file, pt_file);
  out.keyframes_rebuilt_identical =
      map_detail::rebuildKeyframes(dir, m, records, out.camera, out.options.tracking.features, kf_file);
  std::vector<Keyframe> kfs;
  kfs.reserve(records.size());
  for (KeyframeRecord& rec : records) kfs.push_back(std::move(rec.kf));

  out.map = std::make_unique<Map>(out.camera);
  out.map->restore(std::move(kfs), std::move(points));
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  spdlog::info("map loaded from {} (generation {}): {} keyframes ({} re-extracted identically), {} points{}, {:.2f} s",
               dir.string(), out.generation, out.map->numKeyframes(), out.keyframes_rebuilt_identical,
               out.map->numPoints(), out.nerf_model ? ", NeRF model" : "", out.seconds);
  return out;
}

std::unique_ptr<SlamSystem> startSlamSystem(const Camera& camera, const SystemOptions& options, LoadedMap& loaded,
                                            MapMode mode) {
  const bool from_map = loaded.map != nullptr && mode != MapMode::kSlam;
  auto slam = std::make_unique<SlamSystem>(camera, options, from_map ? std::move(loaded.map) : nullptr,
                                           from_map ? mode : MapMode::kSlam);
  if (from_map && loaded.nerf_model && slam->nerf())
    slam->nerf()->resume(*loaded.nerf_model, mode != MapMode::kLocalize);
  return slam;
}

}  // namespace nerfslam
