#pragma once
// The files of a map folder (layout in map_store.h): the manifest map.json, which names every data
// file of one generation with its role, size and CRC-32; reads that verify a file against its entry;
// and the generations, each save writing new names, committing by replacing the manifest atomically
// and then deleting what the new manifest does not name. What the data files hold is map_codec's
// and map_store's business; this header knows only names, sizes and checksums.
//
//   const MapGeneration next = nextMapGeneration(dir);               // 1, or one after the folder's map
//   files.push_back(writeMapFile(dir, "points." + mapGenerationName(next.number) + ".bin", "points", bytes));
//   commitMapManifest(dir, next.number, {{"creator", "..."}}, files);  // the new map is the folder's map
//   const MapManifest m = readMapManifest(dir);                       // format, version, entries checked
//   const std::string bytes = readMapFile(dir, *m.find("points"));     // size and CRC-32 checked
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace nerfslam {

// 2: keypoint and map-point descriptors are our steered BRIEF (tracking/brief.h); version 1 maps
// hold cv::ORB descriptors, which do not match them.
constexpr int kMapFormatVersion = 2;
constexpr const char* kMapManifestName = "map.json";
constexpr const char* kMapFormatName = "nerfslam-map";

// One data file of a generation, as the manifest lists it.
struct MapFileEntry {
  std::string name;  // relative to the map folder, '/' separated
  std::string role;  // camera config keyframes points image nerf
  uint64_t size = 0;
  uint32_t crc = 0;
  // Images: the keyframe and a checksum of the decoded pixels (reuse across generations).
  int64_t keyframe = -1;
  uint32_t pixels_crc = 0;
  int width = 0, height = 0, channels = 0;
};

// A manifest as read and checked by readMapManifest.
struct MapManifest {
  nlohmann::json j;
  uint64_t generation = 0;
  std::vector<MapFileEntry> files;
  const MapFileEntry* find(const std::string& role) const;      // the first entry of the role, or null
  const MapFileEntry* findName(const std::string& name) const;  // the entry of the name, or null
};

// A generation number as it appears in file names: 6 digits or more ("000042").
std::string mapGenerationName(uint64_t generation);

// Reads `dir`/map.json and checks the format and version, the generation and every file entry
// (fields and types, relative names inside the folder, no name twice, known roles, a camera, config,
// keyframes and points file). Throws an Error naming map.json and the field.
MapManifest readMapManifest(const std::filesystem::path& dir);

// The bytes of the file of `entry` after checking its presence, size and CRC-32 against the entry.
std::string readMapFile(const std::filesystem::path& dir, const MapFileEntry& entry);
// The same checks without keeping the bytes (read in chunks: for large files such as NeRF models).
void verifyMapFile(const std::filesystem::path& dir, const MapFileEntry& entry);

// Writes `data` atomically to `dir`/`name` and returns its entry.
MapFileEntry writeMapFile(const std::filesystem::path& dir, const std::string& name, const std::string& role,
                          const std::string& data);
// The entry of a file another writer has written to `dir`/`name` (size and CRC-32 read from disk).
MapFileEntry mapFileEntry(const std::filesystem::path& dir, const std::string& name, const std::string& role);

// The generation a save into `dir` writes, and the folder's map when it has a readable one.
struct MapGeneration {
  uint64_t number = 1;
  std::optional<MapManifest> previous;
};
// 1 in a folder without a manifest; one after the manifest's generation; when the manifest is
// unreadable (warned), one after the largest generation in the folder's file names. Throws when the
// folder holds a map of another format version (a save must never overwrite it).
MapGeneration nextMapGeneration(const std::filesystem::path& dir);

// The commit of a save: writes map.json atomically with `fields` (creator, counts, ...) plus the
// format, format_version, generation, created_utc and the list of `files`; before the rename the
// previous generation is the folder's map, after it this one. Then deletes the files of ours that
// the new manifest does not name (previous generations, temporaries of killed saves); files that
// are not ours are left alone.
void commitMapManifest(const std::filesystem::path& dir, uint64_t generation, nlohmann::json fields,
                       const std::vector<MapFileEntry>& files);

}  // namespace nerfslam
