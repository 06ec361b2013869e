#include "nerfslam/eval/image_metrics.h"

#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "nerfslam/core/error.h"
#include "nerfslam/core/statistics.h"

namespace nerfslam {
namespace {

constexpr int kWindow = 11;
constexpr double kSigma = 1.5;
constexpr double kK1 = 0.01;
constexpr double kK2 = 0.03;

void checkPair(const cv::Mat& a, const cv::Mat& b, const char* what) {
  if (a.empty() || b.empty()) fail("{}: empty image", what);
  if (a.size() != b.size()) fail("{}: image sizes differ ({}x{} vs {}x{})", what, a.cols, a.rows, b.cols, b.rows);
  if (a.type() != b.type())
    fail("{}: image types differ ({} vs {})", what, cv::typeToString(a.type()), cv::typeToString(b.type()));
}

void checkMax(double max_value, const char* what) {
  if (!(max_value > 0) || !std::isfinite(max_value))
    fail("{}: max value must be a positive number, got {}", what, max_value);
}

}  // namespace

double mse(const cv::Mat& a, const cv::Mat& b) {
  checkPair(a, b, "MSE");
  cv::Mat da, db;
  a.convertTo(da, CV_64F);
  b.convertTo(db, CV_64F);
  cv::Mat diff = da - db;
  const cv::Scalar s = cv::sum(diff.mul(diff));
  double total = 0;
  for (int c = 0; c < a.channels(); ++c) total += s[c];
  return total / (static_cast<double>(a.total()) * a.channels());
}

double psnr(const cv::Mat& a, const cv::Mat& b, double max_value) {
  checkMax(max_value, "PSNR");
  const double m = mse(a, b);
  if (m == 0.0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(max_value * max_value / m);
}

cv::Mat ssimMap(const cv::Mat& a, const cv::Mat& b, double max_value) {
  checkPair(a, b, "SSIM");
  checkMax(max_value, "SSIM");
  if (a.channels() != 1) fail("SSIM map: expected single-channel images, got {} channels", a.channels());
  if (a.rows < kWindow || a.cols < kWindow)
    fail("SSIM: images must be at least {}x{} pixels, got {}x{}", kWindow, kWindow, a.cols, a.rows);
  cv::Mat x, y;
  a.convertTo(x, CV_64F);
  b.convertTo(y, CV_64F);
  const cv::Mat g = cv::getGaussianKernel(kWindow, kSigma, CV_64F);  // normalised to sum 1
  // 'valid' filtering: filter, then keep only the pixels whose window lies inside the image (the
  // border mode then never contributes).
  const int r = kWindow / 2;
  const cv::Rect valid(r, r, a.cols - 2 * r, a.rows - 2 * r);
  auto filt = [&](const cv::Mat& m) {
    cv::Mat out;
    cv::sepFilter2D(m, out, CV_64F, g, g, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
    return cv::Mat(out, valid).clone();
  };
  const cv::Mat mu_x = filt(x), mu_y = filt(y);
  const cv::Mat xx = filt(x.mul(x)), yy = filt(y.mul(y)), xy = filt(x.mul(y));
  const cv::Mat mu_xx = mu_x.mul(mu_x), mu_yy = mu_y.mul(mu_y), mu_xy = mu_x.mul(mu_y);
  const cv::Mat s_xx = xx - mu_xx, s_yy = yy - mu_yy, s_xy = xy - mu_xy;
  const double C1 = (kK1 * max_value) * (kK1 * max_value);
  const double C2 = (kK2 * max_value) * (kK2 * max_value);
  cv::Mat num = (2 * mu_xy + C1).mul(2 * s_xy + C2);
  cv::Mat den = (mu_xx + mu_yy + C1).mul(s_xx + s_yy + C2);
  cv::Mat map;
  cv::divide(num, den, map);
  return map;
}

double ssim(const cv::Mat& a, const cv::Mat& b, double max_value) {
  checkPair(a, b, "SSIM");
  checkMax(max_value, "SSIM");
  std::vector<cv::Mat> ca, cb;
  cv::split(a, ca);
  cv::split(b, cb);
  double total = 0;
  for (size_t c = 0; c < ca.size(); ++c) total += cv::mean(ssimMap(ca[c], cb[c], max_value))[0];
  return total / static_cast<double>(ca.size());
}

std::optional<double> depthMedianAbsRel(const cv::Mat& depth, const cv::Mat& truth, double scale) {
  if (depth.type() != CV_32FC1 || truth.type() != CV_32FC1 || depth.size() != truth.size())
    fail("depthMedianAbsRel: the depth maps must be CV_32FC1 of one size ({}x{} and {}x{})", depth.cols, depth.rows,
         truth.cols, truth.rows);
  std::vector<double> rel;
  for (int y = 0; y < truth.rows; ++y) {
    const float* t = truth.ptr<float>(y);
    const float* d = depth.ptr<float>(y);
    for (int x = 0; x < truth.cols; ++x)
      if (t[x] > 0.f && d[x] > 0.f) rel.push_back(std::abs(scale * d[x] - t[x]) / t[x]);
  }
  if (rel.empty()) return std::nullopt;
  return median(std::move(rel));
}

}  // namespace nerfslam
