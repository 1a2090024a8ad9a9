// Centre of mass, its Jacobian, energy and the centroidal momentum map (Orin & Goswami 2008,
// as Pinocchio's ccrba): quantities of the whole robot, built from world-frame body terms.
#pragma once

#include "kernels/spatial/joints.h"

namespace tg {

template <class M, class S> TG_HD S total_mass() {
  S m = 0;
  for (int i = 0; i < M::NB; ++i) m += S(data<M, S>().mass[i]);
  return m;
}

// World position of body i's centre of mass.
template <class M, class S> TG_HD Vec3<S> body_com(int i, const SE3<S>* oMi) {
  const auto& d = data<M, S>();
  return act_point(oMi[i], v3(S(d.com[i][0]), S(d.com[i][1]), S(d.com[i][2])));
}

template <class M, class S> TG_HD void com(const S* q, S* out) {
  SE3<S> liMi[M::NB], oMi[M::NB];
  forward_kinematics<M, S>(q, liMi, oMi);
  Vec3<S> c = v3(S(0), S(0), S(0));
  for (int i = 0; i < M::NB; ++i) c = c + S(data<M, S>().mass[i]) * body_com<M, S>(i, oMi);
  store3((S(1) / total_mass<M, S>()) * c, out);
}

// d com / d qd, (3 x NV): each joint moves its subtree's mass-weighted centre of mass.
template <class M, class S> TG_HD void jacobian_com(const S* q, S* J) {
  const auto& d = data<M, S>();
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
      const Sv<S> s = placed_axis<M, S>(oMi[i], i, k);
      const Vec3<S> col = inv_m * (ms[i] * lin(s) + cross(ang(s), mc[i]));
      for (int r = 0; r < 3; ++r) J[M::NV * r + d.vi[i] + k] = col.x[r];
    }
}

// [kinetic, potential, mechanical] energy, potential relative to the world origin.
template <class M, class S> TG_HD void energy(const S* q, const S* qd, S* out) {
  const auto& d = data<M, S>();
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
  // The rotors' (armature) kinetic energy.
  for (int k = 0; k < M::NV; ++k) kinetic += S(0.5) * S(d.armature[k]) * qd[k] * qd[k];
  out[0] = kinetic;
  out[1] = potential;
  out[2] = kinetic + potential;
}

