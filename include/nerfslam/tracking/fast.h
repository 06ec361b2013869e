#pragma once
// FAST-9 corners (16-pixel Bresenham circle of radius 3) with 3x3 non-maximum suppression, computed
// with Highway SIMD under runtime dispatch.
//
// One pass gives every corner down to a threshold together with its score, so a caller that wants
// corners at several thresholds (the adaptive per-cell threshold of frame extraction) runs it once
// at the lowest. The result is exactly cv::FAST's (TYPE_9_16, nonmaxSuppression = true):
// - a pixel is a corner at threshold t when 9 contiguous circle pixels are all brighter than
//   centre + t or all darker than centre - t;
// - its score (cv::KeyPoint::response) is the largest t at which it is one;
// - it is kept when its score is strictly greater than the scores of its 8 neighbours.
// A corner's score does not depend on the threshold it was found with, so the corners of a pass at
// a high threshold are exactly the corners of a pass at a lower one that score at least that high.
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

namespace nerfslam {

struct FastCorner {
  int x = 0, y = 0;  // image pixel
  int score = 0;     // the largest threshold at which the pixel is a corner (>= the pass's threshold)
};

// Corners of the 8-bit, one-channel `image` among the pixels of `area`, scoring at least
// `threshold` (clamped to 1..254: like cv::FAST, corners of score 0 are never kept), in row-major order. `area` must
// lie at least 3 pixels inside the image. Pixels outside `area` count as non-corners in the non-maximum suppression, so
// the result equals cv::FAST on the sub-image `area` grown by 3 pixels on every side.
void detectFast(const cv::Mat& image, const cv::Rect& area, int threshold, std::vector<FastCorner>* corners);

// The same score for one pixel, by the scalar code that finishes a row detectFast's vectors do not
// cover: -1 when the pixel is not a corner at threshold 0. `centre` points at the pixel, `stride`
// is the row step.
int fastScore(const uint8_t* centre, std::ptrdiff_t stride);

}  // namespace nerfslam
