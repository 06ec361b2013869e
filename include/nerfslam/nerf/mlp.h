#pragma once
// The MLP kernels: a register-blocked SIMD GEMM with fused activations, used for every layer's
// forward, backward-data and weight-gradient product over a tile of samples (activations of a
// tile stay in L1 between layers). Highway runtime dispatch (AVX-512, AVX2, SSE4, NEON, scalar).
#include <cstddef>

namespace nerfslam::nerf {

enum class Epilogue {
  kNone,      // C = acc            (or C += acc when accumulate)
  kRelu,      // C = max(acc, 0)
  kReluMask,  // C = acc * (mask > 0) (backward through a ReLU whose output is `mask`)
};

// C[m*ldc + n] (+)= sum_k A(m, k) * B[k*ldb + n], for m < M, n < N, k < K, where
// A(m, k) = a[m*a_ms + k*a_ks] (any strides: sample-major, feature-major or transposed).
// N must be a multiple of 16. mask (kReluMask) is read as mask[m*ldm + n].
// `accumulate` adds to C (only with Epilogue::kNone).
struct GemmArgs {
  size_t M = 0, N = 0, K = 0;
  const float* a = nullptr;
  size_t a_ms = 0, a_ks = 0;
  const float* b = nullptr;
  size_t ldb = 0;
  float* c = nullptr;
  size_t ldc = 0;
  bool accumulate = false;
  Epilogue epilogue = Epilogue::kNone;
  const float* mask = nullptr;
  size_t ldm = 0;
};

void gemm(const GemmArgs& args);        // dispatched to the best SIMD target
void gemmScalar(const GemmArgs& args);  // reference

// FLOPs of one call (2*M*N*K), for benchmarks.
inline double gemmFlops(const GemmArgs& a) { return 2.0 * double(a.M) * double(a.N) * double(a.K); }

}  // namespace nerfslam::nerf
