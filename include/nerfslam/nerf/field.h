#pragma once
// The NeRF radiance field (Müller et al. 2022, instant-ngp) on the CPU: a multiresolution hash
// encoding of the position, a density MLP, a degree-4 spherical-harmonics encoding of the view
// direction and a colour MLP, with fused SIMD kernels (Highway runtime dispatch) and a sparse Adam
// optimiser. See hash_grid.h, mlp.h, sh.h and adam.h for the pieces.
//
// Network (tiny-cuda-nn conventions: no biases, outputs padded to 16):
//   enc   = hash_grid(pos)                        n_levels * 2 features
//   d     = W_d1 (relu(W_d0 enc))                 16 outputs; d[0] is the log-density
//   sigma = exp(min(d[0], max_log_density))       (trunc_exp: the backward pass uses the same
//                                                 clamped exponential as the derivative, so a
//                                                 sample above the clamp still gets pulled down)
//   rgb   = sigmoid(W_c2 relu(W_c1 relu(W_c0 [sh4(dir), d])))
//
// Threading: every const method is safe to call concurrently. Training splits the samples of a
// step over threads; each thread owns one Workspace and one Gradients, calls forward() then
// backward() any number of times, and one thread then calls step() with all the Gradients in a
// fixed order. The result is bit-identical for the same seed, the same split and the same order.
//
// Cost: the hash-table gathers and scatters of the fine levels dominate a training step (the MLPs
// run close to the FMA peak); larger steps amortise step(), which visits every touched entry
// (bench_nerf_field measures it).
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "nerfslam/core/options.h"
#include "nerfslam/nerf/adam.h"

namespace nerfslam::nerf {

// Features stored per hash-table entry (F in the paper). Fixed: F=2 is instant-ngp's choice and
// lets one entry be one 8-byte load.
constexpr int kFeaturesPerLevel = 2;
// Width of the density MLP's output (log-density + 15 geometry features) and of the SH encoding.
constexpr int kDensityOutputs = 16;
constexpr int kShCoeffs = 16;

struct FieldConfig {
  int n_levels = 16;
  int log2_hashmap_size = 19;
  int base_resolution = 16;
  // Finest grid resolution, already multiplied by the scene's aabb_scale (2048 * aabb_scale).
  double finest_resolution = 2048.0;
  // Width of the hidden layers of both MLPs (paper: 64).
  int hidden = 64;
  // sigma = exp(min(log_density, max_log_density)); exp(15) = 3.3e6 keeps every later
  // 1 - exp(-sigma * dt) finite in fp32.
  double max_log_density = 15.0;
  // Half-width of the uniform initialisation of the hash-table features (paper: 1e-4).
  double hash_init_range = 1e-4;
  AdamOptions adam;

  template <class V>
  void visit(V& v) {
    v("n_levels", n_levels, "Hash-grid levels L (a multiple of 8: the encoding is L*2 wide)", check::range(8, 32));
    v("log2_hashmap_size", log2_hashmap_size, "log2 of the entries per hash-grid level T", check::range(14, 22));
    v("base_resolution", base_resolution, "Coarsest grid resolution N_min", check::range(2, 1024));
    v("finest_resolution", finest_resolution, "Finest grid resolution N_max (2048 * aabb_scale in instant-ngp)",
      check::range(2.0, 1e6));
    v("hidden", hidden, "Hidden-layer width of the density and colour MLPs (a multiple of 16)", check::range(16, 128));
    v("max_log_density", max_log_density, "Clamp of the log-density before exp()", check::range(1.0, 30.0));
    v("hash_init_range", hash_init_range, "Hash features start uniform in [-r, r]", check::range(0.0, 1.0));
    v("adam", adam, "Adam optimiser");
  }
};

// Throws nerfslam::Error naming the field when the config is invalid (including the "multiple of"
// constraints visit() cannot express).
void validate(const FieldConfig& config);

// A named parameter array, for the model file and for tests.
struct FloatArray {
  std::string name;
  float* data = nullptr;
  size_t size = 0;
};
struct U32Array {
  std::string name;
  uint32_t* data = nullptr;
  size_t size = 0;
};

class RadianceField {
 public:
  // Per-thread training scratch: what forward() keeps for backward(). Reused across calls
  // (grows to the largest batch seen).
  class Workspace {
   public:
    Workspace();
    ~Workspace();
    Workspace(Workspace&&) noexcept;
    Workspace& operator=(Workspace&&) noexcept;
    struct Impl;

   private:
    friend class RadianceField;
    std::unique_ptr<Impl> impl_;
  };
  // Per-thread gradient accumulator: dense MLP gradients, a dense hash-grid gradient buffer and a
  // bitmap of the hash entries touched since the last step(). step() consumes and clears it.
  class Gradients {
   public:
    Gradients();
    ~Gradients();
    Gradients(Gradients&&) noexcept;
    Gradients& operator=(Gradients&&) noexcept;
    struct Impl;

   private:
    friend class RadianceField;
    std::unique_ptr<Impl> impl_;
  };

  // Throws nerfslam::Error on an invalid config. Deterministic in the seed.
  RadianceField(const FieldConfig& config, uint64_t seed);
  ~RadianceField();
  RadianceField(RadianceField&&) noexcept;
  RadianceField& operator=(RadianceField&&) noexcept;

  const FieldConfig& config() const;

