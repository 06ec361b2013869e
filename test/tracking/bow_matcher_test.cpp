#include "nerfslam/tracking/bow_matcher.h"

#include <gtest/gtest.h>

#include <random>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/tracking/frame.h"
#include "test_support.h"

namespace nerfslam {
namespace {

TEST(BowMatcher, RecoversAPermutationOfPerturbedDescriptors) {
  std::mt19937 rng(21);
  cv::Mat a(300, 32, CV_8U);
  for (int r = 0; r < a.rows; ++r)
    for (int c = 0; c < 32; ++c) a.at<uint8_t>(r, c) = uint8_t(rng());
  std::vector<int> perm(size_t(a.rows));
  for (size_t i = 0; i < perm.size(); ++i) perm[i] = int(i);
  std::shuffle(perm.begin(), perm.end(), rng);
  cv::Mat b(a.rows, 32, CV_8U);  // row perm[i] of B is row i of A with up to 3 bits flipped
  for (int i = 0; i < a.rows; ++i) {
    a.row(i).copyTo(b.row(perm[size_t(i)]));
    for (uint32_t f = rng() % 4; f > 0; --f) {
      const uint32_t bit = rng() % 256;
      b.at<uint8_t>(perm[size_t(i)], int(bit / 8)) ^= uint8_t(1u << (bit % 8));
    }
  }
  VocabularyOptions o;
  o.k = 4;
  o.levels = 3;
  const Vocabulary voc = Vocabulary::learn({a}, o);
  BowVector bow_a, bow_b;
  FeatureVector fa, fb;
  voc.transform(a, &bow_a, &fa, 1);
  voc.transform(b, &bow_b, &fb, 1);
  const auto m = matchByDirectIndex(fa, a, fb, b);
  int correct = 0;
  for (const auto& [i, j] : m) correct += perm[size_t(i)] == j ? 1 : 0;
  EXPECT_EQ(correct, int(m.size())) << "every match is right";
  EXPECT_GE(int(m.size()), int(0.95 * a.rows));
  for (size_t k = 1; k < m.size(); ++k) EXPECT_LT(m[k - 1].first, m[k].first);
}

TEST(BowMatcher, EachFeatureOfBIsMatchedOnce) {
  // Two identical features of A compete for one feature of B: the first (equal distance) wins.
  cv::Mat a(2, 32, CV_8U, cv::Scalar(0x0f)), b(1, 32, CV_8U, cv::Scalar(0x0f));
  const FeatureVector fa = {{3, {0, 1}}}, fb = {{3, {0}}};
  const auto m = matchByDirectIndex(fa, a, fb, b);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(m[0], std::make_pair(0, 0));
  // Different nodes: nothing compared, nothing matched.
  EXPECT_TRUE(matchByDirectIndex({{2, {0, 1}}}, a, fb, b).empty());
  EXPECT_NE(test::errorOf([&] { matchByDirectIndex(fa, cv::Mat(2, 16, CV_8U), fb, b); }).find("32 bytes"),
            std::string::npos);
  EXPECT_NE(test::errorOf([&] { matchByDirectIndex({{3, {5}}}, a, fb, b); }).find("feature 5 of A"), std::string::npos);
}

// KITTI 06 frames 0 and 1 (evaluation images): the direct index at level 1 keeps most of the
// matches an exhaustive search finds with the same thresholds, and they are geometrically sound.
TEST(BowMatcher, ConsecutiveKittiFramesMatchNearby) {
  NERFSLAM_REQUIRE_DATA(kitti, "kitti06_first51/image_l");
  const Vocabulary voc = loadVocabulary(test::sourceDir() / "config/vocabulary/brief_k12_L4.voc");
  Frame f[2];
  FeatureVector fv[2], all[2];
  for (int i = 0; i < 2; ++i) {
    const cv::Mat img = cv::imread((kitti / cv::format("%06d.png", i)).string(), cv::IMREAD_GRAYSCALE);
    ASSERT_FALSE(img.empty());
    f[i] = extractFrame(img, Camera::pinhole(img.cols, img.rows, 700, 700, img.cols / 2.0, img.rows / 2.0),
                        FeatureOptions{});
    BowVector bow;
    voc.transform(f[i].descriptors, &bow, &fv[i], 1);
    all[i] = {{0, {}}};  // one node holding every feature: the exhaustive search
    for (int r = 0; r < f[i].descriptors.rows; ++r) all[i][0].second.push_back(r);
  }
  const auto near = [&](const std::vector<std::pair<int, int>>& m) {
    size_t n = 0;
    for (const auto& [i, j] : m) {
      const cv::Point2f d = f[0].keypoints[size_t(i)].pt - f[1].keypoints[size_t(j)].pt;
      n += std::hypot(d.x, d.y) < 60 ? 1 : 0;
    }
    return n;
  };
  const auto m = matchByDirectIndex(fv[0], f[0].descriptors, fv[1], f[1].descriptors);
  const auto exhaustive = matchByDirectIndex(all[0], f[0].descriptors, all[1], f[1].descriptors);
  ASSERT_GE(m.size(), 150u);
  EXPECT_GE(double(near(m)), 0.9 * double(m.size())) << near(m) << " of " << m.size() << " matches within 60 px";
  EXPECT_GE(double(near(m)), 0.7 * double(near(exhaustive))) << near(m) << " vs " << near(exhaustive);
}

}  // namespace
}  // namespace nerfslam
