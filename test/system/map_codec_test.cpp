// The binaries of a map folder (src/system/map_codec.h): keyframes and map points encoded and
// decoded back exactly (and re-encoded to the same bytes), refusal of foreign, truncated and
// inconsistent data with errors naming the file and the record, and the cross-check of the two
// files' associations.
#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <opencv2/core.hpp>

#include "map_test_maps.h"
#include "nerfslam/core/error.h"
#include "system/map_codec.h"
#include "test_support.h"

namespace nerfslam {
namespace {
using namespace maptest;
using map_detail::KeyframeImageRef;
using map_detail::KeyframeRecord;

// Keyframes and points of a small map (one keyframe fixed, one point without a descriptor) and
// made-up image references.
struct Snapshot {
  std::vector<Keyframe> kfs;
  std::vector<MapPoint> points;
  std::vector<KeyframeImageRef> images;
  Snapshot() {
    Camera cam;
    const auto map = makeSmallMap(4, 320, 240, &cam);
    std::tie(kfs, points) = map->snapshot();
    kfs.front().fixed = true;
    points.back().descriptor = cv::Mat();
    for (const Keyframe& kf : kfs)
      images.push_back({fmt::format("images/kf{:06d}.000001.png", kf.id), 320, 240, 3,
                        static_cast<uint32_t>(0x9e3779b9u * static_cast<uint32_t>(kf.id + 1))});
  }
};

// Keyframes whose frames hold what the records hold (all the keyframes file stores).
std::vector<Keyframe> keyframesOf(const std::vector<KeyframeRecord>& records) {
  std::vector<Keyframe> out;
  for (const KeyframeRecord& r : records) {
    Keyframe kf = r.kf;
    auto f = std::make_shared<Frame>();
    f->id = r.frame_id;
    f->timestamp = r.timestamp;
    f->keypoints = r.keypoints;
    f->undistorted = r.undistorted;
    f->descriptors = r.descriptors;
    kf.frame = f;
    out.push_back(std::move(kf));
  }
  return out;
}

TEST(MapCodec, KeyframesAndPointsRoundTripExactly) {
  const Snapshot s;
  ASSERT_GE(s.kfs.size(), 3u);
  ASSERT_GE(s.points.size(), 20u);
  const std::string kf_bytes = map_detail::encodeKeyframes(s.kfs, s.images);
  const std::vector<KeyframeRecord> records = map_detail::decodeKeyframes(kf_bytes, "kf.bin");
  ASSERT_EQ(records.size(), s.kfs.size());
  for (size_t k = 0; k < records.size(); ++k) {
    const Keyframe& kf = s.kfs[k];
    const KeyframeRecord& r = records[k];
    SCOPED_TRACE("keyframe " + std::to_string(kf.id));
    EXPECT_EQ(r.kf.id, kf.id);
    EXPECT_EQ(r.kf.fixed, kf.fixed);
    EXPECT_EQ(r.kf.T_world_cam.rotation().coeffs(), kf.T_world_cam.rotation().coeffs());
    EXPECT_EQ(r.kf.T_world_cam.translation(), kf.T_world_cam.translation());
    EXPECT_EQ(r.kf.points, kf.points);
    EXPECT_FALSE(r.kf.frame) << "the frame is rebuilt from the image, not stored";
    EXPECT_EQ(r.frame_id, kf.frame->id);
    EXPECT_EQ(r.timestamp, kf.frame->timestamp);
    EXPECT_EQ(r.image.name, s.images[k].name);
    EXPECT_EQ(r.image.width, 320);
    EXPECT_EQ(r.image.height, 240);
    EXPECT_EQ(r.image.channels, 3);
    EXPECT_EQ(r.image.pixels_crc, s.images[k].pixels_crc);
    expectSameKeypoints(r.keypoints, r.undistorted, kf.frame->keypoints, kf.frame->undistorted);
    ASSERT_EQ(r.descriptors.size(), kf.frame->descriptors.size());
    EXPECT_EQ(cv::norm(r.descriptors, kf.frame->descriptors, cv::NORM_HAMMING), 0.0);
  }
  EXPECT_EQ(map_detail::encodeKeyframes(keyframesOf(records), s.images), kf_bytes);

  const std::string pt_bytes = map_detail::encodePoints(s.points);
  const std::vector<MapPoint> points = map_detail::decodePoints(pt_bytes, "pt.bin");
  ASSERT_EQ(points.size(), s.points.size());
  for (size_t i = 0; i < points.size(); ++i) expectSamePoint(points[i], s.points[i]);
  EXPECT_TRUE(points.back().descriptor.empty());
  EXPECT_EQ(map_detail::encodePoints(points), pt_bytes);
  EXPECT_NO_THROW(map_detail::checkAssociations(records, points, "kf.bin", "pt.bin"));
}

TEST(MapCodec, DecodeRefusesForeignTruncatedAndTrailingData) {
  const Snapshot s;
  const std::string kf = map_detail::encodeKeyframes(s.kfs, s.images);
  const std::string pt = map_detail::encodePoints(s.points);
  auto keyframesError = [](const std::string& data) {
    return test::errorOf([&] { map_detail::decodeKeyframes(data, "kf.bin"); });
  };
  auto pointsError = [](const std::string& data) {
    return test::errorOf([&] { map_detail::decodePoints(data, "pt.bin"); });
  };
  std::string e = keyframesError(pt);
  EXPECT_NE(e.find("kf.bin: field 'magic': not a nerfslam keyframes file"), std::string::npos) << e;
  e = pointsError(kf);
  EXPECT_NE(e.find("pt.bin: field 'magic': not a nerfslam map points file"), std::string::npos) << e;
  std::string other = kf;
  other[8] = 2;  // the version, after the 8-byte magic
  e = keyframesError(other);
  EXPECT_NE(e.find("kf.bin: field 'version': keyframes file version 2, this nerfslam reads 1"), std::string::npos) << e;

  // Cut anywhere: an error naming the file and saying it is truncated, never a crash.
  auto expectTruncated = [](const std::string& data, const std::string& name, const auto& errorOfData) {
    for (size_t n = 0; n < data.size(); n += 1 + data.size() / 211) {
      const std::string err = errorOfData(data.substr(0, n));
      ASSERT_EQ(err.rfind(name + ": field '", 0), 0u) << "cut at " << n << ": " << err;
      ASSERT_NE(err.find("truncated"), std::string::npos) << "cut at " << n << ": " << err;
    }
  };
  expectTruncated(kf, "kf.bin", keyframesError);
  expectTruncated(pt, "pt.bin", pointsError);
  e = keyframesError(kf + "x");
  EXPECT_NE(e.find("kf.bin: field 'count': 1 bytes after the last keyframe"), std::string::npos) << e;
  e = pointsError(pt + "xy");
  EXPECT_NE(e.find("pt.bin: field 'count': 2 bytes after the last point"), std::string::npos) << e;

  // Fields of the first record: the quaternion's x (after magic, version, count, id, frame id,
  // timestamp and the fixed flag) and a point's descriptor size (after its id, position, normal,
  // first keyframe and the visible and found counts).
  other = kf;
  const double two = 2.0;
  std::memcpy(&other[8 + 4 + 8 + 8 + 8 + 8 + 1], &two, sizeof two);
  e = keyframesError(other);
  EXPECT_NE(e.find(fmt::format("kf.bin: field 'keyframe[0] (id {}).pose': not a finite rigid pose", s.kfs[0].id)),
            std::string::npos)
      << e;
  other = pt;
  const uint32_t five = 5;
  std::memcpy(&other[8 + 4 + 8 + 8 + 48 + 8 + 4 + 4], &five, sizeof five);
  e = pointsError(other);
  EXPECT_NE(
      e.find(fmt::format("pt.bin: field 'point[0] (id {}).descriptor_bytes': 5 (expected 0 or 32)", s.points[0].id)),
      std::string::npos)
      << e;
}

TEST(MapCodec, EncodeRefusesInconsistentFramesAndDescriptors) {
  Snapshot s;
  Frame f = *s.kfs[1].frame;
  f.undistorted.pop_back();
  s.kfs[1].frame = std::make_shared<const Frame>(f);
  std::string e = test::errorOf([&] { map_detail::encodeKeyframes(s.kfs, s.images); });
  EXPECT_NE(e.find(fmt::format("keyframe {}: inconsistent frame", s.kfs[1].id)), std::string::npos) << e;
  const cv::Mat wide(4, 64, CV_8U, cv::Scalar(7));
  s.points[2].descriptor = wide(cv::Rect(0, 0, 16, 2));  // 32 bytes, not one continuous row
  e = test::errorOf([&] { map_detail::encodePoints(s.points); });
  EXPECT_NE(e.find(fmt::format("map point {}: descriptor is not a continuous 8-bit row", s.points[2].id)),
            std::string::npos)
      << e;
}

TEST(MapCodec, AssociationsOfTheTwoFilesMustAgree) {
  const Snapshot s;
  const std::vector<KeyframeRecord> records =
      map_detail::decodeKeyframes(map_detail::encodeKeyframes(s.kfs, s.images), "kf.bin");
  const std::vector<MapPoint> points = map_detail::decodePoints(map_detail::encodePoints(s.points), "pt.bin");
  auto check = [&](std::vector<KeyframeRecord> r, std::vector<MapPoint> p) {
    return test::errorOf([&] { map_detail::checkAssociations(r, p, "kf.bin", "pt.bin"); });
  };
  ASSERT_EQ(check(records, points), "");

  auto r = records;
  r[1].kf.id = r[0].kf.id;
  std::string e = check(r, points);
  EXPECT_NE(e.find(fmt::format("kf.bin: field 'keyframe[1].id': id {} listed twice", r[0].kf.id)), std::string::npos)
      << e;

  auto p = points;
  while (p[0].observations.size() > 1) p[0].observations.erase(p[0].observations.begin());
  e = check(records, p);
  EXPECT_NE(e.find(fmt::format("pt.bin: field 'point[0] (id {}).observations': 1 observations", p[0].id)),
            std::string::npos)
      << e;

  p = points;
  const auto [kid, idx] = *p[0].observations.begin();
  p[0].observations.erase(kid);
  p[0].observations.emplace(999999, idx);
  e = check(records, p);
  EXPECT_NE(e.find("keyframe 999999 is not in kf.bin"), std::string::npos) << e;

  // A keypoint slot naming a point the points file does not have.
  r = records;
  size_t k = 0, i = 0;
  auto freeSlot = [&] {
    for (k = 0; k < r.size(); ++k)
      for (i = 0; i < r[k].kf.points.size(); ++i)
        if (r[k].kf.points[i] == kNoPoint) return;
  };
  freeSlot();
  ASSERT_LT(k, r.size()) << "no free keypoint slot";
  r[k].kf.points[i] = 123456789;
  e = check(r, points);
  EXPECT_NE(e.find(fmt::format("kf.bin: field 'keyframe[{}] (id {}).keypoints[{}].point': map point 123456789 is "
                               "not in pt.bin",
                               k, r[k].kf.id, i)),
            std::string::npos)
      << e;
}

}  // namespace
}  // namespace nerfslam
