#pragma once
// Private to the system module: the binary files of a map folder, keyframes.<G>.bin and
// points.<G>.bin (their layout is in include/nerfslam/system/map_store.h). Encoding, decoding with
// errors naming the file and the field ("keyframe[3] (id 12).keypoints.octave"), and the check that
// the two files' keypoint <-> map point associations agree.
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "nerfslam/mapping/map.h"

namespace nerfslam::map_detail {

constexpr int kDescriptorBytes = 32;  // one keypoint or map-point descriptor

// The stored image of a keyframe, as the keyframes file refers to it.
struct KeyframeImageRef {
  std::string name;  // the image file, relative to the map folder
  int width = 0, height = 0, channels = 0;
  uint32_t pixels_crc = 0;  // CRC-32 of the decoded pixel rows (map_rebuild.h pixelsCrc)
};

// A keyframe as decoded: everything stored, and a Keyframe whose frame is not set yet (it is
// rebuilt from the image, map_rebuild.h).
struct KeyframeRecord {
  Keyframe kf;  // frame not set yet
  uint64_t frame_id = 0;
  double timestamp = 0;
  KeyframeImageRef image;
  std::vector<cv::KeyPoint> keypoints;
  std::vector<Eigen::Vector2d> undistorted;
  cv::Mat descriptors;
};

// The keyframes file of `kfs` (each with its frame), `images[k]` being the image of kfs[k]. Throws an
// Error naming the keyframe when its frame's keypoints, slots, undistorted points and descriptors
// disagree in number or type.
std::string encodeKeyframes(const std::vector<Keyframe>& kfs, const std::vector<KeyframeImageRef>& images);
// Decodes a keyframes file; `file` names it in errors (bad magic or version, truncation, a non-rigid
// pose, an invalid keypoint, bytes after the last keyframe).
std::vector<KeyframeRecord> decodeKeyframes(const std::string& data, const std::string& file);

// The map points file of `points`. Throws an Error naming the point whose descriptor is not a
// continuous 8-bit row.
std::string encodePoints(const std::vector<MapPoint>& points);
std::vector<MapPoint> decodePoints(const std::string& data, const std::string& file);

// Ids listed once in each file; every point observed at least twice, by keyframes of `kf_file`
// whose keypoint slots name it; every keypoint slot that names a point listed by that point.
// Throws an Error naming the file and the record.
void checkAssociations(const std::vector<KeyframeRecord>& records, const std::vector<MapPoint>& points,
                       const std::string& kf_file, const std::string& pt_file);

}  // namespace nerfslam::map_detail
