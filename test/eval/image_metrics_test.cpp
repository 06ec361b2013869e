#include "nerfslam/eval/image_metrics.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <random>
#include <vector>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

cv::Mat randomImage(int rows, int cols, int type, unsigned seed, double lo, double hi) {
  cv::Mat m(rows, cols, type);
  cv::RNG rng(seed);
  rng.fill(m, cv::RNG::UNIFORM, lo, hi);
  return m;
}

// Straightforward reference: for every pixel whose 11x11 window lies inside the image, Gaussian-
// weighted means, variances and covariance by explicit loops, the SSIM formula, then the mean.
double referenceSsim(const cv::Mat& a, const cv::Mat& b, double L) {
  double w[11][11], wsum = 0;
  for (int i = 0; i < 11; ++i)
    for (int j = 0; j < 11; ++j) {
      w[i][j] = std::exp(-((i - 5) * (i - 5) + (j - 5) * (j - 5)) / (2 * 1.5 * 1.5));
      wsum += w[i][j];
    }
  const double C1 = (0.01 * L) * (0.01 * L), C2 = (0.03 * L) * (0.03 * L);
  const int ch = a.channels();
  double total = 0;
  for (int c = 0; c < ch; ++c) {
    double sum = 0;
    int count = 0;
    for (int y = 5; y < a.rows - 5; ++y)
      for (int x = 5; x < a.cols - 5; ++x) {
        double mx = 0, my = 0, sxx = 0, syy = 0, sxy = 0;
        for (int i = 0; i < 11; ++i)
          for (int j = 0; j < 11; ++j) {
            const double g = w[i][j] / wsum;
            const double px = a.ptr<double>(y - 5 + i)[(x - 5 + j) * ch + c];
            const double py = b.ptr<double>(y - 5 + i)[(x - 5 + j) * ch + c];
            mx += g * px;
            my += g * py;
            sxx += g * px * px;
            syy += g * py * py;
            sxy += g * px * py;
          }
        sxx -= mx * mx;
        syy -= my * my;
        sxy -= mx * my;
        sum += (2 * mx * my + C1) * (2 * sxy + C2) / ((mx * mx + my * my + C1) * (sxx + syy + C2));
        ++count;
      }
    total += sum / count;
  }
  return total / ch;
}

TEST(Psnr, IdenticalImagesAreInfinite) {
  const cv::Mat a = randomImage(20, 30, CV_8UC3, 1, 0, 256);
  EXPECT_TRUE(std::isinf(psnr(a, a, 255)));
  EXPECT_EQ(mse(a, a), 0.0);
}

TEST(Psnr, ConstantOffsetClosedForm) {
  // 8-bit values in [0, 200] plus 10: no saturation, MSE = 100 exactly.
  const cv::Mat a = randomImage(16, 24, CV_8UC3, 2, 0, 200);
  const cv::Mat b = a + cv::Scalar::all(10);
  EXPECT_DOUBLE_EQ(mse(a, b), 100.0);
  EXPECT_NEAR(psnr(a, b, 255), 10 * std::log10(255.0 * 255.0 / 100.0), 1e-12);
  // Float images in [0, 1] with an offset of 0.1 under max 1: PSNR = 20 dB.
  const cv::Mat f = randomImage(16, 24, CV_64FC1, 3, 0, 0.9);
  EXPECT_NEAR(psnr(f, f + 0.1, 1.0), 20.0, 1e-9);
  // float32 input is accepted as well.
  cv::Mat f32;
  f.convertTo(f32, CV_32F);
  EXPECT_NEAR(psnr(f32, f32 + 0.05f, 1.0), 10 * std::log10(1.0 / 0.0025), 1e-4);
}

TEST(Ssim, IdenticalImagesGiveOne) {
  const cv::Mat a = randomImage(32, 40, CV_8UC3, 4, 0, 256);
  EXPECT_NEAR(ssim(a, a, 255), 1.0, 1e-12);
  const cv::Mat f = randomImage(32, 40, CV_32FC1, 5, 0, 1);
  EXPECT_NEAR(ssim(f, f, 1.0), 1.0, 1e-12);
}

