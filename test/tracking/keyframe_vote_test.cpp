#include "nerfslam/tracking/keyframe_vote.h"

#include <gtest/gtest.h>

namespace nerfslam {
namespace {

cv::Mat randomDescriptors(int n, uint32_t seed) {
  cv::Mat d(n, 32, CV_8U);
  cv::RNG rng(seed);
  rng.fill(d, cv::RNG::UNIFORM, 0, 256);
  return d;
}

// `d` with its first `bits` bits flipped.
cv::Mat flipped(const cv::Mat& d, int bits) {
  cv::Mat out = d.clone();
  for (int b = 0; b < bits; ++b) out.at<uint8_t>(0, b / 8) ^= uint8_t(1u << (b % 8));
  return out;
}

TEST(KeyframeVote, TableKeepsEachPointsDescriptorAndObservers) {
  const cv::Mat d = randomDescriptors(2, 1);
  DescriptorVoteTable t;
  EXPECT_EQ(t.size(), 0u);
  t.add(d.ptr<uint8_t>(0), {4, 7});
  t.add(d.ptr<uint8_t>(1), {});
  ASSERT_EQ(t.size(), 2u);
  EXPECT_EQ(t.descriptors.size(), 64u);
  EXPECT_EQ(descriptorDistance(t.descriptors.data() + 32, d.ptr<uint8_t>(1)), 0);
  EXPECT_EQ(t.observer_begin, (std::vector<int>{0, 2, 2}));
  EXPECT_EQ(t.observers, (std::vector<KeyframeId>{4, 7}));
}

TEST(KeyframeVote, KeyframesObservingTheNearestPointsWinBestFirst) {
  // Points 0..5 with their observers; the frame holds noisy copies of points 0, 1, 2 and 4 and one
  // descriptor unlike any point.
  const cv::Mat pts = randomDescriptors(6, 2);
  const std::vector<std::vector<KeyframeId>> obs = {{1, 2}, {2}, {2, 3}, {5}, {3}, {9}};
  DescriptorVoteTable t;
  for (int i = 0; i < pts.rows; ++i) t.add(pts.ptr<uint8_t>(i), obs[static_cast<size_t>(i)]);
  Frame f;
  f.descriptors = randomDescriptors(5, 3);
  flipped(pts.row(0), 10).copyTo(f.descriptors.row(0));
  flipped(pts.row(1), 20).copyTo(f.descriptors.row(1));
  flipped(pts.row(2), 5).copyTo(f.descriptors.row(2));
  flipped(pts.row(4), 40).copyTo(f.descriptors.row(3));
  // Votes: 2 has three, 3 two (points 2 and 4), 1 one; 5 and 9 none (left out).
  EXPECT_EQ(keyframesByDescriptorVotes(f, t, 10), (std::vector<KeyframeId>{2, 3, 1}));
  EXPECT_EQ(keyframesByDescriptorVotes(f, t, 2), (std::vector<KeyframeId>{2, 3}));
  // max_distance 30: the copy of point 4 (40 bits off) no longer votes; 3 and 1 then tie at one
  // vote, the newer first.
  EXPECT_EQ(keyframesByDescriptorVotes(f, t, 10, 600, 30), (std::vector<KeyframeId>{2, 3, 1}));
  // max_distance 8: only the copy of point 2 (5 bits off) votes.
  EXPECT_EQ(keyframesByDescriptorVotes(f, t, 10, 600, 8), (std::vector<KeyframeId>{3, 2}));
  // max_features 2 of 5 descriptors: every third (rows 0 and 3) votes.
  EXPECT_EQ(keyframesByDescriptorVotes(f, t, 10, 2), (std::vector<KeyframeId>{3, 2, 1}));
  EXPECT_TRUE(keyframesByDescriptorVotes(f, t, 0).empty());
  EXPECT_TRUE(keyframesByDescriptorVotes(f, DescriptorVoteTable{}, 10).empty());
  EXPECT_TRUE(keyframesByDescriptorVotes(Frame{}, t, 10).empty());
}

}  // namespace
}  // namespace nerfslam
