// M = L^T D L with L unit lower triangular (Featherstone, RBDA 6.5, spatial_v2 LTDL.m). Entry (k, j) of M,
// and of L (there is no fill-in), is non-zero only for j an ancestor dof of k, so the eliminations
// follow the tree: one per pair (k, i) with i an ancestor of k (dof_ancestors). Each updates row i over
// [0, i] as one contiguous (vectorised) segment: the entries of other branches there are exact zeros
// in row k, and stay so. M and its factor share the storage (row-major NV x NV, lower triangle read).
#pragma once

#include <type_traits>

#include "kernels/dynamics/products.h"

namespace tg {

// In place: D on the diagonal, L strictly below it.
template <class Robot, class Scalar> TG_HD void ltdl_factor(Scalar* H) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  for (int k = NV - 1; k >= 0; --k) {
    const Scalar* Hk = H + NV * k;
    const Scalar inv = Scalar(1) / Hk[k];
    for (const int i : d.dof_ancestors[k]) {
      if (i < 0) break;
      // eliminate (k, i): row i loses L_ki times row k
      const Scalar a = Hk[i] * inv;
      Scalar* Hi = H + NV * i;
      for (int j = 0; j <= i; ++j) Hi[j] -= a * Hk[j];
      H[NV * k + i] = a;
    }
  }
}

// x := M^-1 x from ltdl_factor's H: L^T z = x (leaves up), z / D, then L y = z (root down); L's zeros
// make the dense triangular loops exact.
template <class Robot, class Scalar> TG_HD void ltdl_solve(const Scalar* H, Scalar* x) {
  constexpr int NV = Robot::NV;
  for (int i = NV - 1; i > 0; --i) {
    const Scalar xi = x[i];
    for (int j = 0; j < i; ++j) x[j] -= H[NV * i + j] * xi;
  }
  for (int i = 0; i < NV; ++i) x[i] /= H[NV * i + i];
  for (int i = 1; i < NV; ++i) {
    Scalar s = Scalar(0);
    for (int j = 0; j < i; ++j) s += H[NV * i + j] * x[j];
    x[i] -= s;
  }
}

