// CPU output memory kept for reuse (large outputs of the torch glue): glibc would map a large block
// afresh, or trim it from the heap's top, on every call, and the kernel zero its pages again.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <mutex>
#include <utility>
#include <vector>
#if defined(__linux__)
#include <sys/mman.h>
#include <unistd.h>
#endif

namespace tg {

#if defined(__linux__) && defined(MADV_HUGEPAGE)
// Blocks of large CPU outputs. A freed block is kept (up to keep() bytes in all, for the life of the
// process, or until release()) and handed to the next output of its size, already mapped: a loop
// calling an op on the same batch pays the page faults once. The blocks kept longest make room for
// a newer one, so sizes no longer in use do not fill the cache. Blocks from 2 MiB are backed by
// transparent huge pages.
struct LargeBlocks {
  static constexpr size_t kMin = size_t(128) << 10, kPage = size_t(4) << 10, kHuge = size_t(2) << 20;
  // At most this many blocks: a loop over ever new batch sizes would otherwise keep thousands of small
  // blocks that are never reused, each searched on every output.
  static constexpr size_t kMaxBlocks = 256;
  static size_t rounded(size_t bytes) {
    const size_t unit = bytes < kHuge ? kPage : kHuge;
    return (bytes + unit - 1) / unit * unit;
  }
  // TORCH_GRID_KEEP_MB, or a quarter of the machine's memory and at least 1 GiB: G1's four
  // second-order tensors at B = 4096 are 5.6 GB, which the kernel would otherwise zero afresh on
  // every call (2x the call's time).
  static size_t keep() {
    static const size_t bytes = [] {
      const char* env = std::getenv("TORCH_GRID_KEEP_MB");
      if (env && *env) return static_cast<size_t>(std::atoll(env)) << 20;
      const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
      const size_t quarter = pages > 0 && page > 0 ? static_cast<size_t>(pages) * static_cast<size_t>(page) / 4 : 0;
      return std::max(quarter, size_t(1) << 30);
    }();
    return bytes;
  }
  static void* take(size_t size) {
    {
      std::lock_guard<std::mutex> lock(state().mutex);
      auto& kept = state().kept;
      for (size_t k = 0; k < kept.size(); ++k)
        if (kept[k].second == size) {
          void* p = kept[k].first;
          kept.erase(kept.begin() + static_cast<std::ptrdiff_t>(k));
          state().bytes -= size;
          return p;
        }
    }
    void* p = nullptr;
    if (posix_memalign(&p, size < kHuge ? kPage : kHuge, size) != 0) return nullptr;
    if (size >= kHuge) madvise(p, size, MADV_HUGEPAGE);
    return p;
  }
  static void give(void* p, size_t size) {
    std::vector<void*> evicted;
    if (size <= keep()) {
      std::lock_guard<std::mutex> lock(state().mutex);
      auto& kept = state().kept;
      size_t n = 0;  // the oldest blocks that make room
      while (state().bytes + size > keep() || kept.size() - n >= kMaxBlocks) {
        evicted.push_back(kept[n].first);
        state().bytes -= kept[n++].second;
      }
      kept.erase(kept.begin(), kept.begin() + static_cast<std::ptrdiff_t>(n));
      kept.emplace_back(p, size);
      state().bytes += size;
      p = nullptr;
    }
    for (void* e : evicted) std::free(e);
    std::free(p);
  }
  // Frees every kept block; returns their bytes.
  static int64_t release() {
    std::vector<std::pair<void*, size_t>> kept;
    {
      std::lock_guard<std::mutex> lock(state().mutex);
      kept.swap(state().kept);
      state().bytes = 0;
    }
    int64_t bytes = 0;
    for (auto& block : kept) {
      std::free(block.first);
      bytes += static_cast<int64_t>(block.second);
    }
    return bytes;
  }

 private:
  struct State {
    std::mutex mutex;
    std::vector<std::pair<void*, size_t>> kept;
    size_t bytes = 0;
  };
  // Never destroyed: a tensor freed during interpreter shutdown still finds it.
  static State& state() {
    static State* s = new State;
    return *s;
  }
};
#endif

// Frees the CPU output blocks kept for reuse; returns their bytes (torch_grid.empty_cache()).
inline int64_t release_kept_blocks() {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  return LargeBlocks::release();
#else
  return 0;
#endif
}

}  // namespace tg
