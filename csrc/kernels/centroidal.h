// Centre of mass, its Jacobian, energy and the centroidal momentum map (Orin & Goswami 2008,
// as Pinocchio's ccrba): quantities of the whole robot, built from world-frame body terms.
#pragma once

#include "joints.h"

namespace tg {

template <class M, class S> TG_HD S total_mass() {
  S m = 0;
  for (int i = 0; i < M::NB; ++i) m += S(M::data().mass[i]);
  return m;
}

// World position of body i's centre of mass.
template <class M, class S> TG_HD Vec3<S> body_com(int i, const SE3<S>* oMi) {
  const auto& d = M::data();
  return act_point(oMi[i], v3(S(d.com[i][0]), S(d.com[i][1]), S(d.com[i][2])));
}

template <class M, class S> TG_HD void com(const S* q, S* out) {
  SE3<S> liMi[M::NB], oMi[M::NB];
  forward_kinematics<M, S>(q, liMi, oMi);
  Vec3<S> c = v3(S(0), S(0), S(0));
  for (int i = 0; i < M::NB; ++i) c = c + S(M::data().mass[i]) * body_com<M, S>(i, oMi);
  store3((S(1) / total_mass<M, S>()) * c, out);
}

// d com / d qd, (3 x NV): each joint moves its subtree's mass-weighted centre of mass.
template <class M, class S> TG_HD void jacobian_com(const S* q, S* J) {
  const auto& d = M::data();
  SE3<S> liMi[M::NB], oMi[M::NB];
  forward_kinematics<M, S>(q, liMi, oMi);
  S ms[M::NB];
  Vec3<S> mc[M::NB];  // subtree mass and mass-weighted centre of mass
  for (int i = 0; i < M::NB; ++i) {
    ms[i] = S(d.mass[i]);
    mc[i] = ms[i] * body_com<M, S>(i, oMi);
  }
  for (int i = M::NB - 1; i >= 0; --i)
    if (d.parent[i] >= 0) {
      ms[d.parent[i]] += ms[i];
      mc[d.parent[i]] = mc[d.parent[i]] + mc[i];
    }
  const S inv_m = S(1) / total_mass<M, S>();
  for (int i = 0; i < M::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) {
      const Sv<S> s = act_motion(oMi[i], joint_axis<M, S>(i, k));
      const Vec3<S> col = inv_m * (ms[i] * lin(s) + cross(ang(s), mc[i]));
      for (int r = 0; r < 3; ++r) J[M::NV * r + d.vi[i] + k] = col.x[r];
    }
}

// [kinetic, potential, mechanical] energy, potential relative to the world origin.
template <class M, class S> TG_HD void energy(const S* q, const S* qd, S* out) {
  const auto& d = M::data();
  SE3<S> liMi[M::NB], oMi[M::NB];
  Sv<S> v[M::NB];
  forward_kinematics<M, S>(q, liMi, oMi);
  const Vec3<S> g = v3(S(d.gravity[0]), S(d.gravity[1]), S(d.gravity[2]));
  S kinetic = 0, potential = 0;
  for (int i = 0; i < M::NB; ++i) {
    const Sv<S> vJ = joint_motion<M, S>(i, qd);
    v[i] = d.parent[i] < 0 ? vJ : actinv_motion(liMi[i], v[d.parent[i]]) + vJ;
    kinetic += S(0.5) * dot(v[i], mul(body_inertia<M, S>(i), v[i]));
    potential -= S(d.mass[i]) * dot(g, body_com<M, S>(i, oMi));
  }
  out[0] = kinetic;
  out[1] = potential;
  out[2] = kinetic + potential;
}

// Centroidal momentum matrix A (6 x NV) and momentum h = A qd, [linear; angular about the com].
template <class M, class S> TG_HD void ccrba(const S* q, const S* qd, S* A, S* h) {
  const auto& d = M::data();
  constexpr int NV = M::NV;
  SE3<S> liMi[M::NB], oMi[M::NB];
  forward_kinematics<M, S>(q, liMi, oMi);
  // Composite inertia of each subtree, in the world frame.
  Inertia<S> Yc[M::NB];
  for (int i = 0; i < M::NB; ++i) Yc[i] = act(oMi[i], body_inertia<M, S>(i));
  for (int i = M::NB - 1; i >= 0; --i)
    if (d.parent[i] >= 0) Yc[d.parent[i]] = Yc[d.parent[i]] + Yc[i];
  Vec3<S> c = v3(S(0), S(0), S(0));
  for (int i = 0; i < M::NB; ++i) c = c + S(d.mass[i]) * body_com<M, S>(i, oMi);
  c = (S(1) / total_mass<M, S>()) * c;
  // Column of joint dof: momentum of its subtree moving along the world axis, moved to the com.
  for (int i = 0; i < M::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) {
      const Sv<S> hk = mul(Yc[i], act_motion(oMi[i], joint_axis<M, S>(i, k)));
      const Vec3<S> l = lin(hk), n = ang(hk) - cross(c, lin(hk));
      for (int r = 0; r < 3; ++r) {
        A[NV * r + d.vi[i] + k] = l.x[r];
        A[NV * (3 + r) + d.vi[i] + k] = n.x[r];
      }
    }
  for (int r = 0; r < 6; ++r) {
    S acc = 0;
    for (int col = 0; col < NV; ++col) acc += A[NV * r + col] * qd[col];
    h[r] = acc;
  }
}

}  // namespace tg
