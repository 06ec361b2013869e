#pragma once
// Steered BRIEF: the 256-bit binary descriptor of our FAST corners.
//
// Each bit compares two pixels of the smoothed pyramid level, at a pair of points of a fixed test
// pattern rotated by the corner's orientation (intensity centroid, as ORB). Our own in place of
// cv::ORB::compute, for speed: ORB blurs every level with a 7x7 Gaussian (about 2 ms a frame on
// this machine, most of the descriptor stage); we smooth with a separable 7-tap binomial filter in
// Highway SIMD (runtime dispatch), and look the rotated pattern up in 64 precomputed orientations.
//
// The pattern's points lie in a disc of radius kBriefRadius, so a rotated point stays within it:
// corners at least kBriefRadius + 3 pixels from the level's border never read unsmoothed pixels.
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

namespace nerfslam {

constexpr int kBriefRadius = 13;
constexpr int kBriefBytes = 32;

// 7-tap binomial smoothing (1 6 15 20 15 6 1)/64 in x and y, sigma 1.2 pixels, of an 8-bit image.
// Pixels within 3 of the border are copied unsmoothed.
void smoothForBrief(const cv::Mat& src, cv::Mat* dst);

// Descriptors (one row of kBriefBytes per keypoint, CV_8U) of `keypoints` (pixel positions in
// `smoothed`, angle in degrees) on a level smoothed by smoothForBrief. Every keypoint must lie at
// least kBriefRadius pixels inside the image.
void computeBrief(const cv::Mat& smoothed, const std::vector<cv::KeyPoint>& keypoints, cv::Mat* descriptors);

// The test pattern: 256 point pairs (x1, y1, x2, y2), integers in the disc of radius kBriefRadius.
const std::vector<cv::Vec4i>& briefPattern();

}  // namespace nerfslam
