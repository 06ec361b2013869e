// libFuzzer target for the dataset readers (io/dataset.h openDataset), one executable per kind:
// fuzz_dataset_<kind> is this file built with NERFSLAM_FUZZ_KIND="<kind>".
//
// At start-up the target builds a dataset folder of its kind in a scratch directory: the image
// files the real shared-data sequence lists, with the real names and sizes but flat contents (cheap
// to decode). Each input is split into sections (fuzz_common.h) that become the kind's index and
// calibration files, so the real index files of /work/shared/data are valid seeds.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "fuzz_common.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/image_io.h"

#ifndef NERFSLAM_FUZZ_KIND
#error "define NERFSLAM_FUZZ_KIND"
#endif

namespace {

namespace fs = std::filesystem;
using namespace nerfslam;

struct Layout {
  fs::path root;
  std::vector<std::string> files;  // section k -> root / files[k]
};

bool isJpeg(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  unsigned char b[2] = {0, 0};
  f.read(reinterpret_cast<char*>(b), 2);
  return b[0] == 0xFF && b[1] == 0xD8;
}

void writeImage(const fs::path& path, int width, int height, int type, bool jpeg) {
  cv::Mat img(height, width, type, cv::Scalar::all(128));
  std::vector<uchar> buf;
  if (!cv::imencode(jpeg ? ".jpg" : ".png", img, buf)) {
    std::fprintf(stderr, "fuzz harness: cannot encode %s\n", path.c_str());
    std::abort();
  }
  fuzz::writeBytes(path, std::string_view(reinterpret_cast<const char*>(buf.data()), buf.size()));
}

// Flat copies (same names, size, channels and codec as the first real image) of the images in
// `src` into `dst`. Returns the file names in natural order.
std::vector<std::string> mirrorImages(const fs::path& src, const fs::path& dst) {
  std::vector<std::string> names;
  std::error_code ec;
  if (!fs::is_directory(src, ec)) {
    std::fprintf(stderr,
                 "fuzz harness: %s not found (set NERFSLAM_DATA_DIR); the dataset folder has no images, so the "
                 "fuzzer only reaches the early index checks\n",
                 src.c_str());
    return names;
  }
  for (const auto& p : listImages(src)) names.push_back(p.filename().string());
  if (names.empty()) return names;
  const cv::Mat first = cv::imread((src / names[0]).string(), cv::IMREAD_UNCHANGED);
  if (first.empty()) {
    std::fprintf(stderr, "fuzz harness: cannot decode %s\n", (src / names[0]).c_str());
    std::abort();
  }
  const int type = CV_MAKETYPE(CV_8U, first.channels());
  const bool jpeg = isJpeg(src / names[0]);
  for (const auto& n : names) writeImage(dst / n, first.cols, first.rows, type, jpeg);
  return names;
}

Layout makeLayout() {
  const std::string kind = NERFSLAM_FUZZ_KIND;
  const fs::path data = fuzz::dataDir();
  const fs::path s = fuzz::scratchDir();
  Layout l;
  if (kind == "tum") {
    // The folder name selects the Freiburg 1 preset when the input has no camera.yaml section.
    l.root = s / "rgbd_dataset_freiburg1_xyz";
    for (int i = 0; i < 10; ++i) writeImage(l.root / "rgb" / (std::to_string(i) + ".png"), 640, 480, CV_8UC3, false);
    l.files = {"rgb.txt", "groundtruth.txt", "camera.yaml"};
  } else if (kind == "euroc") {
    l.root = s / "V1_01";
    mirrorImages(data / "euroc_V1_01_piece/mav0/cam0/data", l.root / "mav0/cam0/data");
    l.files = {"mav0/cam0/data.csv", "mav0/cam0/sensor.yaml", "groundtruth_body_tum.txt",
               "mav0/state_groundtruth_estimate0/data.csv"};
  } else if (kind == "kitti") {
    l.root = s / "06";
    mirrorImages(data / "kitti06_first51/image_l", l.root / "image_l");
    l.files = {"times.txt", "calib.txt", "poses.txt"};
  } else if (kind == "transforms") {
    l.root = s / "lego";
    mirrorImages(data / "lego_train/train", l.root / "train");
    l.files = {"transforms.json"};
  } else if (kind == "middlebury") {
    l.root = s / "templeRing";
    mirrorImages(data / "middlebury_templeRing", l.root);
    l.files = {"templeR_par.txt"};
  } else if (kind == "strecha") {
    l.root = s / "fountain";
    for (const auto& n : mirrorImages(data / "strecha_fountain-P11/images", l.root / "images"))
      l.files.push_back("gt_dense_cameras/" + n + ".camera");
    if (l.files.empty()) l.files = {"gt_dense_cameras/0000.jpg.camera"};
  } else if (kind == "tsukuba") {
    l.root = s / "tsukuba";
    mirrorImages(data / "new_tsukuba_150/images", l.root / "images");
    l.files = {"cam_traj_truth.txt", "intrinsics.txt"};
  } else if (kind == "folder") {
    l.root = s / "chessboard";
    mirrorImages(data / "opencv_chessboard", l.root);
    l.files = {"times.txt", "camera.yaml"};
  } else {
    std::fprintf(stderr, "fuzz harness: unknown kind %s\n", kind.c_str());
    std::abort();
  }
  std::error_code ec;
  fs::create_directories(l.root, ec);
  if (kind == "strecha") fs::create_directories(l.root / "gt_dense_cameras", ec);
  return l;
}

const Layout& layout() {
  static const Layout l = makeLayout();
  return l;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::quietLogs();
  layout();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const Layout& l = layout();
  fuzz::writeSections(l.root, l.files, data, size);
  fuzz::expectOnlyError([&] {
    const auto ds = openDataset(NERFSLAM_FUZZ_KIND, l.root);
    // Walk everything open() produced: a bad value must have been rejected there, not here.
    const Camera& cam = ds->camera();
    volatile double sink = cam.width + cam.height;
    for (size_t i = 0; i < ds->size(); ++i) {
      sink = sink + ds->timestamp(i);
      if (const auto T = ds->groundTruth(i)) sink = sink + T->translation().sum();
      sink = sink + static_cast<double>(ds->imagePath(i).size());
    }
    if (const auto a = ds->aabbScale()) sink = sink + *a;
    (void)sink;
  });
  return 0;
}
