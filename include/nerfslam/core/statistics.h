#pragma once
// Small statistics on samples.
#include <algorithm>
#include <vector>

namespace nerfslam {

// The upper median (element n/2 of the sorted samples); 0 for no samples.
inline double median(std::vector<double> v) {
  if (v.empty()) return 0;
  const size_t k = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + long(k), v.end());
  return v[k];
}

}  // namespace nerfslam