// Centroidal momentum matrix A (6 x NV) and momentum h = A qd, [linear; angular about the com].
template <class M, class S> TG_HD void ccrba(const S* q, const S* qd, S* A, S* h) {
  const auto& d = data<M, S>();
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
      const Sv<S> hk = mul(Yc[i], placed_axis<M, S>(oMi[i], i, k));
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

// Shared by the centroidal derivatives: world placements and velocities, joint axes and their
// rates, subtree inertias Yc, inertia rates dYc and momenta H, total mass and com.
template <class M, class S> struct CentroidalWork {
  SE3<S> oMi[M::NB];
  Sv<S> v[M::NB], H[M::NB], s[M::NV], sdot[M::NV], w[M::NV];  // w = v_parent x s
  Inertia<S> Yc[M::NB];
  M6<S> dYc[M::NB];
  S m;
  Vec3<S> c;
};

template <class M, class S> TG_HD void centroidal_setup(const S* q, const S* qd, CentroidalWork<M, S>& W) {
  const auto& d = data<M, S>();
  W.m = total_mass<M, S>();
  W.c = v3(S(0), S(0), S(0));
  for (int i = 0; i < M::NB; ++i) {
    const int p = d.parent[i];
    const SE3<S> liMi = joint_placement<M, S>(i, q);
    W.oMi[i] = p < 0 ? liMi : W.oMi[p] * liMi;
    const Sv<S> vp = p < 0 ? sv_zero<S>() : W.v[p];
    W.v[i] = vp;
    for (int k = 0; k < d.nvj[i]; ++k) {
      W.s[d.vi[i] + k] = act_motion(W.oMi[i], joint_axis<M, S>(i, k));
      W.v[i] = W.v[i] + qd[d.vi[i] + k] * W.s[d.vi[i] + k];
    }
    for (int k = 0; k < d.nvj[i]; ++k) {
      W.sdot[d.vi[i] + k] = cross_motion(W.v[i], W.s[d.vi[i] + k]);
      W.w[d.vi[i] + k] = cross_motion(vp, W.s[d.vi[i] + k]);
    }
    W.Yc[i] = act(W.oMi[i], body_inertia<M, S>(i));
    W.dYc[i] = inertia_rate_matrix(W.Yc[i], W.v[i]);
    W.H[i] = mul(W.Yc[i], W.v[i]);
    W.c = W.c + S(d.mass[i]) * body_com<M, S>(i, W.oMi);
  }
  W.c = (S(1) / W.m) * W.c;
  for (int i = M::NB - 1; i >= 0; --i) {
    const int p = d.parent[i];
    if (p < 0) continue;
    W.Yc[p] = W.Yc[p] + W.Yc[i];
    for (int k = 0; k < 36; ++k) W.dYc[p].m[k] += W.dYc[i].m[k];
    W.H[p] = W.H[p] + W.H[i];
  }
}

// Pinocchio's dAg (6 x NV): the time variation of the centroidal map with h_dot = A qdd + dAg qd,
// and A itself (may be null). Column j of A is Yc_j S_j seen at the com; dAg's is dYc_j S_j +
// Yc_j dS_j/dt seen at the com. (The elementwise dA/dt adds -cdot x (A_j)_lin to the angular
// rows, which sums to -cdot x m cdot = 0 against qd; Pinocchio leaves it out, and so do we.)
template <class M, class S> TG_HD void cmm_time_variation(const S* q, const S* qd, S* Adot, S* A) {
  const auto& d = data<M, S>();
  CentroidalWork<M, S> W;
  centroidal_setup<M, S>(q, qd, W);
  for (int i = 0; i < M::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) {
      const int col = d.vi[i] + k;
      const Sv<S> dF = at_point(mul(W.dYc[i], W.s[col]) + mul(W.Yc[i], W.sdot[col]), W.c);
      const Sv<S> F = at_point(mul(W.Yc[i], W.s[col]), W.c);
      for (int r = 0; r < 6; ++r) {
        Adot[M::NV * r + col] = dF.v[r];
        if (A) A[M::NV * r + col] = F.v[r];
      }
    }
}

// d h / dq (6 x NV), h the centroidal momentum at fixed qd. Moving joint j carries its subtree's
// momentum H_j by the twist s (s x* H_j) while the parent's velocity stays (Yc_j (v_parent x s));
// the com moves by J_com's column, shifting the angular part by -(dc x h_lin).
template <class M, class S> TG_HD void dccrba(const S* q, const S* qd, S* dh_dq) {
  const auto& d = data<M, S>();
  CentroidalWork<M, S> W;
  centroidal_setup<M, S>(q, qd, W);
  Sv<S> total = sv_zero<S>();
  for (int i = 0; i < M::NB; ++i)
    if (d.parent[i] < 0) total = total + W.H[i];
  // Subtree mass and mass-weighted com, for the com's motion.
  S ms[M::NB];
  Vec3<S> mc[M::NB];
  for (int i = 0; i < M::NB; ++i) {
    ms[i] = S(d.mass[i]);
    mc[i] = ms[i] * body_com<M, S>(i, W.oMi);
  }
  for (int i = M::NB - 1; i >= 0; --i)
    if (d.parent[i] >= 0) {
      ms[d.parent[i]] += ms[i];
      mc[d.parent[i]] = mc[d.parent[i]] + mc[i];
    }
  for (int i = 0; i < M::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) {
      const int col = d.vi[i] + k;
      const Sv<S>& s = W.s[col];
      const Sv<S> dH = cross_force(s, W.H[i]) + mul(W.Yc[i], W.w[col]);
      const Vec3<S> dc = (S(1) / W.m) * (ms[i] * lin(s) + cross(ang(s), mc[i]));
      const Sv<S> col6 = at_point(dH, W.c) - sv(v3(S(0), S(0), S(0)), cross(dc, lin(total)));
      for (int r = 0; r < 6; ++r) dh_dq[M::NV * r + col] = col6.v[r];
    }
}

}  // namespace tg
