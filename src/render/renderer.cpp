#include "nerfslam/render/renderer.h"

#define GL_GLEXT_PROTOTYPES 1
#include <GL/gl.h>
#include <GL/glext.h>
#include <GL/osmesa.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <spdlog/spdlog.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

std::atomic<int> g_live_contexts{0};

// llvmpipe spawns LP_NUM_THREADS rasteriser threads per context (default: one per core). Respect
// a user's setting; otherwise use the cores we have (the machine's hardware concurrency).
void configureMesaOnce() {
  static std::once_flag once;
  std::call_once(once, [] {
    if (!std::getenv("LP_NUM_THREADS")) {
      unsigned n = std::thread::hardware_concurrency();
      if (n == 0) n = 2;
      if (n > 8) n = 8;
      ::setenv("LP_NUM_THREADS", std::to_string(n).c_str(), 0);
    }
  });
}

GLint glMinFilter(TextureFilter filter) {
  return filter == TextureFilter::kTrilinear ? GL_LINEAR_MIPMAP_LINEAR : GL_LINEAR_MIPMAP_NEAREST;
}

const char* kVertexShader = R"(#version 330 core
layout(location = 0) in vec3 a_pos;
layout(location = 1) in vec2 a_uv;
layout(location = 2) in vec3 a_color;
uniform mat4 u_view;   // world -> camera (OpenCV axes)
uniform mat4 u_proj;
uniform float u_point_size;
out vec2 v_uv;
out vec3 v_color;
out float v_z;
void main() {
  vec4 pc = u_view * vec4(a_pos, 1.0);
  v_z = pc.z;
  v_uv = a_uv;
  v_color = a_color;
  gl_PointSize = u_point_size;
  gl_Position = u_proj * pc;
}
)";

const char* kFragmentShader = R"(#version 330 core
in vec2 v_uv;
in vec3 v_color;
in float v_z;
uniform sampler2D u_tex;
uniform int u_textured;
layout(location = 0) out vec4 o_color;
layout(location = 1) out float o_depth;
void main() {
  vec3 c = v_color;
  if (u_textured != 0) c *= texture(u_tex, v_uv).rgb;
  o_color = vec4(c, 1.0);
  o_depth = v_z;
}
)";

GLuint compileShader(GLenum type, const char* src) {
  GLuint s = glCreateShader(type);
  glShaderSource(s, 1, &src, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[2048];
    glGetShaderInfoLog(s, sizeof log, nullptr, log);
    glDeleteShader(s);
    fail("OpenGL shader compilation failed: {}", log);
  }
  return s;
}

}  // namespace

Eigen::Matrix4d glProjection(double fx, double fy, double cx, double cy, int width, int height, double near,
                             double far) {
  if (!(fx > 0 && fy > 0) || width <= 0 || height <= 0 || !(near > 0) || !(far > near))
    fail("glProjection: invalid intrinsics or clip range (fx={}, fy={}, {}x{}, near={}, far={})", fx, fy, width, height,
         near, far);
  // Window x = (ndc_x + 1) * W / 2 must equal u + 0.5 = fx x/z + cx + 0.5, i.e.
  // ndc_x = (2 fx x/z + 2 cx + 1) / W - 1; same for y with the rows counted from the framebuffer
  // bottom (no flip: readback order = image order). clip w = z, ndc z in [-1, 1] over [near, far].
  Eigen::Matrix4d P = Eigen::Matrix4d::Zero();
  P(0, 0) = 2.0 * fx / width;
  P(0, 2) = (2.0 * cx + 1.0) / width - 1.0;
  P(1, 1) = 2.0 * fy / height;
  P(1, 2) = (2.0 * cy + 1.0) / height - 1.0;
  P(2, 2) = (far + near) / (far - near);
  P(2, 3) = -2.0 * far * near / (far - near);
  P(3, 2) = 1.0;
  return P;
}

GlContext::GlContext() {
  configureMesaOnce();
  const int attribs[] = {OSMESA_FORMAT,
                         OSMESA_RGBA,
                         OSMESA_DEPTH_BITS,
                         0,
                         OSMESA_STENCIL_BITS,
                         0,
                         OSMESA_PROFILE,
                         OSMESA_CORE_PROFILE,
                         OSMESA_CONTEXT_MAJOR_VERSION,
                         3,
                         OSMESA_CONTEXT_MINOR_VERSION,
                         3,
                         0};
  OSMesaContext c = OSMesaCreateContextAttribs(attribs, nullptr);
  if (!c) fail("could not create an OSMesa OpenGL 3.3 core context (is Mesa's llvmpipe available?)");
  ctx_ = c;
  dummy_.assign(4 * 4 * 4, 0);
  makeCurrent();
  ++g_live_contexts;
}

