#pragma once
// A tracked image: grey pyramid, FAST corners spread over a grid on every level, steered-BRIEF
// descriptors computed on those corners, and their undistorted (ideal pinhole) positions.
//
// Descriptor choice: 256-bit steered BRIEF with a learned test pattern, as ORB's rBRIEF (brief.h;
// orientation by intensity centroid). Binary descriptors match with a popcount Hamming distance,
// survive the viewpoint changes of relocalisation far better than PTAM's fixed 8x8 patches, and
// need no per-keyframe warping. Coordinates of keypoints are always level-0 pixels.
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/options.h"

namespace nerfslam {

struct FeatureOptions {
  int num_levels = 8;          // pyramid levels (level 0 = full resolution)
  double scale_factor = 1.2;   // size ratio between consecutive levels (ORB-SLAM's)
  int max_features = 1000;     // total over all levels (split by level area)
  int fast_threshold = 20;     // initial FAST threshold (adapted per grid cell)
  int min_fast_threshold = 7;  // lower bound of the adaptive threshold in low-texture cells
  int cell_size = 40;          // grid bucketing cell (level pixels)
  template <class V>
  void visit(V& v) {
    v("num_levels", num_levels, "Image pyramid levels", check::range(1, 8));
    v("scale_factor", scale_factor, "Scale ratio between pyramid levels", check::range(1.05, 2.5));
    v("max_features", max_features, "Features per frame over all levels", check::range(50, 20000));
    v("fast_threshold", fast_threshold, "Initial FAST threshold (8-bit intensities)", check::range(1, 255));
    v("min_fast_threshold", min_fast_threshold, "Lowest FAST threshold used in low-texture grid cells",
      check::range(1, 255));
    v("cell_size", cell_size, "Grid bucketing cell size in pixels", check::range(8, 256));
  }
};

// Per-stage cost in milliseconds of CPU time of the calling thread (CLOCK_THREAD_CPUTIME_ID): a
// one-core cost that stays meaningful on a loaded machine (OpenCV's own worker threads, if
// cv::setNumThreads allows them, are not counted).
struct FrameTimings {
  double pyramid_ms = 0, fast_ms = 0, descriptor_ms = 0;
};

class Frame {
 public:
  uint64_t id = 0;
  double timestamp = 0;
  Camera camera;                             // calibration of the level-0 image (may have distortion)
  std::vector<cv::Mat> pyramid;              // CV_8U grey, pyramid[0] is the input image
  cv::Mat colour;                            // 8-bit BGR input (shared, not copied); empty for grey input
  std::vector<double> level_scale;           // level_scale[l] = scale_factor^l
  std::vector<cv::KeyPoint> keypoints;       // level-0 pixels (distorted), octave = level, angle in deg
  cv::Mat descriptors;                       // keypoints.size() x 32 CV_8U
  std::vector<Eigen::Vector2d> undistorted;  // ideal pinhole pixels (same K) of each keypoint
  FrameTimings timings;

  size_t size() const { return keypoints.size(); }
  // Indices of keypoints within `radius` (level-0 pixels, distorted coordinates) of `uv`, on
  // levels [min_level, max_level] (max_level < 0: all). Uses a grid; cost ~ radius^2.
  std::vector<int> featuresInArea(const Eigen::Vector2d& uv, double radius, int min_level = 0,
                                  int max_level = -1) const;
  // The same into `out` (cleared first): a caller in a loop reuses one buffer, no allocation per call.
  void featuresInArea(const Eigen::Vector2d& uv, double radius, std::vector<int>* out, int min_level = 0,
                      int max_level = -1) const;

  // (Re)builds the grid featuresInArea uses from the keypoints (extractFrame calls it).
  void buildGrid();
  // Grid used by featuresInArea (filled by extractFrame).
  int grid_cell = 32, grid_cols = 0, grid_rows = 0;
  std::vector<std::vector<int>> grid;
};

// Builds the frame: grey conversion (if BGR; the BGR image is kept in Frame::colour), pyramid, FAST with grid bucketing
// + adaptive threshold, orientation, ORB descriptors, undistortion. Throws nerfslam::Error on an empty image or an
// image whose size differs from the camera's.
Frame extractFrame(const cv::Mat& image, const Camera& camera, const FeatureOptions& options, uint64_t id = 0,
                   double timestamp = 0);

// Hamming distance of two 32-byte descriptors (rows of CV_8U mats).
int descriptorDistance(const uint8_t* a, const uint8_t* b);
inline int descriptorDistance(const cv::Mat& a, const cv::Mat& b) {
  return descriptorDistance(a.ptr<uint8_t>(), b.ptr<uint8_t>());
}

}  // namespace nerfslam
