#pragma once
// Place recognition shared by relocalisation (tracking thread) and loop closing (its own thread):
// the vocabulary and the keyframe database (tracking/keyframe_database.h) behind a shared_mutex.
// Queries take it shared (several at once), adding and erasing keyframes take it exclusively (a
// few microseconds per keyframe: its bag's postings).
//
// Who adds: the loop-closing thread adds each keyframe after its own loop query (ORB-SLAM's order);
// keyframes it never sees (loop closing switched off, or its queue full) are added by the mapping
// thread once processed (SlamSystem). A map loaded from a folder (--localize, --extend) has its
// keyframes added at load (addMapKeyframes): map folders do not store the database, it is rebuilt
// from the keyframes' descriptors.
//
// Relocalisation candidates (relocalizationCandidates) are those of ORB-SLAM's
// KeyFrameDatabase::DetectRelocalizationCandidates: the keyframes sharing words with the frame (the
// database's inverted index: only the frame's words' posting lists are walked), those with at least
// min_common_words_ratio x the most shared words scored (L1 BoW score), each score accumulated over
// the keyframe's best covisible keyframes that are candidates too, and per group above
// min_group_score_ratio x the best group's score the group's best keyframe kept, best group first.
#include <cstdint>
#include <memory>
#include <shared_mutex>
#include <string>
#include <vector>

#include "nerfslam/mapping/map.h"
#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/keyframe_database.h"
#include "nerfslam/tracking/vocabulary.h"

namespace nerfslam {

struct RelocalizationQuery {
  size_t max_candidates = 5;            // groups kept, best first
  double min_common_words_ratio = 0.8;  // of the most words a keyframe shares with the frame
  int covisible_keyframes = 10;         // best covisible keyframes a score is accumulated over
  double min_group_score_ratio = 0.75;  // of the best group's accumulated score
};

class PlaceRecognition {
 public:
  explicit PlaceRecognition(std::shared_ptr<const Vocabulary> vocabulary);

  const Vocabulary& vocabulary() const { return *voc_; }
  const std::shared_ptr<const Vocabulary>& vocabularyPtr() const { return voc_; }
  // The frame's bag of words (thread-safe: the vocabulary is read only).
  BowVector bagOfWords(const Frame& frame) const;

  void add(KeyframeId id, const BowVector& bow);
  // The keyframe's bag from its frame's descriptors; false when it is not in the map.
  bool addKeyframe(const Map& map, KeyframeId id);
  // Every keyframe of `map` not in the database yet; returns how many were added.
  size_t addMapKeyframes(const Map& map);
  bool erase(KeyframeId id);
  // Removes every keyframe not in `alive` (sorted ascending, e.g. Map::keyframeIds(): the keyframes
  // culled since they were added, whose bags would otherwise stay for the whole run); returns how many.
  size_t eraseMissing(const std::vector<KeyframeId>& alive);
  void clear();
  size_t size() const;
  bool contains(KeyframeId id) const;

  std::vector<PlaceCandidate> query(const BowVector& bow, const PlaceQuery& q = {}) const;
  // ORB-SLAM's relocalisation candidates (see above) among the keyframes still in `map`, best
  // first. Cost: the postings of the frame's words and the covisibility of the keyframes sharing
  // enough words, not the size of the map.
  std::vector<KeyframeId> relocalizationCandidates(const Map& map, const BowVector& bow,
                                                   const RelocalizationQuery& q = {}) const;
  std::string serialize() const;

 private:
  std::shared_ptr<const Vocabulary> voc_;
  mutable std::shared_mutex mutex_;
  KeyframeDatabase db_;
};

}  // namespace nerfslam
