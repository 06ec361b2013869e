// `nerfslam export` writing onto a full disk (issue 22): PCL's PLY and PCD writers did not check
// their writes, so a full disk left a cut-off file behind a successful exit.
#include <gtest/gtest.h>

#include <pcl/PolygonMesh.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <fmt/format.h>

#include "nerfslam/nerf/model_io.h"
#include "test_support.h"

namespace nerfslam {
namespace {

namespace fs = std::filesystem;

// A small model with random parameters (a density that varies in space, above and below the export
// threshold) in a 20^3-cell block of its occupancy grid: export writes clouds and a mesh of a few
// hundred KB.
nerf::NerfModel blockModel() {
  nerf::FieldConfig c;
  c.n_levels = 8;
  c.log2_hashmap_size = 14;
  c.finest_resolution = 256;
  c.hidden = 16;
  nerf::SceneTransform scene;
  nerf::NerfModel m = nerf::NerfModel::create(c, scene, 3);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (auto& a : m.field->parameters())
    for (size_t i = 0; i < a.size; ++i) a.data[i] = u(rng);
  m.field->parametersChanged();
  const int R = nerf::OccupancyGrid::kRes;
  std::vector<float> values(m.grid->values().size(), 0.f);
  for (int z = 50; z < 70; ++z)
    for (int y = 50; y < 70; ++y)
      for (int x = 50; x < 70; ++x) values[size_t(x) + size_t(R) * (size_t(y) + size_t(R) * size_t(z))] = 1.f;
  m.grid->setValues(values, 0.01f);
  return m;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// Each format, into a folder where the file is new (PLY, mesh) and over a previous export, in a child process
// under a 64 KiB file-size limit (`ulimit -f`, SIGXFSZ ignored: a write past it fails with EFBIG as
// a full disk fails with ENOSPC): exit 1 with "<file>: write failed (disk full?)", the previous
// file unchanged, no new or temporary file. Without the limit the same export writes a file PCL
// loads back.
TEST(ExportCli, FullDiskFailsNamingTheFileAndLeavesNoCutOffFile) {
  test::TempDir tmp;
  nerf::NerfModel model = blockModel();
  nerf::saveModel(model, tmp / "model.nerf");
  for (const std::string format : {"ply", "mesh", "pcd"}) {
    SCOPED_TRACE(format);
    const std::string ext = format == "pcd" ? ".pcd" : ".ply";
    const fs::path good = tmp / ("good" + ext);
    const auto ok = test::runCli(
        fmt::format("export --model {} --format {} --out {}", (tmp / "model.nerf").string(), format, good.string()));
    ASSERT_EQ(ok.exit_code, 0) << ok.output;
    if (format == "mesh") {
      pcl::PolygonMesh mesh;
      ASSERT_EQ(pcl::io::loadPLYFile(good.string(), mesh), 0);
      EXPECT_GT(mesh.polygons.size(), 1000u);
    } else {
      pcl::PointCloud<pcl::PointXYZRGB> cloud;
      ASSERT_EQ(ext == ".pcd" ? pcl::io::loadPCDFile(good.string(), cloud) : pcl::io::loadPLYFile(good.string(), cloud),
                0);
      EXPECT_GT(cloud.size(), 10000u);
    }
    ASSERT_GT(fs::file_size(good), 200u * 1024);

    for (const bool previous : {false, true}) {
      if (format == "pcd" && !previous) continue;  // the same writer as for PLY (keeps the test short)
      const fs::path dir = tmp / fmt::format("full_{}_{}", format, int(previous));
      fs::create_directories(dir);
      const fs::path out = dir / ("x" + ext);
      if (previous) test::writeText(out, "the previous export\n");
      const auto r =
          test::runCommand(fmt::format("trap '' XFSZ; ulimit -f 64; '{}' export --model {} --format {} --out {}",
                                       test::cliPath().string(), (tmp / "model.nerf").string(), format, out.string()));
      EXPECT_EQ(r.exit_code, 1) << r.output;
      EXPECT_NE(r.output.find("error: " + out.string() + ": write failed (disk full?)"), std::string::npos) << r.output;
      std::vector<std::string> left;
      for (const auto& e : fs::directory_iterator(dir)) left.push_back(e.path().filename().string());
      if (previous) {
        EXPECT_EQ(left, std::vector<std::string>{out.filename().string()});
        EXPECT_EQ(slurp(out), "the previous export\n");
      } else {
        EXPECT_TRUE(left.empty()) << left.front();
      }
    }
  }
}

// `export --format octomap|grid` (issue 25): the bad inputs are refused with the figure or field at
// fault and leave no file; a good export writes an OctoMap file liboctomap reads and a map_server pair.
TEST(ExportCli, OccupancyBadInputIsRefusedWithoutAFile) {
  test::TempDir tmp;
  nerf::NerfModel model = blockModel();
  nerf::saveModel(model, tmp / "untrained.nerf");
  model.training_steps = 100;
  nerf::saveModel(model, tmp / "model.nerf");
  // Two cameras 2 m in front of the block (world z in [-0.33, 0.15]) looking at it along +z.
  test::writeText(tmp / "camera.yaml", "model: pinhole\nwidth: 64\nheight: 48\nfx: 40\nfy: 40\ncx: 31.5\ncy: 23.5\n");
  test::writeText(tmp / "keyframes.txt", "0 -0.1 -0.1 -2 0 0 0 1\n1 0.1 -0.1 -2 0 0 0 1\n");
  const std::string views =
      fmt::format("--keyframes {} --camera {}", (tmp / "keyframes.txt").string(), (tmp / "camera.yaml").string());
  auto run = [&](const std::string& model_file, const std::string& rest) {
    return test::runCli(fmt::format("export --model {} {} {}", (tmp / model_file).string(), views, rest));
  };
  auto refused = [&](const test::CommandResult& r, const std::string& what) {
    EXPECT_NE(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find(what), std::string::npos) << r.output;
  };
  const std::string bt = (tmp / "map.bt").string(), grid = (tmp / "map.yaml").string();
  refused(run("untrained.nerf", "--format octomap --out " + bt), "an empty model");
  refused(run("model.nerf", "--format octomap --resolution 0 --out " + bt), "--resolution: must be > 0");
  refused(run("model.nerf", "--format octomap --resolution -1 --out " + bt), "--resolution");
  refused(run("model.nerf", "--format octomap --resolution 0.00001 --max-memory-mb 100 --out " + bt),
          "more than the 100 MB allowed");
  refused(run("model.nerf", "--format grid --height-band 1,0.5 --out " + grid), "lo must be < hi");
  refused(run("model.nerf", "--format grid --height-band 0.5 --out " + grid), "expected 2");
  refused(run("model.nerf", "--format octomap --out " + (tmp / "missing" / "map.bt").string()), "does not exist");
  refused(run("model.nerf", "--format grid --out " + bt), "NAME.yaml");
  refused(test::runCli(fmt::format("export --model {} --format octomap --out {}", (tmp / "model.nerf").string(), bt)),
          "needs --keyframes and --camera");
  EXPECT_FALSE(fs::exists(tmp / "map.bt"));
  EXPECT_FALSE(fs::exists(tmp / "map.yaml"));
  EXPECT_FALSE(fs::exists(tmp / "map.pgm"));
  EXPECT_FALSE(fs::exists(tmp / "missing"));
  // The good exports.
  const auto ok = run("model.nerf", "--format octomap --resolution 0.04 --out " + bt);
  ASSERT_EQ(ok.exit_code, 0) << ok.output;
  EXPECT_TRUE(fs::exists(tmp / "map.meta.yaml"));
  const std::string head = slurp(tmp / "map.bt").substr(0, 40);
  EXPECT_EQ(head.rfind("# Octomap OcTree binary file", 0), 0u) << head;
  const auto g =
      run("model.nerf", "--format grid --resolution 0.04 --floor 0,1,0,0.4 --height-band 0.05,0.6 --out " + grid);
  ASSERT_EQ(g.exit_code, 0) << g.output;
  EXPECT_TRUE(fs::exists(tmp / "map.pgm"));
  EXPECT_NE(slurp(tmp / "map.yaml").find("resolution: 0.04"), std::string::npos);
}

}  // namespace
}  // namespace nerfslam