// x (COLS entries) := a x - sum_m c[m] X[ks[m]] over n rows of X (row stride XS), also added to t if given.
template <int XS, int COLS, class Scalar>
TG_HD void less_rows_plain(int n, const int* ks, const Scalar* c, const Scalar* X, Scalar* x, Scalar a = Scalar(1), Scalar* t = nullptr) {
  for (int e = 0; e < COLS; ++e) x[e] *= a;
  for (int m = 0; m < n; ++m) {
    const Scalar cm = c[m];
    const Scalar* xr = X + XS * ks[m];
    for (int e = 0; e < COLS; ++e) x[e] -= cm * xr[e];
  }
  if (t)
    for (int e = 0; e < COLS; ++e) t[e] += x[e];
}
// On a CPU x is held in registers as 8-lane vectors (GCC's vector extension) while the rows stream past:
// each FMA then has a dozen independent others beside it, where a few columns at a time would wait on the
// one before. A GPU thread, or a scalar that is itself a vector of samples, updates x in place (as does the
// CPU build of a GPU thread's paths, TG_DEVICE_PATH, so that the CPU's tests run the GPU's loop).
#if defined(__GNUC__) && !defined(__CUDACC__) && !TG_DEVICE_PATH
template <int XS, int COLS, class Scalar>
inline void less_rows(int n, const int* ks, const Scalar* c, const Scalar* X, Scalar* x, Scalar a = Scalar(1), Scalar* t = nullptr) {
  if constexpr (!std::is_floating_point_v<Scalar>) {  // a scalar of lanes (lanes.h) is a vector already
    less_rows_plain<XS, COLS>(n, ks, c, X, x, a, t);
  } else {
    typedef Scalar V __attribute__((vector_size(8 * sizeof(Scalar))));
    constexpr int NL = COLS / 8, T = COLS % 8;
    V acc[NL > 0 ? NL : 1];
    Scalar tail[T > 0 ? T : 1];
#pragma GCC unroll 16
    for (int l = 0; l < NL; ++l) {
      __builtin_memcpy(&acc[l], x + 8 * l, sizeof(V));
      acc[l] *= a;
    }
    for (int e = 0; e < T; ++e) tail[e] = a * x[8 * NL + e];
    for (int m = 0; m < n; ++m) {
      const Scalar cm = c[m];
      const Scalar* xr = X + XS * ks[m];
#pragma GCC unroll 16
      for (int l = 0; l < NL; ++l) {
        V y;
        __builtin_memcpy(&y, xr + 8 * l, sizeof(V));
        acc[l] -= cm * y;
      }
      for (int e = 0; e < T; ++e) tail[e] -= cm * xr[8 * NL + e];
    }
#pragma GCC unroll 16
    for (int l = 0; l < NL; ++l) __builtin_memcpy(x + 8 * l, &acc[l], sizeof(V));
    for (int e = 0; e < T; ++e) x[8 * NL + e] = tail[e];
    if (t) {
#pragma GCC unroll 16
      for (int l = 0; l < NL; ++l) {
        V y;
        __builtin_memcpy(&y, t + 8 * l, sizeof(V));
        y += acc[l];
        __builtin_memcpy(t + 8 * l, &y, sizeof(V));
      }
      for (int e = 0; e < T; ++e) t[8 * NL + e] += tail[e];
    }
  }
}
constexpr int kSolveCols = 128;
#else
template <int XS, int COLS, class Scalar>
TG_HD void less_rows(int n, const int* ks, const Scalar* c, const Scalar* X, Scalar* x, Scalar a = Scalar(1), Scalar* t = nullptr) {
  less_rows_plain<XS, COLS>(n, ks, c, X, x, a, t);
}
constexpr int kSolveCols = 16;
#endif

// Columns [c0, c0 + W) of X := M^-1 X (NV x COLS, row-major) from ltdl_factor's H, a row at a time: L^T Z = X
// from the leaves (row j less L_ij times each row i below it, [j + 1, dof_end)), then Y = D^-1 Z - L Y from
// the root (row i less L_ij times each row j among its ancestors); each row of Y also added to T's (of X's
// layout) if given.
template <class Robot, int COLS, int W, class Scalar> TG_HD void ltdl_solve_columns(const Scalar* H, Scalar* X, int c0, Scalar* T = nullptr) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  int ks[NV];
  Scalar L[NV];
  for (int j = NV - 1; j >= 0; --j) {
    int n = 0;
    for (int i = j + 1; i < d.dof_end[j]; ++i) ks[n] = i, L[n++] = H[NV * i + j];
    if (n) less_rows<COLS, W>(n, ks, L, X + c0, X + COLS * j + c0);
  }
  for (int i = 0; i < NV; ++i) {
    int n = 0;
    for (const int j : d.dof_ancestors[i]) {
      if (j < 0) break;
      ks[n] = j, L[n++] = H[NV * i + j];
    }
    less_rows<COLS, W>(n, ks, L, X + c0, X + COLS * i + c0, Scalar(1) / H[NV * i + i], T ? T + COLS * i + c0 : nullptr);
  }
}

// X := M^-1 X for NV x COLS X (row-major), at most as many columns at a time as a CPU core's registers hold;
// the result also added to T's (of X's layout) if given.
template <class Robot, int COLS, class Scalar> TG_HD void ltdl_solve_rows(const Scalar* H, Scalar* X, Scalar* T = nullptr) {
  constexpr int W = kSolveCols, RC = COLS % W;
  for (int c0 = 0; c0 < COLS - RC; c0 += W) ltdl_solve_columns<Robot, COLS, W>(H, X, c0, T);
  if constexpr (RC > 0) ltdl_solve_columns<Robot, COLS, RC>(H, X, COLS - RC, T);
}

}  // namespace tg
