// Torch glue shared by every generated op wrapper and every robot: checks the arguments, allocates
// the outputs, and runs one op of a robot library (batch.h's RobotTable) over the batch, on the
// CPU (at::parallel_for) or on CUDA (current stream). Robot sizes are read from the table at run
// time, so this compiles once per torch version and serves every robot.
#pragma once

#include <ATen/Context.h>
#include <ATen/Parallel.h>
#include <ATen/core/Tensor.h>
#include <ATen/ops/baddbmm.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/from_blob.h>
#include <c10/core/impl/LocalDispatchKeySet.h>
#include <torch/library.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <cstring>
#include <limits>
#if defined(__linux__)
#include <sys/mman.h>
#include <unistd.h>
#endif
#if defined(__x86_64__)
#include <emmintrin.h>
#endif

#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "batch/batch.h"
#include "torch/blocks.h"
#ifdef TG_WITH_CUDA
#include "torch/cuda_device.h"
#endif

#ifdef TG_WITH_CUDA
#include <c10/cuda/CUDACachingAllocator.h>
#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>
#include <cuda_runtime_api.h>
#endif

namespace tg {

// Whether CPU ops run on vector lanes where the robot library has lane kernels (the default), or every
// sample on the scalar kernel (torch_grid.set_cpu_lanes): the two compute the same values.
inline std::atomic<bool>& cpu_lanes_enabled() {
  static std::atomic<bool> on{true};
  return on;
}
inline bool set_cpu_lanes(bool on) { return cpu_lanes_enabled().exchange(on); }

class Call {
 public:
  // `q` fixes the dtype and device every other argument must share; `kernels` are the op's, of which the
  // call runs the one of that dtype, device and convention.
  Call(const RobotTable& robot, const OpKernels& kernels, const char* op, const at::Tensor& q, int64_t convention)
      : robot_(robot), kernels_(kernels), op_(op), convention_(convention) {
    dtype_ = q.scalar_type();
    device_ = q.device();
    TORCH_CHECK(dtype_ == at::kFloat || dtype_ == at::kDouble, op_, ": q must be float32 or float64, got ", dtype_);
    TORCH_CHECK(device_.is_cpu() || device_.is_cuda(), op_, ": q must be on the CPU or a CUDA device, got ", device_);
    TORCH_CHECK(convention == PIN || convention == MUJOCO, op_, ": convention must be 0 (pin) or 1 (mujoco), got ", convention);
#ifdef TG_WITH_CUDA
    if (device_.is_cuda()) prepare_first_launch();
#endif
  }

  // First, every tensor input's shape (*batch, *trailing): the batch shapes broadcast, as in torch.
  void batch_of(const at::Tensor& t, const char* name, std::initializer_list<int64_t> trailing) {
    const int64_t nt = static_cast<int64_t>(trailing.size()), nb = t.dim() - nt;
    bool ok = nb >= 0;
    int64_t d = nb;
    for (int64_t s : trailing) ok = ok && t.size(d++) == s;
    if (!ok) {
      std::string want = "(...";
      for (int64_t s : trailing) want += ", " + std::to_string(s);
      TORCH_CHECK(false, op_, ": ", name, " must have shape ", want, "), got ", t.sizes());
    }
    const at::IntArrayRef batch = t.sizes().slice(0, nb);
    if (!have_batch_) {
      batch_shape_.assign(batch.begin(), batch.end());
      have_batch_ = true;
    } else if (batch != at::IntArrayRef(batch_shape_)) {
      const int64_t n = std::max<int64_t>(nb, batch_shape_.size());
      std::vector<int64_t> out(n, 1);
      for (int64_t k = 0; k < n; ++k) {
        const int64_t a = k - (n - nb), b = k - (n - static_cast<int64_t>(batch_shape_.size()));
        const int64_t sa = a >= 0 ? batch[a] : 1, sb = b >= 0 ? batch_shape_[b] : 1;
        TORCH_CHECK(sa == sb || sa == 1 || sb == 1, op_, ": the batch shape of ", name, ", ", batch,
                    ", does not broadcast with ", at::IntArrayRef(batch_shape_));
        out[k] = sa == 1 ? sb : sa;
      }
      batch_shape_ = std::move(out);
    }
  }
  void batch_of(const std::optional<at::Tensor>& t, const char* name, std::initializer_list<int64_t> trailing) {
    if (t.has_value()) batch_of(*t, name, trailing);
  }

