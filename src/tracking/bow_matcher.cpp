#include "nerfslam/tracking/bow_matcher.h"

#include <algorithm>
#include <limits>

#include "nerfslam/core/error.h"
#include "nerfslam/tracking/frame.h"

namespace nerfslam {

std::vector<std::pair<int, int>> matchByDirectIndex(const FeatureVector& a, const cv::Mat& da, const FeatureVector& b,
                                                    const cv::Mat& db, const BowMatchOptions& o) {
  for (const cv::Mat* m : {&da, &db})
    if (!m->empty() && (m->type() != CV_8U || m->cols != 32))
      fail("matchByDirectIndex: descriptors must be CV_8U rows of 32 bytes (got {} columns)", m->cols);
  // best_for_b[j] = (distance, index in A) of the best match claimed so far for feature j of B.
  std::vector<std::pair<int, int>> best_for_b(size_t(db.rows), {std::numeric_limits<int>::max(), -1});
  auto ia = a.begin();
  auto ib = b.begin();
  while (ia != a.end() && ib != b.end()) {
    if (ia->first < ib->first) {
      ++ia;
      continue;
    }
    if (ib->first < ia->first) {
      ++ib;
      continue;
    }
    for (int fa : ia->second) {
      if (fa < 0 || fa >= da.rows) fail("matchByDirectIndex: feature {} of A is not a descriptor row", fa);
      int best = std::numeric_limits<int>::max(), second = best, best_j = -1;
      for (int fb : ib->second) {
        if (fb < 0 || fb >= db.rows) fail("matchByDirectIndex: feature {} of B is not a descriptor row", fb);
        const int d = descriptorDistance(da.ptr<uint8_t>(fa), db.ptr<uint8_t>(fb));
        if (d < best) {
          second = best;
          best = d;
          best_j = fb;
        } else if (d < second) {
          second = d;
        }
      }
      if (best_j < 0 || best > o.max_distance) continue;
      if (second != std::numeric_limits<int>::max() && double(best) >= o.ratio * double(second)) continue;
      auto& claim = best_for_b[size_t(best_j)];
      if (best < claim.first || (best == claim.first && fa < claim.second)) claim = {best, fa};
    }
    ++ia;
    ++ib;
  }
  std::vector<std::pair<int, int>> out;
  for (size_t j = 0; j < best_for_b.size(); ++j)
    if (best_for_b[j].second >= 0) out.emplace_back(best_for_b[j].second, int(j));
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace nerfslam
