// CUDA side of the batch layer: the same per-sample kernels as the CPU, one thread per sample.
#pragma once

#include <cuda_runtime.h>

#include "batch/batch.h"

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

// Threads per block follow the work: enough blocks to cover every one of the `sms` multiprocessors
// before blocks fill up (a batch of 256 samples uses every SM), at most 128 threads a block (within
// any kernel's limit at 255 registers a thread).
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
  constexpr int NC = Coordinates<Op<Robot, Scalar, C>>::value;
  const int64_t work = b.n * (NC > 0 ? NC : 1);
  const int64_t per_sm = (work + sms - 1) / sms;
  const int threads = static_cast<int>(per_sm < 1 ? 1 : per_sm > 128 ? 128 : per_sm);
  const int64_t blocks = (work + threads - 1) / threads;
  batch_kernel<Op, Robot, Scalar, C><<<static_cast<unsigned>(blocks), threads, 0, static_cast<cudaStream_t>(stream)>>>(b);
  return static_cast<int>(cudaGetLastError());
}

}  // namespace tg
