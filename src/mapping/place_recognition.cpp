#include "nerfslam/mapping/place_recognition.h"

#include <algorithm>
#include <mutex>
#include <unordered_map>

#include "nerfslam/core/error.h"

namespace nerfslam {

PlaceRecognition::PlaceRecognition(std::shared_ptr<const Vocabulary> vocabulary)
    : voc_(std::move(vocabulary)), db_(voc_ ? voc_->wordCount() : 0) {
  if (!voc_ || voc_->empty()) fail("PlaceRecognition: no vocabulary");
}

BowVector PlaceRecognition::bagOfWords(const Frame& frame) const {
  BowVector bow;
  if (!frame.descriptors.empty()) voc_->transform(frame.descriptors, &bow);
  return bow;
}

void PlaceRecognition::add(KeyframeId id, const BowVector& bow) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  db_.add(uint64_t(id), bow);
}

bool PlaceRecognition::addKeyframe(const Map& map, KeyframeId id) {
  const auto kf = map.keyframe(id);
  if (!kf || !kf->frame) return false;
  add(id, bagOfWords(*kf->frame));
  return true;
}

size_t PlaceRecognition::addMapKeyframes(const Map& map) {
  size_t added = 0;
  for (KeyframeId id : map.keyframeIds())
    if (!contains(id)) added += addKeyframe(map, id);
  return added;
}

bool PlaceRecognition::erase(KeyframeId id) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  return db_.erase(uint64_t(id));
}

size_t PlaceRecognition::eraseMissing(const std::vector<KeyframeId>& alive) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  size_t erased = 0;
  for (uint64_t k : db_.keyframes())
    if (!std::binary_search(alive.begin(), alive.end(), KeyframeId(k))) erased += db_.erase(k);
  return erased;
}

void PlaceRecognition::clear() {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  db_.clear();
}

size_t PlaceRecognition::size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return db_.size();
}

bool PlaceRecognition::contains(KeyframeId id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return db_.contains(uint64_t(id));
}

std::vector<PlaceCandidate> PlaceRecognition::query(const BowVector& bow, const PlaceQuery& q) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return db_.query(bow, q);
}

std::string PlaceRecognition::serialize() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return db_.serialize();
}

std::vector<KeyframeId> PlaceRecognition::relocalizationCandidates(const Map& map, const BowVector& bow,
                                                                   const RelocalizationQuery& q) const {
  if (bow.empty() || q.max_candidates == 0) return {};
  // 1. Keyframes sharing words with the frame (and their L1 scores).
  PlaceQuery pq;
  pq.max_results = 0;
  const std::vector<PlaceCandidate> sharing = query(bow, pq);
  if (sharing.empty()) return {};
  int max_common = 0;
  for (const PlaceCandidate& c : sharing) max_common = std::max(max_common, c.shared_words);
  const int min_common = static_cast<int>(q.min_common_words_ratio * max_common);
  // 2. Those sharing enough words, with their scores.
  std::unordered_map<KeyframeId, double> score;
  for (const PlaceCandidate& c : sharing)
    if (c.shared_words >= min_common) score[static_cast<KeyframeId>(c.keyframe)] = c.score;
  // 3. Each score accumulated over the keyframe's best covisible keyframes that scored too; the
  // group is represented by its best-scoring keyframe.
  struct Group {
    KeyframeId best;
    double best_score, acc;
  };
  std::vector<Group> groups;
  groups.reserve(score.size());
  double best_acc = 0;
  for (const auto& [id, s] : score) {
    const auto covisible = map.covisibleKeyframes(id, 1);
    if (covisible.empty() && !map.keyframe(id)) continue;  // culled since it was added
    Group g{id, s, s};
    const size_t n = std::min(covisible.size(), static_cast<size_t>(std::max(0, q.covisible_keyframes)));
    for (size_t i = 0; i < n; ++i) {
      const auto it = score.find(covisible[i].first);
      if (it == score.end()) continue;
      g.acc += it->second;
      if (it->second > g.best_score || (it->second == g.best_score && it->first < g.best)) {
        g.best = it->first;
        g.best_score = it->second;
      }
    }
    best_acc = std::max(best_acc, g.acc);
    groups.push_back(g);
  }
  // 4. The groups above min_group_score_ratio x the best, best first, each keyframe once.
  std::sort(groups.begin(), groups.end(),
            [](const Group& a, const Group& b) { return a.acc != b.acc ? a.acc > b.acc : a.best < b.best; });
  std::vector<KeyframeId> out;
  for (const Group& g : groups) {
    if (out.size() >= q.max_candidates || g.acc < q.min_group_score_ratio * best_acc) break;
    if (std::find(out.begin(), out.end(), g.best) == out.end()) out.push_back(g.best);
  }
  return out;
}

}  // namespace nerfslam
