// Degree-4 SH: orthonormal on the sphere (checks every constant) and the first bands in closed form.
#include <gtest/gtest.h>

#include <cmath>

#include "nerfslam/nerf/sh.h"

namespace nerfslam::nerf {
namespace {

TEST(SphericalHarmonics, OrthonormalOnTheSphere) {
  // Gauss-Legendre would be exact; a fine midpoint rule in (cos theta, phi) is accurate to ~1e-4
  // for these polynomials of degree <= 8.
  const int nt = 200, np = 400;
  double gram[16][16] = {};
  for (int i = 0; i < nt; ++i) {
    const double z = -1.0 + (i + 0.5) * 2.0 / nt;
    const double r = std::sqrt(1 - z * z);
    for (int j = 0; j < np; ++j) {
      const double phi = (j + 0.5) * 2 * M_PI / np;
      float y[16];
      shEncode4(float(r * std::cos(phi)), float(r * std::sin(phi)), float(z), y);
      const double w = (2.0 / nt) * (2 * M_PI / np);
      for (int a = 0; a < 16; ++a)
        for (int b = 0; b < 16; ++b) gram[a][b] += w * y[a] * y[b];
    }
  }
  for (int a = 0; a < 16; ++a)
    for (int b = 0; b < 16; ++b) EXPECT_NEAR(gram[a][b], a == b ? 1.0 : 0.0, 2e-3) << a << "," << b;
}

TEST(SphericalHarmonics, LowBandsClosedForm) {
  float y[16];
  shEncode4(0.f, 0.f, 1.f, y);
  EXPECT_NEAR(y[0], 0.5 / std::sqrt(M_PI), 1e-6);
  EXPECT_NEAR(y[2], std::sqrt(3.0 / (4 * M_PI)), 1e-6);
  EXPECT_NEAR(y[6], std::sqrt(5.0 / (16 * M_PI)) * 2.0, 1e-6);  // (3z^2-1) at z=1
  EXPECT_NEAR(y[1], 0.0, 1e-7);
  float b[6 * 16];
  const float dirs[6] = {0.6f, 0.f, 0.8f, 0.f, -0.6f, 0.8f};
  shEncodeBatch(dirs, 2, b, 16);
  shEncode4(0.6f, 0.f, 0.8f, y);
  for (int k = 0; k < 16; ++k) EXPECT_EQ(b[k], y[k]);
}

}  // namespace
}  // namespace nerfslam::nerf
