#include "nerfslam/tracking/vocabulary.h"

#include <gtest/gtest.h>

#include <fstream>
#include <random>
#include <set>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/tracking/frame.h"
#include "test_support.h"

namespace nerfslam {
namespace {

// `clusters` random 256-bit centres, `per_cluster` descriptors each with up to `flips` bits flipped,
// dealt round-robin over `images` images. label[i][r] is the cluster of row r of image i.
struct Clustered {
  std::vector<cv::Mat> images;
  std::vector<std::vector<int>> label;
  std::vector<cv::Mat> centres;
};
Clustered makeClusters(int clusters, int per_cluster, int flips, int images, uint32_t seed) {
  std::mt19937 rng(seed);
  Clustered c;
  c.images.assign(size_t(images), cv::Mat());
  c.label.assign(size_t(images), {});
  for (int k = 0; k < clusters; ++k) {
    cv::Mat centre(1, 32, CV_8U);
    for (int b = 0; b < 32; ++b) centre.at<uint8_t>(b) = uint8_t(rng());
    c.centres.push_back(centre);
    for (int n = 0; n < per_cluster; ++n) {
      cv::Mat d = centre.clone();
      const int f = int(rng() % uint32_t(flips + 1));
      for (int j = 0; j < f; ++j) {
        const uint32_t bit = rng() % 256;
        d.at<uint8_t>(int(bit / 8)) ^= uint8_t(1u << (bit % 8));
      }
      const size_t img = size_t(n % images);
      c.images[img].push_back(d);
      c.label[img].push_back(k);
    }
  }
  return c;
}

TEST(Vocabulary, RecoversKnownClusters) {
  const Clustered c = makeClusters(8, 60, 12, 6, 7);
  VocabularyOptions o;
  o.k = 8;
  o.levels = 1;
  const Vocabulary voc = Vocabulary::learn(c.images, o);
  ASSERT_EQ(voc.wordCount(), 8u);
  std::vector<std::set<WordId>> words_of_cluster(8);
  for (size_t i = 0; i < c.images.size(); ++i)
    for (int r = 0; r < c.images[i].rows; ++r)
      words_of_cluster[size_t(c.label[i][size_t(r)])].insert(voc.word(c.images[i].ptr<uint8_t>(r)));
  std::set<WordId> all;
  for (int k = 0; k < 8; ++k) {
    ASSERT_EQ(words_of_cluster[size_t(k)].size(), 1u) << "cluster " << k << " split over several words";
    all.insert(*words_of_cluster[size_t(k)].begin());
    // The learned centre is the true centre (the bitwise majority of small perturbations of it).
    const WordId w = *words_of_cluster[size_t(k)].begin();
    EXPECT_LE(descriptorDistance(voc.nodeDescriptor(voc.wordNode(w)), c.centres[size_t(k)].ptr<uint8_t>()), 2);
  }
  EXPECT_EQ(all.size(), 8u) << "two clusters share a word";
}

TEST(Vocabulary, TwoLevelTreeRecoversNestedClusters) {
  // 4 groups of 4 clusters: the centres of a group lie 40 bits from the group's centre (and about
  // 128 bits from other groups'), members up to 6 bits from their cluster's centre.
  std::mt19937 rng(11);
  auto flip = [&](cv::Mat d, int n) {
    for (int j = 0; j < n; ++j) {
      const uint32_t bit = rng() % 256;
      d.at<uint8_t>(int(bit / 8)) ^= uint8_t(1u << (bit % 8));
    }
    return d;
  };
  std::vector<cv::Mat> images(8);
  std::vector<std::vector<int>> label(8);
  for (int g = 0; g < 4; ++g) {
    cv::Mat group(1, 32, CV_8U);
    for (int b = 0; b < 32; ++b) group.at<uint8_t>(b) = uint8_t(rng());
    for (int c = 0; c < 4; ++c) {
      const cv::Mat centre = flip(group.clone(), 40);
      for (int n = 0; n < 40; ++n) {
        images[size_t(n % 8)].push_back(flip(centre.clone(), int(rng() % 7)));
        label[size_t(n % 8)].push_back(4 * g + c);
      }
    }
  }
  VocabularyOptions o;
  o.k = 4;
  o.levels = 2;
  const Vocabulary voc = Vocabulary::learn(images, o);
  EXPECT_EQ(voc.wordCount(), 16u);
  std::vector<std::set<WordId>> words_of_cluster(16);
  std::vector<std::set<NodeId>> top_of_group(4);
  for (size_t i = 0; i < images.size(); ++i)
    for (int r = 0; r < images[i].rows; ++r) {
      NodeId top = 0;
      const int l = label[i][size_t(r)];
      words_of_cluster[size_t(l)].insert(voc.word(images[i].ptr<uint8_t>(r), 1, &top));
      top_of_group[size_t(l / 4)].insert(top);
      EXPECT_EQ(voc.depth(top), 1);
    }
  std::set<WordId> all;
  for (const auto& s : words_of_cluster) {
    ASSERT_EQ(s.size(), 1u);
    all.insert(*s.begin());
  }
  EXPECT_EQ(all.size(), 16u);
  std::set<NodeId> tops;
  for (const auto& s : top_of_group) {
    ASSERT_EQ(s.size(), 1u) << "a group split at the first level";
    tops.insert(*s.begin());
  }
  EXPECT_EQ(tops.size(), 4u);
}

TEST(Vocabulary, LearningIsDeterministic) {
  const Clustered c = makeClusters(30, 30, 40, 5, 3);
  VocabularyOptions o;
  o.k = 3;
  o.levels = 3;
  const std::string a = Vocabulary::learn(c.images, o).serialize();
  EXPECT_EQ(a, Vocabulary::learn(c.images, o).serialize());
  o.seed += 1;
  EXPECT_NE(a, Vocabulary::learn(c.images, o).serialize());
}

TEST(Vocabulary, IdfAndBagOfWords) {
  Clustered c = makeClusters(4, 40, 4, 4, 5);
  // Every cluster is dealt over the 4 images; a fifth holds only cluster 3, whose word is then in
  // all 5 images (idf 0) while the others are in 4 of 5 (idf ln 5/4).
  c.images.push_back(cv::repeat(c.centres[3], 3, 1));
  VocabularyOptions o;
  o.k = 4;
  o.levels = 1;
  const Vocabulary voc = Vocabulary::learn(c.images, o);
  ASSERT_EQ(voc.wordCount(), 4u);
  const WordId w3 = voc.word(c.centres[3].ptr<uint8_t>()), w0 = voc.word(c.centres[0].ptr<uint8_t>());
  EXPECT_FLOAT_EQ(voc.idf(w3), 0.0f);
  EXPECT_NEAR(voc.idf(w0), std::log(5.0 / 4.0), 1e-6);

  BowVector bow;
  FeatureVector direct;
  voc.transform(c.images[0], &bow, &direct, 1);
  double sum = 0;
  for (size_t i = 0; i < bow.size(); ++i) {
    sum += bow[i].second;
    EXPECT_GT(bow[i].second, 0.0f);
    if (i > 0) {
      EXPECT_LT(bow[i - 1].first, bow[i].first);
    }
    EXPECT_NE(bow[i].first, w3) << "a word of idf 0 carries no weight";
  }
  EXPECT_NEAR(sum, 1.0, 1e-6);
  // Direct index: every feature once, under the node of its word at level 1 (the words here).
  std::vector<int> seen;
  for (const auto& [node, feats] : direct)
    for (int f : feats) {
      seen.push_back(f);
      EXPECT_EQ(voc.wordNode(voc.word(c.images[0].ptr<uint8_t>(f))), node);
    }
  std::sort(seen.begin(), seen.end());
  ASSERT_EQ(int(seen.size()), c.images[0].rows);
  for (int i = 0; i < c.images[0].rows; ++i) EXPECT_EQ(seen[size_t(i)], i);
}

TEST(Vocabulary, L1Score) {
  const BowVector a = {{1, 0.5f}, {4, 0.25f}, {9, 0.25f}}, b = {{1, 0.25f}, {5, 0.5f}, {9, 0.25f}}, c = {{2, 1.0f}};
  EXPECT_NEAR(Vocabulary::score(a, a), 1.0, 1e-9);
  EXPECT_NEAR(Vocabulary::score(a, b), 0.5, 1e-9);  // 1 - (0.25 + 0.25 + 0.5 + 0) / 2
  EXPECT_NEAR(Vocabulary::score(b, a), 0.5, 1e-9);
  EXPECT_EQ(Vocabulary::score(a, c), 0.0);
  EXPECT_EQ(Vocabulary::score(a, {}), 0.0);
}

TEST(Vocabulary, RefusesBadInput) {
  VocabularyOptions o;
  EXPECT_NE(test::errorOf([&] { Vocabulary::learn({}, o); }).find("no training descriptors"), std::string::npos);
  EXPECT_NE(test::errorOf([&] { Vocabulary::learn({cv::Mat(3, 16, CV_8U, cv::Scalar(0))}, o); }).find("32 bytes"),
            std::string::npos);
  o.k = 1;
  EXPECT_NE(test::errorOf([&] { Vocabulary::learn({cv::Mat(3, 32, CV_8U)}, o); }).find("k must be"), std::string::npos);
  BowVector bow;
  EXPECT_NE(test::errorOf([&] { Vocabulary().transform(cv::Mat(1, 32, CV_8U), &bow); }).find("empty"),
            std::string::npos);
}

// ------------------------------------------------------------------------------------ file format

Vocabulary smallVocabulary() {
  const Clustered c = makeClusters(12, 20, 20, 4, 9);
  VocabularyOptions o;
  o.k = 3;
  o.levels = 2;
  return Vocabulary::learn(c.images, o);
}

std::string readAll(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

TEST(VocabularyFile, RoundTrip) {
  test::TempDir dir;
  const Vocabulary v = smallVocabulary();
  saveVocabulary(v, dir / "v.voc");
  const Vocabulary w = loadVocabulary(dir / "v.voc");
  EXPECT_EQ(w.k(), v.k());
  EXPECT_EQ(w.levels(), v.levels());
  EXPECT_EQ(w.wordCount(), v.wordCount());
  EXPECT_EQ(w.serialize(), v.serialize());
  EXPECT_EQ(readAll(dir / "v.voc"), v.serialize());
  for (size_t n = 0; n < v.wordCount(); ++n) EXPECT_EQ(w.idf(WordId(n)), v.idf(WordId(n)));
}

void putU32(std::string* s, size_t at, uint32_t v) {
  for (int i = 0; i < 4; ++i) (*s)[at + size_t(i)] = char(uint8_t(v >> (8 * i)));
}

TEST(VocabularyFile, BadFilesNameTheFileAndField) {
  test::TempDir dir;
  const std::string good = smallVocabulary().serialize();
  auto errorFor = [&](const std::string& bytes) {
    const auto p = dir / "bad.voc";
    test::writeText(p, bytes);
    return test::errorOf([&] { loadVocabulary(p); });
  };
  auto expectError = [&](const std::string& bytes, const std::string& field) {
    const std::string e = errorFor(bytes);
    EXPECT_NE(e.find((dir / "bad.voc").string()), std::string::npos) << e;
    EXPECT_NE(e.find(field), std::string::npos) << "expected field " << field << " in: " << e;
  };
  EXPECT_NE(test::errorOf([&] { loadVocabulary(dir / "missing.voc"); }).find("missing.voc: vocabulary file not found"),
            std::string::npos);
  expectError("", "magic");
  expectError("not a vocabulary at all, just text", "magic");
  expectError(good.substr(0, 14), "version");
  expectError(good.substr(0, 34), "node_count");
  expectError(good.substr(0, 100), "node_table");
  expectError(good.substr(0, good.size() - 10), "idf");
  expectError(good.substr(0, good.size() - 2), "idf");
  expectError(good + "x", "end");
  std::string s = good;
  putU32(&s, 8, 2);
  expectError(s, "version");
  EXPECT_NE(errorFor(s).find("version 2, this build reads version 1"), std::string::npos);
  s = good;
  putU32(&s, 12, 64);
  expectError(s, "descriptor_bytes");
  s = good;
  s[60] = char(s[60] ^ 0x10);
  expectError(s, "crc32");
  // A tiny file declaring 2^32 - 1 nodes: refused from the sizes, nothing allocated.
  s = good.substr(0, 32) + std::string(8, '\0');
  putU32(&s, 28, 0xFFFFFFFFu);
  expectError(s, "node_table");
}

// ------------------------------------------------------------------------------- shipped vocabulary

TEST(VocabularyFile, ShippedVocabularyLoads) {
  const auto path = test::sourceDir() / "config/vocabulary/brief_k12_L4.voc";
  const Vocabulary v = loadVocabulary(path);
  EXPECT_EQ(v.k(), 12);
  EXPECT_EQ(v.levels(), 4);
  EXPECT_GT(v.wordCount(), 20000u);
  EXPECT_LT(std::filesystem::file_size(path), 1u << 20);
}

}  // namespace
}  // namespace nerfslam
