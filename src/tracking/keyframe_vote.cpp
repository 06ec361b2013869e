#include "nerfslam/tracking/keyframe_vote.h"

#include <algorithm>
#include <map>
#include <utility>

namespace nerfslam {

void DescriptorVoteTable::add(const uint8_t* descriptor, const std::vector<KeyframeId>& observed_by) {
  descriptors.insert(descriptors.end(), descriptor, descriptor + kDescriptorBytes);
  observers.insert(observers.end(), observed_by.begin(), observed_by.end());
  observer_begin.push_back(static_cast<int>(observers.size()));
}

std::vector<KeyframeId> keyframesByDescriptorVotes(const Frame& frame, const DescriptorVoteTable& table,
                                                   int max_keyframes, int max_features, int max_distance) {
  if (max_keyframes <= 0 || frame.descriptors.rows == 0 || max_features <= 0 || table.size() == 0) return {};
  const size_t num_points = table.size();
  const int n = frame.descriptors.rows;
  const int stride = std::max(1, (n + max_features - 1) / max_features);
  std::map<KeyframeId, int> votes;
  for (int i = 0; i < n; i += stride) {
    const uint8_t* d = frame.descriptors.ptr<uint8_t>(i);
    int best = max_distance + 1;
    size_t best_j = num_points;
    for (size_t j = 0; j < num_points; ++j) {
      const int dist = descriptorDistance(d, &table.descriptors[j * DescriptorVoteTable::kDescriptorBytes]);
      if (dist < best) {
        best = dist;
        best_j = j;
      }
    }
    if (best_j < num_points)
      for (int k = table.observer_begin[best_j]; k < table.observer_begin[best_j + 1]; ++k)
        ++votes[table.observers[static_cast<size_t>(k)]];
  }
  std::vector<std::pair<KeyframeId, int>> ranked(votes.begin(), votes.end());
  std::sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) {
    return a.second != b.second ? a.second > b.second : a.first > b.first;
  });
  std::vector<KeyframeId> out;
  for (const auto& [kid, v] : ranked) {
    if (static_cast<int>(out.size()) >= max_keyframes) break;
    out.push_back(kid);
  }
  return out;
}

}  // namespace nerfslam
