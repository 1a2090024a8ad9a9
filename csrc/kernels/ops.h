// The ops exposed to torch: each binds per-sample input/output pointers to an algorithm and to
// the convention's input conversion and output reframe. Shapes and argument order match the op
// table in torch_grid/ops.py, which generates the registration.
#pragma once

#include "aba.h"
#include "centroidal.h"
#include "convention.h"
#include "crba.h"
#include "frames.h"
#include "minv.h"
#include "regressors.h"
#include "rnea.h"
#include "rnea_derivatives.h"

namespace tg {

#define TG_OP_BEGIN(Name)                                                   \
  template <class M, class S, int C> struct Name {                          \
    TG_HD static void run(const S* const* in, S* const* out, const int* iargs, int n_iargs) { \
      (void)iargs; (void)n_iargs;                                           \
      const Conv<M, S, C> cv(in[0]);
#define TG_OP_END \
    }             \
  };

// Columns [c0, c0 + W) of X <- -A X for an NV x NV matrix A and an NV x COLS row-major X: rows of
// the product are sums of rows of X, which keeps the inner loop contiguous; W is a compile-time
// width, so it vectorises.
template <class M, class S, int COLS, int W> TG_HD void negate_left_multiply_block(const S* A, S* X, int c0) {
  constexpr int NV = M::NV;
  S T[NV * W];
  for (int r = 0; r < NV; ++r) {
    S* t = T + W * r;
    for (int c = 0; c < W; ++c) t[c] = S(0);
    for (int k = 0; k < NV; ++k) {
      const S a = A[NV * r + k];
      const S* x = X + COLS * k + c0;
      for (int c = 0; c < W; ++c) t[c] -= a * x[c];
    }
  }
  for (int r = 0; r < NV; ++r)
    for (int c = 0; c < W; ++c) X[COLS * r + c0 + c] = T[W * r + c];
}

// X <- -A X in blocks of at most 16 columns: the temporary stays small on a GPU thread.
template <class M, class S, int COLS> TG_HD void negate_left_multiply(const S* A, S* X) {
  constexpr int W = COLS < 16 ? COLS : 16, R = COLS % W;
  for (int c0 = 0; c0 + W <= COLS; c0 += W) negate_left_multiply_block<M, S, COLS, W>(A, X, c0);
  if constexpr (R > 0) negate_left_multiply_block<M, S, COLS, R>(A, X, COLS - R);
}

// The base-linear columns of Pinocchio's M (NV x 3, row-major), all a MuJoCo twin's reframe reads
// of M: M e_c = RNEA(q, 0, e_c) without gravity, three O(n) passes in little memory.
template <class M, class S> TG_HD void mass_base_columns(const S* q, S* Mb) {
  S zero[M::NV], e[M::NV], col[M::NV];
  for (int k = 0; k < M::NV; ++k) zero[k] = S(0);
  for (int c = 0; c < 3; ++c) {
    for (int k = 0; k < M::NV; ++k) e[k] = S(k == c ? 1 : 0);
    rnea<M, S, false>(q, zero, e, nullptr, col);
    for (int r = 0; r < M::NV; ++r) Mb[3 * r + c] = col[r];
  }
}

// qdd = M^-1 (tau - nle(q, qd, f_ext)) from a computed M^-1 (Pinocchio's convention).
template <class M, class S>
TG_HD void forward_dynamics_from_minv(const S* q, const S* qd, const S* tau, const S* fext, const S* Minv, S* qdd) {
  S zero[M::NV], nle[M::NV];
  for (int k = 0; k < M::NV; ++k) zero[k] = S(0);
  rnea<M, S>(q, qd, zero, fext, nle);
  for (int r = 0; r < M::NV; ++r) {
    S acc = 0;
    for (int k = 0; k < M::NV; ++k) acc += Minv[M::NV * r + k] * (tau[k] - nle[k]);
    qdd[r] = acc;
  }
}

// in: q, qd, qdd, f_ext?   out: tau
TG_OP_BEGIN(InverseDynamics)
  S qd[M::NV], qdd[M::NV];
  cv.velocity(in[1], qd);
  cv.acceleration(qd, in[2], qdd);
  rnea<M, S>(cv.q, qd, qdd, in[3], out[0]);
  cv.force_out(out[0]);
TG_OP_END

// in: q, qd, tau, f_ext?   out: qdd
TG_OP_BEGIN(ForwardDynamics)
  S qd[M::NV], tau[M::NV];
  cv.velocity(in[1], qd);
  cv.force(in[2], tau);
  aba<M, S>(cv.q, qd, tau, in[3], out[0]);
  cv.acceleration_out(qd, out[0]);
TG_OP_END

// in: q   out: M
TG_OP_BEGIN(Crba)
  crba<M, S>(cv.q, out[0]);
  cv.congruence_out(out[0]);
TG_OP_END

// in: q   out: M^-1
TG_OP_BEGIN(Minv)
  minv<M, S>(cv.q, out[0]);
  cv.congruence_out(out[0]);
TG_OP_END

// in: q   out: g(q)
TG_OP_BEGIN(GeneralizedGravity)
  S zero[M::NV];
  for (int k = 0; k < M::NV; ++k) zero[k] = S(0);
  rnea<M, S>(cv.q, zero, zero, nullptr, out[0]);
  cv.force_out(out[0]);
TG_OP_END

// in: q, qd   out: C(q, qd) qd + g(q); MuJoCo's qacc = 0 is a_lin = -w x v_lin in Pinocchio's.
TG_OP_BEGIN(NonlinearEffects)
  S qd[M::NV], zero[M::NV], qdd[M::NV];
  for (int k = 0; k < M::NV; ++k) zero[k] = S(0);
  cv.velocity(in[1], qd);
  cv.acceleration(qd, zero, qdd);
  rnea<M, S>(cv.q, qd, qdd, nullptr, out[0]);
  cv.force_out(out[0]);
TG_OP_END

// in: q, qd   out: [kinetic, potential, mechanical]
TG_OP_BEGIN(Energy)
  S qd[M::NV];
  cv.velocity(in[1], qd);
  energy<M, S>(cv.q, qd, out[0]);
TG_OP_END

// in: q   out: com (3)
TG_OP_BEGIN(Com)
  com<M, S>(cv.q, out[0]);
TG_OP_END

// in: q   out: J_com (3 x NV)
TG_OP_BEGIN(JacobianCom)
  jacobian_com<M, S>(cv.q, out[0]);
  cv.columns_out(out[0], 3);
TG_OP_END

// in: q, qd   out: A (6 x NV), h (6)
TG_OP_BEGIN(Ccrba)
  S qd[M::NV];
  cv.velocity(in[1], qd);
  ccrba<M, S>(cv.q, qd, out[0], out[1]);
  cv.columns_out(out[0], 6);
TG_OP_END

// in: q   out: positions (NF x 3), rotations (NF x 3 x 3)
TG_OP_BEGIN(ForwardKinematics)
  frames_forward_kinematics<M, S>(cv.q, out[0], out[1]);
TG_OP_END

// in: q; iargs: frame indices   out: (n x 6) [xyz, rpy]
TG_OP_BEGIN(EndEffectorPose)
  end_effector_pose<M, S>(cv.q, iargs, n_iargs, out[0]);
TG_OP_END

// in: q; iargs: frame, reference   out: J (6 x NV)
TG_OP_BEGIN(FrameJacobian)
  frame_jacobian<M, S>(cv.q, iargs[0], iargs[1], out[0]);
  cv.columns_out(out[0], 6);
TG_OP_END

// in: q, qd, qdd, f_ext?   out: dtau/dq, dtau/dqd (tangent derivatives)
TG_OP_BEGIN(InverseDynamicsGradient)
  S qd[M::NV], qdd[M::NV], tau[M::NV];
  cv.velocity(in[1], qd);
  cv.acceleration(qd, in[2], qdd);
  rnea_derivatives<M, S>(cv.q, qd, qdd, in[3], tau, out[0], out[1]);
  if constexpr (Conv<M, S, C>::active) {
    S Mb[M::NV * 3];
    mass_base_columns<M, S>(cv.q, Mb);
    cv.inverse_dynamics_gradient_out(qd, qdd, tau, Mb, out[0], out[1]);
  }
TG_OP_END

// in: q, qd   out: spatial velocity [v; w] of each body in its joint frame (NB x 6)
TG_OP_BEGIN(BodyVelocities)
  S qd[M::NV];
  cv.velocity(in[1], qd);
  body_velocities<M, S>(cv.q, qd, out[0]);
TG_OP_END

// in: q, qd; iargs: frame, reference   out: d/dt frame_jacobian (6 x NV)
TG_OP_BEGIN(FrameJacobianDot)
  S qd[M::NV];
  cv.velocity(in[1], qd);
  if constexpr (Conv<M, S, C>::active) {
    S J[6 * M::NV];
    frame_jacobian_dot<M, S>(cv.q, qd, iargs[0], iargs[1], out[0], J);
    cv.jacobian_dot_out(qd, J, out[0], 6);
  } else {
    frame_jacobian_dot<M, S>(cv.q, qd, iargs[0], iargs[1], out[0], nullptr);
  }
TG_OP_END

// in: q, x   out: M^-1 x, by ABA without velocity or gravity (MuJoCo's: G M^-1 G^T x)
TG_OP_BEGIN(InertiaSolve)
  S zero[M::NV], x[M::NV];
  for (int k = 0; k < M::NV; ++k) zero[k] = S(0);
  cv.force(in[1], x);
  aba<M, S, false>(cv.q, zero, x, nullptr, out[0]);
  cv.force_out(out[0]);
TG_OP_END

// in: q, w (NF x 6)   out: sum_f J_f^T w_f (NV), the frames' vector-Jacobian product
TG_OP_BEGIN(FramesVjp)
  frames_vjp<M, S>(cv.q, in[1], out[0]);
  cv.force_out(out[0]);
TG_OP_END

// in: q, qd   out: dA/dt (6 x NV); MuJoCo's as the time derivative of its A at fixed qvel
TG_OP_BEGIN(CmmTimeVariation)
  S qd[M::NV];
  cv.velocity(in[1], qd);
  if constexpr (Conv<M, S, C>::active) {
    S A[6 * M::NV];
    cmm_time_variation<M, S>(cv.q, qd, out[0], A);
    cv.jacobian_dot_out(qd, A, out[0], 6);
  } else {
    cmm_time_variation<M, S>(cv.q, qd, out[0], nullptr);
  }
TG_OP_END

// in: q, qd   out: dh/dq (6 x NV), h the centroidal momentum
TG_OP_BEGIN(Dccrba)
  S qd[M::NV];
  cv.velocity(in[1], qd);
  dccrba<M, S>(cv.q, qd, out[0]);
  if constexpr (Conv<M, S, C>::active) {
    S A[6 * M::NV], Adot[6 * M::NV];
    cmm_time_variation<M, S>(cv.q, qd, Adot, A);
    cv.momentum_gradient_out(qd, A, out[0]);
  }
TG_OP_END

// in: q, qd   out: C (NV x NV), C qd + g = nonlinear effects
TG_OP_BEGIN(CoriolisMatrix)
  S qd[M::NV];
  cv.velocity(in[1], qd);
  coriolis_matrix<M, S>(cv.q, qd, out[0]);
  if constexpr (Conv<M, S, C>::active) {
    S Mb[M::NV * 3];
    mass_base_columns<M, S>(cv.q, Mb);
    cv.coriolis_out(qd, Mb, out[0]);
  }
TG_OP_END

// in: q   out: d tau / d f_ext (NV x NB x 6)
TG_OP_BEGIN(InverseDynamicsExternalForceGradient)
  external_force_jacobian<M, S>(cv.q, out[0]);
  cv.force_rows_out(out[0], 6 * M::NB);
TG_OP_END

// in: q   out: d qdd / d f_ext (NV x NB x 6) = -M^-1 d tau / d f_ext
TG_OP_BEGIN(ForwardDynamicsExternalForceGradient)
  S Minv[M::NV * M::NV];
  minv<M, S>(cv.q, Minv);
  external_force_jacobian<M, S>(cv.q, out[0]);
  negate_left_multiply<M, S, 6 * M::NB>(Minv, out[0]);
  cv.force_rows_out(out[0], 6 * M::NB);
TG_OP_END

// in: q; iargs: frame, reference   out: Lambda = (J M^-1 J^T)^-1 (6 x 6)
TG_OP_BEGIN(OscInertia)
  S Minv[M::NV * M::NV], J[6 * M::NV], JMinv[6 * M::NV], A[36];
  minv<M, S>(cv.q, Minv);
  frame_jacobian<M, S>(cv.q, iargs[0], iargs[1], J);
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < M::NV; ++c) {
      S acc = 0;
      for (int k = 0; k < M::NV; ++k) acc += J[M::NV * r + k] * Minv[M::NV * k + c];
      JMinv[M::NV * r + c] = acc;
    }
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) {
      S acc = 0;
      for (int k = 0; k < M::NV; ++k) acc += JMinv[M::NV * r + k] * J[M::NV * c + k];
      A[6 * r + c] = acc;
    }
  spd_inverse(6, A, out[0]);
