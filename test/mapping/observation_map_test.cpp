#include "nerfslam/mapping/observation_map.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <map>
#include <random>
#include <vector>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

// Random operations on a SortedVectorMap and a std::map side by side: the same results, the same
// contents in the same order after every operation.
TEST(SortedVectorMap, BehavesAsStdMapUnderRandomOperations) {
  std::mt19937 rng(7);
  SortedVectorMap<int64_t, int> flat;
  std::map<int64_t, int> ref;
  for (int op = 0; op < 20000; ++op) {
    const int64_t k = std::uniform_int_distribution<int64_t>(-5, 60)(rng);
    const int v = std::uniform_int_distribution<int>(0, 1000)(rng);
    switch (std::uniform_int_distribution<int>(0, 5)(rng)) {
      case 0:
        flat[k] = v;
        ref[k] = v;
        break;
      case 1: {
        const auto a = flat.emplace(k, v);
        const auto b = ref.emplace(k, v);
        ASSERT_EQ(a.second, b.second);
        ASSERT_EQ(a.first->second, b.first->second);
        break;
      }
      case 2:
        ASSERT_EQ(flat.erase(k), ref.erase(k));
        break;
      case 3: {
        auto it = flat.find(k);
        ASSERT_EQ(it != flat.end(), ref.count(k) == 1);
        if (it != flat.end()) {
          ASSERT_EQ(it->second, ref.at(k));
          flat.erase(it);
          ref.erase(k);
        }
        break;
      }
      case 4:
        ASSERT_EQ(flat.count(k), ref.count(k));
        if (ref.count(k)) {
          ASSERT_EQ(flat.at(k), ref.at(k));
        }
        break;
      default:
        if (std::uniform_int_distribution<int>(0, 200)(rng) == 0) {
          flat.clear();
          ref.clear();
        }
    }
    ASSERT_EQ(flat.size(), ref.size());
    ASSERT_EQ(flat.empty(), ref.empty());
    std::vector<std::pair<int64_t, int>> a(flat.begin(), flat.end()), b(ref.begin(), ref.end());
    ASSERT_EQ(a, b) << "after operation " << op;
  }
}

TEST(SortedVectorMap, AtOfAMissingKeyThrows) {
  SortedVectorMap<int64_t, int> m;
  m[3] = 1;
  EXPECT_EQ(m.at(3), 1);
  EXPECT_THROW(m.at(4), Error);
}

}  // namespace
}  // namespace nerfslam
