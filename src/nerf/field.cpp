// RadianceField: parameters, tiled forward/backward over the hash encoding and the two MLPs, and
// the deterministic sparse optimiser step. The kernels are in hash_grid.cpp, mlp.cpp, adam.cpp.
#include "nerfslam/nerf/field.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <thread>

#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/core/timing.h"
#include "nerfslam/nerf/hash_grid.h"
#include "nerfslam/nerf/mlp.h"
#include "nerfslam/nerf/sh.h"

namespace nerfslam::nerf {

namespace {

// Samples per tile: every layer of a tile runs before the next tile, so the tile's activations
// stay in L1/L2 between layers.
constexpr size_t kTile = 64;
constexpr int kColorIn = kShCoeffs + kDensityOutputs;  // 32
constexpr int kColorOutPadded = 16;

constexpr const char* kConfigSource = "field config";

}  // namespace

void validate(const FieldConfig& c) {
  validateOptions(c, kConfigSource);
  auto bad = [](const std::string& field, const std::string& what) { throw fieldError(kConfigSource, field, what); };
  if (c.n_levels % 8 != 0) bad("n_levels", "must be a multiple of 8");
  if (c.hidden % 16 != 0) bad("hidden", "must be a multiple of 16");
  if (c.finest_resolution < c.base_resolution) bad("finest_resolution", "must be >= base_resolution");
}

// ---------------------------------------------------------------------------------------------
// Parameter layout.

struct RadianceField::Impl {
  FieldConfig cfg;
  std::vector<GridLevel> levels;
  size_t n_entries = 0;  // hash entries over all levels
  int n_enc = 0;         // encoding width = 2 * n_levels
  int H = 0;

  // Hash grid: params, Adam moments and per-entry step counters.
  HugeVector<float> table, table_m, table_v;
  HugeVector<uint32_t> table_steps;
  // MLP weights, concatenated: d0 [n_enc][H], d1 [H][16], c0 [32][H], c1 [H][H], c2 [H][16].
  std::vector<float> mlp, mlp_m, mlp_v, mlp_grad_sum;
  size_t off_d0 = 0, off_d1 = 0, off_c0 = 0, off_c1 = 0, off_c2 = 0, n_mlp = 0;
  // Transposed copies [out][in] for the backward-data products.
  std::vector<float> mlp_t;
  // MLP step count as low/high 32-bit words (exposed to the model file as "adam.mlp_step").
  uint32_t mlp_step_words[2] = {0, 0};
  uint64_t mlpStep() const { return uint64_t(mlp_step_words[0]) | (uint64_t(mlp_step_words[1]) << 32); }
  void setMlpStep(uint64_t t) {
    mlp_step_words[0] = uint32_t(t & 0xffffffffu);
    mlp_step_words[1] = uint32_t(t >> 32);
  }
  AdamBiasTable bias;
  // Per optimiser worker: one level's gradient buffer and touched bitmap (grown to the largest level).
  struct LevelScratch {
    HugeVector<float> grad;
    std::vector<uint64_t> touched;
  };
  std::vector<LevelScratch> level_scratch;
  RadianceField::StepProfile profile;

  explicit Impl(const FieldConfig& c) : cfg(c), bias(c.adam) {}

  const float* W(size_t off) const { return mlp.data() + off; }
  const float* WT(size_t off) const { return mlp_t.data() + off; }

  HashGridView grid() const { return {levels.data(), int(levels.size()), table.data()}; }

