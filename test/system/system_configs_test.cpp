// The run configurations shipped in config/system/ load with the loader `nerfslam run --config` uses
// (loadOptionsFile + validateOptions into SystemOptions), so a renamed or removed option, or a value
// out of range, breaks this test rather than the README's commands.
#include <algorithm>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/mapping/odometry.h"
#include "nerfslam/render/synth.h"
#include "nerfslam/system/slam_system.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

std::vector<fs::path> systemConfigs() {
  std::vector<fs::path> out;
  const fs::path dir = test::sourceDir() / "config" / "system";
  if (fs::is_directory(dir))
    for (const auto& e : fs::directory_iterator(dir))
      if (e.path().extension() == ".yaml") out.push_back(e.path());
  std::sort(out.begin(), out.end());
  return out;
}

std::string readText(const fs::path& path) {
  std::ifstream is(path);
  std::stringstream ss;
  ss << is.rdbuf();
  return ss.str();
}

SystemOptions loadRunConfig(const fs::path& path) {
  SystemOptions o;
  loadOptionsFile(path, o);
  validateOptions(o, path.string());
  return o;
}

TEST(SystemConfigs, EveryShippedConfigLoadsAndValidates) {
  const auto configs = systemConfigs();
  // The README's commands name these; more may be added.
  for (const char* name :
       {"kitti.yaml", "video.yaml", "photos.yaml", "synthetic.yaml", "tum.yaml", "euroc.yaml", "long_run.yaml"})
    EXPECT_TRUE(std::any_of(configs.begin(), configs.end(), [&](const fs::path& p) { return p.filename() == name; }))
        << "config/system/" << name << " is missing";
  for (const auto& path : configs) {
    SCOPED_TRACE(path.string());
    EXPECT_NO_THROW(loadRunConfig(path));
    // A configuration sets options: not an empty file or a bare comment.
    const YAML::Node root = YAML::LoadFile(path.string());
    EXPECT_TRUE(root.IsMap() && root.size() > 0);
  }
}

// Each option set in a shipped file carries a comment saying why (on its line or the lines above it,
// or for a section's first option, above the section).
TEST(SystemConfigs, EveryOptionIsCommented) {
  const std::regex option_line(R"(^(\s*)([A-Za-z_][A-Za-z0-9_]*):\s*([^#\s][^#]*)?(#.*)?$)");
  for (const auto& path : systemConfigs()) {
    std::istringstream is(readText(path));
    std::string line;
    bool comment_above = false;  // a comment since the last option line
    int lineno = 0;
    while (std::getline(is, line)) {
      ++lineno;
      const auto first = line.find_first_not_of(' ');
      if (first == std::string::npos) continue;
      if (line[first] == '#') {
        comment_above = true;
        continue;
      }
      std::smatch m;
      ASSERT_TRUE(std::regex_match(line, m, option_line)) << path << ":" << lineno << ": not a `key: value` line";
      const bool section = !m[3].matched;
      if (section) continue;  // the comment above a section counts for its first option
      EXPECT_TRUE(comment_above || m[4].matched)
          << path << ":" << lineno << ": option '" << m[2] << "' has no comment saying why";
      comment_above = false;
    }
  }
}

// The values the README's figures depend on.
TEST(SystemConfigs, PhotoSetAndLongRunSettings) {
  const fs::path dir = test::sourceDir() / "config" / "system";
  const SystemOptions defaults;
  const SystemOptions photos = loadRunConfig(dir / "photos.yaml");
  EXPECT_EQ(photos.tracking.initializer.max_tracks, 0);  // every corner tracked to initialise
  EXPECT_EQ(photos.nerf.holdout_every, 5);               // views held out of the NeRF to score it
  const SystemOptions long_run = loadRunConfig(dir / "long_run.yaml");
  EXPECT_DOUBLE_EQ(long_run.mapping.redundant_ratio, 0.8);
  EXPECT_NE(long_run.mapping.redundant_ratio, defaults.mapping.redundant_ratio);
  // Driving: the final NeRF training in larger steps and a learned sky (docs/benchmarks.md, KITTI 06
  // and New Tsukuba).
  SystemOptions kitti = loadRunConfig(dir / "kitti.yaml");
  EXPECT_EQ(kitti.nerf.final_samples_per_step, 1 << 16);
  EXPECT_NE(kitti.nerf.final_samples_per_step, defaults.nerf.final_samples_per_step);
  EXPECT_TRUE(kitti.nerf.train.learned_background);
  EXPECT_FALSE(defaults.nerf.train.learned_background);
  kitti.nerf.final_samples_per_step = defaults.nerf.final_samples_per_step;
  kitti.nerf.train.learned_background = defaults.nerf.train.learned_background;
  EXPECT_EQ(printOptions(kitti), printOptions(defaults)) << "kitti.yaml sets nothing else";
  // The files that write the defaults out (their figures are the defaults' figures) set nothing else.
  for (const char* name : {"video.yaml", "synthetic.yaml", "tum.yaml", "euroc.yaml"}) {
    SCOPED_TRACE(name);
    SystemOptions o = loadRunConfig(dir / name);
    if (std::string(name) == "synthetic.yaml") {
      // And the extrinsic of synth's odometry (used only with run --odometry).
      EXPECT_TRUE(
          rigidTransformFromRowMajor(o.odometry.T_base_cam).isApprox(SynthOdometry::defaultBaseToCamera(), 1e-12));
      o.odometry.T_base_cam = defaults.odometry.T_base_cam;
    }
    EXPECT_EQ(printOptions(o), printOptions(defaults));
  }
}

// A renamed option is an error naming the file and the key, as `run --config` reports it.
TEST(SystemConfigs, ARenamedOptionIsAnError) {
  test::TempDir tmp;
  std::string text = readText(test::sourceDir() / "config" / "system" / "photos.yaml");
  const size_t at = text.find("max_tracks:");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, std::string("max_tracks").size(), "max_track");
  test::writeText(tmp / "renamed.yaml", text);
  const std::string e = test::errorOf([&] { loadRunConfig(tmp / "renamed.yaml"); });
  EXPECT_NE(e.find("renamed.yaml"), std::string::npos) << e;
  EXPECT_NE(e.find("tracking.initializer.max_track"), std::string::npos) << e;
  EXPECT_NE(e.find("did you mean 'max_tracks'"), std::string::npos) << e;
}

}  // namespace
}  // namespace nerfslam
