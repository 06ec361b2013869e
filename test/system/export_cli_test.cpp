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

}  // namespace
}  // namespace nerfslam
