#include "nerfslam/core/calibration.h"

#include <algorithm>
#include <cctype>
#include <cmath>

#include <spdlog/spdlog.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"

namespace nerfslam {

namespace fs = std::filesystem;

namespace {

// A decimal integer of 1 to 4 digits, surrounding spaces allowed; -1 otherwise.
int parseCount(std::string s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.erase(s.begin());
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.pop_back();
  if (s.empty() || s.size() > 4) return -1;
  for (char c : s)
    if (!std::isdigit(static_cast<unsigned char>(c))) return -1;
  return std::stoi(s);
}

}  // namespace

ChessboardSpec parseBoardSize(const std::string& text, double square) {
  const size_t x = text.find_first_of("xX");
  const int cols = x == std::string::npos ? -1 : parseCount(text.substr(0, x));
  const int rows = x == std::string::npos ? -1 : parseCount(text.substr(x + 1));
  if (cols < 0 || rows < 0) fail("--board '{}': expected COLSxROWS counted in inner corners, e.g. 9x6", text);
  ChessboardSpec b;
  b.cols = cols;
  b.rows = rows;
  if (b.cols < 2 || b.rows < 2) fail("--board '{}': a board needs at least 2x2 inner corners", text);
  if (!(square > 0) || !std::isfinite(square)) fail("--square {}: the square size must be > 0 metres", square);
  b.square = square;
  return b;
}

std::vector<fs::path> listImageFiles(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) fail("{}: not a directory", dir.string());
  static const std::vector<std::string> exts = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"};
  std::vector<fs::path> out;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    if (!e.is_regular_file()) continue;
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
    if (std::find(exts.begin(), exts.end(), ext) != exts.end()) out.push_back(e.path());
  }
  if (ec) fail("{}: cannot list directory: {}", dir.string(), ec.message());
  std::sort(out.begin(), out.end());
  return out;
}

namespace {

// Subpixel window: large enough to be accurate, small enough to stay inside one square.
cv::Size subPixWindow(const std::vector<cv::Point2f>& corners, const ChessboardSpec& board) {
  double min_d = 1e9;
  for (int r = 0; r < board.rows; ++r)
    for (int c = 0; c + 1 < board.cols; ++c) {
      const cv::Point2f d = corners[r * board.cols + c + 1] - corners[r * board.cols + c];
      min_d = std::min(min_d, static_cast<double>(std::hypot(d.x, d.y)));
    }
  const int half = std::clamp(static_cast<int>(min_d * 0.4), 2, 11);
  return {half, half};
}

// RMS reprojection error of one view, using our camera model.
double viewRms(const Camera& cam, const std::vector<cv::Point3f>& obj, const std::vector<cv::Point2f>& img,
               const cv::Mat& rvec, const cv::Mat& tvec, double* sum_sq) {
  cv::Mat R;
  cv::Rodrigues(rvec, R);
  Eigen::Matrix3d Re;
  Eigen::Vector3d te;
  for (int i = 0; i < 3; ++i) {
    te(i) = tvec.at<double>(i);
    for (int j = 0; j < 3; ++j) Re(i, j) = R.at<double>(i, j);
  }
  double s = 0;
  for (size_t i = 0; i < obj.size(); ++i) {
    const Eigen::Vector2d uv = cam.project(Re * Eigen::Vector3d(obj[i].x, obj[i].y, obj[i].z) + te);
    s += (uv - Eigen::Vector2d(img[i].x, img[i].y)).squaredNorm();
  }
  *sum_sq += s;
  return std::sqrt(s / static_cast<double>(obj.size()));
}

}  // namespace

