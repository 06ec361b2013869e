#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/pyramid.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/tracking/brief.h"
#include "test_support.h"

namespace nerfslam {
namespace {

Camera tsukubaCamera() { return Camera::pinhole(640, 480, 615, 615, 320, 240); }

// Fraction of an nx x ny grid over the image that holds at least one keypoint.
double coverage(const Frame& f, int nx, int ny) {
  std::vector<char> hit(static_cast<size_t>(nx * ny), 0);
  for (const auto& k : f.keypoints)
    hit[static_cast<size_t>(std::min(ny - 1, static_cast<int>(k.pt.y * ny / f.camera.height)) * nx +
                            std::min(nx - 1, static_cast<int>(k.pt.x * nx / f.camera.width)))] = 1;
  int n = 0;
  for (char h : hit) n += h;
  return static_cast<double>(n) / (nx * ny);
}

TEST(Frame, FeaturesSpreadOverRealImageWithConsistentDescriptors) {
  NERFSLAM_REQUIRE_DATA(dir, "new_tsukuba_150");
  const cv::Mat img = cv::imread((dir / "images/rgb_00000.png").string(), cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(img.empty());
  FeatureOptions opt;
  const Frame f = extractFrame(img, tsukubaCamera(), opt, 7, 0.5);
  EXPECT_EQ(f.id, 7u);
  EXPECT_GT(f.size(), 0.8 * opt.max_features);
  EXPECT_LE(f.size(), static_cast<size_t>(opt.max_features) + 8);
  EXPECT_EQ(f.descriptors.rows, static_cast<int>(f.size()));
  EXPECT_EQ(f.descriptors.cols, 32);
  EXPECT_EQ(f.pyramid.size(), static_cast<size_t>(opt.num_levels));
  EXPECT_GT(coverage(f, 8, 6), 0.85);
  std::vector<int> per_level(f.pyramid.size(), 0);
  for (const auto& k : f.keypoints) ++per_level[static_cast<size_t>(k.octave)];
  for (int n : per_level) EXPECT_GT(n, 20);

  // Descriptors of levels 0 and 2 equal computeBrief's on the smoothed level, at the keypoints'
  // level positions and orientations.
  for (int level : {0, 2}) {
    std::vector<cv::KeyPoint> kps;
    std::vector<int> idx;
    const cv::Size level_size = f.pyramid[static_cast<size_t>(level)].size();
    for (size_t i = 0; i < f.size(); ++i)
      if (f.keypoints[i].octave == level) {
        kps.push_back(f.keypoints[i]);
        const cv::Point2f p = imageToLevel(f.pyramid[0].size(), level_size, f.keypoints[i].pt);
        kps.back().pt = cv::Point2f(std::round(p.x), std::round(p.y));
        idx.push_back(static_cast<int>(i));
      }
    ASSERT_GT(kps.size(), 20u);
    cv::Mat smoothed, desc;
    smoothForBrief(f.pyramid[static_cast<size_t>(level)], &smoothed);
    computeBrief(smoothed, kps, &desc);
    for (size_t j = 0; j < kps.size(); ++j)
      EXPECT_EQ(descriptorDistance(desc.ptr<uint8_t>(static_cast<int>(j)), f.descriptors.ptr<uint8_t>(idx[j])), 0);
  }

  // featuresInArea agrees with brute force.
  const Eigen::Vector2d c(300, 200);
  std::vector<int> brute;
  for (size_t i = 0; i < f.size(); ++i)
    if ((Eigen::Vector2d(f.keypoints[i].pt.x, f.keypoints[i].pt.y) - c).norm() <= 37.0) brute.push_back(int(i));
  std::vector<int> grid = f.featuresInArea(c, 37.0);
  std::sort(grid.begin(), grid.end());
  EXPECT_EQ(grid, brute);
}

TEST(Frame, AdaptiveThresholdKeepsFeaturesInLowContrast) {
  NERFSLAM_REQUIRE_DATA(dir, "new_tsukuba_150");
  cv::Mat img = cv::imread((dir / "images/rgb_00000.png").string(), cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(img.empty());
  cv::Mat low;
  img.convertTo(low, CV_8U, 0.3, 90);  // 3.3x less contrast
  FeatureOptions opt;
  const Frame f = extractFrame(low, tsukubaCamera(), opt);
  std::vector<cv::KeyPoint> fixed;
  cv::FAST(low, fixed, opt.fast_threshold, true);
  EXPECT_GT(f.size(), 0.5 * opt.max_features);
  EXPECT_GT(f.size(), 2 * fixed.size());  // a fixed threshold finds far fewer corners
  // Spread stays close to the full-contrast image's.
  const Frame full = extractFrame(img, tsukubaCamera(), opt);
  EXPECT_GT(coverage(f, 8, 6), 0.8 * coverage(full, 8, 6));
  std::printf("coverage full %.3f low %.3f; features low %zu, fixed-threshold FAST %zu\n", coverage(full, 8, 6),
              coverage(f, 8, 6), f.size(), fixed.size());
}

TEST(Frame, RejectsBadInput) {
  const Camera cam = tsukubaCamera();
  EXPECT_THROW(extractFrame(cv::Mat(), cam, {}), std::exception);
  EXPECT_THROW(extractFrame(cv::Mat(100, 100, CV_8U, cv::Scalar(0)), cam, {}), std::exception);
  const Frame blank = extractFrame(cv::Mat(480, 640, CV_8U, cv::Scalar(128)), cam, {});
  EXPECT_EQ(blank.size(), 0u);
  EXPECT_TRUE(blank.featuresInArea(Eigen::Vector2d(10, 10), 50).empty());
}

// Each pyramid level's pixels mapped back to the image (levelToImage, what keypoints go through):
// the centroid of a smooth blob near a corner of a 320x240 image, measured on every level, lands on
// the blob's centre. Multiplying by the nominal 1.2^l instead (the old mapping) misses it by more
// than a pixel on the coarse levels, differently along x and y (the levels' sizes are rounded).
TEST(Frame, PyramidLevelsMapBackToTheImageExactly) {
  const Camera cam = Camera::pinhole(320, 240, 262.5, 262.5, 159.5, 119.5);
  const double x0 = 291.3, y0 = 27.8, sigma = 5.0;
  cv::Mat img(240, 320, CV_8U);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x)
      img.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(
          20 + 220 * std::exp(-((x - x0) * (x - x0) + (y - y0) * (y - y0)) / (2 * sigma * sigma)));
  const Frame f = extractFrame(img, cam, {});
  ASSERT_GE(f.pyramid.size(), 6u);
  double worst = 0, worst_nominal = 0;
  for (size_t l = 1; l < f.pyramid.size(); ++l) {
    const cv::Mat& lvl = f.pyramid[l];
    double sw = 0, sx = 0, sy = 0;
    for (int y = 0; y < lvl.rows; ++y)
      for (int x = 0; x < lvl.cols; ++x) {
        const double w = std::max(0.0, lvl.at<uint8_t>(y, x) - 20.0);
        sw += w;
        sx += w * x;
        sy += w * y;
      }
    const cv::Point2f c(static_cast<float>(sx / sw), static_cast<float>(sy / sw));
    const cv::Point2f p = levelToImage(f.pyramid[0].size(), lvl.size(), c);
    worst = std::max(worst, std::hypot(p.x - x0, p.y - y0));
    const double s = f.level_scale[l];
    worst_nominal = std::max(worst_nominal, std::hypot(c.x * s - x0, c.y * s - y0));
  }
  EXPECT_LT(worst, 0.1);
  EXPECT_GT(worst_nominal, 1.0);
  // imageToLevel is its inverse.
  const cv::Point2f back =
      imageToLevel(img.size(), f.pyramid[5].size(), levelToImage(img.size(), f.pyramid[5].size(), {40.f, 30.f}));
  EXPECT_NEAR(back.x, 40.f, 1e-4);
  EXPECT_NEAR(back.y, 30.f, 1e-4);
  // Level 0 is the image itself.
  const cv::Point2f same = levelToImage(img.size(), img.size(), cv::Point2f(12.25f, 7.5f));
  EXPECT_FLOAT_EQ(same.x, 12.25f);
  EXPECT_FLOAT_EQ(same.y, 7.5f);
}

}  // namespace
}  // namespace nerfslam
