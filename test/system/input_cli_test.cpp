// Outside input through the CLI (issue 22, docs/reliability.md "Outside input"): each case is one
// short `nerfslam` run and the error it must give.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/camera.h"
#include "test_support.h"

namespace nerfslam {
namespace {

namespace fs = std::filesystem;

// A folder dataset of `n` noise frames (320x240) with times.txt and camera.yaml.
fs::path makeFolderDataset(const fs::path& dir, int n) {
  fs::create_directories(dir);
  std::ofstream times(dir / "times.txt");
  for (int i = 0; i < n; ++i) {
    cv::imwrite((dir / fmt::format("{:06d}.png", i)).string(), test::noiseImage(320, 240, uint32_t(i + 1)));
    times << 0.1 * i << "\n";
  }
  saveCameraYaml(Camera::pinhole(320, 240, 300, 300, 159.5, 119.5), dir / "camera.yaml");
  return dir;
}

void expectRefused(const std::string& args, const std::string& message) {
  SCOPED_TRACE(args);
  const test::CommandResult r = test::runCli(args);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("error: " + message), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("bad_alloc"), std::string::npos) << r.output;
}

// A directory where a file is expected: "<path>: is a directory" from every subcommand, where
// `export --model DIR` printed "error: std::bad_alloc" (an ifstream opens a directory; seeking to its
// end made the model loader allocate 2^63 bytes).
TEST(InputCli, DirectoriesWhereFilesAreExpectedAreNamed) {
  test::TempDir tmp;
  const fs::path d = tmp / "d";
  fs::create_directories(d);
  const std::string D = d.string(), out = (tmp / "out").string();
  expectRefused("export --model " + D + " --format ply --out " + (tmp / "x.ply").string(),
                D + ": is a directory, not a NeRF model file");
  expectRefused("export --model " + D + " --format mesh --out " + (tmp / "x.ply").string(),
                D + ": is a directory, not a NeRF model file");
  expectRefused("render --model " + D + " --pose '0 0 0 0 0 0 1' --out " + out,
                D + ": is a directory, not a NeRF model file");
  expectRefused("render-preview --points " + D + " --out " + (tmp / "p.png").string(),
                D + ": is a directory, not a PLY file");
  expectRefused("render-preview --trajectory " + D + " --out " + (tmp / "p.png").string(),
                D + ": is a directory, not a trajectory file");
  expectRefused("render-preview --keyframes " + D + " --out " + (tmp / "p.png").string(),
                D + ": is a directory, not a trajectory file");
  expectRefused("eval --ref " + D + " --est " + D, D + ": is a directory, not a trajectory file");
  expectRefused("synth --camera " + D + " --frames 2 --out " + out, D + ": is a directory, not a YAML file");
  expectRefused("run --no-nerf --config " + D + " --out " + out, D + ": is a directory, not a YAML file");
}

// The same for the files a dataset names: its times.txt, camera.yaml, an image its index lists, its
// transforms.json (a folder dataset took a times.txt or camera.yaml directory for a missing file).
TEST(InputCli, DirectoriesWhereADatasetNamesAFileAreNamed) {
  test::TempDir tmp;
  const fs::path d = tmp / "d";
  fs::create_directories(d);
  const std::string D = d.string(), out = (tmp / "out").string();
  const fs::path seq = makeFolderDataset(tmp / "seq", 3);
  const std::string run = "run --no-nerf --dataset folder:" + seq.string() + " --out " + out;
  expectRefused(run + " --camera " + D, D + ": is a directory, not a YAML file");
  fs::rename(seq / "times.txt", tmp / "times.txt");
  fs::create_directory(seq / "times.txt");
  expectRefused(run, (seq / "times.txt").string() + ": is a directory");
  fs::remove(seq / "times.txt");
  fs::rename(tmp / "times.txt", seq / "times.txt");
  fs::rename(seq / "camera.yaml", tmp / "camera.yaml");
  fs::create_directory(seq / "camera.yaml");
  expectRefused(run, (seq / "camera.yaml").string() + ": is a directory, not a YAML file");
  fs::remove(seq / "camera.yaml");
  fs::rename(tmp / "camera.yaml", seq / "camera.yaml");

  // TUM: an image the index lists; transforms.json itself.
  const fs::path tum = tmp / "tum";
  fs::create_directories(tum / "rgb" / "2.png");
  cv::imwrite((tum / "rgb" / "1.png").string(), test::noiseImage(320, 240, 1));
  test::writeText(tum / "rgb.txt", "1.0 rgb/1.png\n2.0 rgb/2.png\n");
  fs::copy(seq / "camera.yaml", tum / "camera.yaml");
  expectRefused("run --no-nerf --dataset tum:" + tum.string() + " --out " + out,
                (tum / "rgb.txt").string() + ":2: image " + (tum / "rgb" / "2.png").string() +
                    " is a directory, not an image file");
  fs::create_directories(tmp / "nerf" / "transforms.json");
  expectRefused("train --transforms " + (tmp / "nerf").string() + " --steps 1 --out " + out,
                (tmp / "nerf" / "transforms.json").string() + ": is a directory, not a transforms.json file");
  EXPECT_FALSE(fs::exists(out + "/trajectory.txt"));
}

// What messages echo stays short (issue 22): a timestamp of 1e300 was printed with 301 digits, a
// long token of a trajectory or index file whole.
TEST(InputCli, MessagesCutLongValuesAndPrintHugeNumbersShort) {
  test::TempDir tmp;
  test::writeText(tmp / "ref.txt", "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n");
  test::writeText(tmp / "est.txt", "1e300 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n");
  const auto r = test::runCli("eval --ref " + (tmp / "ref.txt").string() + " --est " + (tmp / "est.txt").string());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("est.txt: pose 2 (timestamp 1.000000) is before pose 1 (1e+300): a trajectory must be in "
                          "time order"),
            std::string::npos)
      << r.output;
  test::writeText(tmp / "long.txt", std::string(1000000, '7') + "x 0 0 0 0 0 0 1\n");
  const auto l = test::runCli("eval --ref " + (tmp / "long.txt").string() + " --est " + (tmp / "est.txt").string());
  EXPECT_EQ(l.exit_code, 1);
  EXPECT_NE(l.output.find("long.txt:1: column 1: '" + std::string(77, '7') + "...' is not a number"), std::string::npos)
      << l.output.substr(0, 500);
  EXPECT_LT(l.output.size(), 1000u);

