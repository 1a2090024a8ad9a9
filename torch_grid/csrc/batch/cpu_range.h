// CPU side of the batch layer: a plain loop over the samples given to one thread.
#pragma once

#include "batch/batch.h"

#include <limits>

namespace tg {

// Under TORCH_GRID_POISON_OUTPUTS (a test of the kernels) the stack below the caller's frame is set to
// NaN before every sample, as a GPU thread's local memory holds whatever an earlier kernel left there:
// a kernel that reads an entry of a local array it never wrote then fails on the CPU too, where the
// stack's leftovers are usually finite and hide it.
[[gnu::noinline]] inline void poison_stack() {
  volatile double area[1 << 15];  // 256 KB, more than any kernel's frame
  for (int i = 0; i < (1 << 15); ++i) area[i] = std::numeric_limits<double>::quiet_NaN();
}

// One sample in a frame of its own, which starts where poison_stack's did.
template <template <class, class, int> class Op, class Robot, class Scalar, int C>
[[gnu::noinline]] void poisoned_sample(const Batch& b, int64_t s) {
  run_sample<Op, Robot, Scalar, C>(b, s);
}

template <template <class, class, int> class Op, class Robot, class Scalar, int C>
void cpu_range(const Batch& b, int64_t begin, int64_t end) {
  for (int64_t s = begin; s < end; ++s) {
    if (b.poisoned) {
      poison_stack();
      poisoned_sample<Op, Robot, Scalar, C>(b, s);
    } else {
      run_sample<Op, Robot, Scalar, C>(b, s);
    }
  }
}

}  // namespace tg
