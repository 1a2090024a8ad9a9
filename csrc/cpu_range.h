// CPU side of the batch layer: a loop over the samples given to one thread.
#pragma once

#include <cstring>
#include <vector>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "batch.h"

namespace tg {

// A batch whose outputs exceed this many bytes streams them to memory (cpu_range).
constexpr int64_t kStreamBytes = int64_t(8) << 20;

// dst[0, n) <- src with non-temporal stores where the CPU has them: the lines go to memory without
// first being read into the cache, and without evicting the inputs from it.
inline void stream_copy(double* dst, const double* src, int64_t n) {
#if defined(__x86_64__)
  int64_t k = 0;
  for (; k < n && (reinterpret_cast<uintptr_t>(dst + k) & 15); ++k) {
    long long bits;
    std::memcpy(&bits, src + k, 8);
    _mm_stream_si64(reinterpret_cast<long long*>(dst + k), bits);
  }
  for (; k + 2 <= n; k += 2) _mm_stream_pd(dst + k, _mm_loadu_pd(src + k));
  for (; k < n; ++k) {
    long long bits;
    std::memcpy(&bits, src + k, 8);
    _mm_stream_si64(reinterpret_cast<long long*>(dst + k), bits);
  }
#else
  std::memcpy(dst, src, static_cast<size_t>(n) * sizeof(double));
#endif
}

template <template <class, class, int> class Op, class M, class S, int C>
void cpu_range(const Batch& b, int64_t begin, int64_t end) {
  int64_t per_sample = 0;
  for (int k = 0; k < kMaxOut; ++k) per_sample += b.out[k] ? b.out_stride[k] : 0;
  if (!std::is_same_v<S, double> || b.n * per_sample * int64_t(sizeof(S)) <= kStreamBytes) {
    for (int64_t s = begin; s < end; ++s) run_sample<Op, M, S, C>(b, s);
    return;
  }
  // Outputs larger than a core keeps in cache (go2's M at B = 4096: 10.6 MB): each sample's are
  // computed into a buffer that stays in L1, then streamed out (G1 crba 3.6 -> 2.9 us per sample).
  std::vector<S> buffer(static_cast<size_t>(per_sample));
  const S* in[kMaxIn];
  S* out[kMaxOut];
  for (int k = 0, offset = 0; k < kMaxOut; ++k) {
    out[k] = b.out[k] ? buffer.data() + offset : nullptr;
    offset += b.out[k] ? static_cast<int>(b.out_stride[k]) : 0;
  }
  for (int64_t s = begin; s < end; ++s) {
    for (int k = 0; k < kMaxIn; ++k) in[k] = b.in[k] ? static_cast<const S*>(b.in[k]) + s * b.in_stride[k] : nullptr;
    Op<M, S, C>::run(in, out, b.iargs, b.n_iargs);
    if constexpr (std::is_same_v<S, double>)
      for (int k = 0; k < kMaxOut; ++k)
        if (out[k]) stream_copy(static_cast<S*>(b.out[k]) + s * b.out_stride[k], out[k], b.out_stride[k]);
  }
#if defined(__x86_64__)
  _mm_sfence();  // streamed stores are weakly ordered: complete them before the batch returns
#endif
}

}  // namespace tg