  // Then each tensor input, in order: one of the broadcast batch shape is read in place (or from a
  // contiguous copy); one whole sample shared by the batch is read with stride 0; any other is
  // expanded into a copy.
  void input(const at::Tensor& t, const char* name, std::initializer_list<int64_t> trailing) {
    TORCH_CHECK(t.scalar_type() == dtype_, op_, ": ", name, " must have dtype ", dtype_, " like q, got ", t.scalar_type());
    TORCH_CHECK(t.device() == device_, op_, ": ", name, " must be on ", device_, " like q, got ", t.device());
    TORCH_CHECK(n_in_ < kMaxIn, op_, ": more than ", kMaxIn, " tensor inputs");
    if (n_in_ == 0) {
      n_ = numel(batch_shape_);
      batch_.n = n_;
    }
    const int k = n_in_++;
    const int64_t stride = numel(trailing), nb = t.dim() - static_cast<int64_t>(trailing.size());
    const at::IntArrayRef batch = t.sizes().slice(0, nb);
    at::Tensor x = t;
    if (batch != at::IntArrayRef(batch_shape_) && numel(batch) != 1) {
      std::vector<int64_t> full = batch_shape_;
      full.insert(full.end(), trailing.begin(), trailing.end());
      x = t.expand(full);
    }
    if (!x.is_contiguous()) x = x.contiguous();
    if (!x.is_same(t)) keep_[k] = x;  // a copy outlives the launch
    batch_.in[k] = x.data_ptr();
    batch_.in_stride[k] = numel(batch) == 1 && n_ != 1 ? 0 : stride;
    batch_.in_size[k] = stride;
    in_size_[k] = stride;
  }
  void input(const std::optional<at::Tensor>& t, const char* name, std::initializer_list<int64_t> trailing) {
    if (t.has_value()) {
      input(*t, name, trailing);
    } else {
      TORCH_CHECK(n_in_ < kMaxIn, op_, ": more than ", kMaxIn, " tensor inputs");
      batch_.in[n_in_++] = nullptr;
    }
  }

