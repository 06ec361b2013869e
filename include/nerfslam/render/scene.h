#pragma once
// Synthetic scenes made of textured geometry, for ground-truth sequences.
//
//   room       a furnished room (walls, floor, ceiling, boxes, a table, a shelf), 6 x 5 x 2.8 m
//   turntable  an object (stacked boxes and a pillar) on a table, seen from an orbit
//   plane      one textured plane (degenerate for fundamental-matrix initialisation)
//   corridor   a rectangular ring corridor (12 x 8 m outside, 2 m wide) for drift and loop closure
//
// World frame: z up, metres; the floor is z = 0. Textures come from the shared data photos (Strecha
// fountain, Middlebury, chessboard, Tsukuba) when they are found and `textures` allows, otherwise
// (or in addition) from procedural high-frequency textures (multi-octave value noise, shapes and
// strokes) that are a deterministic function of the seed, so every surface gives FAST corners.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "nerfslam/render/renderer.h"

namespace nerfslam {

// Decorrelated sub-seed from a seed and a stream id (splitmix64 of a * golden + b + salt). Every
// seeded generator of the render module derives its stream here; the salt keeps a caller's streams
// (and so its existing output) distinct from another's.
uint64_t mixSeed(uint64_t a, uint64_t b, uint64_t salt);

struct SynthSceneOptions {
  std::string name = "room";
  uint64_t seed = 1;
  // "auto": photos from the data folder when present, procedural otherwise; "procedural": never
  // read photos (identical output on every machine); "photo": require the photos.
  std::string textures = "auto";
  // Data folder with the photos; empty: $NERFSLAM_DATA_DIR, else <source>/../shared/data.
  std::filesystem::path data_dir;
  int texture_size = 512;  // procedural texture side in pixels
};

struct Scene {
  std::string name;
  std::vector<cv::Mat> textures;       // BGR 8-bit
  std::vector<Mesh> meshes;            // textured triangles; Mesh::texture indexes `textures`
  Eigen::Vector3d bbox_min, bbox_max;  // of all geometry
  // Where cameras may go (inside the free space) and what they look at.
  Eigen::Vector3d camera_min, camera_max;
  Eigen::Vector3d focus;   // centre of interest (turntable object, plane centre, room centre)
  Eigen::Vector3d anchor;  // a free-space point for stationary (rotation) and orbit trajectories
  bool look_outward = true;
  // Look-at scenes: how far (rad) the handheld camera wanders around the focus from the anchor.
  double handheld_sweep = 0.5;  // true: look around from inside (room, corridor); false: at `focus`
  // Closed centreline the loop trajectory follows (corridor, room); empty: an ellipse in camera box.
  std::vector<Eigen::Vector2d> loop_path;
  double loop_height = 1.5;
  // Named 3D landmarks (corners of boxes, marker centres) for tests.
  std::vector<std::pair<std::string, Eigen::Vector3d>> landmarks;
  bool photographic = false;  // true when photos were used as textures
};

const std::vector<std::string>& sceneNames();
// Throws nerfslam::Error listing the valid names for an unknown scene.
Scene makeScene(const SynthSceneOptions& opts);

// A deterministic high-frequency texture (value noise octaves, random shapes and text-like
// strokes), BGR, size x size.
cv::Mat proceduralTexture(int size, uint64_t seed, int style = 0);

// Uploads the scene's textures and meshes to `renderer` (after clearMeshes()).
void uploadScene(const Scene& scene, Renderer& renderer);

}  // namespace nerfslam