GlContext::~GlContext() {
  if (ctx_) {
    OSMesaContext c = static_cast<OSMesaContext>(ctx_);
    if (OSMesaGetCurrentContext() == c) OSMesaMakeCurrent(nullptr, nullptr, 0, 0, 0);
    OSMesaDestroyContext(c);
    --g_live_contexts;
  }
}

void GlContext::makeCurrent() {
  if (!OSMesaMakeCurrent(static_cast<OSMesaContext>(ctx_), dummy_.data(), GL_UNSIGNED_BYTE, 4, 4))
    fail("OSMesaMakeCurrent failed");
}

int GlContext::liveCount() { return g_live_contexts.load(); }

struct Renderer::Impl {
  GlContext ctx;
  GLuint program = 0;
  GLint loc_view = -1, loc_proj = -1, loc_point = -1, loc_textured = -1, loc_tex = -1;
  GLuint fbo = 0, rb_color = 0, rb_depthz = 0, rb_zbuf = 0;
  int fb_w = 0, fb_h = 0;
  std::vector<GLuint> textures;
  TextureFilter texture_filter = TextureFilter::kTrilinear;
  struct GpuMesh {
    GLuint vao = 0, vbo = 0, ebo = 0;
    GLenum mode = GL_TRIANGLES;
    GLsizei count = 0;
    bool indexed = false;
    int texture = -1;
    Eigen::Vector3f lo = Eigen::Vector3f::Zero(), hi = Eigen::Vector3f::Zero();  // bounding box (world)
  };
  std::vector<GpuMesh> meshes;
  std::vector<std::pair<float, size_t>> draw_order;  // scratch of render()

  Impl() {
    GLuint vs = compileShader(GL_VERTEX_SHADER, kVertexShader);
    GLuint fs = compileShader(GL_FRAGMENT_SHADER, kFragmentShader);
    program = glCreateProgram();
    glAttachShader(program, vs);
    glAttachShader(program, fs);
    glLinkProgram(program);
    glDeleteShader(vs);
    glDeleteShader(fs);
    GLint ok = 0;
    glGetProgramiv(program, GL_LINK_STATUS, &ok);
    if (!ok) {
      char log[2048];
      glGetProgramInfoLog(program, sizeof log, nullptr, log);
      glDeleteProgram(program);
      fail("OpenGL program link failed: {}", log);
    }
    loc_view = glGetUniformLocation(program, "u_view");
    loc_proj = glGetUniformLocation(program, "u_proj");
    loc_point = glGetUniformLocation(program, "u_point_size");
    loc_textured = glGetUniformLocation(program, "u_textured");
    loc_tex = glGetUniformLocation(program, "u_tex");
  }

  ~Impl() {
    ctx.makeCurrent();
    for (auto& m : meshes) release(m);
    if (!textures.empty()) glDeleteTextures(static_cast<GLsizei>(textures.size()), textures.data());
    releaseFramebuffer();
    if (program) glDeleteProgram(program);
  }

  static void release(GpuMesh& m) {
    if (m.ebo) glDeleteBuffers(1, &m.ebo);
    if (m.vbo) glDeleteBuffers(1, &m.vbo);
    if (m.vao) glDeleteVertexArrays(1, &m.vao);
    m = GpuMesh{};
  }

  void releaseFramebuffer() {
    if (fbo) glDeleteFramebuffers(1, &fbo);
    GLuint rbs[] = {rb_color, rb_depthz, rb_zbuf};
    for (GLuint r : rbs)
      if (r) glDeleteRenderbuffers(1, &r);
    fbo = rb_color = rb_depthz = rb_zbuf = 0;
    fb_w = fb_h = 0;
  }

  void ensureFramebuffer(int w, int h) {
    if (fbo && w == fb_w && h == fb_h) return;
    releaseFramebuffer();
    glGenFramebuffers(1, &fbo);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo);
    auto makeRb = [&](GLenum fmt, GLenum attachment) {
      GLuint rb = 0;
      glGenRenderbuffers(1, &rb);
      glBindRenderbuffer(GL_RENDERBUFFER, rb);
      glRenderbufferStorage(GL_RENDERBUFFER, fmt, w, h);
      glFramebufferRenderbuffer(GL_FRAMEBUFFER, attachment, GL_RENDERBUFFER, rb);
      return rb;
    };
    rb_color = makeRb(GL_RGBA8, GL_COLOR_ATTACHMENT0);
    rb_depthz = makeRb(GL_R32F, GL_COLOR_ATTACHMENT1);
    rb_zbuf = makeRb(GL_DEPTH_COMPONENT32F, GL_DEPTH_ATTACHMENT);
    const GLenum bufs[] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1};
    glDrawBuffers(2, bufs);
    GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
    if (status != GL_FRAMEBUFFER_COMPLETE) {
      releaseFramebuffer();
      fail("offscreen framebuffer {}x{} incomplete (status 0x{:x})", w, h, status);
    }
    fb_w = w;
    fb_h = h;
  }
};

