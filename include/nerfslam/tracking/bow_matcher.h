#pragma once
// Descriptor matching guided by the vocabulary's direct index (as ORB-SLAM's SearchByBoW): a
// feature of image A is compared only with the features of image B under the same vocabulary node
// (FeatureVector, vocabulary.h), instead of with all of them. Used between two keyframes (loop
// candidates, before the Sim(3) solver) and between a frame and a keyframe (relocalisation).
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/tracking/vocabulary.h"

namespace nerfslam {

struct BowMatchOptions {
  int max_distance = 50;  // Hamming distance of an accepted match (ORB-SLAM's TH_LOW)
  double ratio = 0.75;    // best < ratio x second best among the candidates under the node
};

// Pairs (index in A, index in B), sorted by A's index. Each feature of B is matched at most once
// (the closer of competing features of A wins). `a` and `b` must be direct indices built at the
// same level of the same vocabulary; descriptors are the images' rows of 32 bytes.
std::vector<std::pair<int, int>> matchByDirectIndex(const FeatureVector& a, const cv::Mat& descriptors_a,
                                                    const FeatureVector& b, const cv::Mat& descriptors_b,
                                                    const BowMatchOptions& options = {});

}  // namespace nerfslam
