// A folder of images: png/jpg/jpeg/bmp/tif/pgm/ppm in natural order (img2 before img10).
// Timestamps: times.txt or timestamps.txt in the folder (one per image, first number of each
// non-comment line, seconds), else DatasetOptions::fps. Camera: camera.yaml in the folder, else the
// override. No ground truth.
#include "dataset_internal.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/image_io.h"

namespace nerfslam::io_detail {

std::unique_ptr<Dataset> openFolder(const fs::path& root, const DatasetOptions& opts) {
  const std::vector<fs::path> images = listImages(root);
  if (images.empty())
    fail("{}: no images in the folder (expected png, jpg, jpeg, bmp, tif, tiff, pgm or ppm files)", root.string());

  std::vector<FrameEntry> frames(images.size());
  for (size_t i = 0; i < images.size(); ++i) frames[i].image = images[i];

  std::error_code ec;
  fs::path times_file;
  for (const char* n : {"times.txt", "timestamps.txt"})
    if (times_file.empty() && fs::exists(root / n, ec)) times_file = root / n;  // a directory: refused by name
  if (!times_file.empty()) {
    const auto lines = readDataLines(times_file);
    if (lines.size() != images.size())
      fail("{}: {} timestamps for {} images in {}; there must be one line per image", times_file.string(), lines.size(),
           images.size(), root.string());
    for (size_t i = 0; i < lines.size(); ++i) {
      const auto toks = splitTokens(lines[i].text);
      frames[i].timestamp = parseNumber(toks.front(), times_file, lines[i].number, "timestamp");
      if (i > 0) checkIncreasing(frames[i - 1].timestamp, frames[i].timestamp, times_file, lines[i].number);
    }
  } else if (opts.fps > 0) {
    for (size_t i = 0; i < frames.size(); ++i) frames[i].timestamp = static_cast<double>(i) / opts.fps;
  } else {
    fail(
        "{}: no times.txt or timestamps.txt in the folder; give the frame rate ({}) or add times.txt (one time in "
        "seconds per line, a line per image in the images' order)",
        root.string(), opts.fps_option);
  }

  std::optional<Camera> cam;
  const fs::path cam_file = root / "camera.yaml";
  if (!opts.camera_override && fs::exists(cam_file, ec)) cam = loadCameraYaml(cam_file);
  auto ds = std::make_unique<SequenceDataset>("folder", root);
  ds->finish(std::move(frames), cam, cam_file.string(), opts,
             fmt::format("{}: no camera.yaml in the image folder; give a camera YAML ({})", root.string(),
                         opts.camera_option));
  return ds;
}

}  // namespace nerfslam::io_detail
