// M(q)^-1 computed directly, without forming M (Carpentier 2018, as Pinocchio's computeMinverse):
// the articulated-body algorithm run for unit torques on all columns at once. Every quantity has
// world-aligned axes:
//   - the articulated inertia IA_i (and D = S^T IA S) is taken about joint i's origin, so passing
//     it to the parent shifts its reference point without a rotation; the lever arms stay those of
//     joint frames (about one far point, the inertias of distal bodies would cancel catastrophically
//     in float32);
//   - the column blocks (subtree forces F, accelerations A), U and S are taken about the root's
//     origin, where they add up without a change of point per body and column.
// Per-body steps are templated on the joint's dof count N (1, 3 for a ball, 6 for a free root) to unroll.
#pragma once

#include "kernels/spatial/joints.h"
#include "kernels/spatial/team.h"

namespace tg {

// A team runs one sample (team.h): the columns col of M^-1 and of F and A are col's lane's alone, from the first
// loop to the last; each body's axes and U about the root's origin the leader stores, and D^-1 and IA's update
// every lane computes alike (the leader storing D^-1 for the forward pass); IA's entries spread over the lanes as
// they pass to the parent. ByDepth: A's slots (Levels).
template <class Robot, class Scalar, bool ByDepth = TG_DEVICE_PATH != 0> struct MinvWork {
  static constexpr int NV = Robot::NV;
  using L = Levels<Robot, ByDepth>;
  const SE3<Scalar>* oMi;  // world placements (the Placements pass)
  M6<Scalar> IA[Robot::NB];  // articulated inertias, about joint i's origin
  // Per dof (joint i's k-th at vi + k): its axis and U = IA S about the root's origin, and row k of
  // (S^T U)^-1 (N x N): per dof rather than per body, so a free root's six do not size every body.
  Sv<Scalar> Sw[NV], Uw[NV];
  Scalar Dinv[NV][6];
  Sv<Scalar> F[NV];  // F[col]: force on the subtree owning col per unit torque at col, about the root's origin
  Sv<Scalar> A[L::N][NV];  // A[body][col]: its acceleration per unit torque at col, likewise (Levels)
};

// A team's shared workspace: the world placements beside the above, by depth on the host too (team_launch sizes it).
template <class Robot, class Scalar> struct MinvTeamWork {
  SE3<Scalar> oMi[Robot::NB];
  MinvWork<Robot, Scalar, true> w;
};

// Backward step of body i: U, Dinv, the subtree block of rows i of Minv, and IA passed to the
// parent.
template <int N, class Robot, class Scalar, bool ByDepth, class Team>
TG_HD void minv_backward(const Team& t, int i, MinvWork<Robot, Scalar, ByDepth>& w, Scalar* Minv) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  const int vi = d.vi[i], p = d.parent[i];
  const SE3<Scalar> X{w.oMi[i].R, w.oMi[i].p - w.oMi[0].p};  // joint i seen from the root's origin
  Sv<Scalar> U[N];  // about joint i's origin
  Scalar D[N * N], Dinv[N * N];
  for (int k = 0; k < N; ++k) {
    const Sv<Scalar> s = joint_axis<Robot, Scalar>(i, k);
    U[k] = mul(w.IA[i], sv(mul(X.R, lin(s)), mul(X.R, ang(s))));
    if (t.leader()) {
      w.Sw[vi + k] = act_motion(X, s);
      w.Uw[vi + k] = at_point(U[k], Scalar(-1) * X.p);
    }
  }
  t.sync();
  // D = S^T U + armature: a motion-force pairing, the same about any point.
  for (int r = 0; r < N; ++r)
    for (int k = 0; k < N; ++k) D[N * r + k] = dot(w.Sw[vi + r], w.Uw[vi + k]) + (r == k ? Scalar(d.armature[vi + r]) : Scalar(0));
  spd_inverse(N, D, Dinv);
  if (t.leader())
    for (int r = 0; r < N; ++r)
      for (int k = 0; k < N; ++k) w.Dinv[vi + r][k] = Dinv[N * r + k];
  // T = Dinv (e_col - S^T F[:, col]) becomes rows i of Minv; F[:, col] += U T.
  for (const int col : t.items(vi, d.vend[i])) {
    Scalar rhs[N];
    for (int r = 0; r < N; ++r) rhs[r] = (col == vi + r ? Scalar(1) : Scalar(0)) - dot(w.Sw[vi + r], w.F[col]);
    for (int r = 0; r < N; ++r) {
      Scalar T = 0;
      for (int k = 0; k < N; ++k) T += Dinv[N * r + k] * rhs[k];
      Minv[NV * (vi + r) + col] = T;
      if (p >= 0) w.F[col] = w.F[col] + T * w.Uw[vi + r];  // a root passes nothing on
    }
  }
  if (p < 0) return;
  // IA_parent += IA - U Dinv U^T, about the parent's origin.
  M6<Scalar> Ia = w.IA[i];
  for (int k = 0; k < N; ++k) {
    Sv<Scalar> UD = sv_zero<Scalar>();
    for (int l = 0; l < N; ++l) UD = UD + Dinv[N * l + k] * U[l];
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < 6; ++c) Ia.m[6 * r + c] -= U[k].v[r] * UD.v[c];
  }
  const M6<Scalar> Ip = shift(Ia, w.oMi[i].p - w.oMi[p].p);
  for (const int e : t.items(0, 36)) w.IA[p].m[e] += Ip.m[e];
  t.sync();  // IA_parent whole before the parent's step reads it
}

