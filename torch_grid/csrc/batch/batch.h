// A batch of samples handed from the torch glue to the kernels: raw pointers and strides only, so
// kernel translation units (host C++ and CUDA) never include torch, and the robot library that
// holds them is plain C++ shared by every torch version's glue.
#pragma once

#include <cstdint>
#include <type_traits>

#include "kernels/spatial/spatial.h"

namespace tg {

// Limits of one call, checked by the glue: tensor inputs, outputs, integer arguments (frame
// indices, reference, mask). A CUDA launch passes the Batch by value (2.3 KB of the 4 KB of
// kernel parameters).
constexpr int kMaxIn = 8, kMaxOut = 5, kMaxIargs = 512;

struct Batch {
  int64_t n = 0;                        // number of samples
  const void* in[kMaxIn] = {};          // null for an absent optional input
  int64_t in_stride[kMaxIn] = {};       // elements between samples
  void* out[kMaxOut] = {};
  int64_t out_stride[kMaxOut] = {};
  int64_t in_size[kMaxIn] = {};         // elements of one sample
  int iargs[kMaxIargs] = {};
  int n_iargs = 0;
  int workspace = 0;                    // bit k: output k is the kernel's scratch, never read back
  // The outputs already hold zeros wherever the op's kernel writes nothing (the glue's own buffer, zeroed
  // once and refilled sample after sample by the same kernel): a kernel that writes a fixed pattern of
  // entries (inverse_dynamics_second_derivatives) then skips zero-filling the rest.
  bool zeroed = false;
  bool poisoned = false;  // TORCH_GRID_POISON_OUTPUTS: the outputs start as NaN (a test of the kernels)
};

// Sample s's inputs and outputs: each present array advanced by s of its strides, the absent ones null.
template <class Scalar> struct SampleArrays {
  const Scalar* in[kMaxIn];
  Scalar* out[kMaxOut];
  TG_HD SampleArrays(const Batch& b, int64_t s) {
    for (int k = 0; k < kMaxIn; ++k) in[k] = b.in[k] ? static_cast<const Scalar*>(b.in[k]) + s * b.in_stride[k] : nullptr;
    for (int k = 0; k < kMaxOut; ++k) out[k] = b.out[k] ? static_cast<Scalar*>(b.out[k]) + s * b.out_stride[k] : nullptr;
  }
};

template <template <class, class, int> class Op, class Robot, class Scalar, int C>
TG_HD void run_sample(const Batch& b, int64_t s) {
  const SampleArrays<Scalar> x(b, s);
  Op<Robot, Scalar, C>::run(x.in, x.out, b.iargs, b.n_iargs, b.zeroed);
}

// Ops that split a sample into independent work items (a forward-mode backward: one per input
// coordinate) say how many with kCoordinates and run one with run_coordinate.
template <class T, class = void> struct Coordinates { static constexpr int value = 0; };
template <class T> struct Coordinates<T, std::void_t<decltype(T::kCoordinates)>> {
  static constexpr int value = T::kCoordinates;
};

template <template <class, class, int> class Op, class Robot, class Scalar, int C>
TG_HD void run_sample_coordinate(const Batch& b, int64_t s, int c) {
  const SampleArrays<Scalar> x(b, s);
  Op<Robot, Scalar, C>::run_coordinate(x.in, x.out, b.iargs, b.n_iargs, c);
}

// Sample s by a team (kernels/spatial/team.h) with its shared workspace w: an op with a team path.
template <template <class, class, int> class Op, class Robot, class Scalar, int C, class Team>
TG_HD void run_sample_team(const Batch& b, int64_t s, const Team& t, typename Op<Robot, Scalar, C>::TeamWork& w) {
  const SampleArrays<Scalar> x(b, s);
  Op<Robot, Scalar, C>::run_team(t, w, x.in, x.out, b.iargs, b.n_iargs);
}

// Samples [begin, end) on the calling CPU thread (cpu_range.h).
using CpuFn = void (*)(const Batch& b, int64_t begin, int64_t end);

// What a CUDA launch needs to know before it runs: registers and local memory (stack) per thread.
struct CudaAttributes {
  int registers = 0;
  int64_t local_bytes = 0;
};
// One CUDA thread per sample (or per work item) on `stream` (a cudaStream_t) of a device with `sms`
// multiprocessors; returns a cudaError_t as int. With b.n == 0 it only fills `attributes` (no launch).
using CudaFn = int (*)(const Batch& b, void* stream, int sms, CudaAttributes* attributes);

// Every kernel of one op in one robot library: [scalar: 0 float, 1 double][convention: 0 pin, 1 mujoco].
// The CPU's scalar kernels are double only (cpu[0] is null): the glue runs small float32 batches through
// them. lanes[s][c] runs the same kernel on groups of samples, RobotTable::lanes at a time in double and
// twice that in float (cpu_lanes.h; null where the op has none).
struct OpKernels {
  CpuFn cpu[2][2];
  CpuFn lanes[2][2];
  CudaFn cuda[2][2];
  int64_t grain;  // the fewest samples worth a CPU thread (ops/table.py: cpu_grain)
};

// What a robot library exports (one C symbol, named after its op namespace): its sizes and one
// OpKernels per op, in the order of the op table whose signature it carries.
constexpr int kTableAbi = 6;
struct RobotTable {
  int abi;
  const char* op_signature;  // hash of the op table the library was generated from
  int nq, nv, nb, nf;
  int converts, mujoco, cuda;  // flags: a quaternion joint (the conventions differ); MuJoCo-convention kernels built; CUDA kernels built
  int lanes;                   // doubles per vector of the CPU lane kernels (1: none)
  int device_paths;            // the CPU kernels take a GPU thread's code paths (TG_DEVICE_PATH)
  int nops;
  const OpKernels* ops;
};

}  // namespace tg
