// Dense row-major matrix products with register blocking, for the NV x NV by NV x k products of the
// derivative kernels (forward_dynamics_derivatives's -M^-1 dtau/dx, the Runge-Kutta chain rule): an RB x CB
// block of the result stays in registers while the rows of X stream past it.
#pragma once

#include "kernels/spatial/spatial.h"

namespace tg {

// GCC unrolls a short fixed-length loop completely before its vectorizer runs, and then multiplies in
// scalars; kept a loop, the column block below is vectorized and held in registers.
// The block's rows, though, are unrolled: a loop over them would index the accumulators, which then
// live in memory.
#if defined(__GNUC__) && !defined(__clang__) && !defined(__CUDACC__)
#define TG_KEEP_LOOP _Pragma("GCC unroll 1")
#define TG_UNROLL _Pragma("GCC unroll 16")
#else
#define TG_KEEP_LOOP
#define TG_UNROLL
#endif

// The register block: 6 x 16 on a CPU; one row of 16 on a GPU, whose thread holds far fewer registers
// (larger blocks spilled more in forward_dynamics_external_force_derivatives on G1); 4 x 4 on CPU lanes
// (3 x 4 for AVX2's 16 registers), each entry of which is a vector register already.
template <class Scalar> struct ProductBlock {
#if TG_DEVICE_PATH
  static constexpr int rows = 1, cols = 16;
#else
  static constexpr bool lanes = IsLanes<Scalar>::value;
  static constexpr int rows = lanes ? (sizeof(Scalar) >= 64 ? 4 : 3) : 6, cols = lanes ? 4 : 16;
#endif
};

// The inner index k of a block's products: every one of 0..K-1, or those of a list (`const int*`).
struct AllColumns {
  TG_HD int operator[](int k) const { return k; }
};

// f(c) for the CB columns of a block: a kept loop for a plain number, which GCC vectorizes; unrolled on
// CPU lanes, whose every entry is a vector register already (the accumulators stay registers).
template <class Scalar, int CB, class F> TG_HD_INLINE void for_columns(F&& f) {
  if constexpr (IsLanes<Scalar>::value && !TG_DEVICE_PATH) {
    TG_UNROLL
    for (int c = 0; c < CB; ++c) f(c);
  } else {
    TG_KEEP_LOOP
    for (int c = 0; c < CB; ++c) f(c);
  }
}

// out (RB x CB, row stride OS) (+)= sum_t w_t g_t X_t: g_t RB x K (row stride gs; with TG, g_t^T for g_t
// K x RB), X_t K x CB (row stride XS), the inner index k = ks[0..K); ADD adds to out, otherwise overwrites
// it. The weights scale the block between terms, w_0 S_0 + w_1 S_1 = w_1 (S_1 + (w_0 / w_1) S_0), not each
// product (nonzero w).
template <int XS, int OS, int RB, int CB, bool ADD, bool TG = false, class Scalar, class Ks = AllColumns>
TG_HD_NOINLINE void block_products(int nt, int K, const Scalar* const* g, int gs, const Scalar* w, const Scalar* const* X, Scalar* out,
                                   Ks ks = {}) {
  Scalar acc[RB][CB];
  TG_UNROLL
  for (int r = 0; r < RB; ++r) for_columns<Scalar, CB>([&](int c) __attribute__((always_inline)) { acc[r][c] = Scalar(0); });
  for (int t = 0; t < nt; ++t) {
    if (t > 0) {
      const Scalar ratio = w[t - 1] / w[t];
      TG_UNROLL
      for (int r = 0; r < RB; ++r) for_columns<Scalar, CB>([&](int c) __attribute__((always_inline)) { acc[r][c] *= ratio; });
    }
    for (int n = 0; n < K; ++n) {
      const int k = ks[n];
      const Scalar* x = X[t] + XS * k;
      TG_UNROLL
      for (int r = 0; r < RB; ++r) {
        const Scalar gr = TG ? g[t][gs * k + r] : g[t][gs * r + k];
        for_columns<Scalar, CB>([&](int c) __attribute__((always_inline)) { acc[r][c] += gr * x[c]; });
      }
    }
  }
  const Scalar last = nt > 0 ? w[nt - 1] : Scalar(0);
  TG_UNROLL
  for (int r = 0; r < RB; ++r)
    for_columns<Scalar, CB>([&](int c) __attribute__((always_inline)) { out[OS * r + c] = ADD ? out[OS * r + c] + last * acc[r][c] : last * acc[r][c]; });
}

// An RB-row block over COLS columns: blocks of ProductBlock's columns, then the rest in vector-sized pieces (8, 4,
// 2, 1), since an odd-width block is not vectorized.
template <int XS, int OS, int RB, int COLS, bool ADD, bool TG = false, class Scalar, class Ks = AllColumns>
TG_HD void row_block_products(int nt, int K, const Scalar* const* g, int gs, const Scalar* w, const Scalar* const* X, Scalar* out,
                              Ks ks = {}) {
  constexpr int CB = ProductBlock<Scalar>::cols, RC = COLS % CB;
  const Scalar* x[4];
  for (int c0 = 0; c0 < COLS - RC; c0 += CB) {
    for (int t = 0; t < nt; ++t) x[t] = X[t] + c0;
    block_products<XS, OS, RB, CB, ADD, TG>(nt, K, g, gs, w, x, out + c0, ks);
  }
  if constexpr (RC > 0) {
    constexpr int W = RC >= 8 ? 8 : RC >= 4 ? 4 : RC >= 2 ? 2 : 1;
    for (int t = 0; t < nt; ++t) x[t] = X[t] + COLS - RC;
    block_products<XS, OS, RB, W, ADD, TG>(nt, K, g, gs, w, x, out + COLS - RC, ks);
    if constexpr (RC > W) {
      for (int t = 0; t < nt; ++t) x[t] += W;
      row_block_products<XS, OS, RB, RC - W, ADD, TG>(nt, K, g, gs, w, x, out + COLS - RC + W, ks);
    }
  }
}

// out (ROWS x COLS, row stride OS) (+)= sum_t w_t g_t X_t for up to 4 terms: g_t ROWS x K (row stride
// gs; with TG, g_t^T for g_t K x ROWS), X_t K x COLS (row stride XS).
template <int ROWS, int COLS, int XS, int OS, bool ADD, bool TG = false, class Scalar>
TG_HD void products(int nt, int K, const Scalar* const* g, int gs, const Scalar* w, const Scalar* const* X, Scalar* out) {
  constexpr int RB = ProductBlock<Scalar>::rows, RR = ROWS % RB;
  const Scalar* gr[4];
  for (int r0 = 0; r0 < ROWS - RR; r0 += RB) {
    for (int t = 0; t < nt; ++t) gr[t] = g[t] + (TG ? r0 : gs * r0);
    row_block_products<XS, OS, RB, COLS, ADD, TG>(nt, K, gr, gs, w, X, out + OS * r0);
  }
  if constexpr (RR > 0) {
    for (int t = 0; t < nt; ++t) gr[t] = g[t] + (TG ? ROWS - RR : gs * (ROWS - RR));
    row_block_products<XS, OS, RR, COLS, ADD, TG>(nt, K, gr, gs, w, X, out + OS * (ROWS - RR));
  }
}

// The columns k of an NV x NV matrix that can be non-zero in rows [r0, r1) when it is zero between dofs
// on different branches of the tree (d tau/dq, d tau/dqd): the rows' ancestors below r0 (dof_ancestors), then
// [r0, the end of their subtrees) (dofs are numbered depth first, dof_end). Into ks, ascending; returns
// their count.
template <class Robot, class Scalar> TG_HD int related_columns(int r0, int r1, int* ks) {
  const auto& d = data<Robot, Scalar>();
  bool mark[Robot::NV];
  for (int k = 0; k < r0; ++k) mark[k] = false;
  int end = r1;
  for (int r = r0; r < r1; ++r) {
    end = d.dof_end[r] > end ? d.dof_end[r] : end;
    for (const int j : d.dof_ancestors[r]) {
      if (j < 0 || (j < r0 && mark[j])) break;  // a marked one's ancestors are marked
      if (j < r0) mark[j] = true;
    }
  }
  int n = 0;
  for (int k = 0; k < r0; ++k)
    if (mark[k]) ks[n++] = k;
  for (int k = r0; k < end; ++k) ks[n++] = k;
  return n;
}

// The related columns of every block of ProductBlock's rows (related_columns), found once per robot on a
// CPU (tree_blocks()); a GPU thread, whose blocks are single rows, finds each as it goes. `sparse`: the
// blocks' related entries are under 90% of NV x NV, so that products over them alone pay.
template <class Robot, class Scalar> struct TreeBlocks {
  static constexpr int NV = Robot::NV, RB = ProductBlock<Scalar>::rows, NBLK = (NV + RB - 1) / RB;
#if TG_DEVICE_PATH
  TG_HD const int* columns(int b, int* buf, int& n) const {
    n = related_columns<Robot, Scalar>(RB * b, RB * b + RB < NV ? RB * b + RB : NV, buf);
    return buf;
  }
#else
  int count[NBLK], ks[NBLK][NV];
  bool sparse;
  TreeBlocks() {
    int related = 0;
    for (int b = 0; b < NBLK; ++b) {
      const int r1 = RB * b + RB < NV ? RB * b + RB : NV;
      count[b] = related_columns<Robot, Scalar>(RB * b, r1, ks[b]);
      related += count[b] * (r1 - RB * b);
    }
    sparse = 10 * related < 9 * NV * NV;
  }
  const int* columns(int b, int*, int& n) const {
    n = count[b];
    return ks[b];
  }
#endif
};

// The robot's TreeBlocks: built at the first call on a CPU; on a GPU thread an empty struct.
#if TG_DEVICE_PATH
template <class Robot, class Scalar> TG_HD TreeBlocks<Robot, Scalar> tree_blocks() { return {}; }
#else
template <class Robot, class Scalar> inline const TreeBlocks<Robot, Scalar>& tree_blocks() {
  static const TreeBlocks<Robot, Scalar> tb;
  return tb;
}
#endif

// out (NV x COLS, row stride OS) (+)= sum_t w_t g_t X_t for up to 4 terms, each g_t NV x NV (row stride NV;
// with TG, g_t^T) zero between dofs on different branches: each block of rows runs over its related columns
// (tb's) alone.
template <class Robot, int COLS, int XS, int OS, bool ADD, bool TG = false, class Scalar>
TG_HD void tree_products(const TreeBlocks<Robot, Scalar>& tb, int nt, const Scalar* const* g, const Scalar* w, const Scalar* const* X, Scalar* out) {
  constexpr int NV = Robot::NV, RB = ProductBlock<Scalar>::rows, RR = NV % RB;
  int buf[NV], n;
  const Scalar* gr[4];
  for (int r0 = 0; r0 < NV - RR; r0 += RB) {
    const int* ks = tb.columns(r0 / RB, buf, n);
    for (int t = 0; t < nt; ++t) gr[t] = g[t] + (TG ? r0 : NV * r0);
    row_block_products<XS, OS, RB, COLS, ADD, TG>(nt, n, gr, NV, w, X, out + OS * r0, ks);
  }
  if constexpr (RR > 0) {
    const int* ks = tb.columns(NV / RB, buf, n);
    for (int t = 0; t < nt; ++t) gr[t] = g[t] + (TG ? NV - RR : NV * (NV - RR));
    row_block_products<XS, OS, RR, COLS, ADD, TG>(nt, n, gr, NV, w, X, out + OS * (NV - RR), ks);
  }
}

}  // namespace tg