CalibrationResult calibrateFromImages(const fs::path& image_dir, const ChessboardSpec& board, DistortionModel model,
                                      const CalibrationImageLoader& load) {
  if (board.cols < 2 || board.rows < 2 || !(board.square > 0))
    fail("calibrate: invalid board {}x{} with {} m squares", board.cols, board.rows, board.square);
  if (model == DistortionModel::kNone) fail("calibrate: the distortion model must be radtan or equidistant");
  const std::vector<fs::path> files = listImageFiles(image_dir);
  if (files.empty())
    fail("{}: no images found (looked for .jpg, .jpeg, .png, .bmp, .tif, .tiff, .pgm, .ppm)", image_dir.string());

  std::vector<cv::Point3f> board_points;
  for (int r = 0; r < board.rows; ++r)
    for (int c = 0; c < board.cols; ++c)
      board_points.emplace_back(static_cast<float>(c * board.square), static_cast<float>(r * board.square), 0.f);

  CalibrationResult result;
  cv::Size image_size;
  std::vector<std::vector<cv::Point3f>> object_points;
  std::vector<std::vector<cv::Point2f>> image_points;
  std::vector<size_t> used_index;  // into result.images
  for (const auto& f : files) {
    CalibrationImage ci;
    ci.path = f;
    cv::Mat gray;
    try {
      gray = load ? load(f) : cv::imread(f.string(), cv::IMREAD_GRAYSCALE);
      if (gray.empty()) ci.problem = "could not be read as an image";
    } catch (const std::exception& e) {
      ci.problem = e.what();
    }
    if (!ci.problem.empty()) {
      // A loader's error names the file itself.
      if (ci.problem.rfind(f.string(), 0) == 0)
        spdlog::warn("{}", ci.problem);
      else
        spdlog::warn("{}: {}", f.string(), ci.problem);
      result.images.push_back(ci);
      continue;
    }
    if (image_size.area() == 0) {
      image_size = gray.size();
    } else if (gray.size() != image_size) {
      fail("{}: image is {}x{} but the first image is {}x{}; calibrate one camera (one image size) at a time",
           f.string(), gray.cols, gray.rows, image_size.width, image_size.height);
    }
    std::vector<cv::Point2f> corners;
    const bool found = cv::findChessboardCorners(
        gray, cv::Size(board.cols, board.rows), corners,
        cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK);
    if (!found) {
      ci.problem = "board not found";
      spdlog::debug("{}: {}", f.string(), ci.problem);
      result.images.push_back(ci);
      continue;
    }
    cv::cornerSubPix(gray, corners, subPixWindow(corners, board), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-4));
    ci.board_found = true;
    used_index.push_back(result.images.size());
    result.images.push_back(ci);
    object_points.push_back(board_points);
    image_points.push_back(corners);
  }
  const int found = static_cast<int>(image_points.size());
  if (found < 3)
    fail(
        "{}: the {}x{} board was found in {} of {} images; calibration needs at least 3 (check --board: it counts "
        "inner corners)",
        image_dir.string(), board.cols, board.rows, found, files.size());

  std::vector<cv::Mat> rvecs, tvecs;
  Camera cam;
  cam.width = image_size.width;
  cam.height = image_size.height;
  try {
    if (model == DistortionModel::kRadTan) {
      cv::Mat K, D;
      cv::calibrateCamera(object_points, image_points, image_size, K, D, rvecs, tvecs);
      cam.fx = K.at<double>(0, 0);
      cam.fy = K.at<double>(1, 1);
      cam.cx = K.at<double>(0, 2);
      cam.cy = K.at<double>(1, 2);
      cam.distortion_model = DistortionModel::kRadTan;
      for (int i = 0; i < 5; ++i) cam.distortion.push_back(D.at<double>(i));
    } else {
      std::vector<std::vector<cv::Point3d>> obj_d;
      std::vector<std::vector<cv::Point2d>> img_d;
      for (size_t v = 0; v < object_points.size(); ++v) {
        obj_d.emplace_back(object_points[v].begin(), object_points[v].end());
        img_d.emplace_back(image_points[v].begin(), image_points[v].end());
      }
      cv::Matx33d K;
      cv::Vec4d D;
      std::vector<cv::Vec3d> rv, tv;
      cv::fisheye::calibrate(obj_d, img_d, image_size, K, D, rv, tv,
                             cv::fisheye::CALIB_RECOMPUTE_EXTRINSIC | cv::fisheye::CALIB_FIX_SKEW,
                             cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-10));
      cam.fx = K(0, 0);
      cam.fy = K(1, 1);
      cam.cx = K(0, 2);
      cam.cy = K(1, 2);
      cam.distortion_model = DistortionModel::kEquidistant;
      cam.distortion = {D[0], D[1], D[2], D[3]};
      for (size_t v = 0; v < rv.size(); ++v) {
        rvecs.push_back(cv::Mat(rv[v]).clone());
        tvecs.push_back(cv::Mat(tv[v]).clone());
      }
    }
  } catch (const cv::Exception& e) {
    fail("{}: calibration failed ({}); try more images with the board at varied angles and distances",
         image_dir.string(), e.err);
  }
  cam.validate(image_dir.string() + " (calibration result)");

  double sum_sq = 0;
  size_t n_points = 0;
  for (size_t v = 0; v < image_points.size(); ++v) {
    result.images[used_index[v]].rms = viewRms(cam, object_points[v], image_points[v], rvecs[v], tvecs[v], &sum_sq);
    n_points += image_points[v].size();
  }
  result.camera = cam;
  result.rms = std::sqrt(sum_sq / static_cast<double>(n_points));
  result.images_used = found;
  return result;
}

}  // namespace nerfslam
