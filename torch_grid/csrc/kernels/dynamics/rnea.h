// Recursive Newton-Euler: tau = M(q) qdd + C(q, qd) qd + g(q) - J^T f_ext.
// Featherstone's ID (spatial_v2 ID.m) in joint frames, with Pinocchio's names.
#pragma once

#include "kernels/spatial/joints.h"

namespace tg {

// liMi: the joint placements (JointPlacements, or a shared Placements pass); qd, qdd in Pinocchio's
// layout; fext (NB x 6, joint frames) may be null; tau is (NV). Gravity = false with qd = 0 gives M qdd.
template <class Robot, class Scalar, bool Gravity, class P>
TG_HD_INLINE void rnea_placed(P& liMi, const Scalar* qd, const Scalar* qdd, const Scalar* fext, Scalar* tau,
                              const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  using L = Levels<Robot>;
  Sv<Scalar> v[L::N], a[L::N], f[Robot::NB];
  // Forward pass: body velocities, accelerations and the forces that produce them.
  for (int i = 0; i < Robot::NB; ++i) {
    const int p = d.parent[i], k = L::of(d, i), kp = L::parent(d, i);
    const auto& X = liMi.place(i);
    const Sv<Scalar> vJ = joint_motion<Robot, Scalar>(i, qd);
    const Sv<Scalar> aJ = joint_motion<Robot, Scalar>(i, qdd);
    const Sv<Scalar> a_parent = p < 0 ? (Gravity ? base_acceleration<Robot, Scalar>() : sv_zero<Scalar>()) : a[kp];
    v[k] = p < 0 ? vJ : actinv_motion(X, v[kp]) + vJ;
    a[k] = actinv_motion(X, a_parent) + aJ + cross_motion(v[k], vJ);
    const Inertia<Scalar> I = pi[i];
    f[i] = mul(I, a[k]) + cross_force(v[k], mul(I, v[k]));
    if (fext) f[i] = f[i] - Sv<Scalar>{{fext[6 * i], fext[6 * i + 1], fext[6 * i + 2], fext[6 * i + 3], fext[6 * i + 4], fext[6 * i + 5]}};
  }
  // Backward pass: project each body's force on its joint (plus the rotors' armature qdd), pass it
  // to the parent.
  for (int i = Robot::NB - 1; i >= 0; --i) {
    joint_project<Robot, Scalar>(i, f[i], tau);
    for (int k = d.vi[i]; k < d.vi[i] + d.nvj[i]; ++k) tau[k] += Scalar(d.armature[k]) * qdd[k];
    if (d.parent[i] >= 0) f[d.parent[i]] = f[d.parent[i]] + act_force(liMi[i], f[i]);
  }
}

template <class Robot, class Scalar, bool Gravity = true>
TG_HD void rnea(const Scalar* q, const Scalar* qd, const Scalar* qdd, const Scalar* fext, Scalar* tau, const InertialParameters<Robot, Scalar>& pi = {}) {
  JointPlacements<Robot, Scalar> liMi(q);
  rnea_placed<Robot, Scalar, Gravity>(liMi, qd, qdd, fext, tau, pi);
}

template <class Robot, class Scalar, bool Gravity = true>
TG_HD void rnea(const Placements<Robot, Scalar>& K, const Scalar* qd, const Scalar* qdd, const Scalar* fext, Scalar* tau,
                const InertialParameters<Robot, Scalar>& pi = {}) {
  rnea_placed<Robot, Scalar, Gravity>(K, qd, qdd, fext, tau, pi);
}

// A team's workspace for inverse dynamics at given world placements: each dof's world axis, and each body's world
// velocity, acceleration and force.
template <class Robot, class Scalar> struct RneaTeamWork {
  Sv<Scalar> S[Robot::NV];
  Sv<Scalar> v[Robot::NB], a[Robot::NB], f[Robot::NB];
};

// tau by team t at the world placements oMi, in world axes about the world's origin (qdd null: zero): each lane
// its bodies' axes; the leader the pass down the tree, v_i = v_p + S_i qd_i and a_i = a_p + S_i qdd_i +
// v_i x S_i qd_i (a few products a body); each lane its bodies' forces f_i = I_i a_i + v_i x* I_i v_i less the
// external ones; each of the 6 force entries summed over subtrees by one lane; each lane its dofs' tau_c =
// S_c . f (plus the armature's). All of tau written when every lane returns.
template <class Robot, class Scalar, class Team>
TG_HD void rnea(const Team& t, const SE3<Scalar>* oMi, RneaTeamWork<Robot, Scalar>& w, const Scalar* qd, const Scalar* qdd,
                const Scalar* fext, Scalar* tau, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  const auto acc = [qdd](int k) { return qdd ? qdd[k] : Scalar(0); };
  for (const int i : t.items(0, Robot::NB))
    for (int k = 0; k < d.nvj[i]; ++k) w.S[d.vi[i] + k] = act_motion(oMi[i], joint_axis<Robot, Scalar>(i, k));
  t.sync();
  if (t.leader())
    for (int i = 0; i < Robot::NB; ++i) {
      const int p = d.parent[i], vi = d.vi[i], n = d.nvj[i];
      Sv<Scalar> v = p < 0 ? sv_zero<Scalar>() : w.v[p];
      Sv<Scalar> a = p < 0 ? base_acceleration<Robot, Scalar>() : w.a[p];
      for (int k = 0; k < n; ++k) v = v + qd[vi + k] * w.S[vi + k];
      for (int k = 0; k < n; ++k) a = a + acc(vi + k) * w.S[vi + k] + qd[vi + k] * cross_motion(v, w.S[vi + k]);
      w.v[i] = v;
      w.a[i] = a;
    }
  t.sync();
  for (const int i : t.items(0, Robot::NB)) {
    const Inertia<Scalar> I = act(oMi[i], pi[i]);
    w.f[i] = mul(I, w.a[i]) + cross_force(w.v[i], mul(I, w.v[i]));
    if (fext) {
      const Sv<Scalar> fe = {{fext[6 * i], fext[6 * i + 1], fext[6 * i + 2], fext[6 * i + 3], fext[6 * i + 4], fext[6 * i + 5]}};
      w.f[i] = w.f[i] - act_force(oMi[i], fe);
    }
  }
  t.sync();
  subtree_entry_sums<Robot, Scalar>(t, 6, [&w](int i, int e) -> Scalar& { return w.f[i].v[e]; });
  t.sync();
  for (const int c : t.items(0, Robot::NV)) tau[c] = dot(w.S[c], w.f[dof_body<Robot, Scalar>(c)]) + Scalar(d.armature[c]) * acc(c);
  t.sync();
}

// A team's shared workspace for inverse_dynamics: the world placements and the above.
template <class Robot, class Scalar> struct InverseDynamicsTeamWork {
  SE3<Scalar> oMi[Robot::NB];
  RneaTeamWork<Robot, Scalar> w;
};

template <class Robot, class Scalar, class Team>
TG_HD void rnea(const Team& t, InverseDynamicsTeamWork<Robot, Scalar>& tw, const Scalar* q, const Scalar* qd, const Scalar* qdd,
                const Scalar* fext, Scalar* tau, const InertialParameters<Robot, Scalar>& pi = {}) {
  world_placements<Robot, Scalar>(t, q, tw.oMi);
  rnea<Robot, Scalar>(t, tw.oMi, tw.w, qd, qdd, fext, tau, pi);
}

}  // namespace tg
