// The map_server pair (nav_grid.h): written, read back as map_server reads it, and refused when bad.
#include "nerfslam/io/nav_grid.h"

#include <filesystem>
#include <fstream>
#include <iterator>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

NavGrid sampleGrid() {
  NavGrid g;
  g.width = 7;
  g.height = 5;
  g.resolution = 0.05;
  g.origin_x = -1.25;
  g.origin_y = 0.5;
  g.cells.assign(35, NavGrid::kUnknown);
  for (int x = 0; x < 7; ++x) g.at(x, 0) = NavGrid::kOccupied;  // the bottom row (lowest y)
  g.at(3, 2) = NavGrid::kFree;
  g.at(4, 2) = NavGrid::kFree;
  g.at(6, 4) = NavGrid::kOccupied;  // the top-right corner
  return g;
}

TEST(NavGrid, MapServerPairRoundTripsWithOriginResolutionAndThresholds) {
  const test::TempDir tmp;
  const fs::path dir = tmp.path();
  const NavGrid g = sampleGrid();
  saveMapServer(g, dir / "map.yaml");
  ASSERT_TRUE(fs::exists(dir / "map.pgm"));
  // The YAML has exactly what map_server reads.
  const YAML::Node y = YAML::LoadFile((dir / "map.yaml").string());
  EXPECT_EQ(y["image"].as<std::string>(), "map.pgm");
  EXPECT_DOUBLE_EQ(y["resolution"].as<double>(), 0.05);
  ASSERT_EQ(y["origin"].size(), 3u);
  EXPECT_DOUBLE_EQ(y["origin"][0].as<double>(), -1.25);
  EXPECT_DOUBLE_EQ(y["origin"][1].as<double>(), 0.5);
  EXPECT_DOUBLE_EQ(y["origin"][2].as<double>(), 0.0);
  EXPECT_EQ(y["negate"].as<int>(), 0);
  EXPECT_DOUBLE_EQ(y["occupied_thresh"].as<double>(), 0.65);
  EXPECT_DOUBLE_EQ(y["free_thresh"].as<double>(), 0.196);
  // The image: top row first (the highest y), occupied 0, free 254, unknown 205.
  std::ifstream in(dir / "map.pgm", std::ios::binary);
  std::string magic;
  int w = 0, h = 0, maxval = 0;
  in >> magic;
  in.ignore(1);
  std::string comment;
  std::getline(in, comment);
  in >> w >> h >> maxval;
  in.ignore(1);
  EXPECT_EQ(magic, "P5");
  EXPECT_EQ(w, 7);
  EXPECT_EQ(h, 5);
  EXPECT_EQ(maxval, 255);
  std::string px(35, '\0');
  in.read(px.data(), 35);
  EXPECT_EQ(static_cast<unsigned char>(px[6]), 0);            // row 0 = y 4, x 6: occupied
  EXPECT_EQ(static_cast<unsigned char>(px[4 * 7 + 0]), 0);    // last row = y 0: occupied
  EXPECT_EQ(static_cast<unsigned char>(px[2 * 7 + 3]), 254);  // y 2: free
  EXPECT_EQ(static_cast<unsigned char>(px[0]), 205);          // unknown
  const NavGrid r = loadMapServer(dir / "map.yaml");
  EXPECT_EQ(r.width, g.width);
  EXPECT_EQ(r.height, g.height);
  EXPECT_DOUBLE_EQ(r.resolution, g.resolution);
  EXPECT_DOUBLE_EQ(r.origin_x, g.origin_x);
  EXPECT_DOUBLE_EQ(r.origin_y, g.origin_y);
  EXPECT_EQ(r.cells, g.cells);
}

TEST(NavGrid, BadPairsAreRefusedNamingTheField) {
  const test::TempDir tmp;
  const fs::path dir = tmp.path();
  saveMapServer(sampleGrid(), dir / "map.yaml");
  auto expectError = [&](const std::string& yaml, const std::string& what) {
    test::writeText(dir / "bad.yaml", yaml);
    try {
      loadMapServer(dir / "bad.yaml");
      ADD_FAILURE() << "accepted: " << yaml;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  expectError("image: map.pgm\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
              "'resolution' is missing");
  expectError("image: map.pgm\nresolution: -1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
              "'resolution' must be > 0");
  expectError("image: map.pgm\nresolution: 0.05\norigin: [0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
              "'origin'");
  expectError(
      "image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.1\nfree_thresh: 0.2\n",
      "free_thresh");
  expectError(
      "image: nope.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
      "not found");
  // A cut-off image.
  std::ifstream pin(dir / "map.pgm", std::ios::binary);
  const std::string pgm((std::istreambuf_iterator<char>(pin)), std::istreambuf_iterator<char>());
  test::writeText(dir / "cut.pgm", pgm.substr(0, pgm.size() - 3));
  expectError(
      "image: cut.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n",
      "truncated");
  // Writing: a bad grid or an unwritable place leaves nothing behind.
  NavGrid empty;
  EXPECT_THROW(saveMapServer(empty, dir / "e.yaml"), Error);
  EXPECT_FALSE(fs::exists(dir / "e.pgm"));
  EXPECT_THROW(saveMapServer(sampleGrid(), dir / "missing_dir" / "m.yaml"), Error);
  EXPECT_FALSE(fs::exists(dir / "missing_dir"));
}

}  // namespace
}  // namespace nerfslam
