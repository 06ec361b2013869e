// Writes the smallest valid NeRF model file (fuzz_model's seed): make_model_seed OUT [--optimizer].
#include <cstdio>
#include <cstring>
#include <exception>

#include "nerfslam/nerf/model_io.h"

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s OUT [--optimizer]\n", argv[0]);
    return 2;
  }
  try {
    nerfslam::nerf::FieldConfig config;
    config.n_levels = 8;
    config.log2_hashmap_size = 14;
    nerfslam::nerf::NerfModel model = nerfslam::nerf::NerfModel::create(config, nerfslam::nerf::SceneTransform{}, 1);
    nerfslam::nerf::SaveOptions opts;
    opts.include_optimizer = argc > 2 && std::strcmp(argv[2], "--optimizer") == 0;
    nerfslam::nerf::saveModel(model, argv[1], opts);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  return 0;
}
