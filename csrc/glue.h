// Torch glue shared by every generated op wrapper: checks the arguments, allocates the outputs,
// and runs one op over the batch on the CPU (at::parallel_for) or on CUDA (current stream).
// Include after the generated robot header, which defines `Robot` and TG_WITH_MJX.
#pragma once

#include <ATen/Parallel.h>
#include <ATen/core/Tensor.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/from_blob.h>
#include <torch/library.h>

#include <cstdlib>
#if defined(__linux__)
#include <sys/mman.h>
#endif

#include <string>
#include <vector>

#include "batch.h"

#ifdef TG_WITH_CUDA
#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>
#include <cuda_runtime_api.h>
#endif

namespace tg {

class Call {
 public:
  // `q` fixes the batch shape, dtype and device every other argument must share.
  Call(const char* op, const at::Tensor& q, int64_t convention) : op_(op), convention_(convention) {
    TORCH_CHECK(q.dim() >= 1, op_, ": q must have shape (..., ", Robot::NQ, "), got a scalar");
    batch_shape_ = q.sizes().vec();
    batch_shape_.pop_back();
    dtype_ = q.scalar_type();
    device_ = q.device();
    TORCH_CHECK(dtype_ == at::kFloat || dtype_ == at::kDouble, op_, ": q must be float32 or float64, got ", dtype_);
    TORCH_CHECK(device_.is_cpu() || device_.is_cuda(), op_, ": q must be on the CPU or a CUDA device, got ", device_);
    TORCH_CHECK(convention == PIN || convention == MJX, op_, ": convention must be 0 (pin) or 1 (mujoco), got ", convention);
    n_ = 1;
    for (auto s : batch_shape_) n_ *= s;
    batch_.n = n_;
  }

  // A tensor input of shape (*batch, *trailing).
  void input(const at::Tensor& t, const char* name, std::vector<int64_t> trailing) {
    std::vector<int64_t> want = batch_shape_;
    want.insert(want.end(), trailing.begin(), trailing.end());
    TORCH_CHECK(t.sizes().vec() == want, op_, ": ", name, " must have shape ", at::IntArrayRef(want), ", got ", t.sizes());
    TORCH_CHECK(t.scalar_type() == dtype_, op_, ": ", name, " must have dtype ", dtype_, " like q, got ", t.scalar_type());
    TORCH_CHECK(t.device() == device_, op_, ": ", name, " must be on ", device_, " like q, got ", t.device());
    TORCH_CHECK(n_in_ < kMaxIn, op_, ": more than ", kMaxIn, " tensor inputs");
    keep_.push_back(t.contiguous());
    const int k = n_in_++;
    batch_.in[k] = keep_.back().data_ptr();
    batch_.in_stride[k] = numel(trailing);
  }
  void input(const std::optional<at::Tensor>& t, const char* name, std::vector<int64_t> trailing) {
    if (t.has_value()) {
      input(*t, name, std::move(trailing));
    } else {
      TORCH_CHECK(n_in_ < kMaxIn, op_, ": more than ", kMaxIn, " tensor inputs");
      batch_.in[n_in_++] = nullptr;
    }
  }

  // Integer arguments: frame indices checked against the robot's frames.
  void frame(int64_t f, const char* name) {
    TORCH_CHECK(f >= 0 && f < Robot::NF, op_, ": ", name, " must be a frame index in [0, ", Robot::NF, "), got ", f);
    push_int(f);
  }
  void frames(at::IntArrayRef fs, const char* name) {
    TORCH_CHECK(!fs.empty(), op_, ": ", name, " must list at least one frame");
    for (auto f : fs) frame(f, name);
  }
  void reference(int64_t r, const char* name) {
    TORCH_CHECK(r >= 0 && r <= 2, op_, ": ", name, " must be 0 (world), 1 (local) or 2 (local_world_aligned), got ", r);
    push_int(r);
  }
  // The inputs a backward op differentiates: bit i for the i-th of its n differentiable inputs.
  void mask(int64_t m, const char* name, int n) {
    TORCH_CHECK(m >= 0 && m < (int64_t(1) << n), op_, ": ", name, " must be a bit mask of ", n, " inputs, got ", m);
    push_int(m);
  }

