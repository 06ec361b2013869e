// Renderer: GL projection convention (pixel centres), marker placement against Camera::project,
// context/resource leaks.
#include <gtest/gtest.h>

#include <dirent.h>
#include <fstream>
#include <random>

#include <opencv2/imgproc.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/render/renderer.h"
#include "nerfslam/render/scene.h"
#include "nerfslam/render/trajectory.h"

namespace nerfslam {
namespace {

Mesh coloredQuad(const std::array<Eigen::Vector3d, 4>& p, cv::Vec3f rgb) {
  Mesh m;
  for (const auto& q : p) {
    Vertex v;
    v.x = static_cast<float>(q.x());
    v.y = static_cast<float>(q.y());
    v.z = static_cast<float>(q.z());
    v.r = rgb[0];
    v.g = rgb[1];
    v.b = rgb[2];
    m.vertices.push_back(v);
  }
  m.indices = {0, 1, 2, 0, 2, 3};
  return m;
}

TEST(GlProjection, MapsCameraPointsToPixelCentresExactly) {
  const double fx = 431.7, fy = 402.2, cx = 151.3, cy = 97.8, n = 0.1, f = 50.0;
  const int W = 320, H = 200;
  const Eigen::Matrix4d P = glProjection(fx, fy, cx, cy, W, H, n, f);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(-1, 1);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d X(U(rng), U(rng), 1.0 + 5.0 * (U(rng) + 1.0));
    const Eigen::Vector4d c = P * X.homogeneous();
    const double ndc_x = c.x() / c.w(), ndc_y = c.y() / c.w();
    // GL window coordinates; OpenCV pixel = window - 0.5 (rows counted from the framebuffer bottom).
    const double win_x = (ndc_x + 1.0) * 0.5 * W, win_y = (ndc_y + 1.0) * 0.5 * H;
    EXPECT_NEAR(win_x - 0.5, fx * X.x() / X.z() + cx, 1e-9);
    EXPECT_NEAR(win_y - 0.5, fy * X.y() / X.z() + cy, 1e-9);
    EXPECT_DOUBLE_EQ(c.w(), X.z());
  }
  const Eigen::Vector4d cn = P * Eigen::Vector4d(0, 0, n, 1), cf = P * Eigen::Vector4d(0, 0, f, 1);
  EXPECT_NEAR(cn.z() / cn.w(), -1.0, 1e-12);
  EXPECT_NEAR(cf.z() / cf.w(), 1.0, 1e-12);
  EXPECT_THROW(glProjection(-1, fy, cx, cy, W, H, n, f), Error);
  EXPECT_THROW(glProjection(fx, fy, cx, cy, W, H, 1.0, 0.5), Error);
}

// A half-plane edge at a fractional pixel position: pixel centres on the covered side are drawn,
// the others not. An off-by-half-pixel projection moves the edge across a pixel centre.
TEST(Renderer, EdgesFallBetweenTheRightPixelCentres) {
  Camera cam = Camera::pinhole(96, 64, 100.0, 110.0, 47.2, 30.9);
  Renderer r;
  const double z = 2.0;
  // Rectangle covering u in [20.3, 70.7], v in [10.6, 50.2] (fractional edges on all sides).
  const double u0 = 20.3, u1 = 70.7, v0 = 10.6, v1 = 50.2;
  auto X = [&](double u) { return (u - cam.cx) / cam.fx * z; };
  auto Y = [&](double v) { return (v - cam.cy) / cam.fy * z; };
  r.addMesh(coloredQuad({Eigen::Vector3d(X(u0), Y(v0), z), Eigen::Vector3d(X(u1), Y(v0), z),
                         Eigen::Vector3d(X(u1), Y(v1), z), Eigen::Vector3d(X(u0), Y(v1), z)},
                        {1, 1, 1}));
  cv::Mat bgr, depth;
  r.render(cam, SE3(), &bgr, &depth);
  ASSERT_EQ(bgr.size(), cv::Size(96, 64));
  for (int v = 0; v < 64; ++v)
    for (int u = 0; u < 96; ++u) {
      const bool inside = u > u0 && u < u1 && v > v0 && v < v1;
      ASSERT_EQ(bgr.at<cv::Vec3b>(v, u)[1] > 128, inside) << "pixel " << u << "," << v;
      if (inside) {
        ASSERT_NEAR(depth.at<float>(v, u), z, 1e-5);
      } else {
        ASSERT_EQ(depth.at<float>(v, u), 0.f);
      }
    }
}

// Meshes are drawn near ones first whatever order they were added in: the image is the same for
// every order (the depth test decides), including a mesh that encloses the camera.
TEST(Renderer, ImageDoesNotDependOnTheOrderMeshesWereAdded) {
  const Camera cam = Camera::pinhole(80, 60, 70.0, 70.0, 39.5, 29.5);
  const std::vector<Mesh> meshes = {
      coloredQuad(
          {Eigen::Vector3d(-5, -5, 4), Eigen::Vector3d(5, -5, 4), Eigen::Vector3d(5, 5, 4), Eigen::Vector3d(-5, 5, 4)},
          {0.2f, 0.4f, 0.9f}),  // far wall
      coloredQuad({Eigen::Vector3d(-0.5, -0.4, 1.5), Eigen::Vector3d(0.6, -0.4, 1.5), Eigen::Vector3d(0.6, 0.5, 1.5),
                   Eigen::Vector3d(-0.5, 0.5, 1.5)},
                  {0.9f, 0.1f, 0.1f}),  // near
      coloredQuad({Eigen::Vector3d(-1, -1, 2.5), Eigen::Vector3d(1.2, -1, 2.0), Eigen::Vector3d(1.2, 0.8, 2.2),
                   Eigen::Vector3d(-1, 0.8, 2.7)},
                  {0.1f, 0.8f, 0.2f}),  // tilted, between them
  };
  cv::Mat ref_bgr, ref_depth;
  const std::vector<std::vector<int>> orders = {{0, 1, 2}, {2, 1, 0}, {1, 0, 2}};
  for (const auto& order : orders) {
    Renderer r;
    for (int i : order) r.addMesh(meshes[i]);
    cv::Mat bgr, depth;
    r.render(cam, SE3(Eigen::Quaterniond(Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitY())), Eigen::Vector3d(0.1, 0, 0)),
             &bgr, &depth);
    if (ref_bgr.empty()) {
      ref_bgr = bgr;
      ref_depth = depth;
      // All three are visible.
      int red = 0, green = 0, blue = 0;
      for (int v = 0; v < bgr.rows; ++v)
        for (int u = 0; u < bgr.cols; ++u) {
          const cv::Vec3b p = bgr.at<cv::Vec3b>(v, u);
          red += p[2] > 200;
          green += p[1] > 180 && p[2] < 60;
          blue += p[0] > 200 && p[2] < 80;
        }
      EXPECT_GT(red, 50);
      EXPECT_GT(green, 50);
      EXPECT_GT(blue, 50);
      continue;
    }
    EXPECT_EQ(cv::norm(bgr, ref_bgr, cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(depth, ref_depth, cv::NORM_INF), 0.0);
  }
}

TEST(Renderer, TextureFilterNames) {
  EXPECT_EQ(parseTextureFilter("mip-nearest"), TextureFilter::kMipNearest);
  EXPECT_EQ(parseTextureFilter("trilinear"), TextureFilter::kTrilinear);
  EXPECT_STREQ(textureFilterName(TextureFilter::kTrilinear), "trilinear");
  EXPECT_THROW(parseTextureFilter("nearest"), Error);
}

// A coloured marker around a known 3D point in the furnished room lands where Camera::project puts
// it (centroid of its pixels, sub-pixel), seen from a generic pose.
TEST(Renderer, MarkerLandsWhereCameraProjectPutsIt) {
  SynthSceneOptions so;
  so.name = "room";
  so.textures = "procedural";
  so.texture_size = 128;
  const Scene scene = makeScene(so);
  Renderer r;
  uploadScene(scene, r);
  const Camera cam = Camera::pinhole(160, 120, 131.25, 131.25, 79.5, 59.5);
  const Eigen::Vector3d eye(0.3, -0.4, 1.5), marker(1.2, 0.9, 1.3);
  const SE3 T_world_cam = lookAt(eye, marker + Eigen::Vector3d(0.15, -0.2, 0.1));
  // A disk (radius 0.08 m, 48 sides) parallel to the image plane, centred on the marker point: its
  // image is a similar disk centred on the projection, and the centroid of its covered pixel centres
  // averages the per-row quantisation away (a square's would not).
  const Eigen::Matrix3d R = T_world_cam.rotationMatrix();
  Mesh disk;
  Vertex c;
  c.x = static_cast<float>(marker.x());
  c.y = static_cast<float>(marker.y());
  c.z = static_cast<float>(marker.z());
  c.g = 0;
  disk.vertices.push_back(c);
  for (int k = 0; k <= 48; ++k) {
    const double a = 2 * M_PI * k / 48;
    const Eigen::Vector3d p = marker + 0.08 * (std::cos(a) * R.col(0) + std::sin(a) * R.col(1));
    Vertex v = c;
    v.x = static_cast<float>(p.x());
    v.y = static_cast<float>(p.y());
    v.z = static_cast<float>(p.z());
    disk.vertices.push_back(v);
    if (k > 0) disk.indices.insert(disk.indices.end(), {0u, static_cast<uint32_t>(k), static_cast<uint32_t>(k + 1)});
  }
  r.addMesh(disk);
  cv::Mat bgr;
  r.render(cam, T_world_cam, &bgr, nullptr);
  double su = 0, sv = 0, n = 0;
  for (int v = 0; v < bgr.rows; ++v)
    for (int u = 0; u < bgr.cols; ++u) {
      const cv::Vec3b c = bgr.at<cv::Vec3b>(v, u);
      if (c[0] == 255 && c[2] == 255 && c[1] == 0) su += u, sv += v, ++n;  // pure magenta
    }
  ASSERT_GT(n, 20);
  const Eigen::Vector2d expected = cam.project(T_world_cam.inverse() * marker);
  EXPECT_NEAR(su / n, expected.x(), 0.15);
  EXPECT_NEAR(sv / n, expected.y(), 0.15);
}

long residentKb() {
  std::ifstream f("/proc/self/statm");
  long pages = 0, resident = 0;
  f >> pages >> resident;
  return resident * 4;
}

int openFds() {
  int n = 0;
  if (DIR* d = opendir("/proc/self/fd")) {
    while (readdir(d)) ++n;
    closedir(d);
  }
  return n;
}

// gcc defines __SANITIZE_ADDRESS__ under ASan; clang 14 says so only through __has_feature.
#if defined(__has_feature)
#if __has_feature(address_sanitizer)
#define NERFSLAM_CLANG_ASAN 1
#endif
#endif

TEST(Renderer, FiftyContextsDoNotLeak) {
  const Camera cam = Camera::pinhole(64, 48, 50, 50, 31.5, 23.5);
  const int live0 = GlContext::liveCount();
  // Full renderers (context, shaders, framebuffer, texture, buffers), then bare contexts.
  auto renderer_cycle = [&] {
    Renderer r;
    r.addTexture(proceduralTexture(64, 1));
    Mesh m = coloredQuad(
        {Eigen::Vector3d(-1, -1, 2), Eigen::Vector3d(1, -1, 2), Eigen::Vector3d(1, 1, 2), Eigen::Vector3d(-1, 1, 2)},
        {1, 1, 1});
    m.texture = 0;
    r.addMesh(m);
    cv::Mat bgr, depth;
    r.render(cam, SE3(), &bgr, &depth);
    EXPECT_EQ(GlContext::liveCount(), live0 + 1);
  };
  for (int i = 0; i < 3; ++i) renderer_cycle();  // warm up (Mesa's one-time allocations, thread pools)
  { GlContext c; }
  const long rss0 = residentKb();
  const int fds0 = openFds();
  for (int i = 0; i < 10; ++i) renderer_cycle();
  for (int i = 0; i < 50; ++i) {
    GlContext c;
    EXPECT_EQ(GlContext::liveCount(), live0 + 1);
  }
  EXPECT_EQ(GlContext::liveCount(), live0);
  EXPECT_LE(openFds(), fds0);
#if defined(__SANITIZE_ADDRESS__) || defined(NERFSLAM_CLANG_ASAN)
  // AddressSanitizer keeps freed memory in quarantine (256 MB by default), so resident memory grows
  // whatever is freed; LeakSanitizer checks for leaks at exit instead.
  (void)rss0;
#else
  EXPECT_LT(residentKb() - rss0, 8 * 1024) << "resident memory grew by " << residentKb() - rss0 << " kB";
#endif
}

TEST(Renderer, RejectsBadInput) {
  Renderer r;
  EXPECT_THROW(r.addTexture(cv::Mat()), Error);
  EXPECT_THROW(r.addTexture(cv::Mat(4, 4, CV_32F)), Error);
  Mesh m;
  m.texture = 5;
  EXPECT_THROW(r.addMesh(m), Error);
  Camera cam = Camera::pinhole(16, 16, 10, 10, 7.5, 7.5);
  cam.width = 9000;
  cv::Mat bgr;
  EXPECT_THROW(r.render(cam, SE3(), &bgr, nullptr), Error);
}

}  // namespace
}  // namespace nerfslam
