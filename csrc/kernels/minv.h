// M(q)^-1 computed directly, without forming M (Carpentier 2018, as Pinocchio's computeMinverse):
// the articulated-body algorithm run for unit torques on all columns at once. Joint frames, as in
// ABA, keep float32 accurate (world-frame inertias of distal bodies cancel catastrophically).
// Per-body steps are templated on the joint's dof count N (1, or 6 for a free root) to unroll.
#pragma once

#include "joints.h"

namespace tg {

template <class M, class S> struct MinvWork {
  static constexpr int NV = M::NV;
  SE3<S> liMi[M::NB];
  M6<S> IA[M::NB];            // articulated inertias
  Sv<S> U[M::NB][6];          // U = IA S
  S Dinv[M::NB][36];          // (S^T U)^-1, N x N
  S F[6][NV];                 // F[:, col]: force on the subtree owning col, per unit torque at col
  S A[M::NB][6][NV];          // A[i][:, col]: acceleration of body i per unit torque at col
};

template <class S, int NV> TG_HD Sv<S> column(const S (&X)[6][NV], int col) {
  return {{X[0][col], X[1][col], X[2][col], X[3][col], X[4][col], X[5][col]}};
}
template <class S, int NV> TG_HD void set_column(S (&X)[6][NV], int col, const Sv<S>& x) {
  for (int s = 0; s < 6; ++s) X[s][col] = x.v[s];
}

// Backward step of body i: U, Dinv, the subtree block of rows i of Minv, then IA and F passed
// to the parent. N == 6 is the free root: S = I, so projections are components and nothing is
// passed on.
template <int N, class M, class S> TG_HD void minv_backward(int i, MinvWork<M, S>& w, S* Minv) {
  const auto& d = M::data();
  constexpr int NV = M::NV;
  const int vi = d.vi[i], p = d.parent[i];
  Sv<S> Si[N];
  S D[N * N];
  for (int k = 0; k < N; ++k) {
    Si[k] = joint_axis<M, S>(i, k);
    w.U[i][k] = mul(w.IA[i], Si[k]);
  }
  for (int r = 0; r < N; ++r)
    for (int k = 0; k < N; ++k) D[N * r + k] = N == 6 ? w.IA[i].m[6 * r + k] : dot(Si[r], w.U[i][k]);
  spd_inverse(N, D, w.Dinv[i]);
  // T = Dinv (e_col - S^T F[:, col]) becomes rows i of Minv; F[:, col] += U T.
  for (int col = vi; col < d.vend[i]; ++col) {
    Sv<S> Fc = column(w.F, col);
    S rhs[N];
    for (int r = 0; r < N; ++r) rhs[r] = (col == vi + r ? S(1) : S(0)) - (N == 6 ? Fc.v[r] : dot(Si[r], Fc));
    for (int r = 0; r < N; ++r) {
      S T = 0;
      for (int k = 0; k < N; ++k) T += w.Dinv[i][N * r + k] * rhs[k];
      Minv[NV * (vi + r) + col] = T;
      if (p >= 0) Fc = Fc + T * w.U[i][r];
    }
    if (p >= 0) set_column(w.F, col, act_force(w.liMi[i], Fc));
  }
  if (p < 0) return;
  // IA_parent += IA - U Dinv U^T, seen from the parent.
  M6<S> Ia = w.IA[i];
  for (int k = 0; k < N; ++k) {
    Sv<S> UD = sv_zero<S>();
    for (int l = 0; l < N; ++l) UD = UD + w.Dinv[i][N * l + k] * w.U[i][l];
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < 6; ++c) Ia.m[6 * r + c] -= w.U[i][k].v[r] * UD.v[c];
  }
  const M6<S> Ip = inertia_to_parent(w.liMi[i], Ia);
  for (int k = 0; k < 36; ++k) w.IA[p].m[k] += Ip.m[k];
}

// Forward step of body i on the upper triangle: a' = parent acceleration seen from i,
// Minv_i -= Dinv U^T a', A_i = a' + S Minv_i.
template <int N, class M, class S> TG_HD void minv_forward(int i, MinvWork<M, S>& w, S* Minv) {
  const auto& d = M::data();
  constexpr int NV = M::NV;
  const int vi = d.vi[i], p = d.parent[i];
  Sv<S> Si[N];
  for (int k = 0; k < N; ++k) Si[k] = joint_axis<M, S>(i, k);
  for (int col = vi; col < NV; ++col) {
    S x[N];
    for (int r = 0; r < N; ++r) x[r] = Minv[NV * (vi + r) + col];
    Sv<S> a = sv_zero<S>();
    if (p >= 0) {
      a = actinv_motion(w.liMi[i], column(w.A[p], col));
      S UtA[N];
      for (int k = 0; k < N; ++k) UtA[k] = dot(w.U[i][k], a);
      for (int r = 0; r < N; ++r)
        for (int k = 0; k < N; ++k) x[r] -= w.Dinv[i][N * r + k] * UtA[k];
    }
    for (int r = 0; r < N; ++r) {
      Minv[NV * (vi + r) + col] = x[r];
      if constexpr (N == 6) a.v[r] += x[r];
      else a = a + x[r] * Si[r];
    }
    set_column(w.A[i], col, a);
  }
}

template <class M, class S> TG_HD void minv(const S* q, S* Minv) {
  const auto& d = M::data();
  MinvWork<M, S> w;
  for (int i = 0; i < M::NB; ++i) {
    w.liMi[i] = joint_placement<M, S>(i, q);
    w.IA[i] = to_matrix(body_inertia<M, S>(i));
  }
  for (int s = 0; s < 6; ++s)
    for (int col = 0; col < M::NV; ++col) w.F[s][col] = S(0);
  for (int k = 0; k < M::NV * M::NV; ++k) Minv[k] = S(0);
  for (int i = M::NB - 1; i >= 0; --i) {
    if (d.nvj[i] == 6) minv_backward<6>(i, w, Minv);
    else minv_backward<1>(i, w, Minv);
  }
  for (int i = 0; i < M::NB; ++i) {
    if (d.nvj[i] == 6) minv_forward<6>(i, w, Minv);
    else minv_forward<1>(i, w, Minv);
  }
  // Mirror the upper triangle.
  for (int r = 0; r < M::NV; ++r)
    for (int c = 0; c < r; ++c) Minv[M::NV * r + c] = Minv[M::NV * c + r];
}

}  // namespace tg