// Forward step of body i on the upper triangle: Minv_i -= Dinv U^T A_parent, A_i = A_parent + S Minv_i.
template <int N, class Robot, class Scalar, bool ByDepth, class Team>
TG_HD void minv_forward(const Team& t, int i, MinvWork<Robot, Scalar, ByDepth>& w, Scalar* Minv) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  using L = typename MinvWork<Robot, Scalar, ByDepth>::L;
  const int vi = d.vi[i], p = d.parent[i], l = L::of(d, i), lp = L::parent(d, i);
  for (const int col : t.items(vi, NV)) {
    Scalar x[N];
    for (int r = 0; r < N; ++r) x[r] = Minv[NV * (vi + r) + col];
    Sv<Scalar> a = sv_zero<Scalar>();
    if (p >= 0) {
      a = w.A[lp][col];
      Scalar UtA[N];
      for (int k = 0; k < N; ++k) UtA[k] = dot(w.Uw[vi + k], a);
      for (int r = 0; r < N; ++r)
        for (int k = 0; k < N; ++k) x[r] -= w.Dinv[vi + r][k] * UtA[k];
    }
    for (int r = 0; r < N; ++r) {
      Minv[NV * (vi + r) + col] = x[r];
      a = a + x[r] * w.Sw[vi + r];
    }
    w.A[l][col] = a;
  }
}

// M^-1 (NV x NV, row-major) at the world placements oMi, by team t with its workspace w; all of it written when
// every lane returns.
template <class Robot, class Scalar, bool ByDepth, class Team>
TG_HD void minv(const Team& t, const SE3<Scalar>* oMi, MinvWork<Robot, Scalar, ByDepth>& w, Scalar* Minv,
                const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  if (t.leader()) w.oMi = oMi;
  for (const int i : t.items(0, Robot::NB)) w.IA[i] = to_matrix(rotate(oMi[i].R, pi[i]));
  for (const int col : t.items(0, NV)) {
    w.F[col] = sv_zero<Scalar>();
    for (int r = 0; r < NV; ++r) Minv[NV * r + col] = Scalar(0);
  }
  t.sync();
  for (int i = Robot::NB - 1; i >= 0; --i) {
    if (d.nvj[i] == 6) minv_backward<6>(t, i, w, Minv);
    else if (d.nvj[i] == 1) minv_backward<1>(t, i, w, Minv);
    else if constexpr (Robot::BALLS) minv_backward<3>(t, i, w, Minv);
  }
  t.sync();  // the leader's S, U and Dinv
  for (int i = 0; i < Robot::NB; ++i) {
    if (d.nvj[i] == 6) minv_forward<6>(t, i, w, Minv);
    else if (d.nvj[i] == 1) minv_forward<1>(t, i, w, Minv);
    else if constexpr (Robot::BALLS) minv_forward<3>(t, i, w, Minv);
  }
  t.sync();
  // Mirror the upper triangle: column c's entries below the diagonal, by c's lane.
  for (const int c : t.items(0, NV))
    for (int r = c + 1; r < NV; ++r) Minv[NV * r + c] = Minv[NV * c + r];
  t.sync();
}

template <class Robot, class Scalar> TG_HD void minv(const Placements<Robot, Scalar>& K, Scalar* Minv, const InertialParameters<Robot, Scalar>& pi = {}) {
  MinvWork<Robot, Scalar> w;
  minv<Robot, Scalar>(Solo{}, K.oMi, w, Minv, pi);
}

template <class Robot, class Scalar> TG_HD void minv(const Scalar* q, Scalar* Minv, const InertialParameters<Robot, Scalar>& pi = {}) {
  const Placements<Robot, Scalar> K(q);
  minv<Robot, Scalar>(K, Minv, pi);
}

// The same by a team from q, the placements computed into the shared workspace.
template <class Robot, class Scalar, class Team>
TG_HD void minv_team(const Team& t, MinvTeamWork<Robot, Scalar>& tw, const Scalar* q, Scalar* Minv, const InertialParameters<Robot, Scalar>& pi = {}) {
  world_placements<Robot, Scalar>(t, q, tw.oMi);
  minv<Robot, Scalar>(t, tw.oMi, tw.w, Minv, pi);
}

}  // namespace tg