  // Integer arguments: frame indices checked against the robot's frames.
  void frame(int64_t f, const char* name) {
    TORCH_CHECK(f >= 0 && f < robot_.nf, op_, ": ", name, " must be a frame index in [0, ", robot_.nf, "), got ", f);
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
  void scheme(int64_t s, const char* name) {
    TORCH_CHECK(s == 0 || s == 1, op_, ": ", name, " must be 0 (euler) or 1 (semi-implicit euler), got ", s);
    push_int(s);
  }
  void integrator(int64_t s, const char* name) {
    TORCH_CHECK(s >= 0 && s <= 4, op_, ": ", name, " must be 0 (euler), 1 (semi-implicit euler), 2 (midpoint), 3 (rk3) or "
                "4 (rk4), got ", s);
    push_int(s);
  }
  void tableau(int64_t s, const char* name) {
    TORCH_CHECK(s >= 2 && s <= 4, op_, ": ", name, " must be 2 (midpoint), 3 (rk3) or 4 (rk4), got ", s);
    push_int(s);
  }
  void passive(int64_t p, const char* name) {
    TORCH_CHECK(p >= 0 && p <= 2, op_, ": ", name, " must be 0 (none), 1 (explicit) or 2 (damping implicit in the "
                "Euler step), got ", p);
    push_int(p);
  }
  // The inputs a backward op differentiates: bit i for the i-th of its n differentiable inputs.
  void mask(int64_t m, const char* name, int n) {
    TORCH_CHECK(m >= 0 && m < (int64_t(1) << n), op_, ": ", name, " must be a bit mask of ", n, " inputs, got ", m);
    push_int(m);
  }

  // A new output of shape (*batch, *trailing).
  at::Tensor output(std::initializer_list<int64_t> trailing) {
    std::vector<int64_t> shape = batch_shape_;
    shape.insert(shape.end(), trailing.begin(), trailing.end());
    TORCH_CHECK(n_out_ < kMaxOut, op_, ": more than ", kMaxOut, " outputs");
    at::Tensor t = empty(shape, at::TensorOptions().dtype(dtype_).device(device_));
    if (poisoned()) t.fill_(std::numeric_limits<double>::quiet_NaN());
    const int k = n_out_++;
    batch_.out[k] = t.data_ptr();
    batch_.out_stride[k] = numel(trailing);
    return t;
  }

  // TORCH_GRID_POISON_OUTPUTS=1 (a test of the kernels): every output starts as NaN, never as zeros or
  // an earlier call's values, so an entry a kernel leaves unwritten shows; workspaces start zeroed, as
  // their kernels expect.
  static bool poisoned() {
    static const bool on = [] {
      const char* env = std::getenv("TORCH_GRID_POISON_OUTPUTS");
      return env && *env && std::strcmp(env, "0") != 0;
    }();
    return on;
  }
  // The buffer slots of d's outputs for n samples set to NaN (workspaces to zero), when poisoned.
  void poison_slots(const Batch& d, int64_t n) const {
    if (!poisoned()) return;
    for (int k = 0; k < n_out_; ++k)
      if (batch_.out[k])
        std::fill_n(static_cast<double*>(d.out[k]), batch_.out_stride[k] * n,
                    workspace_ >> k & 1 ? 0.0 : std::numeric_limits<double>::quiet_NaN());
  }

  // The kernel's scratch of shape (*trailing) per sample: on CUDA a new output like any other; on the
  // CPU each thread's block of the streamed buffer, never copied out (the tensor returned is one block
  // expanded over the batch). It starts zeroed: the Runge-Kutta step reads entries of its workspace that
  // it never writes as zeros (the streamed buffer is zeroed once and keeps its layout; as_double's is
  // zeroed again for each chunk, whose layout moves).
  at::Tensor workspace(std::initializer_list<int64_t> trailing) {
    if (device_.is_cuda()) {
      workspace_ |= 1 << n_out_;
      return output(trailing).zero_();
    }
    std::vector<int64_t> shape = batch_shape_;
    shape.insert(shape.end(), trailing.begin(), trailing.end());
    TORCH_CHECK(n_out_ < kMaxOut, op_, ": more than ", kMaxOut, " outputs");
    at::Tensor t = at::empty(std::vector<int64_t>(trailing), at::TensorOptions().dtype(dtype_).device(device_));
    const int k = n_out_++;
    workspace_ |= 1 << k;
    batch_.workspace = workspace_;
    batch_.out[k] = t.data_ptr();
    batch_.out_stride[k] = numel(trailing);
    return t.expand(shape);
  }

  void run() {
    const OpKernels& kernels = kernels_;
    if (n_ == 0) return;
    batch_.poisoned = poisoned();
    const int s = dtype_ == at::kDouble ? 1 : 0;
    // Without a quaternion joint there is nothing to convert: both conventions share the Pinocchio kernel.
    const int c = convention_ == MUJOCO && robot_.converts ? 1 : 0;
    TORCH_CHECK(!c || robot_.mujoco, op_, ": this build has no MuJoCo-convention kernels (enable_mujoco_kernels=False)");
    TORCH_CHECK(!c || kernels.cpu[1][1], op_, " has no MuJoCo-convention kernel for a robot with free or ball joints "
                "(not implemented); call it in the pin convention");
    if (device_.is_cuda()) {
#ifdef TG_WITH_CUDA
      TORCH_CHECK(robot_.cuda && kernels.cuda[s][c], op_,
                  ": this robot was built without CUDA kernels (no GPU or nvcc when it was built)");
      launch(kernels.cuda[s][c]);
#else
      TORCH_CHECK(false, op_, ": torch_grid's glue was built without CUDA (no GPU or nvcc when it was built)");
#endif
      return;
    }
    // The scalar CPU kernels are double: a float32 batch of at least one group of float lanes runs on
    // them, straight from its tensors; a smaller one goes through the double kernels (as_double). Float64
    // outputs too large for the cache are streamed. Lane kernels take groups of lanes_ samples.
    const bool on = robot_.lanes > 1 && cpu_lanes_enabled().load(std::memory_order_relaxed);
    const bool float_lanes = s == 0 && on && kernels.lanes[0][c] && n_ >= 2 * robot_.lanes;
    const bool lanes = float_lanes || (on && kernels.lanes[1][c]);
    const CpuFn fn = float_lanes ? kernels.lanes[0][c] : lanes ? kernels.lanes[1][c] : kernels.cpu[1][c];
    lanes_ = float_lanes ? 2 * robot_.lanes : lanes ? robot_.lanes : 1;
    const auto range = float_lanes ? &Call::direct
                       : s == 0    ? &Call::as_double
                       : workspace_ || n_ * out_per_sample() * int64_t(sizeof(double)) > kStreamBytes ? &Call::streamed
                                                                                                      : &Call::direct;
    // As many threads as get kernels.grain samples each, the least work worth waking one for (ops/table.py: cpu_grain).
    const int64_t threads = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), n_ / kernels.grain));
    // Several pieces a thread, none under an eighth of the grain, each a whole number of lane groups.
    Pieces pieces(n_, threads == 1 ? n_ : whole_groups(std::max((n_ + 8 * threads - 1) / (8 * threads), kernels.grain / 8)));
    at::parallel_for(0, threads, 1, [this, fn, range, &pieces](int64_t, int64_t) { (this->*range)(fn, pieces); });
  }

  // On a device path the kernel leaves each X of a negated product (ops/table.py: negated_products) as it is
  // before its last step, X <- -F X, done here as one batched matrix product: on a GPU, in the matrix library's
  // coalesced blocks rather than in each thread's local memory. The op's dtype is its own: autocast, which
  // sees this product inside the op, is off for it. A float32 product runs in float64 wherever torch lets
  // float32 matrix products take TF32 (torch.backends.cuda.matmul.allow_tf32, or flags torch cannot read),
  // whose 10-bit mantissas the op's float32 results do not have.
  void negated_products(const at::Tensor& f, std::initializer_list<at::Tensor*> xs) const {
    if (n_ == 0 || !(device_.is_cuda() || robot_.device_paths)) return;
    const c10::impl::ExcludeDispatchKeyGuard no_autocast(c10::autocast_dispatch_keyset);
    bool widen = false;
    if (dtype_ == at::kFloat && device_.is_cuda()) {
      try {
        widen = at::globalContext().allowTF32CuBLAS();
      } catch (const c10::Error&) {  // TF32 flags set through both of torch's interfaces, in disagreement
        widen = true;
      }
    }
    const int64_t nv = robot_.nv;
    const at::Tensor m = (widen ? f.to(at::kDouble) : f).reshape({n_, nv, nv});
    for (at::Tensor* x : xs) {
      const at::Tensor x3 = (widen ? x->to(at::kDouble) : *x).reshape({n_, nv, nv});
      const at::Tensor p = at::baddbmm(x3, m, x3, /*beta=*/0, /*alpha=*/-1).view(x->sizes());  // beta 0: x3 only shapes it
      *x = widen ? p.to(at::kFloat) : p;
    }
  }

 private:
