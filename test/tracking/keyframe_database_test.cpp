#include "nerfslam/tracking/keyframe_database.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <thread>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/crc32.h"
#include "nerfslam/tracking/frame.h"
#include "test_support.h"

namespace nerfslam {
namespace {

TEST(KeyframeDatabase, QueryScoresAreTheL1Score) {
  KeyframeDatabase db(10);
  const BowVector a = {{1, 0.5f}, {4, 0.25f}, {9, 0.25f}}, b = {{1, 0.25f}, {5, 0.5f}, {9, 0.25f}}, c = {{2, 1.0f}},
                  q = {{1, 0.4f}, {5, 0.4f}, {9, 0.2f}};
  db.add(10, a);
  db.add(20, b);
  db.add(30, c);
  EXPECT_EQ(db.size(), 3u);
  EXPECT_EQ(db.postingCount(), 7u);
  EXPECT_EQ(db.postingCount(9), 2u);
  EXPECT_EQ(db.postingCount(3), 0u);
  const auto r = db.query(q);
  ASSERT_EQ(r.size(), 2u);  // keyframe 30 shares no word
  EXPECT_EQ(r[0].keyframe, 20u);
  EXPECT_NEAR(r[0].score, Vocabulary::score(q, b), 1e-6);
  EXPECT_EQ(r[0].shared_words, 3);
  EXPECT_EQ(r[1].keyframe, 10u);
  EXPECT_NEAR(r[1].score, Vocabulary::score(q, a), 1e-6);
  EXPECT_EQ(r[1].shared_words, 2);

  PlaceQuery p;
  p.min_score = 0.7;  // scores 0.85 and 0.6
  ASSERT_EQ(db.query(q, p).size(), 1u);
  p.min_score = 0;
  p.max_results = 1;
  ASSERT_EQ(db.query(q, p).size(), 1u);
  EXPECT_EQ(db.query(q, p)[0].keyframe, 20u);
  p.max_results = 0;
  p.exclude = [](uint64_t kf) { return kf == 20; };
  ASSERT_EQ(db.query(q, p).size(), 1u);
  EXPECT_EQ(db.query(q, p)[0].keyframe, 10u);
  p.exclude = nullptr;
  p.min_shared_words = 3;
  ASSERT_EQ(db.query(q, p).size(), 1u);
}

TEST(KeyframeDatabase, AddReplacesAndEraseRemoves) {
  KeyframeDatabase db(10);
  db.add(1, {{1, 1.0f}});
  db.add(2, {{1, 0.5f}, {2, 0.5f}});
  db.add(1, {{3, 1.0f}});  // replaced: no longer under word 1
  EXPECT_EQ(db.size(), 2u);
  EXPECT_EQ(db.postingCount(), 3u);
  auto r = db.query({{1, 1.0f}});
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].keyframe, 2u);
  EXPECT_TRUE(db.erase(2));
  EXPECT_FALSE(db.erase(2));
  EXPECT_TRUE(db.query({{1, 1.0f}}).empty());
  EXPECT_EQ(db.postingCount(), 1u);
  ASSERT_NE(db.bow(1), nullptr);
  EXPECT_EQ(db.bow(1)->front().first, 3u);
  EXPECT_EQ(db.bow(2), nullptr);
  EXPECT_NE(test::errorOf([&] { db.add(5, {{10, 1.0f}}); }).find("word 10"), std::string::npos);
  db.clear();
  EXPECT_EQ(db.size(), 0u);
  EXPECT_EQ(db.postingCount(), 0u);
}

BowVector randomBow(std::mt19937& rng, size_t words, int n) {
  std::map<WordId, float> m;
  for (int i = 0; i < n; ++i) m[WordId(rng() % words)] += 1.0f;
  BowVector b(m.begin(), m.end());
  float total = 0;
  for (const auto& e : b) total += e.second;
  for (auto& e : b) e.second /= total;
  return b;
}

