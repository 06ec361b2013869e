// Degree-4 real spherical harmonics (tiny-cuda-nn's SphericalHarmonics encoding constants).
#include "nerfslam/nerf/sh.h"

namespace nerfslam::nerf {

void shEncode4(float x, float y, float z, float* out) {
  const float xy = x * y, xz = x * z, yz = y * z, x2 = x * x, y2 = y * y, z2 = z * z;
  out[0] = 0.28209479177387814f;
  out[1] = -0.48860251190291987f * y;
  out[2] = 0.48860251190291987f * z;
  out[3] = -0.48860251190291987f * x;
  out[4] = 1.0925484305920792f * xy;
  out[5] = -1.0925484305920792f * yz;
  out[6] = 0.94617469575755997f * z2 - 0.31539156525251999f;
  out[7] = -1.0925484305920792f * xz;
  out[8] = 0.54627421529603959f * x2 - 0.54627421529603959f * y2;
  out[9] = 0.59004358992664352f * y * (-3.0f * x2 + y2);
  out[10] = 2.8906114426405538f * xy * z;
  out[11] = 0.45704579946446572f * y * (1.0f - 5.0f * z2);
  out[12] = 0.3731763325901154f * z * (5.0f * z2 - 3.0f);
  out[13] = 0.45704579946446572f * x * (1.0f - 5.0f * z2);
  out[14] = 1.4453057213202769f * z * (x2 - y2);
  out[15] = 0.59004358992664352f * x * (-x2 + 3.0f * y2);
}

void shEncodeBatch(const float* dir, size_t n, float* out, size_t ld) {
  for (size_t s = 0; s < n; ++s) shEncode4(dir[3 * s], dir[3 * s + 1], dir[3 * s + 2], out + s * ld);
}

}  // namespace nerfslam::nerf
