#pragma once
// A trained NeRF (field + occupancy grid + scene normalisation) and its versioned binary file.
//
// File layout (little-endian; version 2, or 1 when the model has no learned background: such files
// are byte for byte what earlier builds wrote, and both versions load):
//   "NERFSLAM"                       8-byte magic
//   uint32 format version            (kModelFormatVersion)
//   uint32 byte-order mark           0x01020304
//   uint64 header length H, then H bytes of JSON: field config, scene transform, grid cascades and
//          threshold, training steps, the learned background's rows and frame (version 2), and the
//          list of arrays that follow (name, type, count)
//   the arrays' raw data in that order (field parameters, "background.logits", optionally Adam
//   state, occupancy values)
//   uint32 CRC-32 (IEEE, as zlib) of every byte before it
// Written atomically (temporary file + rename). load rejects a truncated, foreign, wrong-version or
// corrupted file with an Error naming the file; parameters are checked finite before writing.
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>

#include "nerfslam/nerf/background.h"
#include "nerfslam/nerf/field.h"
#include "nerfslam/nerf/occupancy.h"
#include "nerfslam/nerf/rays.h"

namespace nerfslam::nerf {

constexpr uint32_t kModelFormatVersion = 2;

struct NerfModel {
  FieldConfig field_config;
  SceneTransform scene;
  std::unique_ptr<RadianceField> field;
  std::unique_ptr<OccupancyGrid> grid;
  // The learned background (background.h); null: renders use RenderOptions::background. The trainer
  // creates it for views without alpha when TrainOptions::learned_background is set.
  std::unique_ptr<Background> background;
  uint64_t training_steps = 0;

  // A fresh model: the field's finest resolution is 2048 * aabb_scale (instant-ngp) unless the
  // config's differs from the default; the grid has log2(aabb_scale)+1 cascades, all cells occupied.
  static NerfModel create(FieldConfig config, const SceneTransform& scene, uint64_t seed);

  // NeRF-space points -> the field's [0,1]^3 input (the scene AABB normalised).
  void toFieldCoords(const float* p_nerf, size_t n, float* q) const;
  float fieldCoordScale() const { return float(1.0 / scene.aabb_scale); }  // dq/dp
};

struct SaveOptions {
  bool include_optimizer = false;  // Adam moments and counters (for resuming training)
};

void saveModel(NerfModel& model, const std::filesystem::path& path, const SaveOptions& options = {});
NerfModel loadModel(const std::filesystem::path& path);

}  // namespace nerfslam::nerf
