#pragma once
// Pyramid levels (tracking/frame.h builds them) and the image they come from.
#include <opencv2/core/types.hpp>

namespace nerfslam {

// A pixel of a pyramid level (the image resized by cv::resize to `level`, pixel centres aligned) in
// the image's pixels: (x + 0.5) * image / level - 0.5 along each axis. The level's true scale, not
// the nominal scale_factor^l: its size is rounded (level 5 of 320x240 is 129x96, 2.481 and 2.5
// against 1.2^5 = 2.488), and x * scale_factor^l put the coarse levels' keypoints up to a pixel or
// two off, with a focal length and a principal point of their own per level.
cv::Point2f levelToImage(const cv::Size& image, const cv::Size& level, const cv::Point2f& p);
// Its inverse: an image pixel in the level's pixels.
cv::Point2f imageToLevel(const cv::Size& image, const cv::Size& level, const cv::Point2f& p);

}  // namespace nerfslam
