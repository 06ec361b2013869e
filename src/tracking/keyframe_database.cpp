#include "nerfslam/tracking/keyframe_database.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "binary_blob.h"
#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"

namespace nerfslam {
namespace {
constexpr std::string_view kMagic("NSKFDB\0\0", 8);
}

void KeyframeDatabase::add(uint64_t keyframe, const BowVector& bow) {
  for (const auto& [w, x] : bow)
    if (w >= word_count_)
      fail("KeyframeDatabase::add: keyframe {} has word {}, the vocabulary has {} words", keyframe, w, word_count_);
  erase(keyframe);
  uint32_t slot;
  if (!free_slots_.empty()) {
    slot = free_slots_.back();
    free_slots_.pop_back();
  } else {
    slot = uint32_t(slots_.size());
    slots_.emplace_back();
  }
  slots_[slot] = {keyframe, bow};
  slot_of_.emplace(keyframe, slot);
  for (const auto& [w, x] : bow) postings_[w].push_back({slot, x});
  posting_count_ += bow.size();
}

bool KeyframeDatabase::erase(uint64_t keyframe) {
  const auto it = slot_of_.find(keyframe);
  if (it == slot_of_.end()) return false;
  const uint32_t slot = it->second;
  for (const auto& [w, x] : slots_[slot].bow) {
    const auto l = postings_.find(w);
    if (l == postings_.end()) continue;
    auto& list = l->second;
    const auto p = std::find_if(list.begin(), list.end(), [&](const Posting& e) { return e.slot == slot; });
    if (p != list.end()) {
      *p = list.back();  // order within a list does not matter
      list.pop_back();
      --posting_count_;
    }
    if (list.empty()) postings_.erase(l);
  }
  slots_[slot] = {};
  free_slots_.push_back(slot);
  slot_of_.erase(it);
  return true;
}

std::vector<uint64_t> KeyframeDatabase::keyframes() const {
  std::vector<uint64_t> out;
  out.reserve(slot_of_.size());
  for (const auto& [k, slot] : slot_of_) out.push_back(k);
  return out;
}

void KeyframeDatabase::clear() {
  postings_.clear();
  slots_.clear();
  free_slots_.clear();
  slot_of_.clear();
  posting_count_ = 0;
}

const BowVector* KeyframeDatabase::bow(uint64_t keyframe) const {
  const auto it = slot_of_.find(keyframe);
  return it == slot_of_.end() ? nullptr : &slots_[it->second].bow;
}

std::vector<PlaceCandidate> KeyframeDatabase::query(const BowVector& bow, const PlaceQuery& q) const {
  // Per-thread accumulators indexed by slot; entries are zero except during a query, which resets
  // the ones it touched. They grow with the largest database queried on this thread.
  struct Scratch {
    std::vector<float> score;
    std::vector<int> shared;
    std::vector<uint32_t> touched;
  };
  thread_local Scratch acc;
  if (acc.score.size() < slots_.size()) {
    acc.score.resize(slots_.size(), 0.0f);
    acc.shared.resize(slots_.size(), 0);
  }
  acc.touched.clear();
  for (const auto& [w, x] : bow) {
    const auto l = postings_.find(w);
    if (l == postings_.end()) continue;
    for (const Posting& p : l->second) {
      if (acc.shared[p.slot]++ == 0) acc.touched.push_back(p.slot);
      acc.score[p.slot] += std::min(x, p.weight);
    }
  }
  std::vector<PlaceCandidate> out;
  for (uint32_t slot : acc.touched) {
    if (acc.shared[slot] >= q.min_shared_words && acc.score[slot] >= q.min_score)
      out.push_back({slots_[slot].keyframe, std::clamp(double(acc.score[slot]), 0.0, 1.0), acc.shared[slot]});
    acc.score[slot] = 0.0f;
    acc.shared[slot] = 0;
  }
  // After the reset: the callback may itself query.
  if (q.exclude)
    out.erase(std::remove_if(out.begin(), out.end(), [&](const PlaceCandidate& c) { return q.exclude(c.keyframe); }),
              out.end());
  auto better = [](const PlaceCandidate& a, const PlaceCandidate& b) {
    return a.score != b.score ? a.score > b.score : a.keyframe < b.keyframe;
  };
  if (q.max_results > 0 && out.size() > q.max_results) {
    std::partial_sort(out.begin(), out.begin() + std::ptrdiff_t(q.max_results), out.end(), better);
    out.resize(q.max_results);
  } else {
    std::sort(out.begin(), out.end(), better);
  }
  return out;
}

std::string KeyframeDatabase::serialize() const {
  std::vector<uint64_t> ids;
  ids.reserve(slot_of_.size());
  for (const auto& [id, slot] : slot_of_) ids.push_back(id);
  std::sort(ids.begin(), ids.end());
  blob::Writer w;
  w.bytes(kMagic.data(), kMagic.size());
  w.u32(kBlobVersion);
  w.u32(uint32_t(word_count_));
  w.u32(uint32_t(ids.size()));
  for (uint64_t id : ids) {
    const BowVector& b = slots_[slot_of_.at(id)].bow;
    w.u64(id);
    w.u32(uint32_t(b.size()));
    for (const auto& [word, x] : b) {
      w.u32(word);
      w.f32(x);
    }
  }
  return w.finish();
}

KeyframeDatabase KeyframeDatabase::deserialize(std::string_view bytes, const std::string& name,
                                               size_t expected_word_count) {
  blob::Reader r(bytes, name, kMagic);
  const uint32_t version = r.u32("version");
  if (version != kBlobVersion)
    throw fieldError(name, "version",
                     fmt::format("keyframe database version {}, this build reads version {}", version, kBlobVersion));
  r.checkCrc();
  const uint32_t words = r.u32("word_count");
  if (expected_word_count > 0 && words != expected_word_count)
    throw fieldError(
        name, "word_count",
        fmt::format("built for a vocabulary of {} words, the loaded vocabulary has {}", words, expected_word_count));
  const uint32_t n = r.count("keyframe_count", 12);
  KeyframeDatabase db(words);
  for (uint32_t i = 0; i < n; ++i) {
    const std::string field = fmt::format("keyframes[{}]", i);
    const uint64_t id = r.u64(field + ".id");
    if (db.contains(id)) throw fieldError(name, field + ".id", fmt::format("keyframe {} appears twice", id));
    const uint32_t m = r.count(field + ".entry_count", 8);
    BowVector b(m);
    for (uint32_t e = 0; e < m; ++e) {
      b[e].first = r.u32(field + ".word");
      b[e].second = r.f32(field + ".weight");
      if (b[e].first >= words || (e > 0 && b[e].first <= b[e - 1].first))
        throw fieldError(name, field + ".word", "words must be increasing and within the vocabulary");
      if (!std::isfinite(b[e].second) || b[e].second <= 0 || b[e].second > 1)
        throw fieldError(name, field + ".weight", "must be in (0, 1]");
    }
    db.add(id, b);
  }
  r.expectEnd();
  return db;
}

void saveKeyframeDatabase(const KeyframeDatabase& db, const std::filesystem::path& path) {
  writeStringAtomic(path, db.serialize());
}

KeyframeDatabase loadKeyframeDatabase(const std::filesystem::path& path, size_t expected_word_count) {
  return KeyframeDatabase::deserialize(readInputFile(path, "keyframe database file"), path.string(),
                                       expected_word_count);
}

}  // namespace nerfslam