TEST(KeyframeDatabase, ConcurrentQueriesAgreeWithSequentialOnes) {
  std::mt19937 rng(4);
  KeyframeDatabase db(500);
  for (uint64_t k = 0; k < 300; ++k) db.add(k * 7, randomBow(rng, 500, 60));
  for (uint64_t k = 0; k < 300; k += 3) db.erase(k * 7);  // slots freed and reused
  for (uint64_t k = 300; k < 350; ++k) db.add(k * 7, randomBow(rng, 500, 60));
  std::vector<BowVector> queries;
  for (int i = 0; i < 40; ++i) queries.push_back(randomBow(rng, 500, 60));
  PlaceQuery all;
  all.max_results = 0;
  std::vector<std::vector<PlaceCandidate>> expected;
  for (const auto& q : queries) {
    expected.push_back(db.query(q, all));
    // Scores are the L1 scores with the stored bags.
    for (const auto& c : expected.back()) EXPECT_NEAR(c.score, Vocabulary::score(q, *db.bow(c.keyframe)), 1e-5);
  }
  std::vector<int> mismatches(2, 0);
  std::vector<std::thread> threads;
  for (int t = 0; t < 2; ++t)
    threads.emplace_back([&, t] {
      for (int rep = 0; rep < 20; ++rep)
        for (size_t i = 0; i < queries.size(); ++i) {
          const auto r = db.query(queries[i], all);
          bool same = r.size() == expected[i].size();
          for (size_t j = 0; same && j < r.size(); ++j)
            same = r[j].keyframe == expected[i][j].keyframe && r[j].score == expected[i][j].score;
          mismatches[size_t(t)] += same ? 0 : 1;
        }
    });
  for (auto& th : threads) th.join();
  EXPECT_EQ(mismatches[0] + mismatches[1], 0);
  EXPECT_EQ(db.size(), 250u);
}

TEST(KeyframeDatabase, BlobRoundTripAndBadBlobs) {
  KeyframeDatabase db(100);
  db.add(7, {{1, 0.5f}, {50, 0.5f}});
  db.add(3, {{2, 0.25f}, {50, 0.75f}});
  const std::string blob = db.serialize();
  const KeyframeDatabase back = KeyframeDatabase::deserialize(blob, "db.bin", 100);
  EXPECT_EQ(back.size(), 2u);
  EXPECT_EQ(back.serialize(), blob);
  EXPECT_EQ(*back.bow(3), *db.bow(3));
  test::TempDir dir;
  saveKeyframeDatabase(db, dir / "kf.db");
  EXPECT_EQ(loadKeyframeDatabase(dir / "kf.db").serialize(), blob);
  EXPECT_NE(
      test::errorOf([&] { loadKeyframeDatabase(dir / "none.db"); }).find("none.db: keyframe database file not found"),
      std::string::npos);

  auto err = [&](const std::string& b, size_t words = 0) {
    return test::errorOf([&] { KeyframeDatabase::deserialize(b, "db.bin", words); });
  };
  EXPECT_NE(err(blob, 99).find("field 'word_count'"), std::string::npos);
  EXPECT_NE(err(blob.substr(0, 6)).find("field 'magic'"), std::string::npos);
  EXPECT_NE(err(blob.substr(0, blob.size() - 3)).find("field 'crc32'"), std::string::npos);
  std::string v = blob;
  v[8] = 9;
  EXPECT_NE(err(v).find("field 'version'"), std::string::npos);
  // Well-formed blobs (CRC right) with bad content.
  auto withCrc = [](std::string body) {
    const uint32_t c = crc32(body);
    for (int i = 0; i < 4; ++i) body.push_back(char(uint8_t(c >> (8 * i))));
    return body;
  };
  const std::string body = blob.substr(0, blob.size() - 4);
  std::string huge = body.substr(0, 16) + std::string("\xff\xff\xff\x0f", 4);
  EXPECT_NE(err(withCrc(huge)).find("field 'keyframe_count'"), std::string::npos);
  std::string bad_word = body;
  bad_word[20 + 12] = char(200);  // keyframe 3's first word: 200 >= 100 words
  EXPECT_NE(err(withCrc(bad_word)).find("keyframes[0].word"), std::string::npos);
  EXPECT_NE(err(withCrc(body + "xy")).find("field 'end'"), std::string::npos);
}

