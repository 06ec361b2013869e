// Multi-view stereo benchmarks: unordered or ring-ordered still views with calibrated cameras and no
// capture times (timestamps are index / 30 s, or index / DatasetOptions::fps). All views must share
// one set of intrinsics (they do in the published sets); a differing K is an error.
//
// Middlebury (Seitz et al. 2006): NAME_par.txt, first line the view count, then per view
// "imgname.png k11..k33 r11..r33 t1 t2 t3" with x ~ K [R | t] X, so R, t map world to camera and
// T_world_cam = [R | t]^-1. Only views whose image is in the folder become frames, in file order.
//
// Strecha (CVPR 2008): images/NAME.jpg with gt_dense_cameras/NAME.jpg.camera holding K (3 lines),
// distortion (1 line, must be zero), R (3 lines), the camera centre C (1 line) and "width height".
// Convention (checked by the epipolar test in test/io/dataset_multiview_test.cpp: ORB matches
// between views satisfy the epipolar constraint of these poses to about a pixel): R is the
// camera-to-world rotation (its columns are the camera axes in world coordinates), so
// T_world_cam = (R, C) and x ~ K [R^T | -R^T C] X.
#include <cmath>

#include "dataset_internal.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/image_io.h"

namespace nerfslam::io_detail {

namespace {

bool isRotation(const Eigen::Matrix3d& R, double tol) {
  return (R * R.transpose() - Eigen::Matrix3d::Identity()).norm() < tol && R.determinant() > 0;
}

void checkSameK(const Eigen::Matrix3d& K, const Eigen::Matrix3d& K0, const std::string& where) {
  if ((K - K0).cwiseAbs().maxCoeff() > 1e-6 * std::max(1.0, K0.cwiseAbs().maxCoeff()))
    fail("{}: intrinsics differ from the first view's; views with different intrinsics are not supported", where);
}

void setTimes(std::vector<FrameEntry>& frames, const DatasetOptions& opts) {
  const double fps = opts.fps > 0 ? opts.fps : 30.0;
  for (size_t i = 0; i < frames.size(); ++i) frames[i].timestamp = static_cast<double>(i) / fps;
}

}  // namespace

std::unique_ptr<Dataset> openMiddlebury(const fs::path& root, const DatasetOptions& opts) {
  std::error_code ec;
  fs::path par;
  for (fs::directory_iterator it(root, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string n = it->path().filename().string();
    if (n.size() > 8 && n.compare(n.size() - 8, 8, "_par.txt") == 0) {
      if (!par.empty()) fail("{}: more than one *_par.txt ({} and {})", root.string(), par.string(), n);
      par = it->path();
    }
  }
  if (par.empty()) fail("{}: no *_par.txt camera file (Middlebury layout)", root.string());
  const auto lines = readDataLines(par);
  if (lines.empty()) fail("{}: empty file", par.string());
  const double count = parseNumber(lines[0].text, par, lines[0].number, "view count");
  if (count != std::floor(count) || count < 1 || count != static_cast<double>(lines.size() - 1))
    fail("{}:{}: the view count {} does not match the {} view lines that follow", par.string(), lines[0].number,
         lines[0].text, lines.size() - 1);

  std::vector<FrameEntry> frames;
  std::optional<Eigen::Matrix3d> K0;
  for (size_t li = 1; li < lines.size(); ++li) {
    const Line& l = lines[li];
    const auto toks = splitTokens(l.text);
    if (toks.size() != 22)
      fail("{}:{}: expected 'imgname k11..k33 r11..r33 t1 t2 t3' (22 fields), found {}", par.string(), l.number,
           toks.size());
    const fs::path img = root / toks[0];
    if (!fs::is_regular_file(img, ec)) continue;  // the folder holds a subset of the views
    double v[21];
    for (int k = 0; k < 21; ++k) v[k] = parseNumber(toks[k + 1], par, l.number, "camera parameter");
    Eigen::Matrix3d K, R;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        K(r, c) = v[3 * r + c];
        R(r, c) = v[9 + 3 * r + c];
      }
    const Eigen::Vector3d t(v[18], v[19], v[20]);
    if (!isRotation(R, 1e-4)) fail("{}:{}: R is not a rotation matrix", par.string(), l.number);
    if (K0)
      checkSameK(K, *K0, fmt::format("{}:{}", par.string(), l.number));
    else
      K0 = K;
    FrameEntry e;
    e.image = img;
    e.T_world_cam = SE3(R, t).inverse();
    frames.push_back(std::move(e));
  }
  if (frames.empty()) fail("{}: none of the views it lists has its image in {}", par.string(), root.string());
  setTimes(frames, opts);
  const Eigen::Matrix3d& K = *K0;
  if (std::abs(K(0, 1)) > 1e-9) fail("{}: non-zero skew in K is not supported", par.string());
  Camera cam = Camera::pinhole(0, 0, K(0, 0), K(1, 1), K(0, 2), K(1, 2));
  auto ds = std::make_unique<SequenceDataset>("middlebury", root);
  ds->finish(std::move(frames), cam, par.string(), opts);
  return ds;
}

std::unique_ptr<Dataset> openStrecha(const fs::path& root, const DatasetOptions& opts) {
  std::error_code ec;
  const fs::path cam_dir = root / "gt_dense_cameras";
  const fs::path img_dir = fs::is_directory(root / "images", ec) ? root / "images" : root;
  const auto images = listImages(img_dir);
  std::vector<FrameEntry> frames;
  std::optional<Eigen::Matrix3d> K0;
  int width = 0, height = 0;
  fs::path first_cam;
  for (const fs::path& img : images) {
    const fs::path cf = cam_dir / (img.filename().string() + ".camera");
    if (!fs::is_regular_file(cf, ec)) continue;
    const auto lines = readDataLines(cf);
    if (lines.size() < 9) fail("{}: expected 9 lines (K, distortion, R, C, size), found {}", cf.string(), lines.size());
    Eigen::Matrix3d K, R;
    for (int r = 0; r < 3; ++r) {
      const auto k = parseNumbers(lines[r], cf, 3, "K row");
      const auto rr = parseNumbers(lines[4 + r], cf, 3, "R row");
      for (int c = 0; c < 3; ++c) {
        K(r, c) = k[c];
        R(r, c) = rr[c];
      }
    }
    const auto dist = parseNumbers(lines[3], cf, 1, "distortion");
    for (double d : dist)
      if (d != 0) fail("{}:{}: non-zero distortion is not supported", cf.string(), lines[3].number);
    const auto C = parseNumbers(lines[7], cf, 3, "camera centre");
    const auto size_d = parseNumbers(lines[8], cf, 2, "width height");
    const std::string size_where = fmt::format("{}:{}", cf.string(), lines[8].number);
    const int size[2] = {imageDimension(size_d[0], size_where, "width height"),
                         imageDimension(size_d[1], size_where, "width height")};
    if (!isRotation(R, 1e-3)) fail("{}:{}: R is not a rotation matrix", cf.string(), lines[4].number);
    if (K0) {
      checkSameK(K, *K0, cf.string());
      if (size[0] != width || size[1] != height)
        fail("{}:{}: image size {}x{} differs from {}'s {}x{}", cf.string(), lines[8].number, size[0], size[1],
             first_cam.string(), width, height);
    } else {
      K0 = K;
      width = size[0];
      height = size[1];
      first_cam = cf;
    }
    FrameEntry e;
    e.image = img;
    e.T_world_cam = SE3(R, Eigen::Vector3d(C[0], C[1], C[2]));
    frames.push_back(std::move(e));
  }
  if (frames.empty())
    fail("{}: no image in {} has a camera file NAME.camera in {}", root.string(), img_dir.string(), cam_dir.string());
  setTimes(frames, opts);
  const Eigen::Matrix3d& K = *K0;
  Camera cam = Camera::pinhole(width, height, K(0, 0), K(1, 1), K(0, 2), K(1, 2));
  auto ds = std::make_unique<SequenceDataset>("strecha", root);
  ds->finish(std::move(frames), cam, first_cam.string(), opts);
  return ds;
}

}  // namespace nerfslam::io_detail
