// CUDA side of the batch layer: the same per-sample kernels as the CPU, one thread per sample; or, for an op with
// a team path (kernels/spatial/team.h) when TORCH_GRID_CUDA_TEAMS=1, one warp per sample.
#pragma once

#include <cuda_runtime.h>

#include <cstdlib>

#include "batch/batch.h"
#include "kernels/spatial/team.h"

namespace tg {

// One thread per sample, or per (sample, coordinate) for an op made of independent coordinates.
template <template <class, class, int> class Op, class Robot, class Scalar, int C>
__global__ void batch_kernel(const Batch b) {
  constexpr int NC = Coordinates<Op<Robot, Scalar, C>>::value;
  const int64_t t = static_cast<int64_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if constexpr (NC > 0) {
    if (t < b.n * NC) run_sample_coordinate<Op, Robot, Scalar, C>(b, t / NC, static_cast<int>(t % NC));
  } else {
    if (t < b.n) run_sample<Op, Robot, Scalar, C>(b, t);
  }
}

// The 32 lanes of a warp running one sample, its workspace in the block's shared memory.
struct WarpTeam {
  static constexpr int lanes = 32;
  int lane_;
  __device__ int lane() const { return lane_; }
  __device__ bool leader() const { return lane_ == 0; }
  __device__ void sync() const { __syncwarp(); }
  __device__ TeamItems items(int b, int e) const { return {b, e, team_first(b, lane_, lanes), lanes, false}; }
};

// Warp w of a block runs sample blockIdx.x * per_block + w, with the w-th workspace of the block's shared memory
// (a whole warp leaves together, so a sync never waits for a lane that left).
template <template <class, class, int> class Op, class Robot, class Scalar, int C>
__global__ void team_kernel(const Batch b, int per_block) {
  using Work = typename Op<Robot, Scalar, C>::TeamWork;
  extern __shared__ __align__(16) unsigned char team_shared[];
  const int warp = static_cast<int>(threadIdx.x) / WarpTeam::lanes;
  const int64_t s = static_cast<int64_t>(blockIdx.x) * per_block + warp;
  if (s >= b.n) return;
  Work& w = reinterpret_cast<Work*>(team_shared)[warp];
  run_sample_team<Op, Robot, Scalar, C>(b, s, WarpTeam{static_cast<int>(threadIdx.x) % WarpTeam::lanes}, w);
}

// Whether the ops with a team path take it: TORCH_GRID_CUDA_TEAMS=1, read at each launch (a process may time both).
inline bool cuda_teams() {
  const char* env = std::getenv("TORCH_GRID_CUDA_TEAMS");
  return env && env[0] == '1' && env[1] == '\0';
}

// A block holds as many samples as fit the 48 KB of shared memory a launch may take without asking, at most 4
// (128 threads), and at least one, whose workspace may take up to the device's limit (asked for at each launch).
template <template <class, class, int> class Op, class Robot, class Scalar, int C>
int team_launch(const Batch& b, void* stream) {
  constexpr int64_t bytes = sizeof(typename Op<Robot, Scalar, C>::TeamWork), plain = 48 << 10;
  constexpr int per_block = bytes >= plain / 4 ? (bytes >= plain / 2 ? 1 : plain / bytes) : 4;
  constexpr int64_t shared = bytes * per_block;
  const auto kernel = team_kernel<Op, Robot, Scalar, C>;
  if constexpr (shared > plain) {
    const cudaError_t err = cudaFuncSetAttribute(kernel, cudaFuncAttributeMaxDynamicSharedMemorySize, static_cast<int>(shared));
    if (err != cudaSuccess) return static_cast<int>(err);
  }
  const int64_t blocks = (b.n + per_block - 1) / per_block;
  kernel<<<static_cast<unsigned>(blocks), WarpTeam::lanes * per_block, shared, static_cast<cudaStream_t>(stream)>>>(b, per_block);
  return static_cast<int>(cudaGetLastError());
}

// Threads per block follow the work: enough blocks to cover every one of the `sms` multiprocessors
// before blocks fill up (a batch of 256 samples uses every SM), at most 128 threads a block (within
// any kernel's limit at 255 registers a thread). The attributes are the thread-per-sample kernel's, whose
// local memory bounds a team kernel's.
template <template <class, class, int> class Op, class Robot, class Scalar, int C>
int cuda_launch(const Batch& b, void* stream, int sms, CudaAttributes* attributes) {
  if (attributes) {
    cudaFuncAttributes a;
    const cudaError_t err = cudaFuncGetAttributes(&a, batch_kernel<Op, Robot, Scalar, C>);
    if (err != cudaSuccess) return static_cast<int>(err);
    attributes->registers = a.numRegs;
    attributes->local_bytes = static_cast<int64_t>(a.localSizeBytes);
  }
  if (b.n == 0) return 0;
  if constexpr (has_team<Op<Robot, Scalar, C>>) {
    // (a workspace beyond a block's shared memory on sm_80 and sm_90, 227 KB, stays one thread a sample)
    if constexpr (sizeof(typename Op<Robot, Scalar, C>::TeamWork) <= (227 << 10))
      if (cuda_teams()) return team_launch<Op, Robot, Scalar, C>(b, stream);
  }
  constexpr int NC = Coordinates<Op<Robot, Scalar, C>>::value;
  const int64_t work = b.n * (NC > 0 ? NC : 1);
  const int64_t per_sm = (work + sms - 1) / sms;
  const int threads = static_cast<int>(per_sm < 1 ? 1 : per_sm > 128 ? 128 : per_sm);
  const int64_t blocks = (work + threads - 1) / threads;
  batch_kernel<Op, Robot, Scalar, C><<<static_cast<unsigned>(blocks), threads, 0, static_cast<cudaStream_t>(stream)>>>(b);
  return static_cast<int>(cudaGetLastError());
}

}  // namespace tg
