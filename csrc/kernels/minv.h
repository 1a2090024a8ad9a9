// M(q)^-1 computed directly, without forming M (Carpentier 2018, as Pinocchio's computeMinverse).
// An ABA over unit torques for all columns at once, in the world frame so that the column blocks
// of subtree forces F and accelerations A need no frame changes. Per-body steps are templated on
// the joint's dof count N (1, or 6 for a free root) so their small loops unroll.
#pragma once

#include "joints.h"

namespace tg {

template <class M, class S> struct MinvWork {
  static constexpr int NV = M::NV;
  M6<S> IA[M::NB];            // articulated inertias, world frame
  Sv<S> Sw[M::NB][6];         // joint axes, world frame
  Sv<S> U[M::NB][6];          // U = IA S
  S Dinv[M::NB][36];          // (S^T U)^-1, N x N
  S F[6][NV];                 // F[:, col]: force on the subtree owning col, per unit torque at col
  S A[M::NB][6][NV];          // A[i][:, col]: world acceleration of body i per unit torque at col
};

// Backward step of body i: U, Dinv, the subtree block of rows i of Minv, and IA of the parent.
template <int N, class M, class S> TG_HD void minv_backward(int i, MinvWork<M, S>& w, S* Minv) {
  const auto& d = M::data();
  constexpr int NV = M::NV;
  const int vi = d.vi[i], p = d.parent[i];
  S D[N * N];
  for (int k = 0; k < N; ++k) w.U[i][k] = mul(w.IA[i], w.Sw[i][k]);
  for (int r = 0; r < N; ++r)
    for (int k = 0; k < N; ++k) D[N * r + k] = dot(w.Sw[i][r], w.U[i][k]);
  spd_inverse(N, D, w.Dinv[i]);
  // T = Dinv (e_col - S^T F[:, col]) becomes rows i of Minv; F[:, col] += U T.
  for (int col = vi; col < d.vend[i]; ++col) {
    Sv<S> Fc;
    for (int s = 0; s < 6; ++s) Fc.v[s] = w.F[s][col];
    S rhs[N];
    for (int r = 0; r < N; ++r) rhs[r] = (col == vi + r ? S(1) : S(0)) - dot(w.Sw[i][r], Fc);
    for (int r = 0; r < N; ++r) {
      S T = 0;
      for (int k = 0; k < N; ++k) T += w.Dinv[i][N * r + k] * rhs[k];
      Minv[NV * (vi + r) + col] = T;
      for (int s = 0; s < 6; ++s) w.F[s][col] += w.U[i][r].v[s] * T;
    }
  }
  if (p < 0) return;
  // IA_parent += IA - U Dinv U^T
  Sv<S> UD[N];
  for (int k = 0; k < N; ++k) {
    UD[k] = sv_zero<S>();
    for (int l = 0; l < N; ++l) UD[k] = UD[k] + w.Dinv[i][N * l + k] * w.U[i][l];
  }
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) {
      S acc = w.IA[i].m[6 * r + c];
      for (int k = 0; k < N; ++k) acc -= w.U[i][k].v[r] * UD[k].v[c];
      w.IA[p].m[6 * r + c] += acc;
    }
}

// Forward step of body i on the upper triangle: Minv_i -= Dinv U^T A_parent; A_i = A_parent + S Minv_i.
template <int N, class M, class S> TG_HD void minv_forward(int i, MinvWork<M, S>& w, S* Minv) {
  const auto& d = M::data();
  constexpr int NV = M::NV;
  const int vi = d.vi[i], p = d.parent[i];
  for (int col = vi; col < NV; ++col) {
    S x[N];
    for (int r = 0; r < N; ++r) x[r] = Minv[NV * (vi + r) + col];
    Sv<S> Ap = sv_zero<S>();
    if (p >= 0) {
      for (int s = 0; s < 6; ++s) Ap.v[s] = w.A[p][s][col];
      S UtA[N];
      for (int k = 0; k < N; ++k) UtA[k] = dot(w.U[i][k], Ap);
      for (int r = 0; r < N; ++r)
        for (int k = 0; k < N; ++k) x[r] -= w.Dinv[i][N * r + k] * UtA[k];
    }
    for (int r = 0; r < N; ++r) {
      Minv[NV * (vi + r) + col] = x[r];
      Ap = Ap + x[r] * w.Sw[i][r];
    }
    for (int s = 0; s < 6; ++s) w.A[i][s][col] = Ap.v[s];
  }
}

template <class M, class S> TG_HD void minv(const S* q, S* Minv) {
  const auto& d = M::data();
  SE3<S> liMi[M::NB], oMi[M::NB];
  forward_kinematics<M, S>(q, liMi, oMi);
  MinvWork<M, S> w;
  for (int i = 0; i < M::NB; ++i) {
    w.IA[i] = to_matrix(act(oMi[i], body_inertia<M, S>(i)));
    for (int k = 0; k < d.nvj[i]; ++k) w.Sw[i][k] = act_motion(oMi[i], joint_axis<M, S>(i, k));
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
