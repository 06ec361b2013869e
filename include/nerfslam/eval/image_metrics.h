#pragma once
// Image quality metrics used to score rendered views against captured images (as NeRF papers do).
//
// PSNR = 10 log10(max_value^2 / MSE), the MSE taken over all pixels and channels; +inf for
// identical images.
//
// SSIM exactly as Wang, Bovik, Sheikh and Simoncelli 2004 (and their MATLAB ssim_index.m, which
// skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5,
// use_sample_covariance=False, data_range=max_value) reproduces): local means, variances and
// covariance under an 11x11 Gaussian window with sigma 1.5 (normalised to sum 1), C1 = (0.01 L)^2,
// C2 = (0.03 L)^2 with L = max_value, and the SSIM map averaged over the valid region only — the
// pixels whose whole window lies inside the image (a border of 5 pixels is excluded; no padding).
// Colour images: the mean of the per-channel SSIMs.
//
// Inputs: cv::Mat of any depth (8U, 16U, 32F, 64F, ...), 1 to 4 channels, identical size, type and
// channel count; values are used as they are (no rescaling), `max_value` is the dynamic range
// (255 for 8-bit, 1.0 for float images in [0, 1]). Errors (nerfslam::Error) for empty or
// mismatched images, a non-positive max_value, and (SSIM) images smaller than 11x11.
#include <optional>

#include <opencv2/core.hpp>

namespace nerfslam {

double mse(const cv::Mat& a, const cv::Mat& b);
double psnr(const cv::Mat& a, const cv::Mat& b, double max_value);
double ssim(const cv::Mat& a, const cv::Mat& b, double max_value);
// The per-pixel SSIM map of one single-channel pair over the valid region ((rows-10) x (cols-10),
// CV_64F); ssim() of a single-channel pair is its mean.
cv::Mat ssimMap(const cv::Mat& a, const cv::Mat& b, double max_value);
// Depth error of a rendered depth map against a true one (both CV_32FC1 of one size, 0 where there
// is none): the median over the pixels where both have depth of |scale * depth - truth| / truth;
// std::nullopt when no pixel has both. Throws an Error for mismatched images.
std::optional<double> depthMedianAbsRel(const cv::Mat& depth, const cv::Mat& truth, double scale = 1.0);

}  // namespace nerfslam
