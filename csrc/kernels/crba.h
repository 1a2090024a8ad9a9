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
  // Unrolled on the host: each body's dof ranges and axes become constants (20% of crba).
#if !defined(__CUDACC__)
#pragma GCC unroll 128
#endif
  for (int i = M::NB - 1; i >= 0; --i) {
    const int vi = d.vi[i], ve = d.vend[i], nj = d.nvj[i];
    const Mat3<S>& R = K.oMi[i].R;
    const SE3<S> X{R, K.oMi[i].p - K.oMi[0].p};  // joint i seen from the root's origin, world axes
    // F_c = Ic_i S_c about joint i's origin, then about the root's.
    for (int k = 0; k < nj; ++k) {
      const Sv<S> Sc = placed_axis<M, S>(SE3<S>{R, v3(S(0), S(0), S(0))}, i, k);  // world axes, joint i's origin
      const Sv<S> f = at_point(mul(Ic[i], Sc), S(-1) * X.p);
      for (int r = 0; r < 6; ++r) F[r][vi + k] = f.v[r];
    }
    // M[r, c] = S_r^T F_c over the subtree, S_r about the root's origin. Zero to the right of the
    // subtree (other branches); the entries left of vi are mirrored below.
    if (d.jtype[i] == FREE) {
      // A free joint's axes are R's columns about its origin: its rows are F_c there, in its axes.
      for (int c = vi; c < ve; ++c) {
        const Vec3<S> fl = v3(F[0][c], F[1][c], F[2][c]), fa = v3(F[3][c], F[4][c], F[5][c]);
        const Vec3<S> l = mulT(R, fl), a = mulT(R, fa - cross(X.p, fl));
        for (int k = 0; k < 3; ++k) {
          Mout[NV * (vi + k) + c] = l.x[k];
          Mout[NV * (vi + 3 + k) + c] = a.x[k];
        }
      }
    } else {
      for (int k = 0; k < nj; ++k) {
        const Sv<S> s = placed_axis<M, S>(X, i, k);
        S* row = Mout + NV * (vi + k);
        for (int c = vi; c < ve; ++c)
          row[c] = s.v[0] * F[0][c] + s.v[1] * F[1][c] + s.v[2] * F[2][c] + s.v[3] * F[3][c] + s.v[4] * F[4][c] +
                   s.v[5] * F[5][c];
      }
    }
    for (int k = 0; k < nj; ++k)
      for (int c = ve; c < NV; ++c) Mout[NV * (vi + k) + c] = S(0);
    const int p = d.parent[i];
    if (p >= 0) Ic[p] = Ic[p] + shift(Ic[i], K.oMi[i].p - K.oMi[p].p);
  }
  // Mirror the upper triangle; the rotors' inertia (armature) adds to the diagonal.
  for (int r = 0; r < NV; ++r) {
    for (int c = 0; c < r; ++c) Mout[NV * r + c] = Mout[NV * c + r];
    Mout[NV * r + r] += S(d.armature[r]);
  }
}

}  // namespace tg
