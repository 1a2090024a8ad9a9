// What the glue's CUDA launches read of the device and of each kernel, once per process: the device's
// multiprocessors, threads and memory, a kernel's registers and local memory, whether a kernel has been
// launched on a device yet (its first launch grows the device's local memory), and the budget for that
// growth.
#pragma once

#include <c10/util/Exception.h>
#include <cuda_runtime_api.h>

#include <algorithm>
#include <cstdlib>
#include <mutex>
#include <unordered_map>
#include <utility>
#include <vector>

#include "batch/batch.h"

namespace tg {

// What a launch needs of a device.
struct CudaDevice {
  int sms = 0, threads_per_sm = 0;
  int64_t memory = 0;
};

// compute(key), computed once per key (and call site) for the process.
template <class K, class V, class F> V cuda_once(K key, F compute) {
  static std::mutex mutex;
  static std::unordered_map<K, V> known;
  std::lock_guard<std::mutex> lock(mutex);
  auto it = known.find(key);
  if (it == known.end()) it = known.emplace(key, compute(key)).first;
  return it->second;
}

// The device of this index; `op` names the caller in an error.
inline CudaDevice cuda_device(int index, const char* op) {
  return cuda_once<int, CudaDevice>(index, [op](int i) {
    CudaDevice d;
    size_t free = 0, total = 0;
    cudaError_t err = cudaDeviceGetAttribute(&d.sms, cudaDevAttrMultiProcessorCount, i);
    if (err == cudaSuccess) err = cudaDeviceGetAttribute(&d.threads_per_sm, cudaDevAttrMaxThreadsPerMultiProcessor, i);
    if (err == cudaSuccess) err = cudaMemGetInfo(&free, &total);
    TORCH_CHECK(err == cudaSuccess, op, ": cannot read the CUDA device's properties: ", cudaGetErrorString(err));
    d.memory = static_cast<int64_t>(total);
    return d;
  });
}

// The kernel's registers and local memory per thread.
inline CudaAttributes cuda_attributes(CudaFn fn, const char* op) {
  return cuda_once<CudaFn, CudaAttributes>(fn, [op](CudaFn f) {
    CudaAttributes a;
    const int err = f(Batch{}, nullptr, 1, &a);
    TORCH_CHECK(err == 0, op, ": cannot read the CUDA kernel's attributes: ", cudaGetErrorString(static_cast<cudaError_t>(err)));
    return a;
  });
}

// The most local memory a first launch may reserve: TORCH_GRID_CUDA_LOCAL_MEMORY_MB, or a quarter of the device.
inline int64_t cuda_local_budget(const CudaDevice& d) {
  const char* env = std::getenv("TORCH_GRID_CUDA_LOCAL_MEMORY_MB");
  if (env && *env) return std::atoll(env) << 20;
  return d.memory / 4;
}

// The (kernel, device) pairs launched in this process, by any call site.
struct CudaLaunched {
  std::mutex mutex;
  std::vector<std::pair<CudaFn, int>> list;
};
inline CudaLaunched& cuda_launched_pairs() {
  static CudaLaunched launched;
  return launched;
}
inline bool cuda_launched(CudaFn fn, int index) {
  CudaLaunched& l = cuda_launched_pairs();
  std::lock_guard<std::mutex> lock(l.mutex);
  return std::find(l.list.begin(), l.list.end(), std::make_pair(fn, index)) != l.list.end();
}
inline void cuda_mark_launched(CudaFn fn, int index) {
  CudaLaunched& l = cuda_launched_pairs();
  std::lock_guard<std::mutex> lock(l.mutex);
  if (std::find(l.list.begin(), l.list.end(), std::make_pair(fn, index)) == l.list.end()) l.list.emplace_back(fn, index);
}

}  // namespace tg
