// Keyframe images of a map folder and the Frames rebuilt from them (src/system/map_rebuild.h): the
// image a keyframe is stored with, the pixel checksum, and a rebuilt frame that keeps the stored
// features whatever feature extraction gives today.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <opencv2/core.hpp>

#include "map_test_maps.h"
#include "nerfslam/core/error.h"
#include "system/map_codec.h"
#include "system/map_rebuild.h"
#include "test_support.h"

namespace nerfslam {
namespace {
using namespace maptest;
using map_detail::KeyframeRecord;

TEST(MapRebuild, PixelsChecksumIgnoresRowPaddingAndSeesOnePixel) {
  cv::Mat img(24, 32, CV_8UC3);
  cv::randu(img, 0, 256);
  cv::Mat wide(30, 50, CV_8UC3, cv::Scalar(1, 2, 3));
  img.copyTo(wide(cv::Rect(5, 3, 32, 24)));
  const cv::Mat view = wide(cv::Rect(5, 3, 32, 24));  // the same pixels, rows 50 pixels apart
  ASSERT_FALSE(view.isContinuous());
  EXPECT_EQ(map_detail::pixelsCrc(view), map_detail::pixelsCrc(img));
  cv::Mat changed = img.clone();
  changed.at<cv::Vec3b>(23, 31)[2] ^= 1;
  EXPECT_NE(map_detail::pixelsCrc(changed), map_detail::pixelsCrc(img));
}

TEST(MapRebuild, KeyframeImageIsTheColourInputElseThePyramidBase) {
  Keyframe kf;
  kf.id = 17;
  auto f = std::make_shared<Frame>();
  kf.frame = f;
  EXPECT_NE(test::errorOf([&] { map_detail::keyframeImage(kf); }).find("keyframe 17: its frame has no image"),
            std::string::npos);
  f->pyramid = {cv::Mat(8, 8, CV_8U, cv::Scalar(5)), cv::Mat(4, 4, CV_8U)};
  EXPECT_EQ(map_detail::keyframeImage(kf).data, f->pyramid[0].data);
  f->colour = cv::Mat(8, 8, CV_8UC3, cv::Scalar(1, 2, 3));
  EXPECT_EQ(map_detail::keyframeImage(kf).data, f->colour.data);
}

TEST(MapRebuild, RebuiltFrameKeepsTheStoredFeatures) {
  Camera cam;
  const auto map = makeSmallMap(3, 320, 240, &cam);
  const auto [kfs, points] = map->snapshot();
  const std::vector<map_detail::KeyframeImageRef> refs(kfs.size(),
                                                       map_detail::KeyframeImageRef{"images/kf.png", 320, 240, 3, 0});
  std::vector<KeyframeRecord> records = map_detail::decodeKeyframes(map_detail::encodeKeyframes(kfs, refs), "kf.bin");
  const KeyframeRecord& rec = records[1];
  const cv::Mat& image = map_detail::keyframeImage(kfs[1]);
  FeatureOptions same = systemTrackingDefaults().features;
  same.max_features = 600;  // as makeSmallMap extracted them

  bool identical = false;
  auto f = map_detail::rebuildFrame(rec, image, cam, same, "kf.bin", &identical);
  EXPECT_TRUE(identical);
  EXPECT_TRUE(map_detail::sameFeatures(*f, rec));
  EXPECT_EQ(f->id, rec.frame_id);
  EXPECT_EQ(f->timestamp, rec.timestamp);

  // Other options extract other features; the stored ones are installed (and the grid rebuilt).
  FeatureOptions fewer = same;
  fewer.max_features = 200;
  EXPECT_FALSE(map_detail::sameFeatures(extractFrame(image, cam, fewer), rec));
  f = map_detail::rebuildFrame(rec, image, cam, fewer, "kf.bin", &identical);
  EXPECT_FALSE(identical);
  EXPECT_TRUE(map_detail::sameFeatures(*f, rec));
  EXPECT_EQ(f->undistorted, rec.undistorted);
  const cv::KeyPoint& k0 = rec.keypoints[0];
  const std::vector<int> near = f->featuresInArea({k0.pt.x, k0.pt.y}, 1.0);
  EXPECT_NE(std::find(near.begin(), near.end(), 0), near.end()) << "the grid indexes the stored keypoints";

  // A stored keypoint on a pyramid level the image does not give with the map's options.
  KeyframeRecord bad = rec;
  bad.keypoints[3].octave = 12;
  const std::string e = test::errorOf([&] { map_detail::rebuildFrame(bad, image, cam, same, "kf.bin", &identical); });
  EXPECT_NE(e.find(fmt::format("kf.bin: field 'keyframe (id {}).keypoints[3].octave': pyramid level 12, but the "
                               "stored image gives {} levels",
                               rec.kf.id, f->pyramid.size())),
            std::string::npos)
      << e;
}

}  // namespace
}  // namespace nerfslam
