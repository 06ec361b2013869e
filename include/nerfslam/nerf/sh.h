#pragma once
// Real spherical harmonics up to degree 4 (16 coefficients) of a unit direction, with
// tiny-cuda-nn's constants and ordering (SphericalHarmonics encoding, degree 4).
#include <cstddef>

namespace nerfslam::nerf {

// out[16] for one unit direction (x, y, z).
void shEncode4(float x, float y, float z, float* out);
// A batch: dir n*3 -> out[s * ld + k], k < 16 (sample-major).
void shEncodeBatch(const float* dir, size_t n, float* out, size_t ld);

}  // namespace nerfslam::nerf