  const fs::path seq = makeFolderDataset(tmp / "seq", 3);
  test::writeText(seq / "times.txt", "1e300\n1\n2\n");
  const auto f = test::runCli("run --no-nerf --dataset folder:" + seq.string() + " --out " + (tmp / "out").string());
  EXPECT_EQ(f.exit_code, 1);
  EXPECT_NE(f.output.find("times.txt:2: timestamp 1.000000000 is not after the previous one (1e+300); timestamps "
                          "must increase"),
            std::string::npos)
      << f.output;
  fs::remove(seq / "times.txt");
  const auto n = test::runCli("run --no-nerf --dataset folder:" + seq.string() + " --out " + (tmp / "out").string());
  EXPECT_NE(n.output.find("error: " + seq.string() +
                          ": no times.txt or timestamps.txt in the folder; give the frame rate (--fps) or add "
                          "times.txt (one time in seconds per line, a line per image in the images' order)"),
            std::string::npos)
      << n.output;
}

// Counts a header declares are checked against the file before anything is allocated: a 1.3 KB PLY
// declaring 200 M vertices took 2.4 GB and 11 s in PCL's reader before it was refused, a 10 MB YAML
// list 2.45 GB in yaml-cpp.
TEST(InputCli, HeadersDeclaringMoreThanTheFileHoldsAreRefusedAtOnce) {
  test::TempDir tmp;
  std::string header = "ply\nformat binary_little_endian 1.0\n";
  for (int i = 0; i < 16; ++i)
    header += fmt::format("comment line {:02d} of a header padded to 1.3 KB ........................\n", i);
  header += "element vertex 200000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  test::writeText(tmp / "big.ply", header + std::string(120, '\0'));
  std::string ascii = header;
  ascii.replace(ascii.find("binary_little_endian"), 20, "ascii");
  test::writeText(tmp / "big_ascii.ply", ascii + "0 0 0\n0 1 0\n");
  const std::string png = (tmp / "p.png").string();
  expectRefused("render-preview --points " + (tmp / "big.ply").string() + " --out " + png,
                (tmp / "big.ply").string() +
                    ": the header declares 200000000 'vertex' elements of 12 bytes (2.40 GB), but 120 bytes follow it");
  expectRefused("render-preview --points " + (tmp / "big_ascii.ply").string() + " --out " + png,
                (tmp / "big_ascii.ply").string() +
                    ": the header declares 200000000 'vertex' elements of 3 properties (at least 1.20 GB in ASCII), "
                    "but 12 bytes follow it");
  EXPECT_FALSE(fs::exists(png));
  {
    std::ofstream yaml(tmp / "list.yaml");
    yaml << "tracking:\n  features:\n    fast_threshold: [";
    for (int i = 0; i < 3300000; ++i) yaml << "1, ";
    yaml << "1]\n";
  }
  expectRefused("run --no-nerf --config " + (tmp / "list.yaml").string() + " --out " + (tmp / "out").string(),
                (tmp / "list.yaml").string() + ": 9.90 MB, more than the 1.00 MB a YAML file may have");
}