Renderer::Renderer() : impl_(std::make_unique<Impl>()) {}
Renderer::~Renderer() = default;

const char* textureFilterName(TextureFilter filter) {
  return filter == TextureFilter::kTrilinear ? "trilinear" : "mip-nearest";
}

TextureFilter parseTextureFilter(const std::string& name) {
  if (name == "mip-nearest") return TextureFilter::kMipNearest;
  if (name == "trilinear") return TextureFilter::kTrilinear;
  fail("unknown texture filter '{}' (valid: trilinear, mip-nearest)", name);
}

void Renderer::setTextureFilter(TextureFilter filter) {
  impl_->texture_filter = filter;
  impl_->ctx.makeCurrent();
  for (GLuint tex : impl_->textures) {
    glBindTexture(GL_TEXTURE_2D, tex);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, glMinFilter(filter));
  }
}

int Renderer::addTexture(const cv::Mat& image) {
  if (image.empty() || image.depth() != CV_8U || (image.channels() != 3 && image.channels() != 1))
    fail("Renderer::addTexture: need a non-empty 8-bit gray or BGR image");
  impl_->ctx.makeCurrent();
  cv::Mat rgba;
  cv::cvtColor(image, rgba, image.channels() == 3 ? cv::COLOR_BGR2RGBA : cv::COLOR_GRAY2RGBA);
  GLuint tex = 0;
  glGenTextures(1, &tex);
  glBindTexture(GL_TEXTURE_2D, tex);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, rgba.cols, rgba.rows, 0, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data);
  glGenerateMipmap(GL_TEXTURE_2D);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, glMinFilter(impl_->texture_filter));
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_REPEAT);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_REPEAT);
  impl_->textures.push_back(tex);
  return static_cast<int>(impl_->textures.size()) - 1;
}

int Renderer::addMesh(const Mesh& mesh) {
  if (mesh.texture >= static_cast<int>(impl_->textures.size()))
    fail("Renderer::addMesh: texture index {} out of range", mesh.texture);
  impl_->ctx.makeCurrent();
  Impl::GpuMesh g;
  g.texture = mesh.texture;
  if (!mesh.vertices.empty()) {
    g.lo = g.hi = Eigen::Vector3f(mesh.vertices[0].x, mesh.vertices[0].y, mesh.vertices[0].z);
    for (const Vertex& v : mesh.vertices) {
      const Eigen::Vector3f p(v.x, v.y, v.z);
      g.lo = g.lo.cwiseMin(p);
      g.hi = g.hi.cwiseMax(p);
    }
  }
  g.mode = mesh.primitive == Primitive::kTriangles ? GL_TRIANGLES
           : mesh.primitive == Primitive::kLines   ? GL_LINES
                                                   : GL_POINTS;
  glGenVertexArrays(1, &g.vao);
  glBindVertexArray(g.vao);
  glGenBuffers(1, &g.vbo);
  glBindBuffer(GL_ARRAY_BUFFER, g.vbo);
  glBufferData(GL_ARRAY_BUFFER, mesh.vertices.size() * sizeof(Vertex), mesh.vertices.data(), GL_STATIC_DRAW);
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, sizeof(Vertex), reinterpret_cast<void*>(offsetof(Vertex, x)));
  glEnableVertexAttribArray(1);
  glVertexAttribPointer(1, 2, GL_FLOAT, GL_FALSE, sizeof(Vertex), reinterpret_cast<void*>(offsetof(Vertex, u)));
  glEnableVertexAttribArray(2);
  glVertexAttribPointer(2, 3, GL_FLOAT, GL_FALSE, sizeof(Vertex), reinterpret_cast<void*>(offsetof(Vertex, r)));
  if (!mesh.indices.empty()) {
    glGenBuffers(1, &g.ebo);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, g.ebo);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, mesh.indices.size() * sizeof(uint32_t), mesh.indices.data(), GL_STATIC_DRAW);
    g.indexed = true;
    g.count = static_cast<GLsizei>(mesh.indices.size());
  } else {
    g.count = static_cast<GLsizei>(mesh.vertices.size());
  }
  glBindVertexArray(0);
  impl_->meshes.push_back(g);
  return static_cast<int>(impl_->meshes.size()) - 1;
}