TEST(Ssim, MatchesDoubleLoopReference) {
  for (int ch : {1, 3}) {
    const cv::Mat a = randomImage(37, 45, CV_64FC(ch), 10 + ch, 0, 1);
    cv::Mat noise = randomImage(37, 45, CV_64FC(ch), 20 + ch, -0.2, 0.2);
    const cv::Mat b = 0.7 * a + noise + 0.1;
    const double ref = referenceSsim(a, b, 1.0);
    EXPECT_NEAR(ssim(a, b, 1.0), ref, 1e-12) << ch << " channels";
    // 8-bit input gives the SSIM of its values under L = 255.
    cv::Mat a8, b8, ad, bd;
    a.convertTo(a8, CV_8U, 255);
    b.convertTo(b8, CV_8U, 255);
    a8.convertTo(ad, CV_64F);
    b8.convertTo(bd, CV_64F);
    EXPECT_NEAR(ssim(a8, b8, 255), referenceSsim(ad, bd, 255), 1e-12);
  }
}

TEST(Ssim, SymmetricBoundedAndMonotoneInNoise) {
  const cv::Mat a = randomImage(40, 40, CV_64FC1, 7, 0, 1);
  cv::Mat smooth;
  cv::GaussianBlur(a, smooth, cv::Size(5, 5), 2.0);
  double prev = 1.0;
  for (double amp : {0.01, 0.05, 0.2, 0.5}) {
    const cv::Mat b = smooth + amp * randomImage(40, 40, CV_64FC1, 8, -1, 1);
    const double s = ssim(smooth, b, 1.0);
    EXPECT_NEAR(s, ssim(b, smooth, 1.0), 1e-15);
    EXPECT_LE(s, 1.0);
    EXPECT_GE(s, -1.0);
    EXPECT_LT(s, prev);
    prev = s;
  }
  // Anti-correlated structure drives SSIM negative.
  EXPECT_LT(ssim(a, 1.0 - a, 1.0), 0.0);
  const cv::Mat m = ssimMap(a, smooth, 1.0);
  EXPECT_EQ(m.rows, 30);
  EXPECT_EQ(m.cols, 30);
}

TEST(ImageMetrics, Errors) {
  const cv::Mat a(20, 20, CV_8UC1, cv::Scalar(3));
  EXPECT_THROW(psnr(a, cv::Mat(20, 21, CV_8UC1), 255), Error);
  EXPECT_THROW(psnr(a, cv::Mat(20, 20, CV_8UC3), 255), Error);
  EXPECT_THROW(psnr(a, a, 0), Error);
  EXPECT_THROW(psnr(cv::Mat(), cv::Mat(), 255), Error);
  EXPECT_THROW(ssim(cv::Mat(10, 10, CV_8UC1), cv::Mat(10, 10, CV_8UC1), 255), Error);
}

// The median relative depth error over the pixels where both maps have depth, with the scale applied
// to the rendered depth.
TEST(DepthMedianAbsRel, MedianOverPixelsWithBothDepths) {
  cv::Mat truth(2, 3, CV_32FC1, cv::Scalar(2.f)), depth(2, 3, CV_32FC1);
  depth.at<float>(0, 0) = 2.2f;  // 10 %
  depth.at<float>(0, 1) = 1.6f;  // 20 %
  depth.at<float>(0, 2) = 2.0f;  // 0 %
  depth.at<float>(1, 0) = 0.f;   // no render depth: skipped
  depth.at<float>(1, 1) = 5.f;   // no true depth: skipped
  depth.at<float>(1, 2) = 2.6f;  // 30 %
  truth.at<float>(1, 1) = 0.f;
  EXPECT_NEAR(*depthMedianAbsRel(depth, truth), 0.2, 1e-6);       // the upper median of 0, .1, .2, .3
  EXPECT_NEAR(*depthMedianAbsRel(depth, truth, 2.0), 1.2, 1e-6);  // 1.2, 0.6, 1.0, 1.6
  EXPECT_FALSE(depthMedianAbsRel(cv::Mat::zeros(2, 3, CV_32FC1), truth).has_value());
  EXPECT_THROW(depthMedianAbsRel(cv::Mat(2, 2, CV_32FC1), truth), Error);
}

}  // namespace
}  // namespace nerfslam
