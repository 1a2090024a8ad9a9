// CPU side of the batch layer: a plain loop over the samples given to one thread.
#pragma once

#include "batch/batch.h"

namespace tg {

template <template <class, class, int> class Op, class Robot, class Scalar, int C>
void cpu_range(const Batch& b, int64_t begin, int64_t end) {
  for (int64_t s = begin; s < end; ++s) run_sample<Op, Robot, Scalar, C>(b, s);
}

}  // namespace tg
