// CPU side of the batch layer on vector lanes: a group of samples runs one kernel whose scalar is
// Lanes<double, kLanes>, or Lanes<float, 2 kLanes> for float32 (lanes.h). Each group's inputs are gathered
// structure-of-arrays (lane l holds sample s0 + l), the kernel runs once, its outputs are scattered back.
// In double, the samples left over (fewer than a group) take the scalar kernel, so a batch of one costs
// what it did; in float, which has no scalar CPU kernel, they run as a group whose spare lanes repeat the
// last sample.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "batch/cpu_range.h"
#include "kernels/spatial/lanes.h"

namespace tg {

// A thread's lanes of one op's inputs and outputs, kept between calls; key names the op whose layout
// (and zeros) it holds, iargs the integer arguments (a frame) that chose the entries its kernel wrote.
template <class L> struct LaneBuffer {
  std::vector<L> data;
  const void* key = nullptr;
  int64_t total = 0;
  int present = 0;
  int workspace = 0;
  std::vector<int> iargs;
};
template <class L> LaneBuffer<L>& lane_buffer() {
  thread_local LaneBuffer<L> buffer;
  return buffer;
}

// In-register transpose of W vectors of W entries (W a power of two): stage h exchanges bit h of the row
// index with bit h of the column index, a pair of rows (i, i + h with bit h of i clear) at a time. All
// indices are constants, so the rows stay in registers: lo/hi of a pair are one or two shuffles each.
// GCC before 12 has only __builtin_shuffle (TG_GCC_SHUFFLE picks it on any GCC, for the tests).
#if defined(__has_builtin) && !defined(TG_GCC_SHUFFLE)
#if __has_builtin(__builtin_shufflevector)
#define TG_SHUFFLE(a, b, I, ...) __builtin_shufflevector(a, b, __VA_ARGS__)
#endif
#endif
#ifndef TG_SHUFFLE
#define TG_SHUFFLE(a, b, I, ...) __builtin_shuffle(a, b, I{__VA_ARGS__})
#endif
template <class V, class I, int W, int h, std::size_t... C> inline void exchange(V& a, V& b, std::index_sequence<C...>) {
  // row i takes its columns with bit h clear from itself, the others from row i + h (shifted down by h)
  const V lo = TG_SHUFFLE(a, b, I, ((C & h) ? W + (C & ~h) : C)...);
  const V hi = TG_SHUFFLE(a, b, I, ((C & h) ? W + C : (C | h))...);
  a = lo, b = hi;
}
template <class V, class I, int W, int h, std::size_t... P> inline void exchange_pairs(V* r, std::index_sequence<P...>) {
  (exchange<V, I, W, h>(r[P / h * 2 * h + P % h], r[P / h * 2 * h + P % h + h], std::make_index_sequence<W>()), ...);
}
template <class T, int W, int h = 1> inline void transpose(typename Lanes<T, W>::V* r) {
  if constexpr (h < W) {
    using I = typename LaneMask<T, W>::I;
    exchange_pairs<typename Lanes<T, W>::V, I, W, h>(r, std::make_index_sequence<W / 2>());
    transpose<T, W, 2 * h>(r);
  }
}
#undef TG_SHUFFLE

// One W x W block: entries [0, W) of lanes x[0, W) to rows y + l * size, sample l's W contiguous entries.
template <class T, int W, std::size_t... L> inline void scatter_block(const Lanes<T, W>* x, int64_t size, T* y, std::index_sequence<L...>) {
  typename Lanes<T, W>::V r[W] = {x[L].x...};
  transpose<T, W>(r);
  (__builtin_memcpy(y + L * size, &r[L], sizeof r[L]), ...);
}

// y[l * size + j] = x[j][l]: the group's output back to sample-major, W x W blocks transposed in
// registers (a lane's entries leave as one contiguous vector store each).
template <class T, int W> inline void scatter(const Lanes<T, W>* x, int64_t size, T* y) {
  int64_t j0 = 0;
  for (; j0 + W <= size; j0 += W) scatter_block<T, W>(x + j0, size, y + j0, std::make_index_sequence<W>());
  for (int l = 0; l < W; ++l)
    for (int64_t j = j0; j < size; ++j) y[l * size + j] = x[j].x[l];
}

// y[j][l] = x[l][j], j in [0, size): W samples' inputs (each contiguous) to lanes, by the same blocks.
template <class T, int W, std::size_t... L> inline void gather_block(const T* const* x, int64_t j0, Lanes<T, W>* y, std::index_sequence<L...>) {
  typename Lanes<T, W>::V r[W];
  (__builtin_memcpy(&r[L], x[L] + j0, sizeof r[L]), ...);
  transpose<T, W>(r);
  ((y[L].x = r[L]), ...);
}
template <class T, int W> inline void gather(const T* const* x, int64_t size, Lanes<T, W>* y) {
  int64_t j0 = 0;
  for (; j0 + W <= size; j0 += W) gather_block<T, W>(x, j0, y + j0, std::make_index_sequence<W>());
  for (int64_t j = j0; j < size; ++j)
    for (int l = 0; l < W; ++l) y[j].x[l] = x[l][j];
}

// The first n lanes of a group alone (a float batch's last, partial group).
template <class T, int W> inline void scatter_lanes(const Lanes<T, W>* x, int64_t size, int n, T* y) {
  for (int l = 0; l < n; ++l)
    for (int64_t j = 0; j < size; ++j) y[l * size + j] = x[j].x[l];
}

template <template <class, class, int> class Op, class Robot, int C, class T = double>
void cpu_range_lanes(const Batch& b, int64_t begin, int64_t end) {
  constexpr int W = kLanes * int(sizeof(double) / sizeof(T));
  constexpr bool padded = !std::is_same_v<T, double>;  // no scalar kernel for the rest
  using L = Lanes<T, W>;
  const int64_t groups_end = padded ? end : begin + (end - begin) / W * W;
  if (groups_end > begin) {
    // one buffer of lanes for every input and output of a sample
    int64_t offset[kMaxIn + kMaxOut] = {}, total = 0;
    for (int k = 0; k < kMaxIn; ++k) offset[k] = total, total += b.in[k] ? b.in_size[k] : 0;
    for (int k = 0; k < kMaxOut; ++k) offset[kMaxIn + k] = total, total += b.out[k] ? b.out_stride[k] : 0;
    // The thread's buffer: the glue's buffered paths call again for each chunk of a batch, and find it
    // as the last call left it.
    LaneBuffer<L>& buffer = lane_buffer<L>();
    const void* key = reinterpret_cast<const void*>(&cpu_range_lanes<Op, Robot, C, T>);
    int present = 0;  // which inputs and outputs the layout has
    for (int k = 0; k < kMaxIn; ++k) present |= (b.in[k] != nullptr) << k;
    for (int k = 0; k < kMaxOut; ++k) present |= (b.out[k] != nullptr) << (kMaxIn + k);
    const bool same_iargs = buffer.iargs.size() == static_cast<size_t>(b.n_iargs) &&
                            std::equal(b.iargs, b.iargs + b.n_iargs, buffer.iargs.begin());
    // The group's outputs are the buffer's, which keeps zeros wherever the kernel writes nothing (the same
    // entries for every group of a call with these integer arguments): the kernel may skip filling them
    // (Batch::zeroed). Under poisoned outputs (fixed for the process) they start as NaN at every call
    // instead, so that an entry the kernel leaves unwritten shows.
    const bool zeroed = !b.poisoned;
    const bool fresh = buffer.key != key || buffer.total != total || buffer.present != present ||
                       buffer.workspace != b.workspace || !same_iargs || !zeroed;
    if (fresh) buffer.data.resize(static_cast<size_t>(total));
    const L* in[kMaxIn];
    L* out[kMaxOut];
    for (int k = 0; k < kMaxIn; ++k) in[k] = b.in[k] ? buffer.data.data() + offset[k] : nullptr;
    for (int k = 0; k < kMaxOut; ++k) {
      out[k] = b.out[k] ? buffer.data.data() + offset[kMaxIn + k] : nullptr;
      const T fill = zeroed || (b.workspace >> k & 1) ? T(0) : std::numeric_limits<T>::quiet_NaN();  // scratch: zeros
      if (out[k] && fresh) std::fill(out[k], out[k] + b.out_stride[k], L(fill));
    }
    buffer.key = key, buffer.total = total, buffer.present = present, buffer.workspace = b.workspace;
    if (!same_iargs) buffer.iargs.assign(b.iargs, b.iargs + b.n_iargs);
    for (int64_t s0 = begin; s0 < groups_end; s0 += W) {
      const int n = static_cast<int>(std::min<int64_t>(W, groups_end - s0));
      // gather: a shared input (stride 0) fills every lane alike; spare lanes repeat the last sample
      for (int k = 0; k < kMaxIn; ++k) {
        if (!b.in[k]) continue;
        const T* x[W];
        for (int l = 0; l < W; ++l) x[l] = static_cast<const T*>(b.in[k]) + (s0 + std::min(l, n - 1)) * b.in_stride[k];
        gather(x, b.in_size[k], buffer.data.data() + offset[k]);
      }
      Op<Robot, L, C>::run(in, out, b.iargs, b.n_iargs, zeroed);
      for (int k = 0; k < kMaxOut; ++k) {
        if (!b.out[k] || (b.workspace >> k & 1)) continue;
        T* y = static_cast<T*>(b.out[k]) + s0 * b.out_stride[k];
        if (n == W)
          scatter(out[k], b.out_stride[k], y);
        else
          scatter_lanes(out[k], b.out_stride[k], n, y);
      }
    }
  }
  if constexpr (!padded) cpu_range<Op, Robot, double, C>(b, groups_end, end);
}

}  // namespace tg