// ----------------------------------------------------------------------------------- real images

cv::Mat descriptorsOf(const std::filesystem::path& f) {
  const cv::Mat img = cv::imread(f.string(), cv::IMREAD_GRAYSCALE);
  const Camera cam = Camera::pinhole(img.cols, img.rows, img.cols, img.cols, img.cols / 2.0, img.rows / 2.0);
  return extractFrame(img, cam, FeatureOptions{}).descriptors;
}

// Evaluation images only (none of them trained the shipped vocabulary): every 5th KITTI 06 frame,
// the temple ring and the fountain. Ids: KITTI frame i -> i, others 1000 + n.
TEST(KeyframeDatabase, RealImagesFindThemselvesAndTheirNeighbours) {
  NERFSLAM_REQUIRE_DATA(kitti, "kitti06_first51/image_l");
  NERFSLAM_REQUIRE_DATA(temple, "middlebury_templeRing");
  NERFSLAM_REQUIRE_DATA(fountain, "strecha_fountain-P11/images");
  const Vocabulary voc = loadVocabulary(test::sourceDir() / "config/vocabulary/brief_k12_L4.voc");
  KeyframeDatabase db(voc.wordCount());
  std::map<uint64_t, BowVector> bows;
  auto addImage = [&](uint64_t id, const std::filesystem::path& f) {
    voc.transform(descriptorsOf(f), &bows[id]);
    db.add(id, bows[id]);
  };
  for (int i = 0; i <= 50; i += 5) addImage(uint64_t(i), kitti / cv::format("%06d.png", i));
  uint64_t other = 1000;
  for (const auto& dir : {temple, fountain}) {
    std::vector<std::filesystem::path> files;
    for (const auto& e : std::filesystem::directory_iterator(dir))
      if (e.path().extension() == ".png" || e.path().extension() == ".jpg") files.push_back(e.path());
    std::sort(files.begin(), files.end());
    for (size_t n = 0; n < files.size(); n += 3) addImage(other++, files[n]);
  }
  ASSERT_GT(db.size(), 20u);
  // Every stored image is its own best match, with score 1.
  for (const auto& [id, bow] : bows) {
    PlaceQuery two;
    two.max_results = 2;
    const auto r = db.query(bow, two);
    ASSERT_FALSE(r.empty());
    EXPECT_EQ(r[0].keyframe, id);
    EXPECT_NEAR(r[0].score, 1.0, 1e-5);
    ASSERT_EQ(r.size(), 2u);
    EXPECT_LT(r[1].score, 0.9);
  }
  // A view one or two frames from a stored KITTI frame scores it above every unrelated image.
  for (int i : {1, 12, 23, 34, 48}) {
    BowVector q;
    voc.transform(descriptorsOf(kitti / cv::format("%06d.png", i)), &q);
    const uint64_t nearest = uint64_t(5 * ((i + 2) / 5));
    double best_unrelated = 0;
    for (const auto& [id, bow] : bows)
      if (id >= 1000) best_unrelated = std::max(best_unrelated, Vocabulary::score(q, bow));
    EXPECT_GT(Vocabulary::score(q, bows[nearest]), best_unrelated) << "frame " << i;
    PlaceQuery one;
    one.max_results = 1;
    const auto r = db.query(q, one);
    ASSERT_EQ(r.size(), 1u);
    EXPECT_EQ(r[0].keyframe, nearest) << "frame " << i;
  }
}

}  // namespace
}  // namespace nerfslam