  void refreshTransposed() {
    mlp_t.resize(n_mlp);
    auto tr = [&](size_t off, size_t in, size_t out) {
      for (size_t i = 0; i < in; ++i)
        for (size_t o = 0; o < out; ++o) mlp_t[off + o * in + i] = mlp[off + i * out + o];
    };
    tr(off_d0, size_t(n_enc), size_t(H));
    tr(off_d1, size_t(H), kDensityOutputs);
    tr(off_c0, kColorIn, size_t(H));
    tr(off_c1, size_t(H), size_t(H));
    tr(off_c2, size_t(H), kColorOutPadded);
  }
};

// What forward() keeps for backward(): the inputs and the hash encoding of every sample (the
// expensive, memory-bound part), the density network's outputs and the outputs. The other MLP
// activations are not stored: backward() recomputes them tile by tile for the samples it
// back-propagates (as instant-ngp's training recomputes its forward pass on the compacted samples),
// so they never leave L1/L2 and the workspace is ~230 bytes per sample instead of ~1 KiB.
struct RadianceField::Workspace::Impl {
  size_t n = 0;
  std::vector<float> pos /*[n][3]*/, dir /*[n][3]*/, enc /*[tile][n_enc][kTile]*/, rgb /*[n][3]*/, sigma /*[n]*/,
      logd /*[n]*/;
  // Per-tile scratch: activations of one tile (forward, and recomputed in backward), gradients.
  std::vector<float> h1, cin, c1, c2, logits, dlog, dc2, dc1, dd, dh1, denc, t_enc;
  std::vector<float> geo;  // [n][kDensityOutputs]: density-network outputs (forwardColor's input)
  // forwardColor: the samples it evaluates, and their inputs and colours compacted.
  std::vector<uint32_t> need;
  std::vector<float> need_geo, need_dir, need_rgb;
  std::vector<uint32_t> live;  // samples with a non-zero loss gradient
  // backward() with dL_dpos: one tile's level-weighted d_enc and position gradients.
  std::vector<float> pos_denc, pos_grad;
};

// The hash-grid part of the gradient is deferred: backward() records each sample's position and
// d loss / d encoding, and step() scatters them level by level (each level's gradient buffer stays
// in cache, levels run on different threads, and no thread keeps a dense copy of the whole table).
struct RadianceField::Gradients::Impl {
  std::vector<float> mlp;
  size_t n_entries = 0;  // of the field that made it (consistency check)
  // Recorded samples: pos [n][3], d_enc level-major per segment: segment k covers samples
  // [seg_begin[k], seg_begin[k+1]) and stores d_enc[l][s][2] at denc + seg_denc[k].
  size_t n = 0;
  std::vector<float> pos, denc;
  std::vector<size_t> seg_begin, seg_denc;
  // Materialised dense view for gradients() (tests, diagnostics); empty otherwise.
  HugeVector<float> dense;
  void clear() {
    n = 0;
    seg_begin.clear();
    seg_denc.clear();
  }
};

RadianceField::Workspace::Workspace() : impl_(std::make_unique<Impl>()) {}
RadianceField::Workspace::~Workspace() = default;
RadianceField::Workspace::Workspace(Workspace&&) noexcept = default;
RadianceField::Workspace& RadianceField::Workspace::operator=(Workspace&&) noexcept = default;
RadianceField::Gradients::Gradients() : impl_(std::make_unique<Impl>()) {}
RadianceField::Gradients::~Gradients() = default;
RadianceField::Gradients::Gradients(Gradients&&) noexcept = default;
RadianceField::Gradients& RadianceField::Gradients::operator=(Gradients&&) noexcept = default;

RadianceField::~RadianceField() = default;
RadianceField::RadianceField(RadianceField&&) noexcept = default;
RadianceField& RadianceField::operator=(RadianceField&&) noexcept = default;

RadianceField::RadianceField(const FieldConfig& config, uint64_t seed) {
  validate(config);
  impl_ = std::make_unique<Impl>(config);
  Impl& f = *impl_;
  f.levels = gridLevels(config.n_levels, config.base_resolution, config.finest_resolution, config.log2_hashmap_size);
  f.n_entries = f.levels.back().offset + size_t(f.levels.back().size);
  f.n_enc = 2 * config.n_levels;
  f.H = config.hidden;
  const size_t H = size_t(f.H);

  std::mt19937_64 rng(seed);
  // 24 random bits -> uniform in [-r, r] (explicit, so the stream is the same on every platform).
  auto uniform = [&](double r) {
    const double u = double(rng() >> 40) / double(1 << 24);
    return float((2.0 * u - 1.0) * r);
  };
  f.table.resize(2 * f.n_entries);
  for (float& x : f.table) x = uniform(config.hash_init_range);
  f.table_m.assign(f.table.size(), 0.f);
  f.table_v.assign(f.table.size(), 0.f);
  f.table_steps.assign(f.n_entries, 0u);

  f.off_d0 = 0;
  f.off_d1 = f.off_d0 + size_t(f.n_enc) * H;
  f.off_c0 = f.off_d1 + H * kDensityOutputs;
  f.off_c1 = f.off_c0 + size_t(kColorIn) * H;
  f.off_c2 = f.off_c1 + H * H;
  f.n_mlp = f.off_c2 + H * kColorOutPadded;
  f.mlp.assign(f.n_mlp, 0.f);
  // Xavier-uniform (tiny-cuda-nn's default): U(-s, s), s = sqrt(6 / (fan_in + fan_out)).
  auto init = [&](size_t off, size_t in, size_t out, size_t used_out) {
    const double s = std::sqrt(6.0 / double(in + used_out));
    for (size_t i = 0; i < in; ++i)
      for (size_t o = 0; o < used_out; ++o) f.mlp[off + i * out + o] = uniform(s);
  };
  init(f.off_d0, size_t(f.n_enc), H, H);
  init(f.off_d1, H, kDensityOutputs, kDensityOutputs);
  init(f.off_c0, kColorIn, H, H);
  init(f.off_c1, H, H, H);
  init(f.off_c2, H, kColorOutPadded, 3);
  f.mlp_m.assign(f.n_mlp, 0.f);
  f.mlp_v.assign(f.n_mlp, 0.f);
  f.mlp_grad_sum.assign(f.n_mlp, 0.f);
  f.refreshTransposed();
}

const FieldConfig& RadianceField::config() const { return impl_->cfg; }
uint64_t RadianceField::stepCount() const { return impl_->mlpStep(); }
const RadianceField::StepProfile& RadianceField::lastStepProfile() const { return impl_->profile; }
size_t RadianceField::numParameters() const { return impl_->table.size() + impl_->n_mlp; }

// ---------------------------------------------------------------------------------------------
// Layer helpers over one tile of m samples.

namespace {

GemmArgs mm(size_t M, size_t N, size_t K, const float* a, size_t a_ms, size_t a_ks, const float* b, size_t ldb,
            float* c, size_t ldc, Epilogue e = Epilogue::kNone, const float* mask = nullptr, size_t ldm = 0,
            bool accumulate = false) {
  GemmArgs g;
  g.M = M;
  g.N = N;
  g.K = K;
  g.a = a;
  g.a_ms = a_ms;
  g.a_ks = a_ks;
  g.b = b;
  g.ldb = ldb;
  g.c = c;
  g.ldc = ldc;
  g.epilogue = e;
  g.mask = mask;
  g.ldm = ldm;
  g.accumulate = accumulate;
  return g;
}

// Grows a buffer to at least `size`, keeping its contents (never shrinks: buffers are reused across
// calls). Capacity grows to size + 1/8, not to std::vector's 2x: the sample count of a training step
// varies a little from step to step, and doubling a buffer of 2^17 samples x 32 floats on the first
// step that is one sample larger than the last would hold ~100 MB that is never used.
template <class T>
inline void growTo(std::vector<T>& v, size_t size) {
  if (v.size() >= size) return;
  if (v.capacity() < size) v.reserve(size + size / 8);
  v.resize(size);
}

inline float sigmoid(float x) { return 1.f / (1.f + std::exp(-x)); }

}  // namespace

// Density network on a tile: encT [n_enc][kTile] -> h1 [m][H] (ReLU) -> d [m][ldd].
static void densityTile(const RadianceField::Impl& f, size_t m, const float* encT, float* h1, float* d, size_t ldd) {
  const size_t H = size_t(f.H);
  gemm(mm(m, H, size_t(f.n_enc), encT, 1, kTile, f.W(f.off_d0), H, h1, H, Epilogue::kRelu));
  gemm(mm(m, kDensityOutputs, H, h1, H, 1, f.W(f.off_d1), kDensityOutputs, d, ldd));
}

// Colour network on a tile: cin [m][32] -> c1, c2 [m][H] -> logits [m][16].
static void colorTile(const RadianceField::Impl& f, size_t m, const float* cin, float* c1, float* c2, float* logits) {
  const size_t H = size_t(f.H);
  gemm(mm(m, H, kColorIn, cin, kColorIn, 1, f.W(f.off_c0), H, c1, H, Epilogue::kRelu));
  gemm(mm(m, H, H, c1, H, 1, f.W(f.off_c1), H, c2, H, Epilogue::kRelu));
  gemm(mm(m, kColorOutPadded, H, c2, H, 1, f.W(f.off_c2), kColorOutPadded, logits, kColorOutPadded));
}

// ---------------------------------------------------------------------------------------------
// Inference.

// dL/dpos of a backward tile's samples (positions pos, m*3; d_enc sample-major [m][E]), levels
// weighted, written to dL_dpos[3 * idx[i]]; scratch from the workspace.
static void positionGradientTile(const RadianceField::Impl& f, RadianceField::Workspace::Impl& ws, size_t m,
                                 const float* pos, const float* d_enc, const float* level_weights, const uint32_t* idx,
                                 float* dL_dpos) {
  const size_t E = size_t(f.n_enc);
  if (level_weights) {
    ws.pos_denc.assign(d_enc, d_enc + m * E);
    for (size_t i = 0; i < m; ++i)
      for (size_t k = 0; k < E; ++k) ws.pos_denc[i * E + k] *= level_weights[k / 2];
    d_enc = ws.pos_denc.data();
  }
  ws.pos_grad.resize(3 * m);
  hashEncodePositionGradient(f.grid(), pos, m, d_enc, ws.pos_grad.data());
  for (size_t i = 0; i < m; ++i)
    for (size_t d = 0; d < 3; ++d) dL_dpos[3 * size_t(idx[i]) + d] = ws.pos_grad[3 * i + d];
}

void RadianceField::queryDensity(const float* pos, size_t n, float* sigma) const {
  const Impl& f = *impl_;
  const size_t H = size_t(f.H);
  std::vector<float> encT(size_t(f.n_enc) * kTile), h1(kTile * H), d(kTile * kDensityOutputs);
  const float clampv = float(f.cfg.max_log_density);
  for (size_t s0 = 0; s0 < n; s0 += kTile) {
    const size_t m = std::min(kTile, n - s0);
    hashEncode(f.grid(), pos + 3 * s0, m, encT.data(), kTile);
    densityTile(f, m, encT.data(), h1.data(), d.data(), kDensityOutputs);
    for (size_t i = 0; i < m; ++i) sigma[s0 + i] = std::exp(std::min(d[i * kDensityOutputs], clampv));
  }
}

void RadianceField::query(const float* pos, const float* dir, size_t n, float* sigma, float* rgb) const {
  const Impl& f = *impl_;
  const size_t H = size_t(f.H);
  std::vector<float> encT(size_t(f.n_enc) * kTile), h1(kTile * H), cin(kTile * kColorIn), c1(kTile * H), c2(kTile * H),
      logits(kTile * kColorOutPadded);
  const float clampv = float(f.cfg.max_log_density);
  for (size_t s0 = 0; s0 < n; s0 += kTile) {
    const size_t m = std::min(kTile, n - s0);
    hashEncode(f.grid(), pos + 3 * s0, m, encT.data(), kTile);
    densityTile(f, m, encT.data(), h1.data(), cin.data() + kShCoeffs, kColorIn);
    shEncodeBatch(dir + 3 * s0, m, cin.data(), kColorIn);
    colorTile(f, m, cin.data(), c1.data(), c2.data(), logits.data());
    for (size_t i = 0; i < m; ++i) {
      if (sigma) sigma[s0 + i] = std::exp(std::min(cin[i * kColorIn + kShCoeffs], clampv));
      if (rgb)
        for (int k = 0; k < 3; ++k) rgb[3 * (s0 + i) + size_t(k)] = sigmoid(logits[i * kColorOutPadded + size_t(k)]);
    }
  }
}

void RadianceField::queryDensityOutputs(const float* pos, size_t n, float* sigma, float* geo) const {
  const Impl& f = *impl_;
  const size_t H = size_t(f.H);
  thread_local std::vector<float> encT, h1;
  if (encT.size() < size_t(f.n_enc) * kTile) encT.resize(size_t(f.n_enc) * kTile);
  if (h1.size() < kTile * H) h1.resize(kTile * H);
  const float clampv = float(f.cfg.max_log_density);
  for (size_t s0 = 0; s0 < n; s0 += kTile) {
    const size_t m = std::min(kTile, n - s0);
    hashEncode(f.grid(), pos + 3 * s0, m, encT.data(), kTile);
    float* d = geo + s0 * kDensityOutputs;
    densityTile(f, m, encT.data(), h1.data(), d, kDensityOutputs);
    if (sigma)
      for (size_t i = 0; i < m; ++i) sigma[s0 + i] = std::exp(std::min(d[i * kDensityOutputs], clampv));
  }
}

void RadianceField::queryColor(const float* geo, const float* dir, size_t n, float* rgb) const {
  const Impl& f = *impl_;
  const size_t H = size_t(f.H);
  thread_local std::vector<float> cin, c1, c2, logits;
  if (cin.size() < kTile * kColorIn) cin.resize(kTile * kColorIn);
  if (c1.size() < kTile * H) c1.resize(kTile * H);
  if (c2.size() < kTile * H) c2.resize(kTile * H);
  if (logits.size() < kTile * kColorOutPadded) logits.resize(kTile * kColorOutPadded);
  for (size_t s0 = 0; s0 < n; s0 += kTile) {
    const size_t m = std::min(kTile, n - s0);
    for (size_t i = 0; i < m; ++i)
      std::copy(geo + (s0 + i) * kDensityOutputs, geo + (s0 + i + 1) * kDensityOutputs,
                cin.data() + i * kColorIn + kShCoeffs);
    shEncodeBatch(dir + 3 * s0, m, cin.data(), kColorIn);
    colorTile(f, m, cin.data(), c1.data(), c2.data(), logits.data());
    for (size_t i = 0; i < m; ++i)
      for (int k = 0; k < 3; ++k) rgb[3 * (s0 + i) + size_t(k)] = sigmoid(logits[i * kColorOutPadded + size_t(k)]);
  }
}

void RadianceField::densityGradient(const float* pos, size_t n, float* grad) const {
  const Impl& f = *impl_;
  const size_t H = size_t(f.H), E = size_t(f.n_enc);
  std::vector<float> encT(E * kTile), h1(kTile * H), d(kTile * kDensityOutputs), dd(kTile * kDensityOutputs),
      dh1(kTile * H), denc(kTile * E);
  const float clampv = float(f.cfg.max_log_density);
  for (size_t s0 = 0; s0 < n; s0 += kTile) {
    const size_t m = std::min(kTile, n - s0);
    hashEncode(f.grid(), pos + 3 * s0, m, encT.data(), kTile);
    densityTile(f, m, encT.data(), h1.data(), d.data(), kDensityOutputs);
    std::fill(dd.begin(), dd.end(), 0.f);
    // trunc_exp: d sigma / d log-density = exp(min(x, clamp)) = sigma.
    for (size_t i = 0; i < m; ++i) dd[i * kDensityOutputs] = std::exp(std::min(d[i * kDensityOutputs], clampv));
    gemm(mm(m, H, kDensityOutputs, dd.data(), kDensityOutputs, 1, f.WT(f.off_d1), H, dh1.data(), H, Epilogue::kReluMask,
            h1.data(), H));
    gemm(mm(m, E, H, dh1.data(), H, 1, f.WT(f.off_d0), E, denc.data(), E));
    hashEncodePositionGradient(f.grid(), pos + 3 * s0, m, denc.data(), grad + 3 * s0);
  }
}

// ---------------------------------------------------------------------------------------------
// Training.

RadianceField::Workspace RadianceField::makeWorkspace() const { return Workspace(); }

RadianceField::Gradients RadianceField::makeGradients() const {
  Gradients g;
  g.impl_->mlp.assign(impl_->n_mlp, 0.f);
  g.impl_->n_entries = impl_->n_entries;
  return g;
}

void RadianceField::forward(Workspace& wsp, const float* pos, const float* dir, size_t n, float* sigma,
                            float* rgb) const {
  forwardDensity(wsp, pos, dir, n, sigma);
  forwardColor(wsp, nullptr, rgb);
}

void RadianceField::forwardDensity(Workspace& wsp, const float* pos, const float* dir, size_t n, float* sigma) const {
  const Impl& f = *impl_;
  Workspace::Impl& ws = *wsp.impl_;
  const size_t H = size_t(f.H), E = size_t(f.n_enc);
  const size_t n_tiles = (n + kTile - 1) / kTile;
  ws.n = n;
  ws.pos.assign(pos, pos + 3 * n);
  ws.dir.assign(dir, dir + 3 * n);
  growTo(ws.enc, n_tiles * E * kTile);
  growTo(ws.geo, n * kDensityOutputs);
  growTo(ws.rgb, n * 3);
  growTo(ws.sigma, n);
  growTo(ws.logd, n);
  growTo(ws.h1, kTile * H);
  const float clampv = float(f.cfg.max_log_density);
  for (size_t t = 0; t < n_tiles; ++t) {
    const size_t s0 = t * kTile, m = std::min(kTile, n - s0);
    float* encT = ws.enc.data() + t * E * kTile;
    hashEncode(f.grid(), pos + 3 * s0, m, encT, kTile);
    float* geo = ws.geo.data() + s0 * kDensityOutputs;
    densityTile(f, m, encT, ws.h1.data(), geo, kDensityOutputs);
    for (size_t i = 0; i < m; ++i) {
      const float ld = geo[i * kDensityOutputs];
      ws.logd[s0 + i] = ld;
      ws.sigma[s0 + i] = std::exp(std::min(ld, clampv));
    }
  }
  if (sigma) std::copy(ws.sigma.begin(), ws.sigma.begin() + long(n), sigma);
}

void RadianceField::forwardColor(Workspace& wsp, const uint8_t* needed, float* rgb) const {
  Workspace::Impl& ws = *wsp.impl_;
  const size_t n = ws.n;
  if (!needed) {
    queryColor(ws.geo.data(), ws.dir.data(), n, ws.rgb.data());
  } else {
    // The needed samples, compacted in order (queryColor's rows are independent, so compacting them
    // does not change a sample's bits); the others get rgb 0.
    std::vector<uint32_t>& idx = ws.need;
    idx.clear();
    for (size_t i = 0; i < n; ++i)
      if (needed[i]) idx.push_back(uint32_t(i));
    const size_t m = idx.size();
    growTo(ws.need_geo, m * kDensityOutputs);
    growTo(ws.need_dir, 3 * m);
    growTo(ws.need_rgb, 3 * m);
    for (size_t j = 0; j < m; ++j) {
      const size_t s = idx[j];
      std::copy_n(ws.geo.begin() + long(s * kDensityOutputs), kDensityOutputs,
                  ws.need_geo.begin() + long(j * kDensityOutputs));
      std::copy_n(ws.dir.begin() + long(3 * s), 3, ws.need_dir.begin() + long(3 * j));
    }
    queryColor(ws.need_geo.data(), ws.need_dir.data(), m, ws.need_rgb.data());
    std::fill(ws.rgb.begin(), ws.rgb.begin() + long(3 * n), 0.f);
    for (size_t j = 0; j < m; ++j) std::copy_n(ws.need_rgb.begin() + long(3 * j), 3, ws.rgb.begin() + long(3 * idx[j]));
  }
  if (rgb) std::copy(ws.rgb.begin(), ws.rgb.begin() + long(3 * n), rgb);
}

void RadianceField::backward(Workspace& wsp, const float* dL_dsigma, const float* dL_drgb, Gradients& grads,
                             float* dL_dpos, const float* level_weights) const {
  const Impl& f = *impl_;
  Workspace::Impl& ws = *wsp.impl_;
  Gradients::Impl& g = *grads.impl_;
  if (g.n_entries != f.n_entries || g.mlp.size() != f.n_mlp)
    fail("RadianceField::backward: gradients were not made by this field");
  const size_t n = ws.n, H = size_t(f.H), E = size_t(f.n_enc);
  // Compaction: samples whose loss gradient is exactly zero (in training, every sample past a ray's
  // early termination, often half of them) contribute nothing; back-propagate the others only, in
  // order, in tiles of kTile.
  std::vector<uint32_t>& live = ws.live;
  live.clear();
  for (size_t i = 0; i < n; ++i) {
    bool nz = dL_dsigma && dL_dsigma[i] != 0.f;
    if (dL_drgb) nz |= dL_drgb[3 * i] != 0.f || dL_drgb[3 * i + 1] != 0.f || dL_drgb[3 * i + 2] != 0.f;
    if (nz) live.push_back(uint32_t(i));
  }
  const size_t nl = live.size();
  if (dL_dpos) std::fill(dL_dpos, dL_dpos + 3 * n, 0.f);
  // Record the live samples as one segment of the deferred hash-grid gradient.
  const size_t seg0 = g.n, denc0 = g.seg_denc.empty() ? 0 : g.seg_denc.back() + E * (g.n - g.seg_begin.back());
  g.seg_begin.push_back(seg0);
  g.seg_denc.push_back(denc0);
  g.n += nl;
  growTo(g.pos, 3 * g.n);
  growTo(g.denc, denc0 + E * nl);
  for (size_t j = 0; j < nl; ++j)
    std::copy(ws.pos.begin() + long(3 * live[j]), ws.pos.begin() + long(3 * live[j] + 3),
              g.pos.begin() + long(3 * (seg0 + j)));
  float* seg_denc = g.denc.data() + denc0;  // [l][s][2], s < nl
  const size_t n_tiles = (nl + kTile - 1) / kTile;
  // Per-tile scratch, in floats per tile.
  using Scratch = std::pair<std::vector<float>*, size_t>;
  const size_t out = kColorOutPadded, dens = kDensityOutputs, cin_w = kColorIn;
  for (const auto& [buf, per_sample] :
       {Scratch{&ws.dlog, out}, Scratch{&ws.dc2, H}, Scratch{&ws.dc1, H}, Scratch{&ws.dd, dens}, Scratch{&ws.dh1, H},
        Scratch{&ws.denc, E}, Scratch{&ws.t_enc, E}, Scratch{&ws.h1, H}, Scratch{&ws.cin, cin_w}, Scratch{&ws.c1, H},
        Scratch{&ws.c2, H}, Scratch{&ws.logits, out}})
    growTo(*buf, kTile * per_sample);
  std::vector<float> tdir(3 * kTile);
  float* gw = g.mlp.data();
  for (size_t t = 0; t < n_tiles; ++t) {
    const size_t j0 = t * kTile, m = std::min(kTile, nl - j0);
    const uint32_t* idx = live.data() + j0;
    // Gather the tile's encodings (a forward tile holds them feature-major [E][kTile]) and
    // directions, and recompute its activations (bit-identical to forward(): the GEMM's result
    // for a row does not depend on the other rows of the tile).
    float* encT = ws.t_enc.data();
    for (size_t i = 0; i < m; ++i) {
      const size_t s = idx[i], ft = s / kTile, fi = s % kTile;
      const float* src = ws.enc.data() + ft * E * kTile + fi;
      for (size_t k = 0; k < E; ++k) encT[k * kTile + i] = src[k * kTile];
      for (size_t k = 0; k < 3; ++k) tdir[3 * i + k] = ws.dir[3 * s + k];
    }
    float* cin = ws.cin.data();
    densityTile(f, m, encT, ws.h1.data(), cin + kShCoeffs, kColorIn);
    shEncodeBatch(tdir.data(), m, cin, kColorIn);
    colorTile(f, m, cin, ws.c1.data(), ws.c2.data(), ws.logits.data());
    const float* h1 = ws.h1.data();
    const float* c1 = ws.c1.data();
    const float* c2 = ws.c2.data();
    // Output activations.
    float* dlog = ws.dlog.data();
    std::fill(dlog, dlog + m * kColorOutPadded, 0.f);
    bool any_rgb = false;
    if (dL_drgb) {
      for (size_t i = 0; i < m; ++i)
        for (size_t k = 0; k < 3; ++k) {
          const float y = ws.rgb[3 * idx[i] + k];
          const float d = dL_drgb[3 * idx[i] + k] * y * (1.f - y);
          dlog[i * kColorOutPadded + k] = d;
          any_rgb |= d != 0.f;
        }
    }
    float* dd = ws.dd.data();
    if (any_rgb) {
      // Colour network.
      gemm(mm(H, kColorOutPadded, m, c2, 1, H, dlog, kColorOutPadded, gw + f.off_c2, kColorOutPadded, Epilogue::kNone,
              nullptr, 0, true));
      gemm(mm(m, H, kColorOutPadded, dlog, kColorOutPadded, 1, f.WT(f.off_c2), H, ws.dc2.data(), H, Epilogue::kReluMask,
              c2, H));
      gemm(mm(H, H, m, c1, 1, H, ws.dc2.data(), H, gw + f.off_c1, H, Epilogue::kNone, nullptr, 0, true));
      gemm(mm(m, H, H, ws.dc2.data(), H, 1, f.WT(f.off_c1), H, ws.dc1.data(), H, Epilogue::kReluMask, c1, H));
      gemm(mm(kColorIn, H, m, cin, 1, kColorIn, ws.dc1.data(), H, gw + f.off_c0, H, Epilogue::kNone, nullptr, 0, true));
      // Only the density-output half of the colour input needs a gradient.
      gemm(mm(m, kDensityOutputs, H, ws.dc1.data(), H, 1, f.WT(f.off_c0) + kShCoeffs, kColorIn, dd, kDensityOutputs));
    } else {
      std::fill(dd, dd + m * kDensityOutputs, 0.f);
    }
    if (dL_dsigma) {
      for (size_t i = 0; i < m; ++i) dd[i * kDensityOutputs] += dL_dsigma[idx[i]] * ws.sigma[idx[i]];  // trunc_exp
    }
    // Density network.
    gemm(mm(H, kDensityOutputs, m, h1, 1, H, dd, kDensityOutputs, gw + f.off_d1, kDensityOutputs, Epilogue::kNone,
            nullptr, 0, true));
    gemm(mm(m, H, kDensityOutputs, dd, kDensityOutputs, 1, f.WT(f.off_d1), H, ws.dh1.data(), H, Epilogue::kReluMask, h1,
            H));
    gemm(mm(E, H, m, encT, kTile, 1, ws.dh1.data(), H, gw + f.off_d0, H, Epilogue::kNone, nullptr, 0, true));
    gemm(mm(m, E, H, ws.dh1.data(), H, 1, f.WT(f.off_d0), E, ws.denc.data(), E));
    if (dL_dpos)
      positionGradientTile(f, ws, m, g.pos.data() + 3 * (seg0 + j0), ws.denc.data(), level_weights, idx, dL_dpos);
    // Keep d_enc level-major for the optimiser's per-level scatter.
    for (size_t l = 0; l < E / 2; ++l) {
      float* dst = seg_denc + l * 2 * nl + 2 * j0;
      const float* src = ws.denc.data() + 2 * l;
      for (size_t i = 0; i < m; ++i) {
        dst[2 * i] = src[i * E];
        dst[2 * i + 1] = src[i * E + 1];
      }
    }
  }
}

// Scatters the recorded samples of `grads` (in order) into one level's gradient buffer.
static void scatterLevel(const RadianceField::Impl& f, const RadianceField::Gradients::Impl& g, int level,
                         float* grad_level, uint64_t* touched_level) {
  const size_t E = size_t(f.n_enc);
  for (size_t k = 0; k < g.seg_begin.size(); ++k) {
    const size_t b = g.seg_begin[k], e = k + 1 < g.seg_begin.size() ? g.seg_begin[k + 1] : g.n;
    if (e <= b) continue;
    (void)E;
    hashEncodeBackwardLevel(f.grid(), level, g.pos.data() + 3 * b, e - b,
                            g.denc.data() + g.seg_denc[k] + size_t(level) * 2 * (e - b), grad_level, touched_level);
  }
}

// ---------------------------------------------------------------------------------------------
// Optimiser.

void RadianceField::clearGradients(Gradients& grads) const {
  Gradients::Impl& g = *grads.impl_;
  g.clear();
  std::fill(g.mlp.begin(), g.mlp.end(), 0.f);
}

void RadianceField::step(const std::vector<Gradients*>& per_thread, float lr, int n_threads, float grad_scale) {
  Impl& f = *impl_;
  for (const Gradients* g : per_thread)
    if (!g || g->impl_->n_entries != f.n_entries || g->impl_->mlp.size() != f.n_mlp)
      fail("RadianceField::step: gradients were not made by this field");
  const double cpu_mlp0 = threadCpuMs();
  // MLP: sum in thread order, dense Adam with L2.
  std::fill(f.mlp_grad_sum.begin(), f.mlp_grad_sum.end(), 0.f);
  for (Gradients* g : per_thread) {
    float* src = g->impl_->mlp.data();
    for (size_t i = 0; i < f.n_mlp; ++i) f.mlp_grad_sum[i] += src[i];
    std::fill(src, src + f.n_mlp, 0.f);
  }
  for (float& x : f.mlp_grad_sum) x *= grad_scale;
  const uint64_t t_mlp = f.mlpStep() + 1;
  f.setMlpStep(t_mlp);
  adamDense(f.mlp.data(), f.mlp_m.data(), f.mlp_v.data(), f.mlp_grad_sum.data(), f.n_mlp, t_mlp, lr, f.cfg.adam,
            float(f.cfg.adam.mlp_l2));
  f.refreshTransposed();
  f.profile = StepProfile{};
  f.profile.mlp_seconds = 1e-3 * (threadCpuMs() - cpu_mlp0);

  // Hash grid, level by level: scatter every recorded sample (threads in the given order, samples
  // in order) into the level's buffer, then apply the sparse Adam rule to the entries touched.
  // Levels are independent, so the split of levels over workers does not change the result.
  size_t recorded = 0;
  for (const Gradients* g : per_thread) recorded += g->impl_->n;
  const int L = int(f.levels.size());
  const int workers = recorded == 0 ? 1 : std::clamp(n_threads, 1, L);
  uint32_t max_level = 0;
  for (const GridLevel& lv : f.levels) max_level = std::max(max_level, lv.size);
  if (f.level_scratch.size() < size_t(workers)) f.level_scratch.resize(size_t(workers));
  std::vector<double> scatter_ms(size_t(workers), 0.0), adam_ms(size_t(workers), 0.0);
  std::vector<size_t> updated(size_t(workers), 0);
  auto work = [&](int w) {
    Impl::LevelScratch& sc = f.level_scratch[size_t(w)];
    if (sc.grad.size() < 2 * size_t(max_level)) sc.grad.assign(2 * size_t(max_level), 0.f);
    if (sc.touched.size() < (size_t(max_level) + 63) / 64) sc.touched.assign((size_t(max_level) + 63) / 64, 0u);
    // Level l goes to worker l % workers: the levels cost about the same (8 corners per sample).
    for (int l = w; l < L && recorded > 0; l += workers) {
      const GridLevel& lv = f.levels[size_t(l)];
      const double c0 = threadCpuMs();
      for (const Gradients* g : per_thread) scatterLevel(f, *g->impl_, l, sc.grad.data(), sc.touched.data());
      const double c1 = threadCpuMs();
      updated[size_t(w)] +=
          adamSparseLevel(f.table.data() + 2 * size_t(lv.offset), f.table_m.data() + 2 * size_t(lv.offset),
                          f.table_v.data() + 2 * size_t(lv.offset), sc.grad.data(), sc.touched.data(),
                          f.table_steps.data() + lv.offset, lv.size, lr, f.cfg.adam, f.bias, grad_scale);
      scatter_ms[size_t(w)] += c1 - c0;
      adam_ms[size_t(w)] += threadCpuMs() - c1;
    }
  };
  if (workers == 1) {
    work(0);
  } else {
    std::vector<std::thread> pool;
    for (int i = 1; i < workers; ++i) pool.emplace_back(work, i);
    work(0);
    for (auto& th : pool) th.join();
  }
  for (int w = 0; w < workers; ++w) {
    f.profile.scatter_seconds += 1e-3 * scatter_ms[size_t(w)];
    f.profile.adam_seconds += 1e-3 * adam_ms[size_t(w)];
    f.profile.entries_updated += updated[size_t(w)];
  }
  for (Gradients* g : per_thread) {
    g->impl_->clear();
    g->impl_->dense = HugeVector<float>();
  }
}

// ---------------------------------------------------------------------------------------------
// Parameter access.

std::vector<FloatArray> RadianceField::parameters() {
  Impl& f = *impl_;
  const size_t H = size_t(f.H);
  return {{"hash_grid", f.table.data(), f.table.size()},
          {"density.w0", f.mlp.data() + f.off_d0, size_t(f.n_enc) * H},
          {"density.w1", f.mlp.data() + f.off_d1, H * kDensityOutputs},
          {"color.w0", f.mlp.data() + f.off_c0, size_t(kColorIn) * H},
          {"color.w1", f.mlp.data() + f.off_c1, H * H},
          {"color.w2", f.mlp.data() + f.off_c2, H * kColorOutPadded}};
}

std::vector<FloatArray> RadianceField::gradients(Gradients& grads) const {
  const Impl& f = *impl_;
  Gradients::Impl& g = *grads.impl_;
  const size_t H = size_t(f.H);
  float* w = g.mlp.data();
  // Materialise the deferred hash-grid gradient (the sum step() would apply).
  g.dense.assign(f.table.size(), 0.f);
  std::vector<uint64_t> touched;
  for (int l = 0; l < int(f.levels.size()); ++l) {
    const GridLevel& lv = f.levels[size_t(l)];
    touched.assign((size_t(lv.size) + 63) / 64, 0u);
    scatterLevel(f, g, l, g.dense.data() + 2 * size_t(lv.offset), touched.data());
  }
  return {{"hash_grid", g.dense.data(), g.dense.size()},
          {"density.w0", w + f.off_d0, size_t(f.n_enc) * H},
          {"density.w1", w + f.off_d1, H * kDensityOutputs},
          {"color.w0", w + f.off_c0, size_t(kColorIn) * H},
          {"color.w1", w + f.off_c1, H * H},
          {"color.w2", w + f.off_c2, H * kColorOutPadded}};
}

std::vector<FloatArray> RadianceField::optimizerMoments() {
  Impl& f = *impl_;
  std::vector<FloatArray> out;
  const std::vector<FloatArray> params = parameters();
  for (const char* which : {"m", "v"}) {
    const bool is_m = which[0] == 'm';
    for (const FloatArray& p : params) {
      float* base;
      if (p.name == "hash_grid") {
        base = (is_m ? f.table_m : f.table_v).data();
      } else {
        base = (is_m ? f.mlp_m : f.mlp_v).data() + (p.data - f.mlp.data());
      }
      out.push_back({std::string("adam.") + which + "." + p.name, base, p.size});
    }
  }
  return out;
}

std::vector<U32Array> RadianceField::optimizerCounters() {
  Impl& f = *impl_;
  return {{"adam.hash_steps", f.table_steps.data(), f.table_steps.size()}, {"adam.mlp_step", f.mlp_step_words, 2}};
}

void RadianceField::parametersChanged() {
  Impl& f = *impl_;
  f.refreshTransposed();
}

}  // namespace nerfslam::nerf