// A corrupt JPEG frame mid-sequence (cut short and re-terminated with FF D9) was decoded by OpenCV
// with only libjpeg's raw warning on stderr, and tracked half grey. Now it is an unreadable frame:
// the run stops reading there with an error naming the file, writes what it has of the frames
// before, says why in the report and exits 1 (the policy for any frame that cannot be read,
// runner.cpp).
TEST(InputCli, CorruptJpegFrameStopsTheRunNamingTheFile) {
  NERFSLAM_REQUIRE_DATA(images, "strecha_fountain-P11/images");
  test::TempDir tmp;
  const fs::path seq = tmp / "seq";
  fs::create_directories(seq);
  std::ofstream times(seq / "times.txt");
  for (int i = 0; i < 4; ++i) {
    fs::copy_file(images / fmt::format("{:04d}.jpg", i), seq / fmt::format("{:04d}.jpg", i));
    times << i << "\n";
  }
  times.close();
  saveCameraYaml(Camera::pinhole(768, 512, 690, 690, 383.5, 255.5), seq / "camera.yaml");
  std::ifstream in(seq / "0002.jpg", std::ios::binary);
  const std::string jpg((std::istreambuf_iterator<char>(in)), {});
  in.close();
  test::writeText(seq / "0002.jpg", jpg.substr(0, jpg.size() / 2) + "\xff\xd9");
  const fs::path out = tmp / "out";
  const auto r = test::runCli("run --no-nerf --dataset folder:" + seq.string() + " --out " + out.string());
  EXPECT_EQ(r.exit_code, 1) << r.output;
  const std::string message =
      (seq / "0002.jpg").string() + ": corrupt JPEG image: Corrupt JPEG data: premature end of data segment";
  EXPECT_NE(r.output.find("[error] " + message), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("done: 2/4 frames tracked, 2 keyframes"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("\nCorrupt JPEG data"), std::string::npos) << "libjpeg's own warning:\n" << r.output;
  std::ifstream report(out / "report.json");
  const std::string rep((std::istreambuf_iterator<char>(report)), {});
  EXPECT_NE(rep.find("\"failure\": \"" + message + "\""), std::string::npos) << rep;
  EXPECT_NE(rep.find("\"frames_processed\": 2"), std::string::npos) << rep;
}

// Outputs written over inputs are refused before anything is written: `calibrate --out` onto one of
// its photos (it replaced the photo with the YAML), `run --out` (or --save-map) into a folder
// dataset's folder (its PNGs would become frames), or any dataset's own folder, `eval --json` onto
// the estimate or a KITTI timestamps file.
TEST(InputCli, OutputsOverInputsAreRefused) {
  test::TempDir tmp;
  const fs::path photos = tmp / "photos";
  fs::create_directories(photos);
  for (int i = 0; i < 2; ++i)
    cv::imwrite((photos / fmt::format("left{:02d}.png", i)).string(), test::noiseImage(64, 48, uint32_t(i + 1)));
  const auto before = fs::file_size(photos / "left01.png");
  expectRefused("calibrate --images " + photos.string() + " --board 9x6 --square 0.025 --out " +
                    (tmp / "photos" / ".." / "photos" / "left01.png").string(),
                "calibrate: --out " + (tmp / "photos" / ".." / "photos" / "left01.png").string() +
                    " is one of the photos in --images; choose another output file");
  EXPECT_EQ(fs::file_size(photos / "left01.png"), before);

  const fs::path seq = makeFolderDataset(tmp / "seq", 3);
  auto listing = [](const fs::path& d) {
    std::vector<std::string> names;
    for (const auto& e : fs::recursive_directory_iterator(d)) names.push_back(e.path().string());
    std::sort(names.begin(), names.end());
    return names;
  };
  const auto files = listing(seq);
  const std::string run = "run --no-nerf --dataset folder:" + seq.string();
  expectRefused(run + " --out " + seq.string(),
                "run: --out " + seq.string() + " is inside the folder dataset " + seq.string() +
                    ", whose frames are every image in it; choose an output folder outside it");
  expectRefused(run + " --out " + (seq / "results").string(),
                "run: --out " + (seq / "results").string() + " is inside the folder dataset");
  expectRefused(run + " --out " + (tmp / "out").string() + " --save-map " + (seq / "map").string(),
                "run: --save-map " + (seq / "map").string() + " is inside the folder dataset");
  EXPECT_EQ(listing(seq), files);
  EXPECT_FALSE(fs::exists(tmp / "out"));

  const fs::path est = tmp / "est.txt", times = tmp / "times.txt";
  test::writeText(est, "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n");
  test::writeText(times, "0\n1\n");
  test::writeText(tmp / "kitti.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n");
  expectRefused("eval --ref " + est.string() + " --est " + est.string() + " --json " + est.string(),
                "eval: --json " + est.string() + " is one of the inputs; choose another output file");
  expectRefused("eval --format kitti --ref " + (tmp / "kitti.txt").string() + " --est " + (tmp / "kitti.txt").string() +
                    " --ref-times " + times.string() + " --json " + times.string(),
                "eval: --json " + times.string() + " is one of the inputs");
  EXPECT_EQ(fs::file_size(times), 4u);
}

}  // namespace
}  // namespace nerfslam
