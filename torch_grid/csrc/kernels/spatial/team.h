// A team: the threads that run one sample together. An algorithm written for a team (a kernel's run_team,
// kernels/dynamics/minv.h) is one source for three machines:
//   - Solo, one thread alone (a CPU thread, or a GPU thread that runs a whole sample): items() is a plain loop
//     and sync() nothing, so the team algorithm is the serial one, in its order of operations;
//   - the 32 lanes of a GPU warp (batch/cuda_launch.cuh), the workspace in the block's shared memory;
//   - 32 CPU threads under ThreadSanitizer (tests/team_harness.cpp), which proves the syncs.
// The rules a team algorithm keeps:
//   - between syncs, each entry of the shared workspace and of the outputs is written by one lane only, and read
//     by other lanes only after a sync: items(b, e) gives this lane the indices j in [b, e) with j = lane (mod
//     lanes), so an entry indexed by j (a column) stays with one lane from one loop to the next, and needs no sync;
//   - code outside items() and leader() runs on every lane alike (uniform): it reads the workspace and keeps
//     what it computes in its own variables, never writes the workspace.
#pragma once

#include <type_traits>

#include "kernels/spatial/spatial.h"

namespace tg {

// The indices j in [b, e) with j = first (mod step), ascending; or descending (reverse), which the CPU build of a
// GPU thread's paths takes (TG_DEVICE_PATH), so that an algorithm whose items depend on one another within a loop
// differs from the CPU's own build, and tests/test_device_paths.py shows it.
struct TeamItems {
  int b, e, first, step;
  bool reverse;
  struct It {
    int j, step;
    TG_HD int operator*() const { return j; }
    TG_HD It& operator++() {
      j += step;
      return *this;
    }
    TG_HD bool operator!=(const It& end) const { return step > 0 ? j < end.j : j > end.j; }
  };
  TG_HD It begin() const {
    if (!reverse) return {first, step};
    const int last = first + (e - 1 - first) / step * step;  // the largest of them (first < e)
    return {first < e ? last : b - 1, -step};
  }
  TG_HD It end() const { return {reverse ? b - 1 : e, step}; }
};

// The first index at or after b that lane `lane` of `lanes` owns.
TG_HD int team_first(int b, int lane, int lanes) { return b + ((lane - b) % lanes + lanes) % lanes; }

// One thread running a whole sample.
struct Solo {
  static constexpr int lanes = 1;
  TG_HD int lane() const { return 0; }
  TG_HD bool leader() const { return true; }
  TG_HD void sync() const {}
  TG_HD TeamItems items(int b, int e) const { return {b, e, b, 1, TG_DEVICE_PATH != 0}; }
};

// An op kernel with a team path declares TeamWork, its shared workspace, and run_team(team, work, args); the
// generated bindings forward both (NoTeam where the kernel has none).
struct NoTeam {};
template <class K, class = void> struct TeamWorkOf { using type = NoTeam; };
template <class K> struct TeamWorkOf<K, std::void_t<typename K::TeamWork>> { using type = typename K::TeamWork; };
template <class Op> constexpr bool has_team = !std::is_same_v<typename TeamWorkOf<Op>::type, NoTeam>;

}  // namespace tg
