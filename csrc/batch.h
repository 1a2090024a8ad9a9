// A batch of samples handed from the torch glue to the kernels: raw pointers and strides only, so
// kernel translation units (host C++ and CUDA) never include torch. TG_MAX_IARGS comes from the
// generated robot header.
#pragma once

#include <cstdint>

#include "kernels/spatial.h"

namespace tg {

constexpr int kMaxIn = 8, kMaxOut = 4;

struct Batch {
  int64_t n = 0;                        // number of samples
  const void* in[kMaxIn] = {};          // null for an absent optional input
  int64_t in_stride[kMaxIn] = {};       // elements between samples
  void* out[kMaxOut] = {};
  int64_t out_stride[kMaxOut] = {};
  int iargs[TG_MAX_IARGS] = {};         // integer arguments (frame indices, reference, mask)
  int n_iargs = 0;
};

template <template <class, class, int> class Op, class M, class S, int C>
TG_HD void run_sample(const Batch& b, int64_t s) {
  const S* in[kMaxIn];
  S* out[kMaxOut];
  for (int k = 0; k < kMaxIn; ++k) in[k] = b.in[k] ? static_cast<const S*>(b.in[k]) + s * b.in_stride[k] : nullptr;
  for (int k = 0; k < kMaxOut; ++k) out[k] = b.out[k] ? static_cast<S*>(b.out[k]) + s * b.out_stride[k] : nullptr;
  Op<M, S, C>::run(in, out, b.iargs, b.n_iargs);
}

// Samples [begin, end) on the calling CPU thread (cpu_range.h); instantiated per op in the kernel units.
template <template <class, class, int> class Op, class M, class S, int C>
void cpu_range(const Batch& b, int64_t begin, int64_t end);

// One CUDA thread per sample on `stream` (a cudaStream_t); returns a cudaError_t as int.
template <template <class, class, int> class Op, class M, class S, int C>
int cuda_launch(const Batch& b, void* stream);

}  // namespace tg
