// M(q)^-1 computed directly, without forming M (Carpentier 2018, as Pinocchio's computeMinverse).
// An ABA over unit torques for all columns at once, in the world frame so that the column blocks
// of subtree forces F and accelerations A need no frame changes.
#pragma once

#include "joints.h"

namespace tg {

template <class M, class S> TG_HD void minv(const S* q, S* Minv) {
  const auto& d = M::data();
  constexpr int NV = M::NV;
  SE3<S> liMi[M::NB], oMi[M::NB];
  forward_kinematics<M, S>(q, liMi, oMi);
  M6<S> IA[M::NB];
  Sv<S> Sw[M::NB][6], U[M::NB][6];
  S Dinv[M::NB][36];
  S F[6][NV];     // F[:, col]: force on the subtree owning col, per unit torque at col
  S A[M::NB][6][NV];  // A[i][:, col]: world acceleration of body i per unit torque at col
  for (int i = 0; i < M::NB; ++i) {
    IA[i] = inertia_to_parent(oMi[i], body_inertia<M, S>(i));
    for (int k = 0; k < d.nvj[i]; ++k) Sw[i][k] = act_motion(oMi[i], joint_axis<M, S>(i, k));
  }
  for (int r = 0; r < 6; ++r)
    for (int col = 0; col < NV; ++col) F[r][col] = S(0);
  for (int k = 0; k < NV * NV; ++k) Minv[k] = S(0);
  // Backward pass: U = IA S, Dinv = (S^T U)^-1, rows of Minv restricted to the subtree.
  for (int i = M::NB - 1; i >= 0; --i) {
    const int n = d.nvj[i], vi = d.vi[i], vend = d.vend[i], p = d.parent[i];
    S D[36];
    for (int k = 0; k < n; ++k) U[i][k] = mul(IA[i], Sw[i][k]);
    for (int r = 0; r < n; ++r)
      for (int k = 0; k < n; ++k) D[n * r + k] = dot(Sw[i][r], U[i][k]);
    for (int k = 0; k < n; ++k) {
      S e[6] = {S(0), S(0), S(0), S(0), S(0), S(0)};
      e[k] = S(1);
      spd_solve(n, D, e);
      for (int r = 0; r < n; ++r) Dinv[i][n * r + k] = e[r];
    }
    for (int col = vi; col < vend; ++col) {
      // T = Dinv (e_col - S^T F[:, col]); F[:, col] += U T.
      S rhs[6], T[6];
      for (int r = 0; r < n; ++r) {
        Sv<S> Fc;
        for (int s = 0; s < 6; ++s) Fc.v[s] = F[s][col];
        rhs[r] = (col == vi + r ? S(1) : S(0)) - dot(Sw[i][r], Fc);
      }
      for (int r = 0; r < n; ++r) {
        T[r] = S(0);
        for (int k = 0; k < n; ++k) T[r] += Dinv[i][n * r + k] * rhs[k];
        Minv[NV * (vi + r) + col] = T[r];
      }
      for (int s = 0; s < 6; ++s)
        for (int r = 0; r < n; ++r) F[s][col] += U[i][r].v[s] * T[r];
    }
    if (p >= 0) {
      // IA_parent += IA - U Dinv U^T
      for (int r = 0; r < 6; ++r)
        for (int c = 0; c < 6; ++c) {
          S acc = IA[i].m[6 * r + c];
          for (int k = 0; k < n; ++k)
            for (int l = 0; l < n; ++l) acc -= U[i][k].v[r] * Dinv[i][n * k + l] * U[i][l].v[c];
          IA[p].m[6 * r + c] += acc;
        }
    }
  }
  // Forward pass on the upper triangle: Minv_i -= Dinv U^T A_parent; A_i = A_parent + S Minv_i.
  for (int i = 0; i < M::NB; ++i) {
    const int n = d.nvj[i], vi = d.vi[i], p = d.parent[i];
    for (int col = vi; col < NV; ++col) {
      if (p >= 0) {
        Sv<S> Ap;
        for (int s = 0; s < 6; ++s) Ap.v[s] = A[p][s][col];
        S UtA[6];
        for (int k = 0; k < n; ++k) UtA[k] = dot(U[i][k], Ap);
        for (int r = 0; r < n; ++r)
          for (int k = 0; k < n; ++k) Minv[NV * (vi + r) + col] -= Dinv[i][n * r + k] * UtA[k];
      }
      for (int s = 0; s < 6; ++s) {
        S acc = p >= 0 ? A[p][s][col] : S(0);
        for (int r = 0; r < n; ++r) acc += Sw[i][r].v[s] * Minv[NV * (vi + r) + col];
        A[i][s][col] = acc;
      }
    }
  }
  for (int r = 0; r < NV; ++r)
    for (int c = 0; c < r; ++c) Minv[NV * r + c] = Minv[NV * c + r];
}

}  // namespace tg
