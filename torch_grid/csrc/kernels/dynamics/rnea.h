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

}  // namespace tg
