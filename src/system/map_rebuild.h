#pragma once
// Private to the system module: the keyframe images of a map folder. At save time, the image a
// keyframe is stored with and the checksum of its pixels; at load time, the keyframe Frames rebuilt
// from those images with tracking's extractFrame (pyramid, grid) and then given the stored features,
// so the saved associations hold whatever feature extraction gives today.
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/system/map_folder.h"
#include "nerfslam/tracking/frame.h"
#include "system/map_codec.h"

namespace nerfslam::map_detail {

// The image a keyframe is stored with: the BGR input when kept, else pyramid level 0. Throws when
// the frame has neither.
const cv::Mat& keyframeImage(const Keyframe& kf);

// CRC-32 of the image's pixel rows (without row padding): equal for equal pixels however stored.
uint32_t pixelsCrc(const cv::Mat& img);

// Whether `f`'s keypoints (position, octave, angle, size) and descriptors equal the record's.
bool sameFeatures(const Frame& f, const KeyframeRecord& rec);

// The record's Frame extracted from `image` with `features`; when its features differ from the
// stored ones (*identical false), the stored keypoints, descriptors and undistorted points replace
// them and the grid is rebuilt. Throws an Error naming `file` when a stored keypoint's octave is
// beyond the pyramid.
std::shared_ptr<const Frame> rebuildFrame(const KeyframeRecord& rec, const cv::Mat& image, const Camera& camera,
                                          const FeatureOptions& features, const std::string& file, bool* identical);

// Sets every record's kf.frame from its image in `dir` (which `manifest` must list as an image; its
// size and CRC-32, its decoded size and pixel checksum are checked against the manifest and the
// record), on two threads; the first failing keyframe in file order is reported. `kf_file` (the
// keyframes file) names the records in errors. Returns how many keyframes re-extracted identically.
int rebuildKeyframes(const std::filesystem::path& dir, const MapManifest& manifest,
                     std::vector<KeyframeRecord>& records, const Camera& camera, const FeatureOptions& features,
                     const std::string& kf_file);

}  // namespace nerfslam::map_detail
