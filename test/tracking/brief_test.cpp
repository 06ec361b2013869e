#include "nerfslam/tracking/brief.h"

#include <gtest/gtest.h>
#include <hwy/targets.h>

#include <algorithm>
#include <random>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/tracking/frame.h"
#include "test_support.h"

namespace nerfslam {
namespace {

// The definition, pixel by pixel: (1 6 15 20 15 6 1)/64 down the columns, rounded, then along the
// rows, rounded; the 3-pixel border copied.
cv::Mat smoothReference(const cv::Mat& src) {
  const int k[7] = {1, 6, 15, 20, 15, 6, 1};
  cv::Mat col(src.size(), CV_32S, cv::Scalar(0)), out = src.clone();
  for (int y = 3; y < src.rows - 3; ++y)
    for (int x = 0; x < src.cols; ++x) {
      int s = 0;
      for (int i = 0; i < 7; ++i) s += k[i] * src.at<uint8_t>(y + i - 3, x);
      col.at<int>(y, x) = (s + 32) >> 6;
    }
  for (int y = 3; y < src.rows - 3; ++y)
    for (int x = 3; x < src.cols - 3; ++x) {
      int s = 0;
      for (int i = 0; i < 7; ++i) s += k[i] * col.at<int>(y, x + i - 3);
      out.at<uint8_t>(y, x) = static_cast<uint8_t>((s + 32) >> 6);
    }
  return out;
}

TEST(Brief, SmoothingMatchesItsDefinitionOnEveryTarget) {
  for (int64_t target : hwy::SupportedAndGeneratedTargets()) {
    hwy::SetSupportedTargetsForTest(target);
    for (const cv::Size sz :
         {cv::Size(7, 7), cv::Size(13, 9), cv::Size(70, 11), cv::Size(640, 480), cv::Size(203, 77)}) {
      const cv::Mat img = test::noiseImage(sz.width, sz.height, static_cast<uint32_t>(sz.area()));
      cv::Mat ours;
      smoothForBrief(img, &ours);
      ASSERT_EQ(cv::norm(ours, smoothReference(img), cv::NORM_INF), 0.0) << hwy::TargetName(target) << " " << sz;
    }
  }
  hwy::SetSupportedTargetsForTest(0);
}

TEST(Brief, PatternIsTheLearnedOneInsideTheDisc) {
  const auto& p = briefPattern();
  ASSERT_EQ(p.size(), 8u * kBriefBytes);
  for (const cv::Vec4i& t : p) {
    EXPECT_LE(t[0] * t[0] + t[1] * t[1], kBriefRadius * kBriefRadius);
    EXPECT_LE(t[2] * t[2] + t[3] * t[3], kBriefRadius * kBriefRadius);
    EXPECT_FALSE(t[0] == t[2] && t[1] == t[3]);
  }
  std::vector<cv::Vec4i> sorted(p.begin(), p.end());
  std::sort(sorted.begin(), sorted.end(), [](const cv::Vec4i& a, const cv::Vec4i& b) {
    return std::lexicographical_compare(a.val, a.val + 4, b.val, b.val + 4);
  });
  EXPECT_EQ(std::adjacent_find(sorted.begin(), sorted.end()), sorted.end()) << "a test appears twice";
}

// The same corners in an image and in the image turned by 90 degrees get nearly the same
// descriptors (steering), and unrelated corners do not.
TEST(Brief, DescriptorsFollowTheCornerOrientation) {
  NERFSLAM_REQUIRE_DATA(dir, "new_tsukuba_150");
  const cv::Mat img = cv::imread((dir / "images/rgb_00000.png").string(), cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(img.empty());
  cv::Mat rot;
  cv::rotate(img, rot, cv::ROTATE_90_CLOCKWISE);  // (x, y) -> (h - 1 - y, x)
  FeatureOptions opt;
  opt.num_levels = 1;
  const Frame a = extractFrame(img, Camera::pinhole(640, 480, 500, 500, 320, 240), opt);
  const Frame b = extractFrame(rot, Camera::pinhole(480, 640, 500, 500, 240, 320), opt);
  std::vector<int> same, other;
  for (size_t i = 0; i < a.keypoints.size(); ++i) {
    const cv::Point2f p = a.keypoints[i].pt;
    const cv::Point2f q(static_cast<float>(img.rows - 1) - p.y, p.x);
    for (size_t j = 0; j < b.keypoints.size(); ++j)
      if (cv::norm(b.keypoints[j].pt - q) < 0.5) {
        same.push_back(descriptorDistance(a.descriptors.ptr<uint8_t>(static_cast<int>(i)),
                                          b.descriptors.ptr<uint8_t>(static_cast<int>(j))));
        other.push_back(descriptorDistance(a.descriptors.ptr<uint8_t>(static_cast<int>(i)),
                                           b.descriptors.ptr<uint8_t>(static_cast<int>((j + 97) % b.size()))));
      }
  }
  ASSERT_GT(same.size(), 100u);
  std::nth_element(same.begin(), same.begin() + static_cast<long>(same.size() / 2), same.end());
  std::nth_element(other.begin(), other.begin() + static_cast<long>(other.size() / 2), other.end());
  const int med_same = same[same.size() / 2], med_other = other[other.size() / 2];
  std::printf("%zu corners found in both: median distance %d (same corner) vs %d (another corner)\n", same.size(),
              med_same, med_other);
  EXPECT_LT(med_same, 40);
  EXPECT_GT(med_other, 90);
}

}  // namespace
}  // namespace nerfslam
