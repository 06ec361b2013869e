#pragma once
// Intrinsic calibration from chessboard photos (Zhang's method through OpenCV): the library side of
// `nerfslam calibrate`.
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "nerfslam/core/camera.h"

namespace nerfslam {

// A chessboard, counted in inner corners (OpenCV's convention: a board of 10x7 squares is 9x6).
struct ChessboardSpec {
  int cols = 0;         // inner corners per row
  int rows = 0;         // inner corners per column
  double square = 0.0;  // side of one square in metres
};

// Parses "COLSxROWS" (e.g. "9x6", both >= 2). Throws an Error quoting the text otherwise.
ChessboardSpec parseBoardSize(const std::string& text, double square);

// The image files in `dir` (jpg, jpeg, png, bmp, tif, tiff, pgm, ppm; any case), sorted by name.
std::vector<std::filesystem::path> listImageFiles(const std::filesystem::path& dir);

struct CalibrationImage {
  std::filesystem::path path;
  bool board_found = false;
  std::string problem;  // why the image was not used ("board not found", "could not be read"), else ""
  double rms = 0.0;     // RMS reprojection error of this image's corners in pixels (when found)
};

struct CalibrationResult {
  Camera camera;
  double rms = 0.0;  // RMS reprojection error over every corner of every used image, pixels
  int images_used = 0;
  std::vector<CalibrationImage> images;  // every image file, in name order
};

// Detects the board (findChessboardCorners + cornerSubPix) in every image of `image_dir` and
// calibrates a radtan (k1 k2 p1 p2 k3, cv::calibrateCamera) or equidistant (cv::fisheye::calibrate)
// camera. Reprojection errors are computed with the returned Camera. Throws an Error when the
// directory has no images, the images differ in size, the board is found in fewer than 3 images, or
// the optimisation fails.
//
// load reads an image as 8-bit grey (default: cv::imread). An image it cannot read, or that it
// refuses by throwing (the CLI passes io/image_io.h's readImage, which refuses truncated and corrupt
// PNG and JPEG files), is reported in `images` with the reason and left out, as one without a board.
using CalibrationImageLoader = std::function<cv::Mat(const std::filesystem::path&)>;
CalibrationResult calibrateFromImages(const std::filesystem::path& image_dir, const ChessboardSpec& board,
                                      DistortionModel model = DistortionModel::kRadTan,
                                      const CalibrationImageLoader& load = {});

}  // namespace nerfslam
