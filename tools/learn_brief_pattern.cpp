// Learns the steered-BRIEF test pattern (src/tracking/brief_pattern.inc) from images, with ORB's
// method (Rublee et al. 2011, section 4.3): every pair of pixels in the disc of radius
// kBriefRadius is a candidate test; each is evaluated on oriented FAST corners of the training
// images (smoothed as computeBrief sees them, rotated by the corner's orientation); tests are
// ranked by how close their mean is to 0.5 and taken greedily when their correlation with every
// test already taken stays under a bound, which is raised until 256 are taken. Unlike ORB, tests
// whose mean is more than 0.2 from 0.5 are never candidates: without that bound the greedy
// selection reaches tests that are almost constant (mean 0.09), unrelated corners then differ in
// fewer bits (median Hamming distance 111 instead of 123 on New Tsukuba), and a camera in an
// unmapped view found false matches that passed tracking's thresholds (tuned on ORB's).
//
//   nerfslam_learn_brief_pattern OUT.inc DIR [DIR...]   (every .png/.jpg in the DIRs, sorted)
//
// The shipped pattern: lego_train/train, middlebury_dino, opencv_chessboard and euroc_V1_01_piece
// of ../shared/data (none of them a tracking accuracy target).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/tracking/brief.h"
#include "nerfslam/tracking/frame.h"

