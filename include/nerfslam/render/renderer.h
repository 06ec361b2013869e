#pragma once
// Headless OpenGL rendering through OSMesa (Mesa's software rasteriser, llvmpipe).
//
// Conventions. Poses are T_world_cam with OpenCV optical axes (x right, y down, z forward); the
// vertex shader works directly in those axes. Pixels follow OpenCV: the centre of the top-left
// pixel is (0, 0), so pixel (u, v) covers [u - 0.5, u + 0.5] x [v - 0.5, v + 0.5]. The projection
// matrix (glProjection) maps a camera point to the GL window position (u + 0.5, v + 0.5) where
// (u, v) = (fx x/z + cx, fy y/z + cy): image row v is framebuffer row v counted from the bottom, so
// glReadPixels returns the image top row first with no flip. Depth is the camera z of the visible
// surface in metres, written by the fragment shader into a float target (exact, not recovered from
// the non-linear depth buffer); 0 where nothing was drawn.
#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"

namespace nerfslam {

// Column-major 4x4 matrix (as GL wants it) taking OpenCV camera coordinates to clip coordinates
// for the ideal pinhole (fx, fy, cx, cy) on a width x height image; near/far in metres (> 0).
Eigen::Matrix4d glProjection(double fx, double fy, double cx, double cy, int width, int height, double near,
                             double far);

// An OSMesa context (GL 4.5 core profile) that owns nothing else. Creation and destruction are
// counted so tests can check for leaks. Not copyable; one thread at a time.
class GlContext {
 public:
  GlContext();
  ~GlContext();
  GlContext(const GlContext&) = delete;
  GlContext& operator=(const GlContext&) = delete;
  void makeCurrent();
  static int liveCount();

 private:
  void* ctx_ = nullptr;  // OSMesaContext
  std::vector<uint8_t> dummy_;
};

struct Vertex {
  float x = 0, y = 0, z = 0;  // world position (metres)
  float u = 0, v = 0;         // texture coordinates (repeat wrap)
  float r = 1, g = 1, b = 1;  // colour: multiplies the texture, or the colour itself when untextured
};

enum class Primitive { kTriangles, kLines, kPoints };

struct Mesh {
  Primitive primitive = Primitive::kTriangles;
  int texture = -1;  // index from Renderer::addTexture, -1 for vertex colours only
  std::vector<Vertex> vertices;
  std::vector<uint32_t> indices;  // empty: draw vertices in order
};

struct RasterOptions {
  double near = 0.05;  // metres
  double far = 200.0;
  cv::Vec3f background{0.f, 0.f, 0.f};  // BGR in [0, 1]
  float point_size = 3.f;               // pixels, for Primitive::kPoints
  float line_width = 1.f;               // pixels, for Primitive::kLines
};

// How textures are sampled when minified. llvmpipe spends most of a frame texturing: on the room
// scene kMipNearest costs 0.7x the CPU of kTrilinear per 640x480 frame, and the images of the two
// differ by 45 dB PSNR (bench_render_synth; README, "Synthetic ground-truth sequences"). But the
// seams between mipmap levels move with the camera, and SLAM on them is less accurate (80 frames of
// the room: ATE 0.75 % against 0.45 %): kTrilinear is the default.
enum class TextureFilter {
  kTrilinear,   // bilinear in the two nearest levels, blended (GL_LINEAR_MIPMAP_LINEAR)
  kMipNearest,  // bilinear within the nearest mipmap level (GL_LINEAR_MIPMAP_NEAREST)
};
// "mip-nearest" / "trilinear"; parseTextureFilter throws nerfslam::Error naming the valid names.
const char* textureFilterName(TextureFilter filter);
TextureFilter parseTextureFilter(const std::string& name);

// Renders meshes to an offscreen framebuffer of any size (up to 8192 x 8192) and reads back colour
// (CV_8UC3 BGR) and depth (CV_32F, metres). Owns its GL context and every GL object it creates.
class Renderer {
 public:
  Renderer();
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  // BGR or gray 8-bit image; mipmapped, filtered as setTextureFilter says, repeat wrapping.
  // Returns its index.
  int addTexture(const cv::Mat& image);
  // Minification filter of every texture, those added before and after (default kTrilinear).
  void setTextureFilter(TextureFilter filter);
  // Uploads a mesh; returns its index. Meshes are drawn near ones first (by the distance from the
  // camera to their bounding box's farthest corner); with the depth test the image does not
  // depend on the order, only the cost does.
  int addMesh(const Mesh& mesh);
  void clearMeshes();
  size_t meshCount() const;

  // Renders the pinhole part of `camera` (distortion ignored) at camera.width x camera.height.
  // `bgr` and/or `depth` may be null to skip that readback.
  void render(const Camera& camera, const SE3& T_world_cam, cv::Mat* bgr, cv::Mat* depth,
              const RasterOptions& opts = {});
  // Waits until every render() so far has been drawn. A readback waits by itself; a render() with
  // neither only queues the drawing in llvmpipe (what a benchmark of drawing alone must wait for).
  void finish();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace nerfslam
