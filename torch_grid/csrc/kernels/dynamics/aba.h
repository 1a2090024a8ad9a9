// Articulated-body algorithm: qdd = M(q)^-1 (tau - C(q, qd) qd - g(q) + J^T f_ext).
// Featherstone's FDab (spatial_v2 FDab.m) in joint frames, multi-dof joints via a small SPD solve.
#pragma once

#include "kernels/spatial/joints.h"

namespace tg {

// Memory (a GPU thread's stack): velocities and accelerations are kept by tree level on a GPU
// (Levels); what children pass up to their parent in the backward pass (articulated inertia, bias
// force) goes to the parent's level, assigned by the first child to arrive (the parent's last in
// depth-first order) and added by the others; U = IA S is kept per dof (joint i's k-th at vi + k).
template <class Robot, class Scalar>
TG_HD void aba(const Scalar* q, const Scalar* qd, const Scalar* tau, const Scalar* fext, Scalar* qdd, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  JointPlacements<Robot, Scalar> liMi(q);
  using L = Levels<Robot>;
  Sv<Scalar> va[L::N], c[Robot::NB], pA[Robot::NB], pA_up[Robot::ND];
  M6<Scalar> IA_up[Robot::ND];
  Sv<Scalar> U[Robot::NV];
  Scalar u[Robot::NV];
  // Forward pass: velocities, velocity-product accelerations c, bias forces pA.
  for (int i = 0; i < Robot::NB; ++i) {
    const int p = d.parent[i], l = L::of(d, i);
    const auto& X = liMi.place(i);
    const Sv<Scalar> vJ = joint_motion<Robot, Scalar>(i, qd);
    va[l] = p < 0 ? vJ : actinv_motion(X, va[L::parent(d, i)]) + vJ;
    c[i] = cross_motion(va[l], vJ);
    const Inertia<Scalar> I = pi[i];
    pA[i] = cross_force(va[l], mul(I, va[l]));
    if (fext) pA[i] = pA[i] - Sv<Scalar>{{fext[6 * i], fext[6 * i + 1], fext[6 * i + 2], fext[6 * i + 3], fext[6 * i + 4], fext[6 * i + 5]}};
  }
  // Backward pass: articulated inertias IA and bias forces pA, U = IA S, D = S^T U, u = tau - S^T pA.
  for (int i = Robot::NB - 1; i >= 0; --i) {
    const int n = d.nvj[i], vi = d.vi[i], l = d.depth[i];
    M6<Scalar> IA = to_matrix(pi[i]);
    if (d.has_children[i]) {
      for (int k = 0; k < 36; ++k) IA.m[k] += IA_up[l].m[k];
      pA[i] = pA[i] + pA_up[l];
    }
    Sv<Scalar> Si[6];
    for (int k = 0; k < n; ++k) {
      Si[k] = joint_axis<Robot, Scalar>(i, k);
      U[vi + k] = mul(IA, Si[k]);
      u[vi + k] = tau[vi + k] - dot(Si[k], pA[i]);
    }
    const int p = d.parent[i];
    if (p < 0) continue;
    // Dinv_u = D^-1 u and Dinv_U = D^-1 U^T (n x 6), through one SPD factorisation each column.
    Scalar D[36], Dinv_u[6], Dinv_Ut[6][6];
    for (int r = 0; r < n; ++r)
      for (int k = 0; k < n; ++k) D[n * r + k] = dot(Si[r], U[vi + k]) + (r == k ? Scalar(d.armature[vi + r]) : Scalar(0));
    for (int r = 0; r < n; ++r) Dinv_u[r] = u[vi + r];
    spd_solve(n, D, Dinv_u);
    for (int col = 0; col < 6; ++col) {
      Scalar x[6];
      for (int r = 0; r < n; ++r) x[r] = U[vi + r].v[col];
      spd_solve(n, D, x);
      for (int r = 0; r < n; ++r) Dinv_Ut[r][col] = x[r];
    }
    // Ia = IA - U D^-1 U^T, pa = pA + Ia c + U D^-1 u, both passed to the parent frame.
    M6<Scalar> Ia = IA;
    for (int r = 0; r < 6; ++r)
      for (int col = 0; col < 6; ++col)
        for (int k = 0; k < n; ++k) Ia.m[6 * r + col] -= U[vi + k].v[r] * Dinv_Ut[k][col];
    Sv<Scalar> pa = pA[i] + mul(Ia, c[i]);
    for (int k = 0; k < n; ++k) pa = pa + Dinv_u[k] * U[vi + k];
    const SE3<Scalar> X = liMi[i];
    const M6<Scalar> Ip = inertia_to_parent(X, Ia);
    const Sv<Scalar> pp = act_force(X, pa);
    if (d.last_child[i]) {
      IA_up[l - 1] = Ip;
      pA_up[l - 1] = pp;
    } else {
      for (int k = 0; k < 36; ++k) IA_up[l - 1].m[k] += Ip.m[k];
      pA_up[l - 1] = pA_up[l - 1] + pp;
    }
  }
  // Forward pass: qdd_i = D^-1 (u - U^T a'), a' the parent acceleration seen in frame i.
  for (int i = 0; i < Robot::NB; ++i) {
    const int n = d.nvj[i], vi = d.vi[i], p = d.parent[i], l = L::of(d, i);
    const Sv<Scalar> a_in = actinv_motion(liMi[i], p < 0 ? base_acceleration<Robot, Scalar>() : va[L::parent(d, i)]) + c[i];
    Scalar D[36], x[6];
    for (int r = 0; r < n; ++r) {
      for (int k = 0; k < n; ++k) D[n * r + k] = dot(joint_axis<Robot, Scalar>(i, r), U[vi + k]) + (r == k ? Scalar(d.armature[vi + r]) : Scalar(0));
      x[r] = u[vi + r] - dot(U[vi + r], a_in);
    }
    spd_solve(n, D, x);
    va[l] = a_in;
    for (int k = 0; k < n; ++k) {
      qdd[vi + k] = x[k];
      va[l] = va[l] + x[k] * joint_axis<Robot, Scalar>(i, k);
    }
  }
}

}  // namespace tg