  // A new output of shape (*batch, *trailing).
  at::Tensor output(std::vector<int64_t> trailing) {
    std::vector<int64_t> shape = batch_shape_;
    shape.insert(shape.end(), trailing.begin(), trailing.end());
    TORCH_CHECK(n_out_ < kMaxOut, op_, ": more than ", kMaxOut, " outputs");
    at::Tensor t = empty(shape, at::TensorOptions().dtype(dtype_).device(device_));
    const int k = n_out_++;
    batch_.out[k] = t.data_ptr();
    batch_.out_stride[k] = numel(trailing);
    return t;
  }

  template <template <class, class, int> class Op> void run() {
    if (n_ == 0) return;
    if (dtype_ == at::kDouble) {
      run_scalar<Op, double>();
    } else {
      run_scalar<Op, float>();
    }
  }

 private:
  template <template <class, class, int> class Op, class S> void run_scalar() {
    // A fixed base has nothing to convert: both conventions share the Pinocchio kernel.
    if (convention_ == MJX && Robot::FLOATING) {
#ifdef TG_WITH_MJX
      run_device<Op, S, MJX>();
#else
      TORCH_CHECK(false, op_, ": this build has no MuJoCo-convention kernels (enable_mujoco_kernels=False)");
#endif
    } else {
      run_device<Op, S, PIN>();
    }
  }

  template <template <class, class, int> class Op, class S, int C> void run_device() {
    if (device_.is_cuda()) {
#ifdef TG_WITH_CUDA
      const c10::cuda::CUDAGuard guard(device_);
      const int err = cuda_launch<Op, Robot, S, C>(batch_, c10::cuda::getCurrentCUDAStream().stream());
      TORCH_CHECK(err == 0, op_, ": CUDA kernel launch failed: ", cudaGetErrorString(static_cast<cudaError_t>(err)));
#else
      TORCH_CHECK(false, op_, ": this robot was built without CUDA kernels (no GPU or nvcc at build time)");
#endif
      return;
    }
    const Batch& b = batch_;
    at::parallel_for(0, n_, 16, [&b](int64_t begin, int64_t end) { cpu_range<Op, Robot, S, C>(b, begin, end); });
  }

  // A CPU output above glibc's largest mmap threshold (32 MiB) is mapped afresh on every call and
  // costs one page fault per 4 KiB on first touch, more than computing it for big robots: back it
  // with transparent huge pages instead. Smaller outputs reuse the heap without faults.
  static at::Tensor empty(const std::vector<int64_t>& shape, const at::TensorOptions& options) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    constexpr size_t kHuge = size_t(2) << 20, kMmapMax = size_t(32) << 20;
    const size_t bytes = static_cast<size_t>(numel(shape)) * options.dtype().itemsize();
    void* data = nullptr;
    if (options.device().is_cpu() && bytes > kMmapMax) {
      const size_t size = (bytes + kHuge - 1) / kHuge * kHuge;
      if (posix_memalign(&data, kHuge, size) == 0) {
        madvise(data, size, MADV_HUGEPAGE);
        return at::from_blob(data, shape, [](void* p) { std::free(p); }, options);
      }
    }
#endif
    return at::empty(shape, options);
  }

  void push_int(int64_t v) {
    TORCH_CHECK(batch_.n_iargs < TG_MAX_IARGS, op_, ": too many integer arguments (at most ", TG_MAX_IARGS, ")");
    batch_.iargs[batch_.n_iargs++] = static_cast<int>(v);
  }
  static int64_t numel(const std::vector<int64_t>& shape) {
    int64_t n = 1;
    for (auto s : shape) n *= s;
    return n;
  }

  const char* op_;
  int64_t convention_;
  std::vector<int64_t> batch_shape_;
  at::ScalarType dtype_;
  at::Device device_ = at::kCPU;
  int64_t n_ = 0;
  int n_in_ = 0, n_out_ = 0;
  std::vector<at::Tensor> keep_;  // contiguous copies outlive the launch
  Batch batch_;
};

}  // namespace tg
