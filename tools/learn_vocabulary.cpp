// Learns the place-recognition vocabulary (include/nerfslam/tracking/vocabulary.h) from images:
// our own extractFrame features (default FeatureOptions) of every .png/.jpg/.ppm in the training
// folders, sorted by path, then Vocabulary::learn with a fixed seed. The same images give the same
// file, bit for bit.
//
//   nerfslam_learn_vocabulary [--k K] [--levels L] [--eval DIR]... OUT.voc DIR [DIR...]
//
// --eval DIR (an image sequence, not a training folder): prints the mean score of consecutive
// images and of images more than 10 apart (fewer in short sequences), and how often an image's
// best match among the others is within 2 frames of it, to compare choices of k and L on images
// the vocabulary has not seen.
//
// The shipped config/vocabulary/brief_k12_L4.voc (k and L chosen with --eval on KITTI 06 and the
// temple ring: the largest of the trees tried under 1 MB) is made, from the repository, by the one
// command (D=../shared/data)
//   build/nerfslam_learn_vocabulary --k 12 --levels 4 config/vocabulary/brief_k12_L4.voc
//     $D/lego_train/train $D/middlebury_dino $D/opencv_chessboard $D/euroc_V1_01_piece $D/new_tsukuba_150
// (the folders in this order; kitti06 and the temple and fountain sequences are kept for evaluation).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/vocabulary.h"

namespace fs = std::filesystem;
using namespace nerfslam;

namespace {

std::vector<fs::path> imagesIn(const std::string& dir) {
  std::vector<fs::path> files;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string ext = e.path().extension().string();
    if (ext == ".png" || ext == ".jpg" || ext == ".JPG" || ext == ".ppm") files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

cv::Mat descriptorsOf(const fs::path& f) {
  const cv::Mat img = cv::imread(f.string(), cv::IMREAD_GRAYSCALE);
  if (img.empty() || img.cols < 100 || img.rows < 100) return {};
  const Camera cam = Camera::pinhole(img.cols, img.rows, img.cols, img.cols, img.cols / 2.0, img.rows / 2.0);
  return extractFrame(img, cam, FeatureOptions{}, 0, 0.0).descriptors;
}

void evaluate(const Vocabulary& voc, const std::string& dir) {
  std::vector<BowVector> bows;
  for (const fs::path& f : imagesIn(dir)) {
    const cv::Mat d = descriptorsOf(f);
    if (d.empty()) continue;
    bows.emplace_back();
    voc.transform(d, &bows.back());
  }
  // "Far": more than 10 images apart (fewer in a short sequence).
  const size_t gap = std::max<size_t>(2, std::min<size_t>(10, bows.size() / 3));
  double near_sum = 0, far_sum = 0;
  int near_n = 0, far_n = 0, best_near = 0;
  for (size_t i = 0; i < bows.size(); ++i) {
    double best = -1;
    size_t best_j = i;
    for (size_t j = 0; j < bows.size(); ++j) {
      if (j == i) continue;
      const double s = Vocabulary::score(bows[i], bows[j]);
      if (s > best) best = s, best_j = j;
      if (j == i + 1) near_sum += s, ++near_n;
      if (j > i + gap) far_sum += s, ++far_n;
    }
    if (best_j + 2 >= i && best_j <= i + 2) ++best_near;
  }
  std::printf(
      "eval %s: %zu images, mean score consecutive %.4f, > %zu apart %.4f (ratio %.2f), best match within 2 "
      "frames %d/%zu\n",
      dir.c_str(), bows.size(), near_sum / std::max(1, near_n), gap, far_sum / std::max(1, far_n),
      (near_sum / std::max(1, near_n)) / std::max(1e-12, far_sum / std::max(1, far_n)), best_near, bows.size());
}

}  // namespace

int main(int argc, char** argv) {
  VocabularyOptions opts;
  std::vector<std::string> positional, eval_dirs;
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    if ((arg == "--k" || arg == "--levels" || arg == "--eval") && a + 1 < argc) {
      const std::string value = argv[++a];
      if (arg == "--eval")
        eval_dirs.push_back(value);
      else
        (arg == "--k" ? opts.k : opts.levels) = std::atoi(value.c_str());
    } else {
      positional.push_back(arg);
    }
  }
  if (positional.size() < 2) {
    std::fprintf(stderr, "usage: %s [--k K] [--levels L] [--eval DIR]... OUT.voc DIR [DIR...]\n", argv[0]);
    return 2;
  }
  try {
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<cv::Mat> images;
    size_t files = 0, descriptors = 0;
    for (size_t p = 1; p < positional.size(); ++p)
      for (const fs::path& f : imagesIn(positional[p])) {
        ++files;
        cv::Mat d = descriptorsOf(f);
        if (d.empty()) continue;
        descriptors += size_t(d.rows);
        images.push_back(std::move(d));
      }
    const auto t1 = std::chrono::steady_clock::now();
    std::printf("%zu files, %zu images with features, %zu descriptors (%.1f s)\n", files, images.size(), descriptors,
                std::chrono::duration<double>(t1 - t0).count());
    const Vocabulary voc = Vocabulary::learn(images, opts);
    const auto t2 = std::chrono::steady_clock::now();
    saveVocabulary(voc, positional[0]);
    std::printf(
        "k %d, %d levels: %zu nodes, %zu words, learned in %.1f s; wrote %s (%ju bytes); total %.1f s wall, %.1f s "
        "CPU\n",
        voc.k(), voc.levels(), voc.nodeCount(), voc.wordCount(), std::chrono::duration<double>(t2 - t1).count(),
        positional[0].c_str(), uintmax_t(fs::file_size(positional[0])),
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
        double(std::clock()) / CLOCKS_PER_SEC);
    for (const std::string& dir : eval_dirs) evaluate(voc, dir);
  } catch (const Error& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  return 0;
}