namespace fs = std::filesystem;
using namespace nerfslam;

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s OUT.inc DIR [DIR...]\n", argv[0]);
    return 2;
  }
  std::vector<fs::path> files;
  for (int a = 2; a < argc; ++a) {
    std::vector<fs::path> in_dir;
    for (const auto& e : fs::recursive_directory_iterator(argv[a])) {
      const std::string ext = e.path().extension().string();
      if (ext == ".png" || ext == ".jpg" || ext == ".JPG" || ext == ".ppm") in_dir.push_back(e.path());
    }
    std::sort(in_dir.begin(), in_dir.end());
    files.insert(files.end(), in_dir.begin(), in_dir.end());
  }
  // Candidate points: the integer points of the disc.
  std::vector<cv::Point> pts;
  for (int y = -kBriefRadius; y <= kBriefRadius; ++y)
    for (int x = -kBriefRadius; x <= kBriefRadius; ++x)
      if (x * x + y * y <= kBriefRadius * kBriefRadius) pts.emplace_back(x, y);
  const size_t P = pts.size();

  // Samples: the smoothed, rotated disc around corners of every image (at most kPerImage each).
  constexpr size_t kSamples = 8192, kPerImage = 96;
  constexpr double kMaxMeanOffset = 0.2;
  std::mt19937 rng(12345);
  std::vector<std::vector<uint8_t>> samples;
  for (const fs::path& f : files) {
    const cv::Mat img = cv::imread(f.string(), cv::IMREAD_GRAYSCALE);
    if (img.empty() || img.cols < 100 || img.rows < 100) continue;
    const Frame fr =
        extractFrame(img, Camera::pinhole(img.cols, img.rows, img.cols, img.cols, img.cols / 2.0, img.rows / 2.0),
                     FeatureOptions{}, 0, 0.0);
    std::vector<cv::Mat> smoothed(fr.pyramid.size());
    for (size_t l = 0; l < fr.pyramid.size(); ++l) smoothForBrief(fr.pyramid[l], &smoothed[l]);
    std::vector<size_t> order(fr.keypoints.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::shuffle(order.begin(), order.end(), rng);
    for (size_t n = 0; n < std::min(kPerImage, order.size()); ++n) {
      const cv::KeyPoint& k = fr.keypoints[order[n]];
      const size_t l = size_t(k.octave);
      const double s = fr.level_scale[l];
      const int cx = cvRound(k.pt.x / s), cy = cvRound(k.pt.y / s);
      const cv::Mat& sm = smoothed[l];
      if (cx < kBriefRadius + 3 || cy < kBriefRadius + 3 || cx >= sm.cols - kBriefRadius - 3 ||
          cy >= sm.rows - kBriefRadius - 3)
        continue;
      const double a = k.angle * M_PI / 180.0, c = std::cos(a), sn = std::sin(a);
      std::vector<uint8_t> v(P);
      for (size_t p = 0; p < P; ++p) {
        const int x = int(std::lround(pts[p].x * c - pts[p].y * sn)),
                  y = int(std::lround(pts[p].x * sn + pts[p].y * c));
        v[p] = sm.at<uint8_t>(cy + y, cx + x);
      }
      samples.push_back(std::move(v));
    }
  }
  std::shuffle(samples.begin(), samples.end(), rng);
  if (samples.size() > kSamples) samples.resize(kSamples);
  const size_t K = samples.size(), W = (K + 63) / 64;
  std::printf("%zu images, %zu samples, %zu points, %zu point pairs\n", files.size(), K, P, P * (P - 1) / 2);
  if (K < 1024) {
    std::fprintf(stderr, "too few samples\n");
    return 1;
  }

  // Bits of every candidate test over the samples.
  struct Test {
    int a, b;
    double mean;
  };
  std::vector<Test> tests;
  std::vector<uint64_t> bits;
  for (size_t a = 0; a < P; ++a)
    for (size_t b = a + 1; b < P; ++b) {
      const size_t t = tests.size();
      bits.resize((t + 1) * W, 0);
      size_t ones = 0;
      for (size_t k = 0; k < K; ++k)
        if (samples[k][a] < samples[k][b]) {
          bits[t * W + k / 64] |= uint64_t(1) << (k % 64);
          ++ones;
        }
      const double mean = double(ones) / double(K);
      if (std::abs(mean - 0.5) > kMaxMeanOffset) {
        bits.resize(t * W);
        continue;
      }
      tests.push_back({int(a), int(b), mean});
    }
  std::printf("%zu candidate tests with a mean within %.2f of 0.5\n", tests.size(), kMaxMeanOffset);
  std::vector<size_t> rank(tests.size());
  for (size_t i = 0; i < rank.size(); ++i) rank[i] = i;
  std::stable_sort(rank.begin(), rank.end(),
                   [&](size_t x, size_t y) { return std::abs(tests[x].mean - 0.5) < std::abs(tests[y].mean - 0.5); });
  auto corr = [&](size_t x, size_t y) {
    size_t n11 = 0;
    for (size_t w = 0; w < W; ++w) n11 += size_t(__builtin_popcountll(bits[x * W + w] & bits[y * W + w]));
    const double px = tests[x].mean, py = tests[y].mean;
    const double den = std::sqrt(px * (1 - px) * py * (1 - py));
    return den > 0 ? std::abs(double(n11) / double(K) - px * py) / den : 1.0;
  };
  std::vector<size_t> chosen;
  double bound = 0.2;
  for (; chosen.size() < 256; bound += 0.02) {
    chosen.clear();
    for (size_t r = 0; r < rank.size() && chosen.size() < 256; ++r) {
      const size_t t = rank[r];
      bool ok = true;
      for (size_t c : chosen)
        if (corr(t, c) >= bound) {
          ok = false;
          break;
        }
      if (ok) chosen.push_back(t);
    }
    std::printf("correlation bound %.2f: %zu tests\n", bound, chosen.size());
  }
  double worst_mean = 0;
  for (size_t c : chosen) worst_mean = std::max(worst_mean, std::abs(tests[c].mean - 0.5));
  std::printf("largest |mean - 0.5| of the chosen tests: %.3f\n", worst_mean);

  const std::string out = argv[1], tmp = out + ".tmp";
  {
    std::ofstream o(tmp);
    o << "// Generated by nerfslam_learn_brief_pattern (tools/learn_brief_pattern.cpp) from " << files.size()
      << " images, " << K << " corners;\n// correlation bound " << bound - 0.02 << ". Do not edit.\n";
    for (size_t c : chosen) {
      const cv::Point& a = pts[size_t(tests[c].a)];
      const cv::Point& b = pts[size_t(tests[c].b)];
      o << "{" << a.x << ", " << a.y << ", " << b.x << ", " << b.y << "},\n";
    }
    if (!o) return 1;
  }
  fs::rename(tmp, out);
  std::printf("wrote %s\n", out.c_str());
  return 0;
}
