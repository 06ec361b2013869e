// Map folders (system/map_folder.h): the manifest and its entries, verified reads, generations and
// the removal of what a new generation does not name; through saveMapFolder / loadMapFolder, the
// refusal of foreign, truncated, corrupted and incomplete folders with messages naming file and
// field, a SIGKILL loop during saves and a save into a full disk.
#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <random>
#include <regex>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "map_test_maps.h"
#include "nerfslam/core/crc32.h"
#include "nerfslam/core/error.h"
#include "nerfslam/system/map_folder.h"
#include "nerfslam/system/map_store.h"
#include "test_support.h"

namespace nerfslam {
namespace {
using namespace maptest;

// ---- the folder's files, directly ---------------------------------------------------------------

// A folder of generation `g` with the four files a manifest must list and one image, committed.
std::vector<MapFileEntry> commitSmallFolder(const fs::path& dir, uint64_t g) {
  fs::create_directories(dir / "images");
  const std::string n = mapGenerationName(g);
  std::vector<MapFileEntry> files;
  for (const char* role : {"camera", "config"})
    files.push_back(writeMapFile(dir, std::string(role) + "." + n + ".yaml", role, std::string(role) + " text"));
  files.push_back(writeMapFile(dir, "keyframes." + n + ".bin", "keyframes", std::string("kf\0bytes", 8)));
  files.push_back(writeMapFile(dir, "points." + n + ".bin", "points", "point bytes"));
  MapFileEntry image = writeMapFile(dir, "images/kf000003." + n + ".png", "image", "png bytes");
  image.keyframe = 3;
  image.pixels_crc = 0x0badf00d;
  image.width = 4;
  image.height = 2;
  image.channels = 1;
  files.push_back(image);
  commitMapManifest(dir, g, {{"creator", "map_folder_test"}}, files);
  return files;
}

TEST(MapFolder, GenerationNamesHaveSixDigitsOrMore) {
  EXPECT_EQ(mapGenerationName(1), "000001");
  EXPECT_EQ(mapGenerationName(42), "000042");
  EXPECT_EQ(mapGenerationName(1234567), "1234567");
}

TEST(MapFolder, CommittedManifestReadsBackAndFilesVerify) {
  test::TempDir tmp;
  const fs::path dir = tmp / "f";
  const std::vector<MapFileEntry> files = commitSmallFolder(dir, 7);
  const json j = readJson(dir / kMapManifestName);
  EXPECT_EQ(j.at("format"), kMapFormatName);
  EXPECT_EQ(j.at("format_version"), kMapFormatVersion);
  EXPECT_EQ(j.at("creator"), "map_folder_test");
  EXPECT_TRUE(
      std::regex_match(j.at("created_utc").get<std::string>(), std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ)")))
      << j.dump();

  const MapManifest m = readMapManifest(dir);
  EXPECT_EQ(m.generation, 7u);
  ASSERT_EQ(m.files.size(), files.size());
  for (size_t i = 0; i < files.size(); ++i) {
    SCOPED_TRACE(files[i].name);
    EXPECT_EQ(m.files[i].name, files[i].name);
    EXPECT_EQ(m.files[i].role, files[i].role);
    EXPECT_EQ(m.files[i].size, files[i].size);
    EXPECT_EQ(m.files[i].crc, files[i].crc);
  }
  const MapFileEntry* image = m.findName("images/kf000003.000007.png");
  ASSERT_NE(image, nullptr);
  EXPECT_EQ(image->keyframe, 3);
  EXPECT_EQ(image->pixels_crc, 0x0badf00du);
  EXPECT_EQ(image->width * image->height * image->channels, 8);
  EXPECT_EQ(j.at("files")[4].at("pixels_crc32"), "0badf00d");
  EXPECT_EQ(m.find("points")->name, "points.000007.bin");
  EXPECT_EQ(m.find("nerf"), nullptr);

  EXPECT_EQ(readMapFile(dir, *m.find("keyframes")), std::string("kf\0bytes", 8));
  EXPECT_EQ(m.find("points")->crc, crc32(std::string("point bytes")));
  EXPECT_NO_THROW(verifyMapFile(dir, *m.find("points")));
  const MapFileEntry other = mapFileEntry(dir, "points.000007.bin", "points");
  EXPECT_EQ(other.size, m.find("points")->size);
  EXPECT_EQ(other.crc, m.find("points")->crc);
  // Same size, other bytes: both reads refuse it, naming the file and the checksum.
  test::writeText(dir / "points.000007.bin", "point bytez");
  for (const std::string& e : {test::errorOf([&] { readMapFile(dir, *m.find("points")); }),
                               test::errorOf([&] { verifyMapFile(dir, *m.find("points")); })}) {
    EXPECT_NE(e.find("points.000007.bin: field 'crc32'"), std::string::npos) << e;
    EXPECT_NE(e.find("corrupted"), std::string::npos) << e;
  }
}

TEST(MapFolder, ManifestReaderRefusesABadEntry) {
  test::TempDir tmp;
  const fs::path dir = tmp / "f";
  commitSmallFolder(dir, 1);
  const json good = readJson(dir / kMapManifestName);
  // Each edit of the manifest and the message it must give.
  const std::vector<std::pair<std::function<void(json&)>, std::string>> cases = {
      {[](json& j) { j["files"][1]["name"] = "../config.000001.yaml"; },
       "field 'files[1].name': '../config.000001.yaml' is not a file inside the map folder"},
      {[](json& j) { j["files"][1]["name"] = "/etc/passwd"; }, "field 'files[1].name': '/etc/passwd' is not a file"},
      {[](json& j) { j["files"][1]["name"] = ""; }, "field 'files[1].name': '' is not a file"},
      {[](json& j) { j["files"][2]["name"] = j["files"][0]["name"]; },
       "field 'files[2].name': 'camera.000001.yaml' listed twice"},
      {[](json& j) { j["files"][3]["role"] = "script"; }, "field 'files[3].role': unknown role 'script'"},
      {[](json& j) { j["files"][0]["crc32"] = "ABCDEF01"; },
       "field 'files[0].crc32': expected 8 lowercase hex digits, got 'ABCDEF01'"},
      {[](json& j) { j["files"][0]["size"] = "many"; }, "field 'files[0].size': unexpected value \"many\""},
      {[](json& j) { j["files"][4].erase("keyframe"); }, "field 'files[4].keyframe': missing"},
      {[](json& j) { j["files"][3]["role"] = "image"; }, "field 'files[3].keyframe': missing"},
      {[](json& j) { j["files"].erase(2); }, "field 'files': no keyframes file listed"},
      {[](json& j) { j["files"] = "all of them"; }, "field 'files': missing (a list of files)"},
      {[](json& j) { j.erase("generation"); }, "field 'generation': missing"},
  };
  for (const auto& [edit, expected] : cases) {
    json j = good;
    edit(j);
    test::writeText(dir / kMapManifestName, j.dump());
    const std::string e = test::errorOf([&] { readMapManifest(dir); });
    EXPECT_NE(e.find("map.json: " + expected), std::string::npos) << "expected '" << expected << "', got: " << e;
  }
  test::writeText(dir / kMapManifestName, good.dump());
  EXPECT_NO_THROW(readMapManifest(dir));
}

TEST(MapFolder, NextGenerationFollowsTheManifestOrTheFileNames) {
  test::TempDir tmp;
  const fs::path dir = tmp / "f";
  fs::create_directories(dir);
  MapGeneration next = nextMapGeneration(dir);
  EXPECT_EQ(next.number, 1u);
  EXPECT_FALSE(next.previous.has_value());
  commitSmallFolder(dir, 5);
  next = nextMapGeneration(dir);
  EXPECT_EQ(next.number, 6u);
  ASSERT_TRUE(next.previous.has_value());
  EXPECT_EQ(next.previous->generation, 5u);
  // An unreadable manifest: one after the largest generation in our file names.
  test::writeText(dir / "images" / "kf000001.000011.png", "stray");
  test::writeText(dir / kMapManifestName, "{ not json");
  next = nextMapGeneration(dir);
  EXPECT_EQ(next.number, 12u);
  EXPECT_FALSE(next.previous.has_value());
  // A map of another format version is never saved over.
  commitSmallFolder(dir, 5);
  json j = readJson(dir / kMapManifestName);
  j["format_version"] = kMapFormatVersion + 1;
  test::writeText(dir / kMapManifestName, j.dump());
  const std::string e = test::errorOf([&] { nextMapGeneration(dir); });
  EXPECT_NE(e.find("map.json: field 'format_version'"), std::string::npos) << e;
}

TEST(MapFolder, CommitRemovesOurUnreferencedFilesOnly) {
  test::TempDir tmp;
  const fs::path dir = tmp / "f";
  commitSmallFolder(dir, 1);
  // Leftovers of killed saves, and files that are not ours.
  const std::set<std::string> ours_stale = {"points.000001.tmp.123.4.bin", "map.tmp.99.1.json",
                                            "images/kf000002.000001.tmp.5.6.png", "nerf.000003.nerf"};
  const std::set<std::string> foreign = {"notes.txt", "points.bin", "images/holiday.png", "camera.yaml"};
  for (const auto& f : ours_stale) test::writeText(dir / f, "x");
  for (const auto& f : foreign) test::writeText(dir / f, "x");
  const std::vector<MapFileEntry> files = commitSmallFolder(dir, 2);
  std::set<std::string> expected = foreign;
  expected.insert(kMapManifestName);
  for (const MapFileEntry& f : files) expected.insert(f.name);
  EXPECT_EQ(folderFiles(dir), expected) << "generation 1's files and the leftovers are gone, the rest stays";
}

// ---- through the map store ----------------------------------------------------------------------

TEST(MapStore, RefusesAnotherFormatVersion) {
  SavedSmallMap s;
  json j = readJson(s.dir / "map.json");
  for (int v : {kMapFormatVersion - 1, kMapFormatVersion + 1}) {
    j["format_version"] = v;
    test::writeText(s.dir / "map.json", j.dump());
    const std::string e = test::errorOf([&] { loadMapFolder(s.dir, s.camera); });
    EXPECT_NE(e.find("map.json: field 'format_version'"), std::string::npos) << e;
    EXPECT_NE(e.find("format version " + std::to_string(v)), std::string::npos) << e;
    EXPECT_NE(e.find(v < kMapFormatVersion ? "older" : "newer"), std::string::npos) << e;
    // Nor is a map of another version overwritten by a save.
    const std::string es = test::errorOf([&] { saveMapFolder(s.dir, *s.map, s.camera, sparseOptions()); });
    EXPECT_NE(es.find("format_version"), std::string::npos) << es;
  }
  j["format"] = "something-else";
  j["format_version"] = kMapFormatVersion;
  test::writeText(s.dir / "map.json", j.dump());
  const std::string e = test::errorOf([&] { loadMapFolder(s.dir); });
  EXPECT_NE(e.find("map.json: field 'format'"), std::string::npos) << e;
}

TEST(MapStore, RefusesTruncatedAndCorruptedFiles) {
  for (const char* role : {"keyframes", "points", "image", "config", "camera"}) {
    SCOPED_TRACE(role);
    SavedSmallMap s;
    const std::string name = fileOfRole(s.dir, role);
    const fs::path p = s.dir / name;
    const auto size = fs::file_size(p);
    fs::resize_file(p, size / 2);
    std::string e = test::errorOf([&] { loadMapFolder(s.dir, s.camera); });
    EXPECT_NE(e.find(name + ": field 'size'"), std::string::npos) << e;
    EXPECT_NE(e.find("truncated"), std::string::npos) << e;
    // Same size, one byte changed.
    SavedSmallMap t;
    const fs::path q = t.dir / fileOfRole(t.dir, role);
    {
      std::fstream f(q, std::ios::in | std::ios::out | std::ios::binary);
      f.seekg(static_cast<std::streamoff>(fs::file_size(q) / 2));
      const char c = static_cast<char>(f.peek());
      f.seekp(static_cast<std::streamoff>(fs::file_size(q) / 2));
      f.put(static_cast<char>(c ^ 0x20));
    }
    e = test::errorOf([&] { loadMapFolder(t.dir, t.camera); });
    EXPECT_NE(e.find(fileOfRole(t.dir, role) + ": field 'crc32'"), std::string::npos) << e;
    EXPECT_NE(e.find("corrupted"), std::string::npos) << e;
  }
  // A truncated manifest.
  SavedSmallMap s;
  const auto size = fs::file_size(s.dir / "map.json");
  fs::resize_file(s.dir / "map.json", size - 20);
  const std::string e = test::errorOf([&] { loadMapFolder(s.dir); });
  EXPECT_NE(e.find("map.json: not valid JSON"), std::string::npos) << e;
}

TEST(MapStore, RefusesMissingFiles) {
  for (const char* role : {"keyframes", "points", "image", "config", "camera"}) {
    SCOPED_TRACE(role);
    SavedSmallMap s;
    const std::string name = fileOfRole(s.dir, role);
    fs::remove(s.dir / name);
    const std::string e = test::errorOf([&] { loadMapFolder(s.dir, s.camera); });
    EXPECT_NE(e.find(name + ": missing"), std::string::npos) << e;
  }
  SavedSmallMap s;
  fs::remove(s.dir / "map.json");
  std::string e = test::errorOf([&] { loadMapFolder(s.dir); });
  EXPECT_NE(e.find("map.json: missing"), std::string::npos) << e;
  EXPECT_NE(e.find("not a map folder"), std::string::npos) << e;
  e = test::errorOf([&] { loadMapFolder(s.tmp / "nowhere"); });
  EXPECT_NE(e.find("nowhere: map folder not found"), std::string::npos) << e;
  // A manifest entry missing a field.
  SavedSmallMap t;
  json j = readJson(t.dir / "map.json");
  j["files"][0].erase("crc32");
  test::writeText(t.dir / "map.json", j.dump());
  e = test::errorOf([&] { loadMapFolder(t.dir); });
  EXPECT_NE(e.find("map.json: field 'files[0].crc32': missing"), std::string::npos) << e;
}

// A save over a folder whose manifest is unreadable starts after the largest generation number in
// the file names. A stray name whose number does not fit 64 bits is not ours: it is ignored, not an
// escaped std::out_of_range (found by review after fuzz_trajectory's std::stoll finding).
TEST(MapStore, SaveOverAnUnreadableMapIgnoresNamesWithHugeNumbers) {
  SavedSmallMap s;
  test::writeText(s.dir / "map.json", "{ not json");
  test::writeText(s.dir / "points.123456789012345678901234567890.bin", "stray");
  test::writeText(s.dir / "points.000041.bin", "stray");
  saveMapFolder(s.dir, *s.map, s.camera, sparseOptions());
  const LoadedMap l = loadMapFolder(s.dir, s.camera);
  EXPECT_EQ(l.generation, 42u) << "one after the largest generation that fits";
  EXPECT_EQ(l.map->keyframeIds().size(), s.map->keyframeIds().size());
}

// ---- SIGKILL during saves -----------------------------------------------------------------------

constexpr const char* kSaveLoopEnv = "NERFSLAM_MAP_SAVE_LOOP";

// Child of MapStore.KillDuringSaveLeavesPreviousMapLoadable (skipped otherwise): loads SRC, then
// saves A, B, A, B, ... into DST until it is killed.
TEST(MapStoreKillHelper, SaveLoopChild) {
  const char* env = std::getenv(kSaveLoopEnv);
  if (!env) GTEST_SKIP() << "helper process of MapStore.KillDuringSaveLeavesPreviousMapLoadable";
  const std::string arg(env);
  const fs::path src = arg.substr(0, arg.find('|')), dst = arg.substr(arg.find('|') + 1);
  LoadedMap a = loadMapFolder(src);
  LoadedMap b = loadMapFolder(src);
  makeVariantB(*b.map);
  for (uint64_t i = 0;; ++i) saveMapFolder(dst, i % 2 ? *b.map : *a.map, a.camera, a.options);
}

TEST(MapStore, KillDuringSaveLeavesPreviousMapLoadable) {
  test::TempDir tmp;
  Camera cam;
  {
    const auto map = makeSmallMap(6, 320, 240, &cam);
    saveMapFolder(tmp / "src", *map, cam, sparseOptions());
  }
  LoadedMap a = loadMapFolder(tmp / "src");
  LoadedMap b = loadMapFolder(tmp / "src");
  makeVariantB(*b.map);
  const std::string fa = fingerprint(*a.map), fb = fingerprint(*b.map);
  ASSERT_NE(fa, fb);
  const fs::path dst = tmp / "dst";
  saveMapFolder(dst, *a.map, a.camera, a.options);

  // How long a child needs to start and finish one save (to aim the kills at its saves).
  const auto t0 = std::chrono::steady_clock::now();
  saveMapFolder(tmp / "timing", *b.map, a.camera, a.options);
  saveMapFolder(tmp / "timing", *a.map, a.camera, a.options);
  const double save_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / 2;

  const fs::path self = fs::read_symlink("/proc/self/exe");
  std::mt19937 rng(12345);
  // Startup + two loads take a few hundred ms; then saves follow each other every ~save_s.
  std::uniform_real_distribution<double> when(0.25, 0.6 + 6 * save_s);
  int kills = 0, interrupted_saves = 0, a_seen = 0, b_seen = 0;
  uint64_t last_generation = 0;
  const std::regex temp_or_newer(R"(\.tmp\.)");
  for (int it = 0; it < 60; ++it) {
    const double after = when(rng);
    const auto r = test::runCommand(fmt::format("{}='{}|{}' timeout -s KILL {:.3f} '{}' --gtest_filter={}",
                                                kSaveLoopEnv, (tmp / "src").string(), dst.string(), after,
                                                self.string(), "MapStoreKillHelper.SaveLoopChild"));
    ASSERT_EQ(r.exit_code, 128 + 9) << "the helper was expected to be killed after " << after << " s: " << r.output;
    ++kills;
    // Files the manifest does not name: a save was interrupted after writing some of them.
    const json manifest = readJson(dst / "map.json");
    std::set<std::string> named{"map.json"};
    for (const auto& f : manifest.at("files")) named.insert(f.at("name").get<std::string>());
    bool partial = false;
    for (const auto& f : folderFiles(dst)) partial = partial || !named.count(f);
    interrupted_saves += partial;

    LoadedMap l;
    ASSERT_NO_THROW(l = loadMapFolder(dst, cam)) << "after a kill at " << after << " s";
    const std::string fl = fingerprint(*l.map);
    ASSERT_TRUE(fl == fa || fl == fb) << "the loaded map is neither of the maps saved (kill at " << after << " s)";
    a_seen += fl == fa;
    b_seen += fl == fb;
    EXPECT_GE(l.generation, last_generation);
    last_generation = l.generation;
  }
  std::printf(
      "%d kills: %d interrupted a save mid-way (files not in the manifest), map A loaded %d times, B %d; "
      "generation %llu; one save %.0f ms\n",
      kills, interrupted_saves, a_seen, b_seen, static_cast<unsigned long long>(last_generation), 1000 * save_s);
  EXPECT_GE(kills, 50);
  EXPECT_GE(interrupted_saves, 10) << "too few kills landed inside a save";
  EXPECT_GT(a_seen, 0);
  EXPECT_GT(b_seen, 0);
  EXPECT_GT(last_generation, 20u);
  // The next complete save removes every leftover of the killed ones.
  saveMapFolder(dst, *a.map, a.camera, a.options);
  std::set<std::string> named{"map.json"};
  const json manifest = readJson(dst / "map.json");
  for (const auto& f : manifest.at("files")) named.insert(f.at("name").get<std::string>());
  EXPECT_EQ(folderFiles(dst), named);
}

// A save that runs out of space. The child process (the helper below) gets a file-size limit
// (RLIMIT_FSIZE via `ulimit -f`) with SIGXFSZ ignored, so a write past the limit fails with EFBIG
// as a full disk fails with ENOSPC: the save must fail with an error naming the file, and the map
// saved before must stay loadable and unchanged, with no temporary file left behind.
constexpr const char* kDiskFullEnv = "NERFSLAM_TEST_MAP_DISK_FULL";

TEST(MapStoreDiskFullHelper, SaveOnceChild) {
  const char* env = std::getenv(kDiskFullEnv);
  if (!env) GTEST_SKIP() << "helper process of MapStore.SaveIntoAFullDiskFailsAndKeepsThePreviousMap";
  std::signal(SIGXFSZ, SIG_IGN);
  const std::string arg(env);
  const fs::path src = arg.substr(0, arg.find('|')), dst = arg.substr(arg.find('|') + 1);
  LoadedMap b = loadMapFolder(src);
  makeVariantB(*b.map);
  try {
    saveMapFolder(dst, *b.map, b.camera, b.options);
  } catch (const Error& e) {
    std::printf("save failed: %s\n", e.what());
    std::fflush(stdout);
    std::_Exit(3);
  }
  std::printf("save succeeded\n");
  std::fflush(stdout);
  std::_Exit(0);
}

TEST(MapStore, SaveIntoAFullDiskFailsAndKeepsThePreviousMap) {
  test::TempDir tmp;
  Camera cam;
  {
    const auto map = makeSmallMap(6, 320, 240, &cam);
    saveMapFolder(tmp / "src", *map, cam, sparseOptions());
  }
  LoadedMap a = loadMapFolder(tmp / "src");
  const std::string fa = fingerprint(*a.map);
  const fs::path self = fs::read_symlink("/proc/self/exe");
  // Into an empty folder (every file new; measured: the first keyframe image fails) and over the
  // previous map (images reused; the keyframes file fails), at limits of 4 and 256 KiB.
  for (const bool over_previous : {false, true})
    for (const int kib : {4, 256}) {
      const fs::path dst = tmp / fmt::format("dst_{}_{}", int(over_previous), kib);
      if (over_previous) saveMapFolder(dst, *a.map, a.camera, a.options);
      auto filesIn = [](const fs::path& d) { return fs::exists(d) ? folderFiles(d) : std::set<std::string>{}; };
      const auto before = filesIn(dst);
      const auto r = test::runCommand(fmt::format("ulimit -f {}; {}='{}|{}' '{}' --gtest_filter={}", kib, kDiskFullEnv,
                                                  (tmp / "src").string(), dst.string(), self.string(),
                                                  "MapStoreDiskFullHelper.SaveOnceChild"));
      ASSERT_EQ(r.exit_code, 3) << "the save into a full disk did not fail with an Error (" << kib
                                << " KiB): " << r.output;
      const auto pos = r.output.find("save failed: ");
      ASSERT_NE(pos, std::string::npos) << r.output;
      const std::string message = r.output.substr(pos, r.output.find('\n', pos) - pos);
      std::printf("%s, %d KiB: %s\n", over_previous ? "over the previous map" : "new folder", kib, message.c_str());
      EXPECT_NE(message.find(dst.string()), std::string::npos) << "the error does not name the file: " << message;
      const auto after = filesIn(dst);
      if (over_previous) {
        // Nothing half-written is left: the folder holds what it held before.
        EXPECT_EQ(after, before) << message;
      } else {
        // No manifest (so no map that could load half of it) and no temporary file.
        EXPECT_EQ(after.count("map.json"), 0u) << message;
        for (const auto& f : after) EXPECT_EQ(f.find(".tmp"), std::string::npos) << f;
        EXPECT_THROW(loadMapFolder(dst, cam), Error);
      }
      if (over_previous) {
        LoadedMap l;
        ASSERT_NO_THROW(l = loadMapFolder(dst, cam));
        EXPECT_EQ(fingerprint(*l.map), fa);
      }
    }
}

}  // namespace
}  // namespace nerfslam