#ifdef TG_WITH_CUDA
  // The kernel of this call's dtype and convention on CUDA (null where the build has none: run refuses it).
  CudaFn cuda_kernel() const {
    const int s = dtype_ == at::kDouble ? 1 : 0, c = convention_ == MUJOCO && robot_.converts ? 1 : 0;
    return robot_.cuda ? kernels_.cuda[s][c] : nullptr;
  }
  // Before a kernel's first launch on a device, its local memory (stack) is checked against what the
  // device would reserve for it: every resident thread gets that much, for the life of the process. The
  // driver grows the device's local memory at that launch (G1's largest kernel: about 16 GB); memory
  // torch's caching allocator holds is invisible to it. So where the device lacks the reservation, torch's
  // cache is emptied before the call copies an input or takes its outputs, which would otherwise be cut
  // from cached blocks that then could not be freed; a launch that still fails for want of memory is
  // retried once after emptying the cache again. That first launch may not be captured in a CUDA graph
  // (a capture records no growth, and the device's properties and the kernel's attributes are read then).
  void prepare_first_launch() {
    const CudaFn fn = cuda_kernel();
    if (!fn || cuda_launched(fn, device_.index())) return;
    first_ = true;
    const c10::cuda::CUDAGuard guard(device_);
    const cudaStream_t stream = c10::cuda::getCurrentCUDAStream().stream();
    cudaStreamCaptureStatus capture = cudaStreamCaptureStatusNone;
    const cudaError_t err = cudaStreamIsCapturing(stream, &capture);
    TORCH_CHECK(err == cudaSuccess, op_, ": cannot query the stream's capture status: ", cudaGetErrorString(err));
    TORCH_CHECK(capture == cudaStreamCaptureStatusNone, op_, ": the first launch of this kernel on ", device_,
                " cannot be captured in a CUDA graph (it grows the device's local memory): call the op once, "
                "outside the capture, before capturing it");
    const CudaDevice d = cuda_device(device_.index(), op_);
    const CudaAttributes a = cuda_attributes(fn, op_);
    constexpr int64_t kPerThreadLimit = int64_t(512) << 10;  // the hardware's local memory per thread
    const int64_t resident = int64_t(d.threads_per_sm) * d.sms;
    const int64_t budget = cuda_local_budget(d);
    reserve_ = a.local_bytes * resident;
    // numbers as text: the message is built from strings alone
    TORCH_CHECK(a.local_bytes <= kPerThreadLimit, op_, ": this robot's kernel needs ", std::to_string(a.local_bytes),
                " bytes of local memory per CUDA thread, above the device's limit of ", std::to_string(kPerThreadLimit));
    TORCH_CHECK(reserve_ <= budget, op_, ": this robot's kernel needs ", std::to_string(a.local_bytes),
                " bytes of local memory per CUDA thread; for ", std::to_string(resident),
                " resident threads the device would reserve ", std::to_string(reserve_ >> 20), " MiB, above the budget of ",
                std::to_string(budget >> 20), " MiB (TORCH_GRID_CUDA_LOCAL_MEMORY_MB; default a quarter of the device memory)");
    size_t free = 0, total = 0;
    if (cudaMemGetInfo(&free, &total) == cudaSuccess && static_cast<int64_t>(free) < reserve_)
      c10::cuda::CUDACachingAllocator::emptyCache();
  }
  void launch(CudaFn fn) {
    const c10::cuda::CUDAGuard guard(device_);
    const cudaStream_t stream = c10::cuda::getCurrentCUDAStream().stream();
    const CudaDevice d = cuda_device(device_.index(), op_);
    int err = fn(batch_, stream, d.sms, nullptr);
    if (first_ && err == cudaErrorMemoryAllocation) {
      c10::cuda::CUDACachingAllocator::emptyCache();
      err = fn(batch_, stream, d.sms, nullptr);
      size_t free = 0, total = 0;
      if (err == cudaErrorMemoryAllocation && cudaMemGetInfo(&free, &total) == cudaSuccess)
        TORCH_CHECK(false, op_, ": CUDA kernel launch failed: out of memory at its first launch, which reserves ",
                    std::to_string(reserve_ >> 20), " MiB of local memory; ", std::to_string(free >> 20),
                    " MiB are free after emptying torch's cache");
    }
    TORCH_CHECK(err == 0, op_, ": CUDA kernel launch failed: ", cudaGetErrorString(static_cast<cudaError_t>(err)));
    if (first_) cuda_mark_launched(fn, device_.index());
  }
