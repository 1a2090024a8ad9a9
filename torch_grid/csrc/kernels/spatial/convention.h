// The MuJoCo convention, fused into every kernel: convert the inputs to Pinocchio's
// convention on entry, reframe the outputs on exit. Only quaternion joints differ:
//   a ball joint's qpos quaternion is wxyz (pin: xyzw), its qvel the same local angular velocity;
//   the free-flyer root's too, and qvel = [v_lin WORLD; w LOCAL] (pin: [v_lin LOCAL; w LOCAL]).
// With G = blockdiag(R, I): v_mujoco = G v_pin, forces covary (G), M -> G M G^T, J -> J G^T.
// docs/guides/conventions.md states them; torch_grid/space/conventions.py is the same in torch.
#pragma once

#include "kernels/spatial/joints.h"

namespace tg {

template <class Robot, class Scalar, int C> struct Conv {
  static constexpr bool active = (C == MUJOCO) && Robot::NFREE > 0;  // a free joint's velocity is reframed
  static constexpr int NB3 = 3 * (Robot::NFREE > 0 ? Robot::NFREE : 1);  // columns of Mb below
  Scalar q[Robot::NQ];                                       // configuration in Pinocchio's layout
  Mat3<Scalar> R[Robot::NFREE > 0 ? Robot::NFREE : 1];           // each free joint's rotation
  int vi[Robot::NFREE > 0 ? Robot::NFREE : 1];              // and its first dof

  TG_HD explicit Conv(const Scalar* q_in) {
    const auto& d = data<Robot, Scalar>();
    for (int k = 0; k < Robot::NQ; ++k) q[k] = q_in[k];
    if constexpr (active)
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int i = d.free_joint[f], a = d.qi[i] + 3;
        // wxyz -> xyzw
        q[a] = q_in[a + 1]; q[a + 1] = q_in[a + 2]; q[a + 2] = q_in[a + 3]; q[a + 3] = q_in[a];
        R[f] = quat_rotation(q[a], q[a + 1], q[a + 2], q[a + 3]);
        vi[f] = d.vi[i];
      }
    if constexpr (C == MUJOCO && Robot::BALLS)
      for (int i = 0; i < Robot::NB; ++i)
        if (d.jtype[i] == BALL) {
          const Scalar* in = q_in + d.qi[i];
          Scalar* out = q + d.qi[i];
          out[0] = in[1]; out[1] = in[2]; out[2] = in[3]; out[3] = in[0];
        }
  }
  // Inputs: each returns the input in Pinocchio's convention, `in` itself when there is nothing to
  // convert, else `buf` (NV) filled.
  // Velocity or generalized force in: each free joint's linear part R^T x.
  TG_HD const Scalar* velocity(const Scalar* in, Scalar* buf) const {
    if constexpr (active) {
      for (int k = 0; k < Robot::NV; ++k) buf[k] = in[k];
      for (int f = 0; f < Robot::NFREE; ++f) store3(mulT(R[f], load3(in + vi[f])), buf + vi[f]);
      return buf;
    } else {
      return in;
    }
  }
  TG_HD const Scalar* force(const Scalar* in, Scalar* buf) const { return velocity(in, buf); }
  // Acceleration in: a_lin = R^T a_mujoco - w x v_lin (v already in Pinocchio's convention).
  TG_HD const Scalar* acceleration(const Scalar* v, const Scalar* in, Scalar* buf) const {
    if constexpr (active) {
      for (int k = 0; k < Robot::NV; ++k) buf[k] = in[k];
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int b = vi[f];
        store3(mulT(R[f], load3(in + b)) - cross(load3(v + b + 3), load3(v + b)), buf + b);
      }
      return buf;
    } else {
      return in;
    }
  }
  // Generalized force out (covector): each free joint's linear rows R x.
  TG_HD void force_out(Scalar* tau) const {
    if constexpr (active)
      for (int f = 0; f < Robot::NFREE; ++f) store3(mul(R[f], load3(tau + vi[f])), tau + vi[f]);
  }
  // Joint velocity out: v_lin = R v_lin (a velocity maps as a force does, by G).
  TG_HD void velocity_out(Scalar* v) const { force_out(v); }
  // Joint acceleration out: qdd_lin = R (qdd_lin + w x v_lin).
  TG_HD void acceleration_out(const Scalar* v, Scalar* qdd) const {
    if constexpr (active)
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int b = vi[f];
        store3(mul(R[f], load3(qdd + b) + cross(load3(v + b + 3), load3(v + b))), qdd + b);
      }
  }
  // Matrix (rows x NV) out: each free joint's linear columns right-multiplied by R^T.
  TG_HD void columns_out(Scalar* J, int rows) const {
    if constexpr (active)
      for (int f = 0; f < Robot::NFREE; ++f)
        for (int r = 0; r < rows; ++r) store3(mul(R[f], load3(J + Robot::NV * r + vi[f])), J + Robot::NV * r + vi[f]);
  }
  // Jacobian time derivative out: d/dt (J G^-1) = Jdot G^-1 + J d(G^-1)/dt, and d(R^T)/dt = -[w]x R^T
  // with w the free joint's local angular velocity (qd in Pinocchio's convention).
  TG_HD void jacobian_dot_out(const Scalar* qd, const Scalar* J, Scalar* Jdot, int rows) const {
    if constexpr (active)
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int b = vi[f];
        const Vec3<Scalar> w = load3(qd + b + 3);
        for (int r = 0; r < rows; ++r) {
          // row r of J [w]x is J_r x w
          const Vec3<Scalar> jd = load3(Jdot + Robot::NV * r + b), j = load3(J + Robot::NV * r + b);
          store3(mul(R[f], jd - cross(j, w)), Jdot + Robot::NV * r + b);
        }
      }
  }
  // Centroidal momentum derivative out: MuJoCo holds qvel fixed, so turning a free joint also turns
  // Pinocchio's v_lin (Jv_q[:, ang a] = -(e_a x v_lin)): dh/dq_mujoco = dh/dq G^-1 + A_pin Jv_q.
  TG_HD void momentum_gradient_out(const Scalar* v, const Scalar* A, Scalar* dh) const {
    if constexpr (active) {
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int b = vi[f];
        const Vec3<Scalar> vl = load3(v + b);
        for (int r = 0; r < 6; ++r) {
          const Vec3<Scalar> a = load3(A + Robot::NV * r + b);
          for (int c = 0; c < 3; ++c) dh[Robot::NV * r + b + 3 + c] += dot(a, cross(vl, unit3<Scalar>(c)));
        }
      }
      columns_out(dh, 6);
    }
  }
  // The same for a vector-Jacobian product: lambda^T (MuJoCo's d tau/dq, d tau/dqd) from Pinocchio's
  // mu^T d tau/dq, mu^T d tau/dqd with mu = G^T lambda, and M mu and tau (Pinocchio's).
  TG_HD void inverse_dynamics_vjp_out(const Scalar* v, const Scalar* a, const Scalar* tau, const Scalar* Mmu, const Scalar* mu, Scalar* g_q, Scalar* g_qd) const {
    if constexpr (active) {
      Vec3<Scalar> gv[Robot::NFREE];  // Pinocchio's g_qd, linear parts
      for (int f = 0; f < Robot::NFREE; ++f) gv[f] = load3(g_qd + vi[f]);
      force_out(g_q);  // x^T G^-1: linear parts rotated by R
      force_out(g_qd);
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int b = vi[f];
        const GradientColumns g = gradient_columns(f, v, a);
        const Vec3<Scalar> mm = load3(Mmu + b), ml = load3(mu + b), tl = load3(tau + b);
        for (int c = 0; c < 3; ++c) {
          g_q[b + 3 + c] += dot(gv[f], g.Jv[c]) + dot(mm, g.Jaq[c]) + dot(ml, cross(unit3<Scalar>(c), tl));
          g_qd[b + c] += dot(mm, g.Jav_lin[c]);
          g_qd[b + 3 + c] += dot(mm, g.Jav_ang[c]);
        }
      }
    }
  }
  // Coriolis matrix out: C_mujoco = G (C G^T + M K) with K = d(G^T)/dt, whose free-joint linear block is
  // d(R^T)/dt = -[w]x R^T. K qd = [v_lin x w; 0] is Pinocchio's acceleration at MuJoCo's qacc = 0, so
  // C_mujoco qd + g_mujoco = MuJoCo's bias force, and dM_mujoco/dt = C_mujoco + C_mujoco^T as
  // Pinocchio's dM/dt = C + C^T (M_mujoco = G M G^T); Mb as below.
  TG_HD void coriolis_out(const Scalar* v, const Scalar* Mb, Scalar* Cq) const {
    if constexpr (active) {
      columns_out(Cq, Robot::NV);
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int b = vi[f];
        const Vec3<Scalar> w = load3(v + b + 3);
        Vec3<Scalar> k[3];  // K's columns: (R^T e_c) x w
        for (int c = 0; c < 3; ++c) k[c] = cross(mulT(R[f], unit3<Scalar>(c)), w);
        for (int r = 0; r < Robot::NV; ++r) {
          const Vec3<Scalar> m = load3(Mb + NB3 * r + 3 * f);
          for (int c = 0; c < 3; ++c) Cq[Robot::NV * r + b + c] += dot(m, k[c]);
        }
      }
      force_rows_out(Cq, Robot::NV);
    }
  }
  // Matrix (NV x cols) of generalized forces out: each free joint's linear rows left-multiplied by R (G X).
  TG_HD void force_rows_out(Scalar* X, int cols) const {
    if constexpr (active)
      for (int f = 0; f < Robot::NFREE; ++f) {
        Scalar* x0 = X + cols * vi[f];
        for (int c = 0; c < cols; ++c) {
          const Vec3<Scalar> x = mul(R[f], v3(x0[c], x0[cols + c], x0[2 * cols + c]));
          x0[c] = x.x[0];
          x0[cols + c] = x.x[1];
          x0[2 * cols + c] = x.x[2];
        }
      }
  }
  // The weight of Pinocchio's entry (r, c) in sum(W * X_mujoco) for X_mujoco = force_rows_out(X): (G^T W)[r, c].
  template <class T> TG_HD Scalar force_rows_weight(const T* W, int r, int c, int cols) const {
    if constexpr (active)
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int k = r - vi[f];
        if (k >= 0 && k < 3) {
          const T* w0 = W + cols * vi[f] + c;
          return R[f].m[k] * w0[0] + R[f].m[3 + k] * w0[cols] + R[f].m[6 + k] * w0[2 * cols];
        }
      }
    return Scalar(W[cols * r + c]);
  }
  // Symmetric NV x NV matrix out: congruence G X G^T.
  TG_HD void congruence_out(Scalar* X) const {
    if constexpr (active) {
      columns_out(X, Robot::NV);
      force_rows_out(X, Robot::NV);
    }
  }

  // Inverse-dynamics derivatives out. MuJoCo holds qvel and qacc fixed in its own frame, so turning a
  // free joint also moves the Pinocchio-frame v and a (Jv_q, Ja_q), and changes G (pref):
  //   dtau/dq_mujoco  = G (dtau/dq G^-1 + dtau/dqd Jv_q + M Ja_q) + pref
  //   dtau/dqd_mujoco = G (dtau/dqd G^-1 + M Ja_v)
  // with, for the free joint's rotation a, on its linear rows (v, a in Pinocchio's convention):
  //   Jv_q[:, ang a] = -(e_a x v_lin)
  //   Ja_q[:, ang a] = -(e_a x a_lin) - e_a x (w x v_lin) + w x (e_a x v_lin)
  //   Ja_v[:, lin a] = -w x (R^T e_a),  Ja_v[:, ang a] = -(e_a x v_lin),  pref[lin, ang a] = R (e_a x tau_lin).
  // Columns (the free joint's linear rows only) of Jv_q, Ja_q and Ja_v above, for its rotation c = 0..2.
  struct GradientColumns {
    Vec3<Scalar> Jv[3], Jaq[3], Jav_lin[3], Jav_ang[3];
  };
  TG_HD GradientColumns gradient_columns(int f, const Scalar* v, const Scalar* a) const {
    const int b = vi[f];
    const Vec3<Scalar> vl = load3(v + b), w = load3(v + b + 3), al = load3(a + b);
    GradientColumns g;
    for (int c = 0; c < 3; ++c) {
      const Vec3<Scalar> e = unit3<Scalar>(c);
      g.Jv[c] = cross(vl, e);
      g.Jaq[c] = cross(al, e) - cross(e, cross(w, vl)) + cross(w, cross(e, vl));
      g.Jav_lin[c] = Scalar(-1) * cross(w, mulT(R[f], e));
      g.Jav_ang[c] = cross(vl, e);
    }
    return g;
  }

  // Mb: the free joints' linear columns of Pinocchio's M (NV x 3 NFREE, free joint f's at 3f), all of
  // M these terms read.
  TG_HD void inverse_dynamics_derivatives_out(const Scalar* v, const Scalar* a, const Scalar* tau, const Scalar* Mb, Scalar* dq, Scalar* dv) const {
    if constexpr (active) {
      constexpr int NV = Robot::NV;
      // The Jv_q and Ja terms read Pinocchio's dtau/dqd and M before any reframe.
      Scalar add_q[NV][NB3], add_vl[NV][NB3], add_va[NV][NB3];
      for (int f = 0; f < Robot::NFREE; ++f) {
        const GradientColumns g = gradient_columns(f, v, a);
        for (int r = 0; r < NV; ++r) {
          const Vec3<Scalar> Mr = load3(Mb + NB3 * r + 3 * f), dvr = load3(dv + NV * r + vi[f]);
          for (int c = 0; c < 3; ++c) {
            add_q[r][3 * f + c] = dot(dvr, g.Jv[c]) + dot(Mr, g.Jaq[c]);
            add_vl[r][3 * f + c] = dot(Mr, g.Jav_lin[c]);
            add_va[r][3 * f + c] = dot(Mr, g.Jav_ang[c]);
          }
        }
      }
      columns_out(dq, NV);  // X G^-1
      columns_out(dv, NV);
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int b = vi[f];
        for (int r = 0; r < NV; ++r)
          for (int c = 0; c < 3; ++c) {
            dq[NV * r + b + 3 + c] += add_q[r][3 * f + c];
            dv[NV * r + b + c] += add_vl[r][3 * f + c];
            dv[NV * r + b + 3 + c] += add_va[r][3 * f + c];
          }
      }
      force_rows_out(dq, NV);  // G (.)
      force_rows_out(dv, NV);
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int b = vi[f];
        const Vec3<Scalar> tl = load3(tau + b);
        for (int c = 0; c < 3; ++c) {
          const Vec3<Scalar> pref = mul(R[f], cross(unit3<Scalar>(c), tl));
          for (int r = 0; r < 3; ++r) dq[NV * (b + r) + b + 3 + c] += pref.x[r];
        }
      }
    }
  }
};

}  // namespace tg
