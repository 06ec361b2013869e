#include "nerfslam/mapping/place_recognition.h"

#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/mapping/loop_closing.h"
#include "test_support.h"

namespace nerfslam {
namespace {

std::shared_ptr<const Frame> frameOf(const std::filesystem::path& f, uint64_t id) {
  const cv::Mat img = cv::imread(f.string(), cv::IMREAD_GRAYSCALE);
  const Camera cam = Camera::pinhole(img.cols, img.rows, img.cols, img.cols, img.cols / 2.0, img.rows / 2.0);
  return std::make_shared<const Frame>(extractFrame(img, cam, FeatureOptions{}, id, double(id)));
}

// Keyframes of a sequence's images, consecutive ones covisible (30 points each pair shares).
std::vector<KeyframeId> addChain(Map& map, const std::vector<std::shared_ptr<const Frame>>& frames) {
  std::vector<KeyframeId> ids;
  for (const auto& f : frames) {
    Keyframe kf;
    kf.frame = f;
    ids.push_back(map.addKeyframe(kf));
  }
  for (size_t i = 1; i < ids.size(); ++i)
    for (int j = 0; j < 30; ++j)
      map.addPoint(Eigen::Vector3d(double(i), double(j), 5.0), {{ids[i - 1], 100 + j}, {ids[i], j}});
  return ids;
}

// A map of N keyframes (every 2nd KITTI 06 frame) and the same map with 2N more from other places
// (New Tsukuba): a frame of a keyframe's image finds that keyframe first, a frame between two
// keyframes one of them, in both maps, with the same candidates: the other places never compete.
TEST(PlaceRecognition, RelocalisationFindsTheKeyframeOfTheImageInAMapOfNAnd3N) {
  NERFSLAM_REQUIRE_DATA(kitti, "kitti06_first51/image_l");
  NERFSLAM_REQUIRE_DATA(tsukuba, "new_tsukuba_150/images");
  auto voc = std::make_shared<const Vocabulary>(loadVocabulary(vocabularyPath("")));
  std::vector<std::shared_ptr<const Frame>> kitti_frames, other_frames;
  for (int i = 0; i <= 50; i += 2) kitti_frames.push_back(frameOf(kitti / cv::format("%06d.png", i), uint64_t(i)));
  for (int i = 0; i < 2 * static_cast<int>(kitti_frames.size()); ++i)
    other_frames.push_back(frameOf(tsukuba / cv::format("rgb_%05d.png", 2 * i), uint64_t(1000 + i)));
  const size_t n = kitti_frames.size();

  Map small, large;
  const std::vector<KeyframeId> ids_small = addChain(small, kitti_frames);
  const std::vector<KeyframeId> ids_large = addChain(large, kitti_frames);
  addChain(large, other_frames);
  PlaceRecognition db_small(voc), db_large(voc);
  EXPECT_EQ(db_small.addMapKeyframes(small), n);
  EXPECT_EQ(db_large.addMapKeyframes(large), 3 * n);
  EXPECT_EQ(db_large.addMapKeyframes(large), 0u);  // all there already
  ASSERT_EQ(ids_small, ids_large);

  for (int frame : {0, 10, 24, 38, 50}) {  // keyframes' own images
    const BowVector bow = db_small.bagOfWords(*kitti_frames[size_t(frame / 2)]);
    const auto a = db_small.relocalizationCandidates(small, bow), b = db_large.relocalizationCandidates(large, bow);
    ASSERT_FALSE(a.empty());
    EXPECT_EQ(a[0], ids_small[size_t(frame / 2)]) << "frame " << frame;
    EXPECT_EQ(a, b) << "frame " << frame;
  }
  for (int frame : {7, 21, 33, 47}) {  // between two keyframes
    const auto f = frameOf(kitti / cv::format("%06d.png", frame), uint64_t(frame));
    const BowVector bow = db_small.bagOfWords(*f);
    const auto a = db_small.relocalizationCandidates(small, bow), b = db_large.relocalizationCandidates(large, bow);
    ASSERT_FALSE(a.empty());
    const KeyframeId before = ids_small[size_t(frame / 2)], after = ids_small[size_t(frame / 2 + 1)];
    EXPECT_TRUE(a[0] == before || a[0] == after) << "frame " << frame << ": keyframe " << a[0];
    EXPECT_EQ(a, b) << "frame " << frame;
  }
  // A culled keyframe is never a candidate; an empty bag finds nothing.
  const KeyframeId gone = ids_large[5];
  large.eraseKeyframe(gone);
  const auto c = db_large.relocalizationCandidates(large, db_large.bagOfWords(*kitti_frames[5]));
  EXPECT_EQ(std::count(c.begin(), c.end(), gone), 0);
  // Its bag leaves the database with eraseMissing (the keyframes still in the map stay).
  EXPECT_TRUE(db_large.contains(gone));
  EXPECT_EQ(db_large.eraseMissing(large.keyframeIds()), 1u);
  EXPECT_FALSE(db_large.contains(gone));
  EXPECT_EQ(db_large.size(), 3 * n - 1);
  EXPECT_EQ(db_large.eraseMissing(large.keyframeIds()), 0u);
  EXPECT_TRUE(db_large.relocalizationCandidates(large, BowVector{}).empty());
  db_large.clear();
  EXPECT_EQ(db_large.size(), 0u);
}

}  // namespace
}  // namespace nerfslam
