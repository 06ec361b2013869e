#pragma once
// Relocalisation where the camera may be anywhere in the map (a loaded map, localisation only, or
// tracking lost): the keyframes that share the most descriptors with the frame. A brute-force vote
// over every map point with a descriptor; a keyframe database would replace it.
#include <cstdint>
#include <vector>

#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/local_map.h"

namespace nerfslam {

// The map's points as the vote sees them (Map::descriptorVoteTable builds it, mapping/map.h): one
// descriptor per point and the keyframes observing it.
struct DescriptorVoteTable {
  static constexpr size_t kDescriptorBytes = 32;
  std::vector<uint8_t> descriptors;    // kDescriptorBytes per point, in the order added
  std::vector<int> observer_begin{0};  // point i: observers[observer_begin[i] .. observer_begin[i + 1])
  std::vector<KeyframeId> observers;
  size_t size() const { return observer_begin.size() - 1; }
  // Appends a point: its descriptor (kDescriptorBytes) and the keyframes observing it.
  void add(const uint8_t* descriptor, const std::vector<KeyframeId>& observed_by);
};

// Up to `max_keyframes` keyframes ranked by votes, best first (ties: the newer first): each of up to
// `max_features` of the frame's descriptors (every n-th) votes for the keyframes observing its nearest
// point of `table` (the first of equally near ones), if that is within `max_distance` (Hamming).
// Keyframes without votes are left out.
std::vector<KeyframeId> keyframesByDescriptorVotes(const Frame& frame, const DescriptorVoteTable& table,
                                                   int max_keyframes, int max_features = 600, int max_distance = 50);

}  // namespace nerfslam
