// Centre of mass, its Jacobian, energy and the centroidal momentum map (Orin & Goswami 2008,
// as Pinocchio's ccrba): quantities of the whole robot, built from world-frame body terms.
#pragma once

#include "kernels/spatial/joints.h"

namespace tg {

// World first moment of body i: its mass times its centre of mass, m p_i + R_i h.
template <class Robot, class Scalar>
TG_HD Vec3<Scalar> body_moment(int i, const SE3<Scalar>* oMi, const InertialParameters<Robot, Scalar>& pi) {
  return pi.mass(i) * oMi[i].p + mul(oMi[i].R, pi.moment(i));
}

template <class Robot, class Scalar> TG_HD void com(const Scalar* q, Scalar* out, const InertialParameters<Robot, Scalar>& pi = {}) {
  SE3<Scalar> liMi[Robot::NB], oMi[Robot::NB];
  forward_kinematics<Robot, Scalar>(q, liMi, oMi);
  Vec3<Scalar> c = v3(Scalar(0), Scalar(0), Scalar(0));
  for (int i = 0; i < Robot::NB; ++i) c = c + body_moment(i, oMi, pi);
  store3((Scalar(1) / pi.total_mass()) * c, out);
}

// d com / d qd, (3 x NV): each joint moves its subtree's mass-weighted centre of mass.
template <class Robot, class Scalar> TG_HD void jacobian_com(const Scalar* q, Scalar* J, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  SE3<Scalar> liMi[Robot::NB], oMi[Robot::NB];
  forward_kinematics<Robot, Scalar>(q, liMi, oMi);
  Scalar ms[Robot::NB];
  Vec3<Scalar> mc[Robot::NB];  // subtree mass and mass-weighted centre of mass
  for (int i = 0; i < Robot::NB; ++i) {
    ms[i] = pi.mass(i);
    mc[i] = body_moment(i, oMi, pi);
  }
  for (int i = Robot::NB - 1; i >= 0; --i)
    if (d.parent[i] >= 0) {
      ms[d.parent[i]] += ms[i];
      mc[d.parent[i]] = mc[d.parent[i]] + mc[i];
    }
  const Scalar inv_m = Scalar(1) / pi.total_mass();
  for (int i = 0; i < Robot::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) {
      const Sv<Scalar> s = placed_axis<Robot, Scalar>(oMi[i], i, k);
      const Vec3<Scalar> col = inv_m * (ms[i] * lin(s) + cross(ang(s), mc[i]));
      for (int r = 0; r < 3; ++r) J[Robot::NV * r + d.vi[i] + k] = col.x[r];
    }
}

// [kinetic, potential, mechanical] energy, potential relative to the world origin.
template <class Robot, class Scalar> TG_HD void energy(const Scalar* q, const Scalar* qd, Scalar* out, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  SE3<Scalar> liMi[Robot::NB], oMi[Robot::NB];
  Sv<Scalar> v[Robot::NB];
  forward_kinematics<Robot, Scalar>(q, liMi, oMi);
  const Vec3<Scalar> g = v3(Scalar(d.gravity[0]), Scalar(d.gravity[1]), Scalar(d.gravity[2]));
  Scalar kinetic = 0, potential = 0;
  for (int i = 0; i < Robot::NB; ++i) {
    const Sv<Scalar> vJ = joint_motion<Robot, Scalar>(i, qd);
    v[i] = d.parent[i] < 0 ? vJ : actinv_motion(liMi[i], v[d.parent[i]]) + vJ;
    kinetic += Scalar(0.5) * dot(v[i], mul(pi[i], v[i]));
    potential -= dot(g, body_moment(i, oMi, pi));
  }
  // The rotors' (armature) kinetic energy.
  for (int k = 0; k < Robot::NV; ++k) kinetic += Scalar(0.5) * Scalar(d.armature[k]) * qd[k] * qd[k];
  out[0] = kinetic;
  out[1] = potential;
  out[2] = kinetic + potential;
}

// Centroidal momentum matrix A (6 x NV) and momentum h = A qd, [linear; angular about the com].
template <class Robot, class Scalar> TG_HD void ccrba(const Scalar* q, const Scalar* qd, Scalar* A, Scalar* h, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  SE3<Scalar> liMi[Robot::NB], oMi[Robot::NB];
  forward_kinematics<Robot, Scalar>(q, liMi, oMi);
  // Composite inertia of each subtree, in the world frame.
  Inertia<Scalar> Yc[Robot::NB];
  for (int i = 0; i < Robot::NB; ++i) Yc[i] = act(oMi[i], pi[i]);
  for (int i = Robot::NB - 1; i >= 0; --i)
    if (d.parent[i] >= 0) Yc[d.parent[i]] = Yc[d.parent[i]] + Yc[i];
  Vec3<Scalar> c = v3(Scalar(0), Scalar(0), Scalar(0));
  for (int i = 0; i < Robot::NB; ++i) c = c + body_moment(i, oMi, pi);
  c = (Scalar(1) / pi.total_mass()) * c;
  // Column of joint dof: momentum of its subtree moving along the world axis, moved to the com.
  for (int i = 0; i < Robot::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) {
      const Sv<Scalar> hk = mul(Yc[i], placed_axis<Robot, Scalar>(oMi[i], i, k));
      const Vec3<Scalar> l = lin(hk), n = ang(hk) - cross(c, lin(hk));
      for (int r = 0; r < 3; ++r) {
        A[NV * r + d.vi[i] + k] = l.x[r];
        A[NV * (3 + r) + d.vi[i] + k] = n.x[r];
      }
    }
  for (int r = 0; r < 6; ++r) {
    Scalar acc = 0;
    for (int col = 0; col < NV; ++col) acc += A[NV * r + col] * qd[col];
    h[r] = acc;
  }
}

// Shared by the centroidal derivatives: world placements and velocities, joint axes and their
// rates, subtree inertias Yc, inertia rates dYc and momenta H, total mass and com.
template <class Robot, class Scalar> struct CentroidalWork {
  SE3<Scalar> oMi[Robot::NB];
  Sv<Scalar> v[Robot::NB], H[Robot::NB], s[Robot::NV], sdot[Robot::NV], w[Robot::NV];  // w = v_parent x s
  Inertia<Scalar> Yc[Robot::NB];
  M6<Scalar> dYc[Robot::NB];
  Scalar m;
  Vec3<Scalar> c;
};

template <class Robot, class Scalar> TG_HD void centroidal_setup(const Scalar* q, const Scalar* qd, CentroidalWork<Robot, Scalar>& W,
                            const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  W.m = pi.total_mass();
  W.c = v3(Scalar(0), Scalar(0), Scalar(0));
  for (int i = 0; i < Robot::NB; ++i) {
    const int p = d.parent[i];
    const SE3<Scalar> liMi = joint_placement<Robot, Scalar>(i, q);
    W.oMi[i] = p < 0 ? liMi : W.oMi[p] * liMi;
    const Sv<Scalar> vp = p < 0 ? sv_zero<Scalar>() : W.v[p];
    W.v[i] = vp;
    for (int k = 0; k < d.nvj[i]; ++k) {
      W.s[d.vi[i] + k] = act_motion(W.oMi[i], joint_axis<Robot, Scalar>(i, k));
      W.v[i] = W.v[i] + qd[d.vi[i] + k] * W.s[d.vi[i] + k];
    }
    for (int k = 0; k < d.nvj[i]; ++k) {
      W.sdot[d.vi[i] + k] = cross_motion(W.v[i], W.s[d.vi[i] + k]);
      W.w[d.vi[i] + k] = cross_motion(vp, W.s[d.vi[i] + k]);
    }
    W.Yc[i] = act(W.oMi[i], pi[i]);
    W.dYc[i] = inertia_rate_matrix(W.Yc[i], W.v[i]);
    W.H[i] = mul(W.Yc[i], W.v[i]);
    W.c = W.c + body_moment(i, W.oMi, pi);
  }
  W.c = (Scalar(1) / W.m) * W.c;
  for (int i = Robot::NB - 1; i >= 0; --i) {
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
template <class Robot, class Scalar> TG_HD void cmm_time_variation(const Scalar* q, const Scalar* qd, Scalar* Adot, Scalar* A,
                                  const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  CentroidalWork<Robot, Scalar> W;
  centroidal_setup<Robot, Scalar>(q, qd, W, pi);
  for (int i = 0; i < Robot::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) {
      const int col = d.vi[i] + k;
      const Sv<Scalar> dF = at_point(mul(W.dYc[i], W.s[col]) + mul(W.Yc[i], W.sdot[col]), W.c);
      const Sv<Scalar> F = at_point(mul(W.Yc[i], W.s[col]), W.c);
      for (int r = 0; r < 6; ++r) {
        Adot[Robot::NV * r + col] = dF.v[r];
        if (A) A[Robot::NV * r + col] = F.v[r];
      }
    }
}

// d h / dq (6 x NV), h the centroidal momentum at fixed qd. Moving joint j carries its subtree's
// momentum H_j by the twist s (s x* H_j) while the parent's velocity stays (Yc_j (v_parent x s));
// the com moves by J_com's column, shifting the angular part by -(dc x h_lin).
template <class Robot, class Scalar> TG_HD void dccrba(const Scalar* q, const Scalar* qd, Scalar* dh_dq, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  CentroidalWork<Robot, Scalar> W;
  centroidal_setup<Robot, Scalar>(q, qd, W, pi);
  Sv<Scalar> total = sv_zero<Scalar>();
  for (int i = 0; i < Robot::NB; ++i)
    if (d.parent[i] < 0) total = total + W.H[i];
  // Subtree mass and mass-weighted com, for the com's motion.
  Scalar ms[Robot::NB];
  Vec3<Scalar> mc[Robot::NB];
  for (int i = 0; i < Robot::NB; ++i) {
    ms[i] = pi.mass(i);
    mc[i] = body_moment(i, W.oMi, pi);
  }
  for (int i = Robot::NB - 1; i >= 0; --i)
    if (d.parent[i] >= 0) {
      ms[d.parent[i]] += ms[i];
      mc[d.parent[i]] = mc[d.parent[i]] + mc[i];
    }
  for (int i = 0; i < Robot::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) {
      const int col = d.vi[i] + k;
      const Sv<Scalar>& s = W.s[col];
      const Sv<Scalar> dH = cross_force(s, W.H[i]) + mul(W.Yc[i], W.w[col]);
      const Vec3<Scalar> dc = (Scalar(1) / W.m) * (ms[i] * lin(s) + cross(ang(s), mc[i]));
      const Sv<Scalar> col6 = at_point(dH, W.c) - sv(v3(Scalar(0), Scalar(0), Scalar(0)), cross(dc, lin(total)));
      for (int r = 0; r < 6; ++r) dh_dq[Robot::NV * r + col] = col6.v[r];
    }
}

}  // namespace tg
