#pragma once
// Keyframe database for place recognition (loop detection, relocalisation): an inverted index from
// each vocabulary word to the keyframes whose bag of words contains it, with the word's weight
// there.
//
// A query walks only the posting lists of its own words and accumulates, per keyframe met, the
// DBoW2 L1 score sum_w min(q_w, k_w) (= 1 - |q - k|_1 / 2 for L1-normalised bags) in a dense
// per-thread array indexed by the keyframe's slot, resetting only the entries it touched: its cost
// is the number of postings under the query's words, never the number of keyframes. Keyframes
// that share no word with the query are never touched.
//
// Blob format (serialize / deserialize, for map folders), little-endian:
//   magic "NSKFDB\0\0" (8 bytes), u32 version (1), u32 word count of the vocabulary,
//   u32 keyframe count, then per keyframe (ascending id): u64 id, u32 entry count, entries
//   {u32 word, f32 weight}; u32 CRC-32 of every byte before it.
// Threads: query() may run on several threads at once (its scratch is per thread); add, erase
// and clear need exclusive access (the owner holds a shared_mutex, queries taking it shared).
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "nerfslam/tracking/vocabulary.h"

namespace nerfslam {

struct PlaceCandidate {
  uint64_t keyframe = 0;
  double score = 0;      // DBoW2 L1 score with the query, in [0, 1]
  int shared_words = 0;  // words the keyframe has in common with the query
};

struct PlaceQuery {
  double min_score = 0.0;   // candidates scoring below are dropped
  size_t max_results = 10;  // best first; 0: all
  int min_shared_words = 1;
  // Keyframes for which this returns true are skipped (e.g. the query's covisible neighbours).
  std::function<bool(uint64_t)> exclude;
};

class KeyframeDatabase {
 public:
  static constexpr uint32_t kBlobVersion = 1;

  // `word_count`: the vocabulary's (words of a bag must be below it).
  explicit KeyframeDatabase(size_t word_count = 0) : word_count_(word_count) {}

  // Adds a keyframe's bag of words; an id already present is replaced. Throws nerfslam::Error for
  // a word outside the vocabulary.
  void add(uint64_t keyframe, const BowVector& bow);
  // Removes a keyframe; false if it was not there. Cost: the postings of its words.
  bool erase(uint64_t keyframe);
  void clear();
  bool contains(uint64_t keyframe) const { return slot_of_.count(keyframe) > 0; }
  size_t size() const { return slot_of_.size(); }
  // The keyframes in the database, in no particular order.
  std::vector<uint64_t> keyframes() const;
  size_t wordCount() const { return word_count_; }
  // The stored bag of a keyframe (nullptr if absent).
  const BowVector* bow(uint64_t keyframe) const;
  // Total postings (entries over all words), and the postings of one word (the keyframes having
  // it: what a query containing it walks).
  size_t postingCount() const { return posting_count_; }
  size_t postingCount(WordId w) const {
    const auto it = postings_.find(w);
    return it == postings_.end() ? 0 : it->second.size();
  }

  // Keyframes sharing words with `bow`, best score first (ties: lower id first).
  std::vector<PlaceCandidate> query(const BowVector& bow, const PlaceQuery& q = {}) const;

  std::string serialize() const;
  // Throws nerfslam::Error naming `name` and the field for a bad blob, and when the blob was built
  // for a vocabulary of another word count than `expected_word_count` (0: accept any).
  static KeyframeDatabase deserialize(std::string_view bytes, const std::string& name, size_t expected_word_count = 0);

 private:
  struct Posting {
    uint32_t slot;
    float weight;
  };
  struct Slot {
    uint64_t keyframe = 0;
    BowVector bow;
  };
  size_t word_count_ = 0;
  // Per word that some keyframe has (a hash map: memory follows the content, not the vocabulary).
  std::unordered_map<WordId, std::vector<Posting>> postings_;
  std::vector<Slot> slots_;  // dense; erased slots are reused
  std::vector<uint32_t> free_slots_;
  std::unordered_map<uint64_t, uint32_t> slot_of_;  // keyframe id -> slot
  size_t posting_count_ = 0;
};

// Atomic write / checked read of the blob as a file.
void saveKeyframeDatabase(const KeyframeDatabase& db, const std::filesystem::path& path);
KeyframeDatabase loadKeyframeDatabase(const std::filesystem::path& path, size_t expected_word_count = 0);

}  // namespace nerfslam
