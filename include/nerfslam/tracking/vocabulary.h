#pragma once
// A vocabulary of binary visual words over our 256-bit steered-BRIEF descriptors, for place
// recognition (loop closure, relocalisation), after the design of DBoW2 (Galvez-Lopez and Tardos
// 2012, "Bags of binary words"):
//
//   - a k-ary tree of depth L learned by hierarchical k-medians on Hamming distance (k-majority:
//     a cluster's centre is the bitwise majority of its descriptors), seeded as k-means++ with a
//     fixed seed, so the same training descriptors always give the same tree, bit for bit;
//   - the words are the tree's leaves (a branch stops early when a cluster has k descriptors or
//     fewer); a descriptor's word is found by descending to the closest child at every level;
//   - each word has an inverse document frequency idf = ln(N / n_w) over the N training images
//     (n_w of which contain it); an image's bag of words is the tf-idf weight of each of its words,
//     L1-normalised, and two bags score s = 1 - |a - b|_1 / 2 in [0, 1] (DBoW2's L1 score);
//   - the direct index of an image groups its feature indices by their ancestor node at one level
//     of the tree, so that guided matching compares only features under the same node.
//
// File format (saveVocabulary / loadVocabulary), little-endian:
//   magic "NSVOCAB\0" (8 bytes), u32 version (1), u32 descriptor bytes (32), u32 k, u32 L,
//   u32 word count, u32 node count, node table (node count x {u32 parent, 32 descriptor bytes};
//   node 0 is the root, its parent field 0xFFFFFFFF and its descriptor zero), idf (word count x
//   f32, the words numbered in node order), u32 CRC-32 of every byte before it.
// Nodes are stored breadth first: every node's parent precedes it and the parents never decrease,
// so each node's children are one contiguous run. Leaves are the words.
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

namespace nerfslam {

using WordId = uint32_t;
using NodeId = uint32_t;

// Bag of words: (word, weight) sorted by word, weights positive and summing to 1 (or empty).
using BowVector = std::vector<std::pair<WordId, float>>;
// Direct index: (node at the chosen level, indices of the image's features under it), sorted by node.
using FeatureVector = std::vector<std::pair<NodeId, std::vector<int>>>;

struct VocabularyOptions {
  int k = 10;                // branching factor (2..64)
  int levels = 4;            // depth L of the tree (1..8); at most k^L words
  int max_iterations = 25;   // k-medians iterations at each node (stops earlier when stable)
  uint64_t seed = 20240601;  // of the k-means++ seeding
};

class Vocabulary {
 public:
  static constexpr uint32_t kFileVersion = 1;
  static constexpr NodeId kNoParent = 0xFFFFFFFFu;

  Vocabulary() = default;

  // Learns the tree from the descriptors of training images (one CV_8U mat of 32-byte rows per
  // image; empty mats allowed) and the idf from the same images. Throws nerfslam::Error on invalid
  // options, a descriptor that is not 32 bytes, or no descriptor at all.
  static Vocabulary learn(const std::vector<cv::Mat>& images, const VocabularyOptions& options);

  bool empty() const { return parent_.empty(); }
  int k() const { return k_; }
  int levels() const { return levels_; }
  size_t wordCount() const { return word_node_.size(); }
  size_t nodeCount() const { return parent_.size(); }

  // The word (leaf) of one 32-byte descriptor. The vocabulary must not be empty.
  WordId word(const uint8_t* descriptor) const;
  // The word and its ancestor at depth `level` (1 = the root's children; a leaf shallower than
  // `level` is its own ancestor).
  WordId word(const uint8_t* descriptor, int level, NodeId* node) const;
  float idf(WordId w) const { return idf_[w]; }
  NodeId wordNode(WordId w) const { return word_node_[w]; }
  NodeId parent(NodeId n) const { return parent_[n]; }
  int depth(NodeId n) const { return depth_[n]; }
  const uint8_t* nodeDescriptor(NodeId n) const { return descriptors_.data() + size_t(n) * 32; }

  // Bag of words of an image's descriptors (rows of 32 bytes); with `direct`, also its direct
  // index at depth `direct_level` (see word()). With the shipped k = 12 tree, matching through
  // level 1 (matchByDirectIndex, bow_matcher.h) kept 170 of the 210 sound matches an exhaustive
  // search finds between KITTI 06 frames 0 and 1, for about a twelfth of the comparisons; level 2
  // kept 118.
  void transform(const cv::Mat& descriptors, BowVector* bow, FeatureVector* direct = nullptr,
                 int direct_level = 1) const;

  // DBoW2's L1 score of two bags of words: 1 - |a - b|_1 / 2, in [0, 1].
  static double score(const BowVector& a, const BowVector& b);

  // The file image described above, and its reader. `name` names the source in errors.
  std::string serialize() const;
  static Vocabulary deserialize(std::string_view bytes, const std::string& name);

 private:
  void finish();  // derives children, depths and words from parent_

  int k_ = 0, levels_ = 0;
  std::vector<NodeId> parent_;         // per node
  std::vector<uint8_t> descriptors_;   // 32 bytes per node
  std::vector<uint32_t> child_begin_;  // per node: first child (children contiguous)
  std::vector<uint32_t> child_count_;  // per node
  std::vector<uint8_t> depth_;         // per node (root 0)
  std::vector<WordId> node_word_;      // per node: its word, or ~0 for inner nodes
  std::vector<NodeId> word_node_;      // per word
  std::vector<float> idf_;             // per word
};

// Writes the vocabulary atomically (core/atomic_file.h). Throws nerfslam::Error naming the file.
void saveVocabulary(const Vocabulary& vocabulary, const std::filesystem::path& path);
// Reads and checks a vocabulary file: a missing, truncated, corrupted (CRC), other-version or
// other-descriptor-size file throws nerfslam::Error naming the file and the field.
Vocabulary loadVocabulary(const std::filesystem::path& path);

}  // namespace nerfslam
