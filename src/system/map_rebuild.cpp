#include "system/map_rebuild.h"

#include <atomic>
#include <cstring>
#include <exception>
#include <thread>

#include <fmt/format.h>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/crc32.h"
#include "nerfslam/core/error.h"

namespace nerfslam::map_detail {
namespace fs = std::filesystem;

namespace {

// The record's image from `dir`: listed in the manifest, verified, decoded, and of the size and
// pixels the keyframes file records.
cv::Mat readKeyframeImage(const fs::path& dir, const MapManifest& m, const KeyframeRecord& rec,
                          const std::string& kf_file) {
  const MapFileEntry* img = m.findName(rec.image.name);
  if (!img || img->role != "image")
    throw fieldError(kf_file, fmt::format("keyframe (id {}).image", rec.kf.id),
                     fmt::format("'{}' is not listed in {}", rec.image.name, kMapManifestName));
  const std::string png = readMapFile(dir, *img);
  const fs::path img_path = dir / img->name;
  const cv::Mat image = cv::imdecode(cv::Mat(1, static_cast<int>(png.size()), CV_8U, const_cast<char*>(png.data())),
                                     cv::IMREAD_UNCHANGED);
  if (image.empty()) fail("{}: not a readable PNG image", img_path.string());
  if (image.cols != rec.image.width || image.rows != rec.image.height || image.channels() != rec.image.channels ||
      image.depth() != CV_8U)
    throw fieldError(img_path.string(), "size",
                     fmt::format("{}x{}x{} image, the keyframe was {}x{}x{}", image.cols, image.rows, image.channels(),
                                 rec.image.width, rec.image.height, rec.image.channels));
  if (pixelsCrc(image) != rec.image.pixels_crc)
    throw fieldError(img_path.string(), "pixels", "the decoded pixels differ from the keyframe's (checksum)");
  return image;
}

}  // namespace

const cv::Mat& keyframeImage(const Keyframe& kf) {
  if (!kf.frame->colour.empty()) return kf.frame->colour;
  if (kf.frame->pyramid.empty()) fail("keyframe {}: its frame has no image", kf.id);
  return kf.frame->pyramid[0];
}

uint32_t pixelsCrc(const cv::Mat& img) {
  uint32_t crc = 0;
  const size_t row = static_cast<size_t>(img.cols) * img.elemSize();
  for (int y = 0; y < img.rows; ++y) crc = crc32(img.ptr(y), row, crc);
  return crc;
}

bool sameFeatures(const Frame& f, const KeyframeRecord& rec) {
  if (f.keypoints.size() != rec.keypoints.size() || f.descriptors.rows != rec.descriptors.rows) return false;
  for (size_t i = 0; i < f.keypoints.size(); ++i) {
    const cv::KeyPoint &a = f.keypoints[i], &b = rec.keypoints[i];
    if (a.pt != b.pt || a.octave != b.octave || a.angle != b.angle || a.size != b.size) return false;
  }
  for (int i = 0; i < f.descriptors.rows; ++i)
    if (std::memcmp(f.descriptors.ptr(i), rec.descriptors.ptr(i), kDescriptorBytes) != 0) return false;
  return true;
}

// Rebuilds the keyframe's Frame from its image (pyramid and everything else by extractFrame), then
// installs the stored features so the saved associations hold whatever extraction gives today.
std::shared_ptr<const Frame> rebuildFrame(const KeyframeRecord& rec, const cv::Mat& image, const Camera& camera,
                                          const FeatureOptions& features, const std::string& file, bool* identical) {
  Frame f = extractFrame(image, camera, features, rec.frame_id, rec.timestamp);
  *identical = sameFeatures(f, rec);
  if (!*identical) {
    f.keypoints = rec.keypoints;
    f.descriptors = rec.descriptors;
    f.undistorted = rec.undistorted;
    for (size_t i = 0; i < f.keypoints.size(); ++i) {
      const cv::KeyPoint& k = f.keypoints[i];
      if (k.octave >= static_cast<int>(f.pyramid.size()))
        throw fieldError(file, fmt::format("keyframe (id {}).keypoints[{}].octave", rec.kf.id, i),
                         fmt::format("pyramid level {}, but the stored image gives {} levels with the map's "
                                     "tracking.features options",
                                     k.octave, f.pyramid.size()));
    }
    f.buildGrid();
  }
  return std::make_shared<const Frame>(std::move(f));
}

int rebuildKeyframes(const fs::path& dir, const MapManifest& manifest, std::vector<KeyframeRecord>& records,
                     const Camera& camera, const FeatureOptions& features, const std::string& kf_file) {
  // Decoding and feature extraction dominate loading: two threads.
  std::vector<char> identical(records.size(), 0);
  std::vector<std::exception_ptr> errors(records.size());
  std::atomic<size_t> next{0};
  auto rebuild = [&] {
    for (size_t k = next++; k < records.size(); k = next++) {
      try {
        KeyframeRecord& rec = records[k];
        const cv::Mat image = readKeyframeImage(dir, manifest, rec, kf_file);
        bool same = false;
        rec.kf.frame = rebuildFrame(rec, image, camera, features, kf_file, &same);
        identical[k] = same;
      } catch (...) {
        errors[k] = std::current_exception();
      }
    }
  };
  {
    std::vector<std::thread> helpers;
    if (records.size() > 1 && std::thread::hardware_concurrency() > 1) helpers.emplace_back(rebuild);
    rebuild();
    for (auto& t : helpers) t.join();
  }
  int n_identical = 0;
  for (size_t k = 0; k < records.size(); ++k) {
    if (errors[k]) std::rethrow_exception(errors[k]);
    n_identical += identical[k];
  }
  return n_identical;
}

}  // namespace nerfslam::map_detail
