// Composite rigid-body algorithm: the joint-space inertia matrix M(q), full and symmetric.
// Featherstone's HandC (spatial_v2) / Pinocchio's crba, with every quantity in world-aligned axes:
//   - the composite inertia Ic_i of subtree i is taken about joint i's origin, so passing it to the
//     parent is a shift of the reference point, without a rotation (and the lever arms, hence the
//     rounding, stay those of joint frames);
//   - column c's force F_c = Ic_i S_c and the axes S_r are taken about one point, the root's
//     origin (not the world's, far away for a floating base), so that M[r, c] = S_r^T F_c.
// Dofs are numbered depth first: the subtree of body i owns the contiguous dofs [vi, vend). When
// the backward pass reaches i, every F_c of that range is known, and the rows of joint i are
// written as contiguous segments (F stored by component, so the loop over c vectorises).
#pragma once

#include "joints.h"

namespace tg {

template <class M, class S> TG_HD void crba(const S* q, S* Mout) {
  const auto& d = data<M, S>();
  constexpr int NV = M::NV;
  const Placements<M, S> K(q);
  Inertia<S> Ic[M::NB];  // about joint i's origin, world-aligned
  S F[6][NV];            // F[:, c]: force of the subtree owning dof c per unit acceleration of c
  for (int i = 0; i < M::NB; ++i) Ic[i] = rotate(K.oMi[i].R, body_inertia<M, S>(i));
  // Backward pass: the forces of joint i's columns, its rows, then its composite inertia to the parent.
  for (int i = M::NB - 1; i >= 0; --i) {
    const int vi = d.vi[i], ve = d.vend[i], nj = d.nvj[i];
    const Mat3<S>& R = K.oMi[i].R;
    const Vec3<S> o = K.oMi[i].p - K.oMi[0].p;  // joint i's origin seen from the root's
    // F_c = Ic_i S_c about joint i's origin, then about the root's: n += o x f.
    for (int k = 0; k < nj; ++k) {
      const Sv<S> s = joint_axis<M, S>(i, k);
      const Sv<S> f = mul(Ic[i], sv(mul(R, lin(s)), mul(R, ang(s))));
      const Vec3<S> fl = lin(f), n = ang(f) + cross(o, fl);
      for (int r = 0; r < 3; ++r) {
        F[r][vi + k] = fl.x[r];
        F[3 + r][vi + k] = n.x[r];
      }
    }
    // M[r, c] = S_r^T F_c over the subtree, S_r about the root's origin: v += o x w. Zero to the
    // right of the subtree (other branches); the entries left of vi are mirrored below.
    for (int k = 0; k < nj; ++k) {
      const Sv<S> s = joint_axis<M, S>(i, k);
      const Vec3<S> w = mul(R, ang(s)), v = mul(R, lin(s)) + cross(o, w);
      S* row = Mout + NV * (vi + k);
      for (int c = vi; c < ve; ++c)
        row[c] = v.x[0] * F[0][c] + v.x[1] * F[1][c] + v.x[2] * F[2][c] + w.x[0] * F[3][c] + w.x[1] * F[4][c] +
                 w.x[2] * F[5][c];
      for (int c = ve; c < NV; ++c) row[c] = S(0);
    }
    const int p = d.parent[i];
    if (p >= 0) Ic[p] = Ic[p] + shift(Ic[i], K.oMi[i].p - K.oMi[p].p);
  }
  // Mirror the upper triangle.
  for (int r = 0; r < NV; ++r)
    for (int c = 0; c < r; ++c) Mout[NV * r + c] = Mout[NV * c + r];
}

}  // namespace tg
