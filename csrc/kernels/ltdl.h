// M = L^T D L with L unit lower triangular (Featherstone, RBDA 6.5, spatial_v2 LTDL.m). Entry (k, j) of M,
// and of L (there is no fill-in), is non-zero only for j an ancestor dof of k, so the eliminations
// follow the tree: one per pair (k, i) with i on dof_parent's chain from k. Each updates row i over
// [0, i] as one contiguous (vectorised) segment: the entries of other branches there are exact zeros
// in row k, and stay so. M and its factor share the storage (row-major NV x NV, lower triangle read).
#pragma once

#include "spatial.h"

namespace tg {

// In place: D on the diagonal, L strictly below it.
template <class M, class S> TG_HD void ltdl_factor(S* H) {
  const auto& d = data<M, S>();
  constexpr int NV = M::NV;
  for (int k = NV - 1; k >= 0; --k) {
    const S* Hk = H + NV * k;
    const S inv = S(1) / Hk[k];
    for (int i = d.dof_parent[k]; i >= 0; i = d.dof_parent[i]) {
      // eliminate (k, i): row i loses L_ki times row k
      const S a = Hk[i] * inv;
      S* Hi = H + NV * i;
      for (int j = 0; j <= i; ++j) Hi[j] -= a * Hk[j];
      H[NV * k + i] = a;
    }
  }
}

// x := M^-1 x from ltdl_factor's H: L^T z = x (leaves up), z / D, then L y = z (root down); L's zeros
// make the dense triangular loops exact.
template <class M, class S> TG_HD void ltdl_solve(const S* H, S* x) {
  constexpr int NV = M::NV;
  for (int i = NV - 1; i > 0; --i) {
    const S xi = x[i];
    for (int j = 0; j < i; ++j) x[j] -= H[NV * i + j] * xi;
  }
  for (int i = 0; i < NV; ++i) x[i] /= H[NV * i + i];
  for (int i = 1; i < NV; ++i) {
    S s = S(0);
    for (int j = 0; j < i; ++j) s += H[NV * i + j] * x[j];
    x[i] -= s;
  }
}

}  // namespace tg
