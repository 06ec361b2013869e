// io/ply_header.h: the header of an outside PLY file checked against the file's size before a
// reader allocates what it declares.
#include "nerfslam/io/ply_header.h"

#include <gtest/gtest.h>
#include <pcl/PolygonMesh.h>
#include <pcl/conversions.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>

#include <string>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {

namespace fs = std::filesystem;

pcl::PointCloud<pcl::PointXYZRGB> smallCloud() {
  pcl::PointCloud<pcl::PointXYZRGB> c;
  for (int i = 0; i < 100; ++i) {
    pcl::PointXYZRGB p;
    p.x = float(i);
    p.y = 1;
    p.z = 2;
    p.r = uint8_t(i);
    c.push_back(p);
  }
  return c;
}

// What PCL writes (binary and ASCII clouds, a binary mesh with a face list), the sparse map's
// ASCII PLY and a big-endian file pass, with their elements read.
TEST(PlyHeader, AcceptsTheFilesPclAndNerfslamWrite) {
  test::TempDir tmp;
  const auto cloud = smallCloud();
  ASSERT_EQ(pcl::io::savePLYFileBinary((tmp / "b.ply").string(), cloud), 0);
  ASSERT_EQ(pcl::io::savePLYFileASCII((tmp / "a.ply").string(), cloud), 0);
  for (const char* f : {"a.ply", "b.ply"}) {
    const PlyHeader h = checkPlyFile(tmp / f);
    ASSERT_FALSE(h.elements.empty()) << f;
    EXPECT_EQ(h.elements[0].name, "vertex");
    EXPECT_EQ(h.elements[0].count, 100u);
  }
  pcl::PolygonMesh mesh;
  pcl::toPCLPointCloud2(cloud, mesh.cloud);
  for (int i = 0; i + 2 < 100; ++i) {  // pcl::index_t is int
    pcl::Vertices v;
    v.vertices = {i, i + 1, i + 2};
    mesh.polygons.push_back(v);
  }
  ASSERT_EQ(pcl::io::savePLYFileBinary((tmp / "m.ply").string(), mesh), 0);
  const PlyHeader m = checkPlyFile(tmp / "m.ply");
  EXPECT_EQ(m.format, "binary_little_endian");
  ASSERT_GE(m.elements.size(), 2u);
  EXPECT_EQ(m.elements[1].name, "face");
  EXPECT_EQ(m.elements[1].count, 98u);
  EXPECT_FALSE(m.elements[1].fixed_size);
  test::writeText(tmp / "map.ply",
                  "ply\nformat ascii 1.0\ncomment nerfslam sparse map (world frame, map units)\nelement vertex 2\n"
                  "property double x\nproperty double y\nproperty double z\nproperty int observations\nend_header\n"
                  "1 2 3 4\n5 6 7 8\n");
  EXPECT_EQ(checkPlyFile(tmp / "map.ply").elements[0].properties, 4);
  test::writeText(tmp / "be.ply",
                  "ply\r\nformat binary_big_endian 1.0\r\nelement vertex 1\r\nproperty short x\r\n"
                  "end_header\r\n\x01\x02");
  EXPECT_EQ(checkPlyFile(tmp / "be.ply").header_bytes, 83u);
}

// Counts beyond what follows the header (binary: count x the element's size, lists counted empty;
// ASCII: 2 bytes a property), a count that would overflow, malformed headers, a directory.
TEST(PlyHeader, RefusesCountsTheFileCannotHoldAndMalformedHeaders) {
  test::TempDir tmp;
  const auto err = [&](const std::string& name, const std::string& content) {
    test::writeText(tmp / name, content);
    return test::errorOf([&] { checkPlyFile(tmp / name); });
  };
  const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
  const std::string bin = "ply\nformat binary_little_endian 1.0\n";
  EXPECT_EQ(err("v.ply", bin + "element vertex 11\n" + xyz + "end_header\n" + std::string(120, 'x')),
            (tmp / "v.ply").string() +
                ": the header declares 11 'vertex' elements of 12 bytes (132 bytes), but 120 bytes follow it");
  EXPECT_EQ(err("ok.ply", bin + "element vertex 10\n" + xyz + "end_header\n" + std::string(120, 'x')), "");
  // The second element gets what the first leaves.
  EXPECT_EQ(
      err("f.ply", bin + "element vertex 10\n" + xyz + "element face 2\nproperty list uchar int vertex_indices\n" +
                       "end_header\n" + std::string(121, 'x')),
      (tmp / "f.ply").string() +
          ": the header declares 2 'face' elements of at least 1 bytes (2 bytes), but 1 bytes follow it");
  EXPECT_NE(err("huge.ply", bin + "element vertex 18446744073709551615\n" + xyz + "end_header\n")
                .find("declares 18446744073709551615 'vertex' elements of 12 bytes (over 18 EB)"),
            std::string::npos);
  EXPECT_EQ(err("a.ply", "ply\nformat ascii 1.0\nelement vertex 3\n" + xyz + "end_header\n1 2 3\n4 5 6\n"),
            (tmp / "a.ply").string() +
                ": the header declares 3 'vertex' elements of 3 properties (at least 18 bytes in ASCII), but 12 "
                "bytes follow it");
  EXPECT_EQ(err("a2.ply", "ply\nformat ascii 1.0\nelement vertex 2\n" + xyz + "end_header\n1 2 3\n4 5 6"), "");
  EXPECT_EQ(err("text.ply", "solid cube\nfacet normal 0 0 1\n"),
            (tmp / "text.ply").string() + ": not a PLY file (it does not start with a \"ply\" line)");
  EXPECT_EQ(err("end.ply", "ply\nformat ascii 1.0\nelement vertex 1\n" + std::string(70000, '#')),
            (tmp / "end.ply").string() + ": PLY header without \"end_header\" in its first 65.5 KB");
  EXPECT_EQ(err("fmt.ply", "ply\nformat binary_middle_endian 1.0\nend_header\n"),
            (tmp / "fmt.ply").string() +
                ": PLY header line 2: unknown format (ascii, binary_little_endian or binary_big_endian expected) "
                "('format binary_middle_endian 1.0')");
  EXPECT_EQ(err("type.ply", bin + "element vertex 1\nproperty float128 x\nend_header\n"),
            (tmp / "type.ply").string() +
                ": PLY header line 4: expected \"property TYPE NAME\" with a PLY type ('property float128 x')");
  EXPECT_EQ(err("count.ply", bin + "element vertex -5\nend_header\n"),
            (tmp / "count.ply").string() +
                ": PLY header line 3: expected \"element NAME COUNT\" with a whole COUNT ('element vertex -5')");
  EXPECT_EQ(err("nofmt.ply", "ply\nelement vertex 0\nend_header\n"),
            (tmp / "nofmt.ply").string() + ": PLY header without a \"format\" line");
  fs::create_directory(tmp / "dir.ply");
  EXPECT_EQ(test::errorOf([&] { checkPlyFile(tmp / "dir.ply"); }),
            (tmp / "dir.ply").string() + ": is a directory, not a PLY file");
}

}  // namespace
}  // namespace nerfslam
