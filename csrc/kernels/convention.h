// The MuJoCo (mjx) convention, fused into every kernel: convert the inputs to Pinocchio's
// convention on entry, reframe the outputs on exit. Only the free-flyer root differs:
//   qpos quaternion wxyz (pin: xyzw); qvel = [v_lin WORLD; w LOCAL] (pin: [v_lin LOCAL; w LOCAL]).
// With G = blockdiag(R, I): v_mjx = G v_pin, forces covary (G), M -> G M G^T, J -> J G^T.
// See shared conventions reference; torch_grid/conventions.py is the same in torch.
#pragma once

#include "spatial.h"

namespace tg {

template <class M, class S, int C> struct Conv {
  static constexpr bool active = (C == MJX) && M::FLOATING;
  S q[M::NQ];  // configuration in Pinocchio's layout
  Mat3<S> R;   // base rotation (identity when inactive)

  TG_HD explicit Conv(const S* q_in) {
    for (int k = 0; k < M::NQ; ++k) q[k] = q_in[k];
    R = identity3<S>();
    if constexpr (active) {
      // wxyz -> xyzw
      q[3] = q_in[4]; q[4] = q_in[5]; q[5] = q_in[6]; q[6] = q_in[3];
      R = quat_rotation(q[3], q[4], q[5], q[6]);
    }
  }
  // Inputs: each returns the input in Pinocchio's convention, `in` itself when there is nothing to
  // convert, else `buf` (NV) filled.
  // Velocity or generalized force in: base-linear part R^T x.
  TG_HD const S* velocity(const S* in, S* buf) const {
    if constexpr (active) {
      for (int k = 0; k < M::NV; ++k) buf[k] = in[k];
      store3(mulT(R, load3(in)), buf);
      return buf;
    } else {
      return in;
    }
  }
  TG_HD const S* force(const S* in, S* buf) const { return velocity(in, buf); }
  // Acceleration in: a_lin = R^T a_mjx - w x v_lin (v already in Pinocchio's convention).
  TG_HD const S* acceleration(const S* v, const S* in, S* buf) const {
    if constexpr (active) {
      for (int k = 0; k < M::NV; ++k) buf[k] = in[k];
      store3(mulT(R, load3(in)) - cross(load3(v + 3), load3(v)), buf);
      return buf;
    } else {
      return in;
    }
  }
  // Generalized force out (covector): base-linear rows R x.
  TG_HD void force_out(S* tau) const {
    if constexpr (active) store3(mul(R, load3(tau)), tau);
  }
  // Joint acceleration out: qdd_lin = R (qdd_lin + w x v_lin).
  TG_HD void acceleration_out(const S* v, S* qdd) const {
    if constexpr (active) store3(mul(R, load3(qdd) + cross(load3(v + 3), load3(v))), qdd);
  }
  // Matrix (rows x NV) out: base-linear columns right-multiplied by R^T.
  TG_HD void columns_out(S* J, int rows) const {
    if constexpr (active)
      for (int r = 0; r < rows; ++r) store3(mul(R, load3(J + M::NV * r)), J + M::NV * r);
  }
  // Jacobian time derivative out: d/dt (J G^-1) = Jdot G^-1 + J d(G^-1)/dt, and d(R^T)/dt = -[w]x R^T
  // with w = qd[3:6] the base's local angular velocity (qd in Pinocchio's convention).
  TG_HD void jacobian_dot_out(const S* qd, const S* J, S* Jdot, int rows) const {
    if constexpr (active) {
      const Vec3<S> w = load3(qd + 3);
      for (int r = 0; r < rows; ++r) {
        // row r of J [w]x is J_r x w
        const Vec3<S> jd = load3(Jdot + M::NV * r), j = load3(J + M::NV * r);
        store3(mul(R, jd - cross(j, w)), Jdot + M::NV * r);
      }
    }
  }
  // Centroidal momentum derivative out: MuJoCo holds qvel fixed, so turning the base also turns
  // Pinocchio's v_lin (Jv_q[:, ang a] = -(e_a x v_lin)): dh/dq_mjx = dh/dq G^-1 + A_pin Jv_q.
  TG_HD void momentum_gradient_out(const S* v, const S* A, S* dh) const {
    if constexpr (active) {
      const Vec3<S> vl = load3(v);
      for (int r = 0; r < 6; ++r) {
        const Vec3<S> a = load3(A + M::NV * r);
        for (int c = 0; c < 3; ++c) {
          Vec3<S> e = v3(S(0), S(0), S(0));
          e.x[c] = S(1);
          dh[M::NV * r + 3 + c] += dot(a, cross(vl, e));
        }
      }
      columns_out(dh, 6);
    }
  }
  // The same for a vector-Jacobian product: lambda^T (MuJoCo's d tau/dq, d tau/dqd) from Pinocchio's
  // mu^T d tau/dq, mu^T d tau/dqd with mu = G^T lambda, and M mu and tau (Pinocchio's).
  TG_HD void inverse_dynamics_vjp_out(const S* v, const S* a, const S* tau, const S* Mmu, const S* mu, S* g_q, S* g_qd) const {
    if constexpr (active) {
      const GradientColumns g = gradient_columns(v, a);
      const Vec3<S> gv = load3(g_qd), mm = load3(Mmu), ml = load3(mu), tl = load3(tau);
      force_out(g_q);  // x^T G^-1: base-linear part rotated by R
      force_out(g_qd);
      for (int c = 0; c < 3; ++c) {
        Vec3<S> e = v3(S(0), S(0), S(0));
        e.x[c] = S(1);
        g_q[3 + c] += dot(gv, g.Jv[c]) + dot(mm, g.Jaq[c]) + dot(ml, cross(e, tl));
        g_qd[c] += dot(mm, g.Jav_lin[c]);
        g_qd[3 + c] += dot(mm, g.Jav_ang[c]);
      }
    }
  }
  // Coriolis matrix out: C_mjx = G (C G^T + M K) with K qd = [v_lin x w; 0], Pinocchio's base
  // acceleration at MuJoCo's qacc = 0, so that C_mjx qd + g_mjx = MuJoCo's bias force; Mb as below.
  TG_HD void coriolis_out(const S* v, const S* Mb, S* Cq) const {
    if constexpr (active) {
      const Vec3<S> vl = load3(v);
      columns_out(Cq, M::NV);
      for (int r = 0; r < M::NV; ++r) {
        const Vec3<S> m = load3(Mb + 3 * r);
        for (int c = 0; c < 3; ++c) {
          Vec3<S> e = v3(S(0), S(0), S(0));
          e.x[c] = S(1);
          Cq[M::NV * r + 3 + c] += dot(m, cross(vl, e));
        }
      }
      force_rows_out(Cq, M::NV);
    }
  }
  // Matrix (NV x cols) of generalized forces out: base-linear rows left-multiplied by R (G X).
  TG_HD void force_rows_out(S* X, int cols) const {
    if constexpr (active)
      for (int c = 0; c < cols; ++c) {
        const Vec3<S> x = mul(R, v3(X[c], X[cols + c], X[2 * cols + c]));
        X[c] = x.x[0];
        X[cols + c] = x.x[1];
        X[2 * cols + c] = x.x[2];
      }
  }
  // The weight of Pinocchio's entry (r, c) in sum(W * X_mjx) for X_mjx = force_rows_out(X): (G^T W)[r, c].
  template <class T> TG_HD S force_rows_weight(const T* W, int r, int c, int cols) const {
    if constexpr (active)
      if (r < 3) return R.m[r] * W[c] + R.m[3 + r] * W[cols + c] + R.m[6 + r] * W[2 * cols + c];
    return S(W[cols * r + c]);
  }
  // Symmetric NV x NV matrix out: congruence G X G^T.
  TG_HD void congruence_out(S* X) const {
    if constexpr (active) {
      columns_out(X, M::NV);
      force_rows_out(X, M::NV);
    }
  }

  // Inverse-dynamics derivatives out. MuJoCo holds qvel and qacc fixed in its own frame, so moving
  // the base rotation also moves the Pinocchio-frame v and a (Jv_q, Ja_q), and changes G (pref):
  //   dtau/dq_mjx  = G (dtau/dq G^-1 + dtau/dqd Jv_q + M Ja_q) + pref
  //   dtau/dqd_mjx = G (dtau/dqd G^-1 + M Ja_v)
  // with, for the base rotation a, on the base-linear rows (v, a in Pinocchio's convention):
  //   Jv_q[:, ang a] = -(e_a x v_lin)
  //   Ja_q[:, ang a] = -(e_a x a_lin) - e_a x (w x v_lin) + w x (e_a x v_lin)
  //   Ja_v[:, lin a] = -w x (R^T e_a),  Ja_v[:, ang a] = -(e_a x v_lin),  pref[lin, ang a] = R (e_a x tau_lin).
  // Columns (base-linear rows only) of Jv_q, Ja_q and Ja_v above, for the base rotation c = 0..2.
  struct GradientColumns {
    Vec3<S> Jv[3], Jaq[3], Jav_lin[3], Jav_ang[3];
  };
  TG_HD GradientColumns gradient_columns(const S* v, const S* a) const {
    const Vec3<S> vl = load3(v), w = load3(v + 3), al = load3(a);
    GradientColumns g;
    for (int c = 0; c < 3; ++c) {
      Vec3<S> e = v3(S(0), S(0), S(0));
      e.x[c] = S(1);
      g.Jv[c] = cross(vl, e);
      g.Jaq[c] = cross(al, e) - cross(e, cross(w, vl)) + cross(w, cross(e, vl));
      g.Jav_lin[c] = S(-1) * cross(w, mulT(R, e));
      g.Jav_ang[c] = cross(vl, e);
    }
    return g;
  }

  // Mb: the base-linear columns of Pinocchio's M (NV x 3), all of M these terms read.
  TG_HD void inverse_dynamics_gradient_out(const S* v, const S* a, const S* tau, const S* Mb, S* dq, S* dv) const {
    if constexpr (active) {
      constexpr int NV = M::NV;
      const GradientColumns g = gradient_columns(v, a);
      // The Jv_q and Ja terms read Pinocchio's dtau/dqd and M before any reframe.
      S add_q[NV][3], add_vl[NV][3], add_va[NV][3];
      for (int r = 0; r < NV; ++r) {
        const Vec3<S> Mr = load3(Mb + 3 * r), dvr = load3(dv + NV * r);
        for (int c = 0; c < 3; ++c) {
          add_q[r][c] = dot(dvr, g.Jv[c]) + dot(Mr, g.Jaq[c]);
          add_vl[r][c] = dot(Mr, g.Jav_lin[c]);
          add_va[r][c] = dot(Mr, g.Jav_ang[c]);
        }
      }
      columns_out(dq, NV);  // X G^-1
      columns_out(dv, NV);
      for (int r = 0; r < NV; ++r)
        for (int c = 0; c < 3; ++c) {
          dq[NV * r + 3 + c] += add_q[r][c];
          dv[NV * r + c] += add_vl[r][c];
          dv[NV * r + 3 + c] += add_va[r][c];
        }
      force_rows_out(dq, NV);  // G (.)
      force_rows_out(dv, NV);
      const Vec3<S> tl = load3(tau);
      for (int c = 0; c < 3; ++c) {
        Vec3<S> e = v3(S(0), S(0), S(0));
        e.x[c] = S(1);
        const Vec3<S> pref = mul(R, cross(e, tl));
        for (int r = 0; r < 3; ++r) dq[NV * r + 3 + c] += pref.x[r];
      }
    }
  }
};

}  // namespace tg