TG_OP_END

// in: q, qd, qdd, f_ext?, lambda   out: lambda^T d tau/dq, lambda^T d tau/dqd (NV each), in O(n)
TG_OP_BEGIN(InverseDynamicsVjp)
  S qd[M::NV], qdd[M::NV], mu[M::NV], tau[M::NV];
  cv.velocity(in[1], qd);
  cv.acceleration(qd, in[2], qdd);
  cv.force(in[4], mu);  // G^T lambda
  rnea_vjp<M, S>(cv.q, qd, qdd, in[3], mu, tau, out[0], out[1]);
  if constexpr (Conv<M, S, C>::active) {
    S zero[M::NV], Mmu[M::NV];
    for (int k = 0; k < M::NV; ++k) zero[k] = S(0);
    rnea<M, S, false>(cv.q, zero, mu, nullptr, Mmu);
    cv.inverse_dynamics_vjp_out(qd, qdd, tau, Mmu, mu, out[0], out[1]);
  }
TG_OP_END

// in: q, qd, tau, f_ext?   out: dqdd/dq, dqdd/dqd, dqdd/dtau. Since ID(q, qd, FD(q, qd, tau)) = tau,
// dqdd/dx = -M^-1 dtau/dx at qdd = FD(q, qd, tau), and dqdd/dtau = M^-1, in either convention.
TG_OP_BEGIN(ForwardDynamicsGradient)
  S qd[M::NV], u[M::NV], qdd[M::NV], tau[M::NV];
  cv.velocity(in[1], qd);
  cv.force(in[2], u);
  minv<M, S>(cv.q, out[2]);  // needed anyway, so qdd comes from it rather than from ABA
  forward_dynamics_from_minv<M, S>(cv.q, qd, u, in[3], out[2], qdd);
  rnea_derivatives<M, S>(cv.q, qd, qdd, in[3], tau, out[0], out[1]);
  if constexpr (Conv<M, S, C>::active) {
    S Mb[M::NV * 3];
    mass_base_columns<M, S>(cv.q, Mb);
    cv.inverse_dynamics_gradient_out(qd, qdd, tau, Mb, out[0], out[1]);
    cv.congruence_out(out[2]);
  }
  negate_left_multiply<M, S, M::NV>(out[2], out[0]);
  negate_left_multiply<M, S, M::NV>(out[2], out[1]);
