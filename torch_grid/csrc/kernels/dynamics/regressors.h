// Inertial-parameter regressors: tau = Y pi, KE = Yk . pi, PE = Yp . pi, with pi stacking each
// body's dynamic parameters in Pinocchio's order [m, h_x, h_y, h_z, I_xx, I_xy, I_yy, I_xz, I_yz,
// I_zz], h = m c and I the rotational inertia about the joint frame origin.
#pragma once

#include "kernels/spatial/joints.h"

namespace tg {

// Body force f = I a + v x* (I v) as 10 columns, one per dynamic parameter (joint frame).
template <class Scalar> TG_HD void body_force_regressor(const Sv<Scalar>& v, const Sv<Scalar>& a, Sv<Scalar>* cols) {
  const Vec3<Scalar> vl = lin(v), va = ang(v), al = lin(a), aa = ang(a);
  const Vec3<Scalar> zero = v3(Scalar(0), Scalar(0), Scalar(0));
  cols[0] = sv(al + cross(va, vl), zero);
  for (int k = 0; k < 3; ++k) {
    Vec3<Scalar> e = zero;
    e.x[k] = Scalar(1);
    // I v with h = e: [v_a x e; e x v_l]; then v x* (I v) added to I a.
    const Vec3<Scalar> p = cross(va, e), n = cross(e, vl);
    cols[1 + k] = sv(cross(aa, e) + cross(va, p), cross(e, al) + cross(va, n) + cross(vl, p));
  }
  // I_o basis (symmetric): xx, xy, yy, xz, yz, zz.
  const int rows[6] = {0, 0, 1, 0, 1, 2}, colsk[6] = {0, 1, 1, 2, 2, 2};
  for (int k = 0; k < 6; ++k) {
    Mat3<Scalar> E{};
    E.m[3 * rows[k] + colsk[k]] = Scalar(1);
    E.m[3 * colsk[k] + rows[k]] = Scalar(1);
    cols[4 + k] = sv(zero, mul(E, aa) + cross(va, mul(E, va)));
  }
}

// Y (NV x 10 NB): column block i holds body i's regressor, carried to each joint above it; the
// entries that can be nonzero go to put(row, column, value) (Y's other entries are zero).
// liMi: the joint placements (JointPlacements, or a shared Placements pass).
template <class Robot, class Scalar, class P, class Put>
TG_HD_INLINE void inverse_dynamics_regressor_entries(P& liMi, const Scalar* qd, const Scalar* qdd, Put&& put) {
  const auto& d = data<Robot, Scalar>();
  Sv<Scalar> v[Robot::NB], a[Robot::NB];
  for (int i = 0; i < Robot::NB; ++i) {
    const int p = d.parent[i];
    const Sv<Scalar> vJ = joint_motion<Robot, Scalar>(i, qd);
    const auto& X = liMi.place(i);
    v[i] = p < 0 ? vJ : actinv_motion(X, v[p]) + vJ;
    a[i] = actinv_motion(X, p < 0 ? base_acceleration<Robot, Scalar>() : a[p]) + joint_motion<Robot, Scalar>(i, qdd) +
           cross_motion(v[i], vJ);
    Sv<Scalar> f[10];
    body_force_regressor(v[i], a[i], f);
    for (int j = i;;) {
      for (int l = 0; l < d.nvj[j]; ++l) {
        const Sv<Scalar> s = joint_axis<Robot, Scalar>(j, l);
        for (int c = 0; c < 10; ++c) put(d.vi[j] + l, 10 * i + c, dot(s, f[c]));
      }
      if (d.parent[j] < 0) break;
      const auto& Xj = liMi[j];
      for (int c = 0; c < 10; ++c) f[c] = act_force(Xj, f[c]);
      j = d.parent[j];
    }
  }
}

template <class Robot, class Scalar, class P> TG_HD_INLINE void inverse_dynamics_regressor_placed(P& liMi, const Scalar* qd, const Scalar* qdd, Scalar* Y) {
  constexpr int NP = 10 * Robot::NB;
  for (int k = 0; k < Robot::NV * NP; ++k) Y[k] = Scalar(0);
  inverse_dynamics_regressor_entries<Robot, Scalar>(liMi, qd, qdd, [Y](int r, int c, const Scalar& y) { Y[NP * r + c] = y; });
}

template <class Robot, class Scalar> TG_HD void inverse_dynamics_regressor(const Scalar* q, const Scalar* qd, const Scalar* qdd, Scalar* Y) {
  JointPlacements<Robot, Scalar> liMi(q);
  inverse_dynamics_regressor_placed<Robot, Scalar>(liMi, qd, qdd, Y);
}

template <class Robot, class Scalar>
TG_HD void inverse_dynamics_regressor(const Placements<Robot, Scalar>& K, const Scalar* qd, const Scalar* qdd, Scalar* Y) {
  inverse_dynamics_regressor_placed<Robot, Scalar>(K, qd, qdd, Y);
}

// Kinetic energy KE = Yk . pi (10 NB): per body [|v_l|^2 / 2, v_l x v_a, v_a v_a^T / 2 (sym)].
template <class Robot, class Scalar> TG_HD void kinetic_energy_regressor(const Scalar* q, const Scalar* qd, Scalar* Yk) {
  Scalar v[6 * Robot::NB];
  body_velocities<Robot, Scalar>(q, qd, v);
  for (int i = 0; i < Robot::NB; ++i) {
    const Vec3<Scalar> vl = load3(v + 6 * i), w = load3(v + 6 * i + 3), h = cross(vl, w);
    Scalar* y = Yk + 10 * i;
    y[0] = Scalar(0.5) * dot(vl, vl);
    for (int k = 0; k < 3; ++k) y[1 + k] = h.x[k];
    y[4] = Scalar(0.5) * w.x[0] * w.x[0];
    y[5] = w.x[0] * w.x[1];
    y[6] = Scalar(0.5) * w.x[1] * w.x[1];
    y[7] = w.x[0] * w.x[2];
    y[8] = w.x[1] * w.x[2];
    y[9] = Scalar(0.5) * w.x[2] * w.x[2];
  }
}

// Potential energy PE = Yp . pi (10 NB): PE_i = -g . (m p_i + R_i h), p_i, R_i the joint frame's placement.
template <class Robot, class Scalar> TG_HD void potential_energy_regressor(const Scalar* q, Scalar* Yp) {
  const auto& d = data<Robot, Scalar>();
  SE3<Scalar> liMi[Robot::NB], oMi[Robot::NB];
  forward_kinematics<Robot, Scalar>(q, liMi, oMi);
  const Vec3<Scalar> g = v3(Scalar(d.gravity[0]), Scalar(d.gravity[1]), Scalar(d.gravity[2]));
  for (int i = 0; i < Robot::NB; ++i) {
    Scalar* y = Yp + 10 * i;
    y[0] = -dot(g, oMi[i].p);
    store3(Scalar(-1) * mulT(oMi[i].R, g), y + 1);
    for (int k = 4; k < 10; ++k) y[k] = Scalar(0);
  }
}

}  // namespace tg
