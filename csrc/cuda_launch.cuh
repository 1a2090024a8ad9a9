// CUDA side of the batch layer: the same per-sample kernels as the CPU, one thread per sample.
#pragma once

#include <cuda_runtime.h>

#include "batch.h"

namespace tg {

template <template <class, class, int> class Op, class M, class S, int C>
__global__ void batch_kernel(const Batch b) {
  const int64_t s = static_cast<int64_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if (s < b.n) run_sample<Op, M, S, C>(b, s);
}

template <template <class, class, int> class Op, class M, class S, int C>
int cuda_launch(const Batch& b, void* stream) {
  constexpr int threads = 128;
  const int64_t blocks = (b.n + threads - 1) / threads;
  batch_kernel<Op, M, S, C><<<static_cast<unsigned>(blocks), threads, 0, static_cast<cudaStream_t>(stream)>>>(b);
  return static_cast<int>(cudaGetLastError());
}

}  // namespace tg
