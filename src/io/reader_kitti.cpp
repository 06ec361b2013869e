// KITTI odometry layout: image_0/ (or image_l/, or image_2/ for the colour camera) holding
// %06d.png, times.txt (seconds, one per frame), calib.txt (P0 — or P2 with image_2/ — as 12 numbers,
// a 3x4 rectified projection matrix; lines may or may not start with "P0:"). Images are rectified:
// no distortion. Ground truth, when present: poses.txt in the sequence folder, poses/XX.txt,
// ../poses/XX.txt or ../../poses/XX.txt (the official dataset/sequences/XX + dataset/poses/XX.txt
// layout), 12 numbers per line (a row-major 3x4 camera-to-world matrix), one line per frame.
#include <cmath>

#include "dataset_internal.h"
#include "nerfslam/core/error.h"

namespace nerfslam::io_detail {

std::unique_ptr<Dataset> openKitti(const fs::path& root, const DatasetOptions& opts) {
  std::error_code ec;
  fs::path img_dir;
  std::string pname = "P0";
  for (const char* d : {"image_0", "image_l", "image_2"}) {
    if (fs::is_directory(root / d, ec)) {
      img_dir = root / d;
      if (std::string(d) == "image_2") pname = "P2";
      break;
    }
  }
  if (img_dir.empty()) fail("{}: no image_0/, image_l/ or image_2/ folder (KITTI odometry layout)", root.string());

  const fs::path times_file = root / "times.txt";
  std::vector<FrameEntry> frames;
  for (const Line& l : readDataLines(times_file)) {
    FrameEntry e;
    e.timestamp = parseNumber(splitTokens(l.text).front(), times_file, l.number, "timestamp");
    if (!frames.empty()) checkIncreasing(frames.back().timestamp, e.timestamp, times_file, l.number);
    const std::string name = fmt::format("{:06d}", frames.size());
    auto img = resolveImage(img_dir / name);
    if (!img)
      fail("{}:{}: no image {}.png for this timestamp (frame {})", times_file.string(), l.number,
           (img_dir / name).string(), frames.size());
    e.image = *img;
    frames.push_back(std::move(e));
  }
  if (frames.empty()) fail("{}: no timestamps", times_file.string());

  // calib.txt: the line starting with "P0:" (or P2:), or the first line when lines carry no names.
  const fs::path calib_file = root / "calib.txt";
  const auto calib = readDataLines(calib_file);
  std::optional<Line> pline;
  for (const Line& l : calib) {
    if (l.text.rfind(pname + ":", 0) == 0) pline = Line{l.number, l.text.substr(pname.size() + 1)};
  }
  if (!pline && !calib.empty() && calib.front().text.find(':') == std::string::npos) {
    const size_t idx = pname == "P2" ? 2 : 0;
    if (idx < calib.size()) pline = calib[idx];
  }
  if (!pline) throw fieldError(calib_file.string(), pname, "missing");
  const auto p = parseNumbers(*pline, calib_file, 12, pname + " (12 numbers of a 3x4 projection matrix)");
  if (p.size() != 12)
    throw fieldError(calib_file.string(), pname,
                     fmt::format("line {}: expected 12 numbers, found {}", pline->number, p.size()));
  // P = K [I | t]: fx = P00, fy = P11, cx = P02, cy = P12 (image size from the first image).
  Camera cam = Camera::pinhole(0, 0, p[0], p[5], p[2], p[6]);

  // Ground truth.
  const std::string seq = fs::absolute(root).lexically_normal().filename().string();
  std::vector<fs::path> candidates = {root / "poses.txt"};
  if (!seq.empty()) {
    candidates.push_back(root / "poses" / (seq + ".txt"));
    candidates.push_back(root / ".." / "poses" / (seq + ".txt"));
    candidates.push_back(root / ".." / ".." / "poses" / (seq + ".txt"));
  }
  for (const fs::path& gt : candidates) {
    if (!fs::exists(gt, ec)) continue;
    const Trajectory traj = readKittiTrajectory(gt);
    if (traj.size() != frames.size())
      fail("{}: {} poses for {} frames in {}; there must be one pose per frame", gt.string(), traj.size(),
           frames.size(), times_file.string());
    for (size_t i = 0; i < frames.size(); ++i) frames[i].T_world_cam = traj[i].pose;
    break;
  }

  auto ds = std::make_unique<SequenceDataset>("kitti", root);
  ds->finish(std::move(frames), cam, fmt::format("{} ({})", calib_file.string(), pname), opts);
  return ds;
}

}  // namespace nerfslam::io_detail