void Renderer::clearMeshes() {
  impl_->ctx.makeCurrent();
  for (auto& m : impl_->meshes) Impl::release(m);
  impl_->meshes.clear();
}

size_t Renderer::meshCount() const { return impl_->meshes.size(); }

void Renderer::render(const Camera& camera, const SE3& T_world_cam, cv::Mat* bgr, cv::Mat* depth,
                      const RasterOptions& opts) {
  const int w = camera.width, h = camera.height;
  if (w <= 0 || h <= 0 || w > 8192 || h > 8192) fail("render size {}x{} outside 1..8192", w, h);
  Impl& I = *impl_;
  I.ctx.makeCurrent();
  I.ensureFramebuffer(w, h);
  glBindFramebuffer(GL_FRAMEBUFFER, I.fbo);
  glViewport(0, 0, w, h);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDisable(GL_CULL_FACE);
  glEnable(GL_PROGRAM_POINT_SIZE);
  glLineWidth(opts.line_width);
  const float bg[4] = {opts.background[2], opts.background[1], opts.background[0], 1.f};
  const float zero[4] = {0.f, 0.f, 0.f, 0.f};
  glClearBufferfv(GL_COLOR, 0, bg);
  glClearBufferfv(GL_COLOR, 1, zero);
  glClear(GL_DEPTH_BUFFER_BIT);

  const Eigen::Matrix4f P =
      glProjection(camera.fx, camera.fy, camera.cx, camera.cy, w, h, opts.near, opts.far).cast<float>();
  const Eigen::Matrix4f V = T_world_cam.inverse().matrix().cast<float>();
  glUseProgram(I.program);
  glUniformMatrix4fv(I.loc_proj, 1, GL_FALSE, P.data());
  glUniformMatrix4fv(I.loc_view, 1, GL_FALSE, V.data());
  glUniform1f(I.loc_point, opts.point_size);
  glUniform1i(I.loc_tex, 0);
  glActiveTexture(GL_TEXTURE0);
  // Near geometry first, what encloses the camera (a room's shell) last: llvmpipe tests depth before
  // shading, so fragments hidden behind what is already drawn cost no texturing. The key is the
  // distance to the bounding box's farthest corner. Only the cost changes (GL_LESS: ties aside, the
  // image does not depend on the order); on the room scene the change was within the noise.
  const Eigen::Vector3f centre = T_world_cam.translation().cast<float>();
  I.draw_order.clear();
  for (size_t i = 0; i < I.meshes.size(); ++i) {
    const auto& m = I.meshes[i];
    const Eigen::Vector3f far = (centre - m.lo).cwiseAbs().cwiseMax((centre - m.hi).cwiseAbs());
    I.draw_order.emplace_back(far.squaredNorm(), i);
  }
  std::sort(I.draw_order.begin(), I.draw_order.end());
  for (const auto& [key, index] : I.draw_order) {
    const auto& m = I.meshes[index];
    if (m.texture >= 0) {
      glBindTexture(GL_TEXTURE_2D, I.textures[m.texture]);
      glUniform1i(I.loc_textured, 1);
    } else {
      glUniform1i(I.loc_textured, 0);
    }
    glBindVertexArray(m.vao);
    if (m.indexed)
      glDrawElements(m.mode, m.count, GL_UNSIGNED_INT, nullptr);
    else
      glDrawArrays(m.mode, 0, m.count);
  }
  glBindVertexArray(0);

  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  if (bgr) {
    cv::Mat bgra(h, w, CV_8UC4);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    glReadPixels(0, 0, w, h, GL_BGRA, GL_UNSIGNED_BYTE, bgra.data);
    cv::cvtColor(bgra, *bgr, cv::COLOR_BGRA2BGR);
  }
  if (depth) {
    depth->create(h, w, CV_32F);
    glReadBuffer(GL_COLOR_ATTACHMENT1);
    glReadPixels(0, 0, w, h, GL_RED, GL_FLOAT, depth->data);
  }
  GLenum err = glGetError();
  if (err != GL_NO_ERROR) fail("OpenGL error 0x{:x} while rendering", err);
}

void Renderer::finish() {
  impl_->ctx.makeCurrent();
  glFinish();
}

}  // namespace nerfslam
