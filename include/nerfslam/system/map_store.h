#pragma once
// Map folders: everything needed to continue from a SLAM run later — the sparse map (keyframes with
// poses, keypoints, descriptors and keypoint -> map point associations; map points with positions,
// normals, descriptors, observations and tracking statistics), each keyframe's image (lossless PNG,
// stored once), the camera, the system options and optionally a NeRF model.
//
// Layout of a map folder (format version kMapFormatVersion = 2):
//   map.json                       the manifest, written last: format, format_version, generation,
//                                  created_utc, creator, counts, and "files": every data file of this
//                                  generation with its role, size in bytes and CRC-32 (IEEE, as zlib)
//   camera.<G>.yaml                the camera (saveCameraYaml / loadCameraYaml)
//   config.<G>.yaml                the SystemOptions (the YAML `nerfslam run --config` reads)
//   keyframes.<G>.bin              keyframes: id, frame id, timestamp, fixed flag, pose (quaternion +
//                                  translation, doubles), image file, keypoints (level-0 pixel, size,
//                                  angle, response, octave, undistorted pixel, map point id), descriptors
//   points.<G>.bin                 map points: id, position, normal, descriptor, first keyframe,
//                                  visible/found counts, observations (keyframe id, keypoint index)
//   images/kf<ID>.<G'>.png         keyframe images (BGR or grey, 8 bit), G' = the generation that wrote
//                                  it: an image already in the folder with the same pixels is reused
//   nerf.<G>.nerf                  optional NeRF model (written by the caller's callback)
// <G> is a generation number (6 digits) that every save increments. Binary files are little-endian
// and start with an 8-byte magic and their own version.
//
// Atomic saves: every file is written with writeFileAtomic (temporary file + fsync + rename) under a
// name of the new generation, the manifest is replaced last, and only then are files that the new
// manifest does not name (the previous generation's, temporaries of killed saves) deleted. The loader
// reads only what the manifest names, so a crash or SIGKILL at any moment leaves the previous map
// loadable. One writer per folder at a time.
//
// Loading verifies the format version, every listed file's presence, size and CRC-32, the camera
// against the one the caller runs with, and the associations; any failure is an Error naming the
// file and the field. Keyframe Frames are rebuilt from the stored images with the tracking module's
// extractFrame (pyramid, grid; with the features options stored in the map) and then given the
// stored keypoints, descriptors and undistorted positions, so the associations stay valid even if
// feature extraction changed; LoadedMap says how many keyframes re-extracted identically.
//
// The pieces: map_folder.h (manifest, generations, verified reads, atomic replace), and, private to
// src/system, map_codec.h (the keyframe and point binaries) and map_rebuild.h (keyframe images and
// the Frames rebuilt from them); saveMapFolder and loadMapFolder compose them.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/system/map_folder.h"
#include "nerfslam/system/slam_system.h"

namespace nerfslam {

// Writes the NeRF model to the given path (e.g. nerf::saveModel); an exception aborts the save.
using NerfModelWriter = std::function<void(const std::filesystem::path&)>;

struct MapSaveResult {
  uint64_t generation = 0;
  size_t keyframes = 0, points = 0;
  size_t images_written = 0, images_reused = 0;
  uint64_t bytes = 0;  // all files of the saved generation
  bool has_nerf = false;
  double seconds = 0;
};

// Saves `map` (a consistent snapshot of it; the map may be in use) into `dir` (created if missing)
// as described above. Throws an Error naming the file when something cannot be written, or when
// `dir` holds a map of another format version; the previous map in `dir` is then left as it was.
MapSaveResult saveMapFolder(const std::filesystem::path& dir, const Map& map, const Camera& camera,
                            const SystemOptions& options, const NerfModelWriter& write_nerf_model = {});

struct LoadedMap {
  std::unique_ptr<Map> map;  // fresh, ids as saved
  Camera camera;
  SystemOptions options;                            // as saved
  std::optional<std::filesystem::path> nerf_model;  // the model file when the map has one (checksum verified)
  uint64_t generation = 0;
  int keyframes_rebuilt_identical = 0;  // keyframes whose re-extracted features equal the stored ones
  double seconds = 0;
  nlohmann::json manifest;
};

// Loads and verifies a map folder. With `expected_camera` (the camera the caller will track with),
// a map made with another camera (size, intrinsics or distortion) is refused.
LoadedMap loadMapFolder(const std::filesystem::path& dir, const std::optional<Camera>& expected_camera = std::nullopt);

// The SystemOptions stored in a map folder (manifest and config file verified; nothing else read).
SystemOptions loadMapOptions(const std::filesystem::path& dir);

// Throws an Error "`source`: field 'FIELD': ..." when `camera` differs from the map's camera
// (relative tolerance 1e-9 on intrinsics and distortion).
void checkSameCamera(const Camera& map_camera, const Camera& camera, const std::string& source);

// A SlamSystem on `camera` started from `loaded` (its map is moved out; an empty LoadedMap or
// MapMode::kSlam: a new map) in `mode`, with the NeRF (when options.nerf.enabled) resumed from the
// map's model when it has one: frozen in kLocalize, training on in kExtend. What `nerfslam run --map`
// and the ROS nodes' ~map both start from; `loaded` comes from loadMapFolder with the same camera
// (or checkSameCamera).
std::unique_ptr<SlamSystem> startSlamSystem(const Camera& camera, const SystemOptions& options, LoadedMap& loaded,
                                            MapMode mode);

}  // namespace nerfslam