#endif

  // glibc maps a block above its mmap threshold afresh, or trims a freed one at the top of the heap,
  // and the kernel then zeroes each page on first touch: about 1 µs per sample for G1's M at
  // B = 4096, 10-25 % of crba or minv, and 8x the time of inverse_dynamics_second_derivatives on G1 at
  // B = 4 (four 1.4 MB outputs, trimmed after every call). CPU outputs above glibc's first
  // threshold, 128 KiB, come from LargeBlocks instead, kept for the next output of the same size.
  static at::Tensor empty(const std::vector<int64_t>& shape, const at::TensorOptions& options) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    const size_t bytes = static_cast<size_t>(numel(shape)) * options.dtype().itemsize();
    if (options.device().is_cpu() && bytes > LargeBlocks::kMin) {
      const size_t size = LargeBlocks::rounded(bytes);
      if (void* data = LargeBlocks::take(size))
        return at::from_blob(data, shape, [size](void* p) { LargeBlocks::give(p, size); }, options);
    }
#endif
    return at::empty(shape, options);
  }

  // Outputs of a float64 batch above this many bytes are written around the cache (streamed).
  static constexpr int64_t kStreamBytes = int64_t(8) << 20;

  int64_t out_per_sample() const {
    int64_t n = 0;
    for (int k = 0; k < n_out_; ++k) n += batch_.out[k] ? batch_.out_stride[k] : 0;
    return n;
  }

  // d's outputs for n samples, laid out in a buffer from `next`; returns the end of them.
  double* output_slots(Batch& d, double* next, int64_t n) const {
    for (int k = 0; k < n_out_; ++k)
      if (batch_.out[k]) {
        d.out[k] = next;
        next += batch_.out_stride[k] * n;
      }
    return next;
  }

  // n samples rounded up to whole groups of lanes: a chunk of the buffered paths is never split into
  // a group and a scalar rest.
  int64_t whole_groups(int64_t n) const { return (n + lanes_ - 1) / lanes_ * lanes_; }

  // The batch [0, n) handed out in pieces to whichever thread asks next, rather than in equal shares: a
  // thread on a slower core (a hyperthread whose sibling is busy, an efficiency core, a virtual CPU
  // its host is sharing) takes fewer pieces, so a call lasts the work's time over the threads' summed
  // speed, not the slowest thread's share. A thread the runtime does not start (parallel_for nested in
  // a parallel region runs serially) leaves its pieces to the others.
  class Pieces {
   public:
    Pieces(int64_t n, int64_t piece) : n_(n), piece_(piece) {}
    // The next piece [begin, end); false once the batch is handed out.
    bool claim(int64_t& begin, int64_t& end) {
      begin = next_.fetch_add(piece_, std::memory_order_relaxed);
      end = std::min(n_, begin + piece_);
      return begin < n_;
    }

   private:
    std::atomic<int64_t> next_{0};
    const int64_t n_, piece_;
  };

  // The pieces a thread claims, straight into the outputs.
  void direct(CpuFn fn, Pieces& pieces) const {
    for (int64_t begin, end; pieces.claim(begin, end);) fn(batch_, begin, end);
  }

  // The pieces of a batch whose outputs exceed what a core keeps in cache (go2's M at B = 4096:
  // 10.6 MB): a few samples at a time into a buffer that stays in L1, then copied to the outputs with
  // non-temporal stores, which skip reading in the lines about to be overwritten (G1 crba 3.6 -> 2.9 µs
  // per sample at B = 4096). The buffer starts zeroed and keeps its layout, so a kernel that writes a
  // fixed pattern leaves zeros elsewhere (G1's second-order tensors: 1.4 MB a sample, a quarter of it
  // written, 13 µs to zero).
  void streamed(CpuFn fn, Pieces& pieces) const {
    const int64_t per_sample = out_per_sample();
    const int64_t chunk = whole_groups(std::max<int64_t>(1, std::min<int64_t>(16, (int64_t(4) << 10) / per_sample)));
    std::vector<double> buffer(static_cast<size_t>(per_sample * chunk));
    Batch d = batch_;
    d.zeroed = !poisoned();
    output_slots(d, buffer.data(), chunk);
    for (int64_t begin, end; pieces.claim(begin, end);) {
      for (int64_t s0 = begin; s0 < end; s0 += chunk) {
        const int64_t n = std::min(chunk, end - s0);
        d.n = n;
        poison_slots(d, n);
        for (int k = 0; k < n_in_; ++k)
          if (batch_.in[k]) d.in[k] = static_cast<const double*>(batch_.in[k]) + s0 * batch_.in_stride[k];
        fn(d, 0, n);
        for (int k = 0; k < n_out_; ++k)
          if (batch_.out[k] && !(workspace_ >> k & 1))
            stream_copy(static_cast<double*>(batch_.out[k]) + batch_.out_stride[k] * s0,
                        static_cast<const double*>(d.out[k]), batch_.out_stride[k] * n);
      }
    }
#if defined(__x86_64__)
    _mm_sfence();  // streamed stores are weakly ordered: complete them before the batch returns
#endif
  }

  // dst[0, n) <- src with non-temporal stores where the CPU has them.
  static void stream_copy(double* dst, const double* src, int64_t n) {
#if defined(__x86_64__)
    int64_t m = 0;
    long long bits;
    for (; m < n && (reinterpret_cast<uintptr_t>(dst + m) & 15); ++m) {
      std::memcpy(&bits, src + m, 8);
      _mm_stream_si64(reinterpret_cast<long long*>(dst + m), bits);
    }
    for (; m + 2 <= n; m += 2) _mm_stream_pd(dst + m, _mm_loadu_pd(src + m));
    for (; m < n; ++m) {
      std::memcpy(&bits, src + m, 8);
      _mm_stream_si64(reinterpret_cast<long long*>(dst + m), bits);
    }
#else
    std::memcpy(dst, src, static_cast<size_t>(n) * sizeof(double));
#endif
  }

  // The pieces of a float32 batch through a float64 kernel, a chunk at a time: the chunk's inputs
  // widened into a buffer that stays in cache, its outputs rounded back into place. On the CPU, double
  // arithmetic costs about what float does, so this adds only the conversions.
  void as_double(CpuFn fn, Pieces& pieces) const {
    int64_t per_sample = out_per_sample();
    for (int k = 0; k < n_in_; ++k) per_sample += batch_.in[k] ? in_size_[k] : 0;
    const int64_t chunk =
        whole_groups(std::max<int64_t>(1, std::min<int64_t>(64, (int64_t(32) << 10) / std::max<int64_t>(per_sample, 1))));
    std::vector<double> buffer(static_cast<size_t>(per_sample * chunk));
    Batch d = batch_;
    bool fresh = true;  // the buffer as allocated: zeroed
    for (int64_t begin, end; pieces.claim(begin, end);) {
      for (int64_t s0 = begin; s0 < end; s0 += chunk) {
        const int64_t n = std::min(chunk, end - s0);
        double* next = buffer.data();
        if (workspace_ && !fresh) std::fill(buffer.begin(), buffer.end(), 0.0);  // see workspace()
        fresh = false;
        d.n = n;
        for (int k = 0; k < n_in_; ++k) {
          if (!batch_.in[k]) continue;
          const float* x = static_cast<const float*>(batch_.in[k]);
          const int64_t size = in_size_[k], stride = batch_.in_stride[k], samples = stride ? n : 1;
          for (int64_t j = 0; j < samples; ++j)
            for (int64_t m = 0; m < size; ++m) next[size * j + m] = x[stride * (s0 + j) + m];
          d.in[k] = next;
          d.in_stride[k] = stride ? size : 0;
          next += size * samples;
        }
        output_slots(d, next, n);
        poison_slots(d, n);
        fn(d, 0, n);
        for (int k = 0; k < n_out_; ++k) {
          if (!batch_.out[k] || workspace_ >> k & 1) continue;
          const int64_t size = batch_.out_stride[k];
          const double* y = static_cast<const double*>(d.out[k]);
          float* x = static_cast<float*>(batch_.out[k]) + size * s0;
          for (int64_t m = 0; m < size * n; ++m) x[m] = static_cast<float>(y[m]);
        }
      }
    }
  }

  void push_int(int64_t v) {
    TORCH_CHECK(batch_.n_iargs < kMaxIargs, op_, ": too many integer arguments (at most ", kMaxIargs, ")");
    batch_.iargs[batch_.n_iargs++] = static_cast<int>(v);
  }
  template <class Shape> static int64_t numel(const Shape& shape) {
    int64_t n = 1;
    for (auto s : shape) n *= s;
    return n;
  }

  const RobotTable& robot_;
  const OpKernels& kernels_;
  const char* op_;
  int64_t convention_;
  std::vector<int64_t> batch_shape_;
  at::ScalarType dtype_;
  at::Device device_ = at::kCPU;
  bool have_batch_ = false;
  int64_t n_ = 0;
  int n_in_ = 0, n_out_ = 0;
  int workspace_ = 0;  // bit k: output k is a workspace
  int64_t lanes_ = 1;  // samples per group of the kernel run (1: the scalar kernel)
  at::Tensor keep_[kMaxIn];  // contiguous copies
  int64_t in_size_[kMaxIn] = {};  // elements of one sample of each input
  Batch batch_;
#ifdef TG_WITH_CUDA
  bool first_ = false;   // this call launches its CUDA kernel for the first time on the device
  int64_t reserve_ = 0;  // bytes of local memory the driver reserves at that launch
#endif
};

}  // namespace tg
