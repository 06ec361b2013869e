#include "nerfslam/tracking/local_map.h"

#include <gtest/gtest.h>

namespace nerfslam {
namespace {

TEST(TrackingLocalMap, FindsPointsByIdAndKeyframesBySlot) {
  TrackingLocalMap m;
  for (uint64_t id : {3u, 8u, 20u}) {
    TrackingMapPoint p;
    p.id = id;
    m.points.push_back(p);
  }
  m.keyframes = {5, 2, 9};
  EXPECT_EQ(m.findPoint(3), 0u);
  EXPECT_EQ(m.findPoint(20), 2u);
  EXPECT_FALSE(m.findPoint(4));
  EXPECT_FALSE(m.findPoint(21));
  EXPECT_EQ(m.findKeyframe(5), 0u);
  EXPECT_EQ(m.findKeyframe(9), 2u);
  EXPECT_FALSE(m.findKeyframe(3));
  EXPECT_FALSE(TrackingLocalMap{}.findPoint(3));
  EXPECT_TRUE(TrackingLocalMap{}.empty());
  EXPECT_FALSE(m.empty());
}

}  // namespace
}  // namespace nerfslam
