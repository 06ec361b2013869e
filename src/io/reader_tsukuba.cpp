// New Tsukuba stereo (Martull et al. 2012), the layout of the shared new_tsukuba_150 copy:
// images/ (natural order; JPEG data despite the .png names: decoding goes by content),
// cam_traj_truth.txt (one line per frame: tx ty tz in centimetres, then a 3x3 matrix M row by row),
// intrinsics.txt ("fx fy cx cy width height", a header line allowed), 30 frames per second.
// Ground truth: the camera centre t / 100 m and the camera-to-world rotation S M S with
// S = diag(1, -1, -1), both in the first camera's frame with OpenCV axes (so frame 0 is identity).
#include "dataset_internal.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/image_io.h"

namespace nerfslam::io_detail {

std::unique_ptr<Dataset> openTsukuba(const fs::path& root, const DatasetOptions& opts) {
  std::error_code ec;
  const fs::path img_dir = fs::is_directory(root / "images", ec) ? root / "images" : root;
  const auto images = listImages(img_dir);
  if (images.empty()) fail("{}: no images", img_dir.string());
  const fs::path traj_file = root / "cam_traj_truth.txt";
  const auto lines = readDataLines(traj_file);
  if (lines.size() < images.size())
    fail("{}: {} poses for {} images in {}; there must be one line per image", traj_file.string(), lines.size(),
         images.size(), img_dir.string());
  const double fps = opts.fps > 0 ? opts.fps : 30.0;
  const Eigen::Matrix3d S = Eigen::Vector3d(1, -1, -1).asDiagonal();
  std::vector<FrameEntry> frames;
  for (size_t i = 0; i < images.size(); ++i) {
    const auto v = parseNumbers(lines[i], traj_file, 12, "tx ty tz m11..m33");
    Eigen::Matrix3d M;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) M(r, c) = v[3 + 3 * r + c];
    if ((M * M.transpose() - Eigen::Matrix3d::Identity()).norm() > 1e-3 || M.determinant() < 0)
      fail("{}:{}: the 3x3 matrix is not a rotation", traj_file.string(), lines[i].number);
    FrameEntry e;
    e.image = images[i];
    e.timestamp = static_cast<double>(i) / fps;
    e.T_world_cam = SE3(S * M * S, Eigen::Vector3d(v[0], v[1], v[2]) / 100.0);
    frames.push_back(std::move(e));
  }

  std::optional<Camera> cam;
  std::string source;
  const fs::path intr = root / "intrinsics.txt";
  if (!opts.camera_override && fs::exists(intr, ec)) {
    std::optional<std::vector<double>> nums;
    for (const Line& l : readDataLines(intr)) {
      const auto toks = splitTokens(l.text);
      if (toks.empty() ||
          !(std::isdigit(static_cast<unsigned char>(toks[0][0])) || toks[0][0] == '-' || toks[0][0] == '.'))
        continue;  // header line
      nums = parseNumbers(l, intr, 6, "fx fy cx cy width height");
      break;
    }
    if (!nums) fail("{}: no 'fx fy cx cy width height' line", intr.string());
    const auto& n = *nums;
    cam = Camera::pinhole(imageDimension(n[4], intr.string(), "width"), imageDimension(n[5], intr.string(), "height"),
                          n[0], n[1], n[2], n[3]);
    source = intr.string();
  }
  auto ds = std::make_unique<SequenceDataset>("tsukuba", root);
  ds->finish(std::move(frames), cam, source, opts,
             fmt::format("{}: no intrinsics.txt; give a camera YAML ({})", root.string(), opts.camera_option));
  return ds;
}

}  // namespace nerfslam::io_detail
