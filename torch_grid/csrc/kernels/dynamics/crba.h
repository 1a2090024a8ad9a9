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

#include "kernels/spatial/joints.h"

namespace tg {

template <class Robot, class Scalar> TG_HD void crba(const Placements<Robot, Scalar>& K, Scalar* Mout, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  Inertia<Scalar> Ic[Robot::NB];  // about joint i's origin, world-aligned
  Scalar F[6][NV];            // F[:, c]: force of the subtree owning dof c per unit acceleration of c
  for (int i = 0; i < Robot::NB; ++i) Ic[i] = rotate(K.oMi[i].R, pi[i]);
  // Backward pass: the forces of joint i's columns, its rows, then its composite inertia to the parent.
  // Unrolled on the host: each body's dof ranges and axes become constants (20% of crba).
#if !defined(__CUDACC__)
#pragma GCC unroll 128
#endif
  for (int i = Robot::NB - 1; i >= 0; --i) {
    const int vi = d.vi[i], ve = d.vend[i], nj = d.nvj[i];
    const Mat3<Scalar>& R = K.oMi[i].R;
    const SE3<Scalar> X{R, K.oMi[i].p - K.oMi[0].p};  // joint i seen from the root's origin, world axes
    // F_c = Ic_i S_c about joint i's origin, then about the root's.
    for (int k = 0; k < nj; ++k) {
      const Sv<Scalar> Sc = placed_axis<Robot, Scalar>(SE3<Scalar>{R, v3(Scalar(0), Scalar(0), Scalar(0))}, i, k);  // world axes, joint i's origin
      const Sv<Scalar> f = at_point(mul(Ic[i], Sc), Scalar(-1) * X.p);
      for (int r = 0; r < 6; ++r) F[r][vi + k] = f.v[r];
    }
    // M[r, c] = S_r^T F_c over the subtree, S_r about the root's origin. Zero to the right of the
    // subtree (other branches); the entries left of vi are mirrored below.
    if (d.jtype[i] == FREE) {
      // A free joint's axes are R's columns about its origin: its rows are F_c there, in its axes.
      for (int c = vi; c < ve; ++c) {
        const Vec3<Scalar> fl = v3(F[0][c], F[1][c], F[2][c]), fa = v3(F[3][c], F[4][c], F[5][c]);
        const Vec3<Scalar> l = mulT(R, fl), a = mulT(R, fa - cross(X.p, fl));
        for (int k = 0; k < 3; ++k) {
          Mout[NV * (vi + k) + c] = l.x[k];
          Mout[NV * (vi + 3 + k) + c] = a.x[k];
        }
      }
    } else {
      for (int k = 0; k < nj; ++k) {
        const Sv<Scalar> s = placed_axis<Robot, Scalar>(X, i, k);
        Scalar* row = Mout + NV * (vi + k);
        for (int c = vi; c < ve; ++c)
          row[c] = s.v[0] * F[0][c] + s.v[1] * F[1][c] + s.v[2] * F[2][c] + s.v[3] * F[3][c] + s.v[4] * F[4][c] +
                   s.v[5] * F[5][c];
      }
    }
    for (int k = 0; k < nj; ++k)
      for (int c = ve; c < NV; ++c) Mout[NV * (vi + k) + c] = Scalar(0);
    const int p = d.parent[i];
    if (p >= 0) Ic[p] = Ic[p] + shift(Ic[i], K.oMi[i].p - K.oMi[p].p);
  }
  // Mirror the upper triangle; the rotors' inertia (armature) adds to the diagonal.
  for (int r = 0; r < NV; ++r) {
    for (int c = 0; c < r; ++c) Mout[NV * r + c] = Mout[NV * c + r];
    Mout[NV * r + r] += Scalar(d.armature[r]);
  }
}

template <class Robot, class Scalar> TG_HD void crba(const Scalar* q, Scalar* Mout, const InertialParameters<Robot, Scalar>& pi = {}) {
  crba<Robot, Scalar>(Placements<Robot, Scalar>(q), Mout, pi);
}

// The world axes and composite inertias, both about the root's origin, of crba's team path.
template <class Robot, class Scalar> struct CrbaAxes {
  Sv<Scalar> S[Robot::NV];
  Inertia<Scalar> Ic[Robot::NB];
};

// M(q) by team t at the world placements oMi, with crba_vjp's layout: each lane its bodies' axes S and inertias
// about the root's origin and its share of M's zeros; each of the inertias' 13 entries summed over subtrees by
// one lane; then a lane per column c, of body b: M[r, c] = M[c, r] = S_r . Ic_b S_c for the dofs r before c in b
// and those of b's ancestors (a pair belongs to its later column alone), the armature on the diagonal. All of M
// written when every lane returns.
template <class Robot, class Scalar, class Team>
TG_HD void crba(const Team& t, const SE3<Scalar>* oMi, CrbaAxes<Robot, Scalar>& w, Scalar* M, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  for (const int i : t.items(0, Robot::NB)) {
    const SE3<Scalar> X{oMi[i].R, oMi[i].p - oMi[0].p};  // joint i seen from the root's origin, world axes
    for (int k = 0; k < d.nvj[i]; ++k) w.S[d.vi[i] + k] = placed_axis<Robot, Scalar>(X, i, k);
    w.Ic[i] = shift(rotate(X.R, pi[i]), X.p);
  }
  for (const int n : t.items(0, NV * NV)) M[n] = Scalar(0);
  t.sync();
  subtree_entry_sums<Robot, Scalar>(t, 13, [&w](int i, int e) -> Scalar& { return inertia_entry(w.Ic[i], e); });
  t.sync();
  for (const int c : t.items(0, NV)) {
    const int b = dof_body<Robot, Scalar>(c);
    const Sv<Scalar> F = mul(w.Ic[b], w.S[c]);
    M[(NV + 1) * c] = dot(w.S[c], F) + Scalar(d.armature[c]);
    for (int r = d.vi[b]; r < c; ++r) M[NV * r + c] = M[NV * c + r] = dot(w.S[r], F);
    for (int j = d.parent[b]; j >= 0; j = d.parent[j])
      for (int r = d.vi[j]; r < d.vi[j] + d.nvj[j]; ++r) M[NV * r + c] = M[NV * c + r] = dot(w.S[r], F);
  }
  t.sync();
}

// A team's shared workspace for crba: the world placements and the above.
template <class Robot, class Scalar> struct CrbaTeamWork {
  SE3<Scalar> oMi[Robot::NB];
  CrbaAxes<Robot, Scalar> axes;
};

template <class Robot, class Scalar, class Team>
TG_HD void crba(const Team& t, CrbaTeamWork<Robot, Scalar>& w, const Scalar* q, Scalar* M, const InertialParameters<Robot, Scalar>& pi = {}) {
  world_placements<Robot, Scalar>(t, q, w.oMi);
  crba<Robot, Scalar>(t, w.oMi, w.axes, M, pi);
}

// The gradient along the tangent of <G, M(q)> for a weight G (NV x NV), O(n d) for a tree of depth d.
// With world axes S and composite inertias Ic about one point (the root's origin), a block of M is
// M[r, s] = S_r . Ic_b S_s for the dof r of joint b and s of a joint a at or above b. A tangent step of
// dof k turns what is below k's joint c, dS/dq_k = S_k x S and dI/dq_k = S_k x* I - I S_k x; a pair
// (r, s) turned as a whole is unchanged, which leaves, with H = (G + G^T)/2, w_rs = 2 H_rs across
// joints (each unordered pair once) and H_rs within one, F_r = Ic_b S_r:
//   a above c, c at or above b:   -w_rs F_r . (S_k x S_s) = -S_k . (w_rs S_s x* F_r)
//   a and b above c:               w_rs S_r . (S_k x* Ic_c - Ic_c S_k x) S_s
// The first, summed over the pairs, is -S_k . Z_c: the subtree sum of A_r x* F_r (A_r = sum of w_rs S_s
// over the joints above b) less that of S_s x* R_s (R_s = sum of w_rs F_r over the joints below a),
// which removes the pairs with a also below c. The second is -tr((P_c + P_c^T) Ic_c [S_k x]), with P_c
// the sum of S_r u_r^T over the joints above c, u_r = A_r + the sum of H_rs S_s within r's joint.
template <class Robot, class Scalar> TG_HD void crba_vjp(const Scalar* q, const Scalar* G, Scalar* out, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV, NB = Robot::NB;
  const Placements<Robot, Scalar> K(q);
  Sv<Scalar> Sw[NV], A[NV], R[NV];  // world axes about the root's origin; A_r; R_s
  M6<Scalar> P[NB];                 // P_c + P_c^T
  Inertia<Scalar> Ic[NB];           // about the root's origin, world axes
  Sv<Scalar> Z[NB];
  const auto w = [&](int r, int s) { return G[NV * r + s] + G[NV * s + r]; };  // 2 H_rs
  // Forward pass: axes, A_r, and P_c from the parent's.
  for (int i = 0; i < NB; ++i) {
    const SE3<Scalar> X{K.oMi[i].R, K.oMi[i].p - K.oMi[0].p};
    for (int k = 0; k < d.nvj[i]; ++k) Sw[d.vi[i] + k] = placed_axis<Robot, Scalar>(X, i, k);
    for (int r = d.vi[i]; r < d.vi[i] + d.nvj[i]; ++r) {
      A[r] = sv_zero<Scalar>();
      R[r] = sv_zero<Scalar>();
      for (int j = d.parent[i]; j >= 0; j = d.parent[j])
        for (int s = d.vi[j]; s < d.vi[j] + d.nvj[j]; ++s) A[r] = A[r] + w(r, s) * Sw[s];
    }
    const int p = d.parent[i];
    for (int k = 0; k < 36; ++k) P[i].m[k] = p >= 0 ? P[p].m[k] : Scalar(0);
    if (p >= 0)
      for (int r = d.vi[p]; r < d.vi[p] + d.nvj[p]; ++r) {
        Sv<Scalar> u = A[r];
        for (int s = d.vi[p]; s < d.vi[p] + d.nvj[p]; ++s) u = u + (Scalar(0.5) * w(r, s)) * Sw[s];
        for (int x = 0; x < 6; ++x)
          for (int y = 0; y < 6; ++y) P[i].m[6 * x + y] += Sw[r].v[x] * u.v[y] + u.v[x] * Sw[r].v[y];
      }
    Ic[i] = shift(rotate(K.oMi[i].R, pi[i]), X.p);
    Z[i] = sv_zero<Scalar>();
  }
  // Backward pass: F_r into the R_s above, the subtree sums Z_c and Ic_c, then both terms for c's dofs.
  for (int i = NB - 1; i >= 0; --i) {
    Sv<Scalar> z = Z[i];
    for (int r = d.vi[i]; r < d.vi[i] + d.nvj[i]; ++r) {
      const Sv<Scalar> F = mul(Ic[i], Sw[r]);
      for (int j = d.parent[i]; j >= 0; j = d.parent[j])
        for (int s = d.vi[j]; s < d.vi[j] + d.nvj[j]; ++s) R[s] = R[s] + w(r, s) * F;
      z = z + cross_force(A[r], F) - cross_force(Sw[r], R[r]);
    }
    // Q = (P + P^T) Ic; tr(Q [v x]) = v . ([t(Q21); t(Q11) + t(Q22)]), t(B) = (B23 - B32, B31 - B13, B12 - B21)
    const M6<Scalar> Y = to_matrix(Ic[i]);
    Scalar Q[36];
    for (int x = 0; x < 6; ++x)
      for (int y = 0; y < 6; ++y) {
        Scalar acc = Scalar(0);
        for (int k = 0; k < 6; ++k) acc += P[i].m[6 * x + k] * Y.m[6 * k + y];
        Q[6 * x + y] = acc;
      }
    const auto t = [&](int r0, int c0) {
      const Scalar* B = Q + 6 * r0 + c0;
      return v3(B[6 * 1 + 2] - B[6 * 2 + 1], B[6 * 2 + 0] - B[6 * 0 + 2], B[6 * 0 + 1] - B[6 * 1 + 0]);
    };
    const Sv<Scalar> phi = sv(t(3, 0), t(0, 0) + t(3, 3));
    for (int r = d.vi[i]; r < d.vi[i] + d.nvj[i]; ++r) out[r] = -dot(Sw[r], z + phi);
    const int p = d.parent[i];
    if (p >= 0) {
      Ic[p] = Ic[p] + Ic[i];
      Z[p] = Z[p] + z;
    }
  }
}

}  // namespace tg
