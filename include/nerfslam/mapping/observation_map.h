#pragma once
// The observations of one map point (keyframe -> keypoint index) as a vector of pairs sorted by
// keyframe: the interface of the std::map it replaces (find, count, operator[], at, emplace, erase,
// in-order iteration), with the storage of a vector. A point has a few to a few dozen observations;
// the tracking thread walks the observations of every point of its local map for each rebuild and
// the mapping thread copies them for every bundle adjustment, and a contiguous array is walked and
// copied without chasing one heap node per observation.
//
// Iteration is in increasing keyframe order, as with std::map; insertion and erasure invalidate
// iterators (unlike std::map's).
#include <algorithm>
#include <cstddef>
#include <utility>
#include <vector>

#include "nerfslam/core/error.h"

namespace nerfslam {

template <class K, class V>
class SortedVectorMap {
 public:
  using value_type = std::pair<K, V>;
  using iterator = typename std::vector<value_type>::iterator;
  using const_iterator = typename std::vector<value_type>::const_iterator;

  iterator begin() { return items_.begin(); }
  iterator end() { return items_.end(); }
  const_iterator begin() const { return items_.begin(); }
  const_iterator end() const { return items_.end(); }
  size_t size() const { return items_.size(); }
  bool empty() const { return items_.empty(); }
  void clear() { items_.clear(); }

  iterator find(const K& k) {
    auto it = lower(k);
    return it != items_.end() && it->first == k ? it : items_.end();
  }
  const_iterator find(const K& k) const {
    auto it = lower(k);
    return it != items_.end() && it->first == k ? it : items_.end();
  }
  size_t count(const K& k) const { return find(k) != end() ? 1 : 0; }
  const V& at(const K& k) const {
    auto it = find(k);
    if (it == end()) fail("SortedVectorMap::at: no such key");
    return it->second;
  }
  // Inserts (k, V{}) when k is absent.
  V& operator[](const K& k) {
    auto it = lower(k);
    if (it == items_.end() || it->first != k) it = items_.insert(it, value_type(k, V{}));
    return it->second;
  }
  // Inserts (k, v) unless k is present; the bool says whether it was inserted.
  std::pair<iterator, bool> emplace(const K& k, const V& v) {
    auto it = lower(k);
    if (it != items_.end() && it->first == k) return {it, false};
    return {items_.insert(it, value_type(k, v)), true};
  }
  iterator erase(const_iterator it) { return items_.erase(it); }
  size_t erase(const K& k) {
    auto it = find(k);
    if (it == end()) return 0;
    items_.erase(it);
    return 1;
  }
  bool operator==(const SortedVectorMap& o) const { return items_ == o.items_; }

 private:
  iterator lower(const K& k) {
    return std::lower_bound(items_.begin(), items_.end(), k,
                            [](const value_type& a, const K& b) { return a.first < b; });
  }
  const_iterator lower(const K& k) const {
    return std::lower_bound(items_.begin(), items_.end(), k,
                            [](const value_type& a, const K& b) { return a.first < b; });
  }
  std::vector<value_type> items_;
};

}  // namespace nerfslam
