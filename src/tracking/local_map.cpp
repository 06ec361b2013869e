#include "nerfslam/tracking/local_map.h"

#include <algorithm>

namespace nerfslam {

std::optional<size_t> TrackingLocalMap::findPoint(uint64_t point_id) const {
  const auto it = std::lower_bound(points.begin(), points.end(), point_id,
                                   [](const TrackingMapPoint& p, uint64_t id) { return p.id < id; });
  if (it == points.end() || it->id != point_id) return std::nullopt;
  return static_cast<size_t>(it - points.begin());
}

std::optional<size_t> TrackingLocalMap::findKeyframe(KeyframeId id) const {
  const auto it = std::find(keyframes.begin(), keyframes.end(), id);
  if (it == keyframes.end()) return std::nullopt;
  return static_cast<size_t>(it - keyframes.begin());
}

}  // namespace nerfslam
