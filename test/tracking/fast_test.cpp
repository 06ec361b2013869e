#include "nerfslam/tracking/fast.h"

#include <gtest/gtest.h>
#include <hwy/targets.h>

#include <algorithm>
#include <cstdio>
#include <iterator>
#include <random>
#include <tuple>

#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "test_support.h"

namespace nerfslam {
namespace {

using Corner = std::tuple<int, int, int>;  // y, x, score

std::vector<Corner> ours(const cv::Mat& img, const cv::Rect& area, int t) {
  std::vector<FastCorner> c;
  detectFast(img, area, t, &c);
  std::vector<Corner> out;
  for (const FastCorner& k : c) out.emplace_back(k.y, k.x, k.score);
  return out;  // row-major already (checked by the caller against a sorted copy)
}

std::vector<Corner> opencv(const cv::Mat& img, const cv::Rect& area, int t) {
  const cv::Rect grown(area.x - 3, area.y - 3, area.width + 6, area.height + 6);
  std::vector<cv::KeyPoint> kps;
  cv::FAST(img(grown), kps, t, true, cv::FastFeatureDetector::TYPE_9_16);
  std::vector<Corner> out;
  for (const cv::KeyPoint& k : kps)
    out.emplace_back(static_cast<int>(k.pt.y) + grown.y, static_cast<int>(k.pt.x) + grown.x,
                     static_cast<int>(k.response));
  std::sort(out.begin(), out.end());
  return out;
}

// Flat patches with a few intensity levels: many equal scores side by side (the strict
// non-maximum comparison), corners at the patch corners, saturated 0/255 values.
cv::Mat blocks(int w, int h, uint32_t seed) {
  cv::Mat img(h, w, CV_8U);
  std::mt19937 rng(seed);
  const uint8_t levels[] = {0, 0, 40, 128, 129, 200, 255, 255};
  for (int by = 0; by < h; by += 6)
    for (int bx = 0; bx < w; bx += 5)
      img(cv::Rect(bx, by, std::min(5, w - bx), std::min(6, h - by))).setTo(levels[rng() & 7]);
  return img;
}

std::vector<cv::Mat> testImages() {
  std::vector<cv::Mat> imgs = {test::noiseImage(97, 61, 1), test::noiseImage(640, 480, 2), blocks(203, 77, 3),
                               blocks(640, 480, 4)};
  cv::Mat smooth;
  cv::GaussianBlur(test::noiseImage(320, 240, 5), smooth, cv::Size(5, 5), 1.5);
  cv::normalize(smooth, smooth, 0, 255, cv::NORM_MINMAX);
  imgs.push_back(smooth);
  const auto dir = test::dataDir();
  for (const char* name : {"new_tsukuba_150/images/rgb_00000.png", "kitti06_first51/image_l/000000.png"}) {
    const cv::Mat img = cv::imread((dir / name).string(), cv::IMREAD_GRAYSCALE);
    if (!img.empty()) imgs.push_back(img);
  }
  return imgs;
}

// Every SIMD target this CPU runs, and the baseline, give cv::FAST's corners and scores exactly.
TEST(Fast, MatchesOpenCvOnEveryTarget) {
  const std::vector<cv::Mat> imgs = testImages();
  size_t total = 0;
  for (int64_t target : hwy::SupportedAndGeneratedTargets()) {
    hwy::SetSupportedTargetsForTest(target);
    std::printf("target %s\n", hwy::TargetName(target));
    for (const cv::Mat& img : imgs) {
      const std::vector<cv::Rect> areas = {cv::Rect(3, 3, img.cols - 6, img.rows - 6),
                                           cv::Rect(5, 4, std::min(61, img.cols - 8), std::min(33, img.rows - 7)),
                                           cv::Rect(3, 10, 1, 5), cv::Rect(7, 3, 17, 1)};
      for (const cv::Rect& area : areas)
        for (int t : {0, 1, 7, 20, 60, 254}) {
          const std::vector<Corner> a = ours(img, area, t);
          std::vector<Corner> sorted = a;
          std::sort(sorted.begin(), sorted.end());
          ASSERT_EQ(a, sorted) << "not row-major";
          const std::vector<Corner> b = opencv(img, area, t);
          if (a != b) {
            std::vector<Corner> only_a, only_b;
            std::set_difference(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(only_a));
            std::set_difference(b.begin(), b.end(), a.begin(), a.end(), std::back_inserter(only_b));
            for (const Corner& c : only_a)
              ADD_FAILURE() << "only ours: y " << std::get<0>(c) << " x " << std::get<1>(c) << " score "
                            << std::get<2>(c);
            for (const Corner& c : only_b)
              ADD_FAILURE() << "only OpenCV: y " << std::get<0>(c) << " x " << std::get<1>(c) << " score "
                            << std::get<2>(c);
          }
          ASSERT_EQ(a, b) << hwy::TargetName(target) << ": image " << img.cols << "x" << img.rows << ", area " << area
                          << ", threshold " << t;
          total += a.size();
        }
    }
  }
  hwy::SetSupportedTargetsForTest(0);
  EXPECT_GT(total, 100000u);  // the comparison saw corners, not empty sets
}

// The score is the definition's: the largest t at which 9 contiguous pixels clear the centre by t.
TEST(Fast, ScoreIsTheLargestThresholdOfACorner) {
  const cv::Mat img = test::noiseImage(160, 120, 9);
  std::vector<FastCorner> c;
  detectFast(img, cv::Rect(3, 3, img.cols - 6, img.rows - 6), 0, &c);
  ASSERT_GT(c.size(), 500u);
  for (const FastCorner& k : c) {
    ASSERT_EQ(k.score, fastScore(&img.at<uint8_t>(k.y, k.x), static_cast<std::ptrdiff_t>(img.step1())));
    // A corner at its score, not one above it.
    std::vector<cv::KeyPoint> at, above;
    const cv::Rect r(k.x - 3, k.y - 3, 7, 7);
    cv::FAST(img(r), at, k.score, false);
    cv::FAST(img(r), above, k.score + 1, false);
    EXPECT_EQ(at.size(), 1u);
    EXPECT_TRUE(above.empty());
  }
  // A flat image has no corners, a single bright dot on black has a score of its contrast - 1.
  cv::Mat flat(20, 20, CV_8U, cv::Scalar(90));
  detectFast(flat, cv::Rect(3, 3, 14, 14), 0, &c);
  EXPECT_TRUE(c.empty());
  flat.at<uint8_t>(10, 10) = 200;
  detectFast(flat, cv::Rect(3, 3, 14, 14), 0, &c);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].x, 10);
  EXPECT_EQ(c[0].y, 10);
  EXPECT_EQ(c[0].score, 200 - 90 - 1);
}

}  // namespace
}  // namespace nerfslam