TG_OP_END

// in: q, qd, qdd   out: Y (NV x 10 NB), tau = Y pi
TG_OP_BEGIN(InverseDynamicsRegressor)
  S qd[M::NV], qdd[M::NV];
  cv.velocity(in[1], qd);
  cv.acceleration(qd, in[2], qdd);
  inverse_dynamics_regressor<M, S>(cv.q, qd, qdd, out[0]);
  cv.force_rows_out(out[0], 10 * M::NB);
TG_OP_END

// in: q, qd   out: Yk (10 NB), KE = Yk . pi
TG_OP_BEGIN(KineticEnergyRegressor)
  S qd[M::NV];
  cv.velocity(in[1], qd);
  kinetic_energy_regressor<M, S>(cv.q, qd, out[0]);
TG_OP_END

// in: q   out: Yp (10 NB), PE = Yp . pi
TG_OP_BEGIN(PotentialEnergyRegressor)
  potential_energy_regressor<M, S>(cv.q, out[0]);
TG_OP_END

// in: q, qd, tau   out: d qdd / d pi (NV x 10 NB) = -M^-1 Y(q, qd, qdd) at qdd = FD(q, qd, tau).
// MuJoCo's qdd differs from Pinocchio's by G and a term free of pi, so the twin is G (.).
TG_OP_BEGIN(ForwardDynamicsParameterGradient)
  S qd[M::NV], u[M::NV], qdd[M::NV], Minv[M::NV * M::NV];
  cv.velocity(in[1], qd);
  cv.force(in[2], u);
  minv<M, S>(cv.q, Minv);
  forward_dynamics_from_minv<M, S>(cv.q, qd, u, nullptr, Minv, qdd);
  inverse_dynamics_regressor<M, S>(cv.q, qd, qdd, out[0]);
  negate_left_multiply<M, S, 10 * M::NB>(Minv, out[0]);
  cv.force_rows_out(out[0], 10 * M::NB);
TG_OP_END

#undef TG_OP_BEGIN
#undef TG_OP_END

}  // namespace tg