  // ---- Inference (thread-safe). pos: n*3 in [0,1]^3 (clamped); dir: n*3 unit vectors.
  void queryDensity(const float* pos, size_t n, float* sigma) const;
  void query(const float* pos, const float* dir, size_t n, float* sigma, float* rgb) const;
  // Two-stage inference (the renderer evaluates colour only where a sample is visible):
  // queryDensityOutputs gives sigma (n) and the density network's kDensityOutputs outputs per
  // sample (geo[i * kDensityOutputs + k]; k = 0 is the log-density); queryColor gives rgb (n*3)
  // from those outputs and unit directions. Together they equal query() bit for bit.
  void queryDensityOutputs(const float* pos, size_t n, float* sigma, float* geo) const;
  void queryColor(const float* geo, const float* dir, size_t n, float* rgb) const;
  // d sigma / d pos (n*3), in unit-cube coordinates; normals are -grad / |grad|.
  void densityGradient(const float* pos, size_t n, float* grad) const;

  // ---- Training.
  Workspace makeWorkspace() const;
  Gradients makeGradients() const;
  // Evaluates sigma (n) and rgb (n*3) and keeps in `ws` what backward() needs. sigma/rgb may be
  // null when not wanted (they are still kept in the workspace).
  void forward(Workspace& ws, const float* pos, const float* dir, size_t n, float* sigma, float* rgb) const;
  // forward() in two stages, for training: forwardDensity() evaluates sigma (n) of every sample,
  // then forwardColor() the colour of the samples with needed[i] != 0 only (all when needed is
  // null); the others get rgb 0 and must have zero loss gradients in backward(). In training these
  // are the samples past their ray's early termination (compositeUsedSamples), about 40 % of them,
  // whose colour the composite never reads. Bit-identical to forward() for the needed samples.
  void forwardDensity(Workspace& ws, const float* pos, const float* dir, size_t n, float* sigma) const;
  void forwardColor(Workspace& ws, const uint8_t* needed, float* rgb) const;
  // Back-propagates dL/dsigma (n) and dL/drgb (n*3) of the last forward() on `ws` and adds the
  // parameter gradients into `grads`. Either pointer may be null (treated as zeros). Samples whose
  // gradients are all exactly zero (e.g. past a ray's early termination) are skipped: they add
  // nothing, and the MLP backward and the hash-grid scatter then run on the others only.
  //
  // dL_dpos (optional, n*3): also the loss gradient with respect to each sample's position (unit-cube
  // field coordinates) through the density network and the encoding (not through the direction),
  // with level l of the encoding weighted by level_weights[l] when given (a coarse-to-fine schedule,
  // as BARF's, for pose refinement). Skipped samples get 0. Costs a scalar pass over the samples'
  // grid corners.
  void backward(Workspace& ws, const float* dL_dsigma, const float* dL_drgb, Gradients& grads, float* dL_dpos = nullptr,
                const float* level_weights = nullptr) const;
  // Sums the per-thread gradients in the given order (deterministic), applies Adam with learning
  // rate `lr` (see adam.h for the sparse update rule), and clears the gradients. Only hash entries
  // some thread touched are updated. n_threads workers split the entries; the result does not
  // depend on n_threads. The summed gradients are multiplied by grad_scale first (a trainer that
  // back-propagates unnormalised per-ray losses, before it knows how many rays the step has, passes
  // 1/rays).
  void step(const std::vector<Gradients*>& per_thread, float lr, int n_threads = 1, float grad_scale = 1.f);
  // Drops what backward() accumulated in `grads` since the last step() (a step that is abandoned).
  void clearGradients(Gradients& grads) const;
  // The accumulated (not yet applied) gradients of `grads`, named like parameters(), for tests
  // and diagnostics.
  std::vector<FloatArray> gradients(Gradients& grads) const;
  // Number of optimiser steps taken so far.
  uint64_t stepCount() const;
  // Where the last step() spent its time (CPU seconds summed over its workers), for benchmarks:
  // the MLP update, the hash-grid scatter (the encoding's backward, deferred to step()), the
  // hash-grid Adam update, and the number of hash entries updated.
  struct StepProfile {
    double mlp_seconds = 0, scatter_seconds = 0, adam_seconds = 0;
    size_t entries_updated = 0;
  };
  const StepProfile& lastStepProfile() const;

  // ---- Parameters, for the model file. Weight matrices are row-major [in][out]:
  //   "hash_grid"  levels concatenated, entry-major [entry][2] (offsets: hash_grid.h levels())
  //   "density.w0" [n_levels*2][hidden], "density.w1" [hidden][16],
  //   "color.w0" [32][hidden] (rows 0..15 SH, 16..31 density outputs), "color.w1" [hidden][hidden],
  //   "color.w2" [hidden][16] (columns 3..15 are padding, always zero).
  std::vector<FloatArray> parameters();
  // Adam state: "adam.m.<name>" and "adam.v.<name>" for each parameter array.
  std::vector<FloatArray> optimizerMoments();
  // "adam.hash_steps" (per hash entry: steps in which the entry was updated) and "adam.mlp_step"
  // (size 2: low and high 32 bits of the MLP step count).
  std::vector<U32Array> optimizerCounters();
  // Call after writing parameter arrays through the pointers above (refreshes derived copies).
  void parametersChanged();
  size_t numParameters() const;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace nerfslam::nerf
