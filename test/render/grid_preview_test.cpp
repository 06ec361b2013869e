// render-preview --grid's drawing (render/grid_preview.h): cells in map_server's grey levels, the
// image flipped (row 0 is the highest y), a trajectory at its cells.
#include "nerfslam/render/grid_preview.h"

#include <gtest/gtest.h>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

TEST(GridPreview, CellsAndTrajectoryAreWhereTheGridSays) {
  NavGrid g;
  g.width = 20;
  g.height = 10;
  g.resolution = 0.1;
  g.origin_x = -1.0;
  g.origin_y = 2.0;
  g.cells.assign(200, NavGrid::kFree);
  g.at(0, 0) = NavGrid::kOccupied;  // bottom-left
  g.at(19, 9) = NavGrid::kUnknown;  // top-right
  GridTrajectory t;
  t.color = {0, 0, 255};
  // Along y = 2.55 (the middle of row 5), x from -0.85 to 0.75 (columns 1 to 17), in the map frame.
  for (double x = -0.85; x <= 0.75; x += 0.05) t.positions.emplace_back(x, 2.55, 1.2);
  const cv::Mat img = drawNavGrid(g, SE3(), {t}, 200);
  const int s = 10;  // 200 / 20 pixels per cell
  ASSERT_EQ(img.cols, 20 * s);
  ASSERT_EQ(img.rows, 10 * s);
  EXPECT_EQ(img.at<cv::Vec3b>(9 * s + 5, 5), cv::Vec3b(0, 0, 0));                 // (0, 0) occupied, bottom row
  EXPECT_EQ(img.at<cv::Vec3b>(5, 19 * s + 5), cv::Vec3b(205, 205, 205));          // (19, 9) unknown, top row
  EXPECT_EQ(img.at<cv::Vec3b>(2 * s + 5, 10 * s + 5), cv::Vec3b(254, 254, 254));  // free
  // The trajectory: red on row 5 (image row 4 from the top, y = 2.5..2.6), not on row 2.
  EXPECT_EQ(img.at<cv::Vec3b>(4 * s + 5, 8 * s + 5), cv::Vec3b(0, 0, 255));
  EXPECT_EQ(img.at<cv::Vec3b>(7 * s + 5, 8 * s + 5), cv::Vec3b(254, 254, 254));
  NavGrid empty;
  EXPECT_THROW(drawNavGrid(empty, SE3(), {}), Error);
}

}  // namespace
}  // namespace nerfslam
