// The derivatives of forward dynamics, from those of inverse dynamics: since ID(q, qd, FD(q, qd, tau)) = tau,
// dqdd/dx = -M^-1 dtau/dx and dqdd/dtau = M^-1; with MuJoCo's implicit damping, the same with M + dt D; with
// the passive forces, their own derivatives added. Shared by the ops (ops.h) and the steps (step/).
#pragma once

#include "kernels/derivatives/rnea_derivatives.h"
#include "kernels/dynamics/crba.h"
#include "kernels/dynamics/ltdl.h"
#include "kernels/dynamics/minv.h"
#include "kernels/dynamics/passive.h"
#include "kernels/dynamics/products.h"
#include "kernels/dynamics/rnea.h"
#include "kernels/spatial/convention.h"

namespace tg {

// Columns [c0, c0 + W) of X <- -A X for an NV x NV matrix A and an NV x COLS row-major X, through a
// temporary of W columns.
template <class Robot, class Scalar, int COLS, int W> TG_HD void negate_left_multiply_block(const Scalar* A, Scalar* X, int c0) {
  constexpr int NV = Robot::NV;
  Scalar T[NV * W];
  const Scalar* g[1] = {A};
  const Scalar* x[1] = {X + c0};
  const Scalar w[1] = {Scalar(-1)};
  products<NV, W, COLS, W, false>(1, NV, g, NV, w, x, T);
  for (int r = 0; r < NV; ++r)
    for (int c = 0; c < W; ++c) X[COLS * r + c0 + c] = T[W * r + c];
}

// X <- -A X in blocks of at most 16 columns: the temporary stays small on a GPU thread.
template <class Robot, class Scalar, int COLS> TG_HD void negate_left_multiply(const Scalar* A, Scalar* X) {
  constexpr int W = COLS < 16 ? COLS : 16, R = COLS % W;
  for (int c0 = 0; c0 + W <= COLS; c0 += W) negate_left_multiply_block<Robot, Scalar, COLS, W>(A, X, c0);
  if constexpr (R > 0) negate_left_multiply_block<Robot, Scalar, COLS, R>(A, X, COLS - R);
}

// qdd = M^-1 (tau - nle(q, qd, f_ext)) from a computed M^-1 (Pinocchio's convention).
template <class Robot, class Scalar> TG_HD void forward_dynamics_from_minv(const Placements<Robot, Scalar>& K, const Scalar* qd, const Scalar* tau,
                                                                 const Scalar* fext, const Scalar* Minv, Scalar* qdd,
                                                                 const InertialParameters<Robot, Scalar>& pi = {}) {
  Scalar zero[Robot::NV], nle[Robot::NV];
  for (int k = 0; k < Robot::NV; ++k) zero[k] = Scalar(0);
  rnea<Robot, Scalar>(K, qd, zero, fext, nle, pi);
  for (int r = 0; r < Robot::NV; ++r) {
    Scalar acc = 0;
    for (int k = 0; k < Robot::NV; ++k) acc += Minv[Robot::NV * r + k] * (tau[k] - nle[k]);
    qdd[r] = acc;
  }
}

// y = A x for an NV x NV matrix A by team t, a row a lane; all of y written when every lane returns.
template <class Robot, class Scalar, class Team> TG_HD void matrix_vector(const Team& t, const Scalar* A, const Scalar* x, Scalar* y) {
  constexpr int NV = Robot::NV;
  for (const int row : t.items(0, NV)) {
    Scalar acc = Scalar(0);
    for (int k = 0; k < NV; ++k) acc += A[NV * row + k] * x[k];
    y[row] = acc;
  }
  t.sync();
}

// A team's shared workspace for forward_dynamics: the world placements, M^-1 and tau - b beside minv's workspace
// and then, in the same place, the bias's.
template <class Robot, class Scalar> struct ForwardDynamicsTeamWork {
  SE3<Scalar> oMi[Robot::NB];
  Scalar Minv[Robot::NV * Robot::NV];
  Scalar r[Robot::NV];
  union {
    MinvWork<Robot, Scalar, true> minv;
    RneaTeamWork<Robot, Scalar> bias;
  };
};

// qdd = M^-1 (tau - b(q, qd, f_ext)) by team t (Pinocchio's convention): M^-1 by minv's team path, the bias b by
// rnea's at qdd = 0, then qdd by rows, a row a lane. All of qdd written when every lane returns.
template <class Robot, class Scalar, class Team>
TG_HD void forward_dynamics(const Team& t, ForwardDynamicsTeamWork<Robot, Scalar>& w, const Scalar* q, const Scalar* qd, const Scalar* tau,
                            const Scalar* fext, Scalar* qdd, const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV;
  world_placements<Robot, Scalar>(t, q, w.oMi);
  minv<Robot, Scalar>(t, w.oMi, w.minv, w.Minv, pi);
  rnea<Robot, Scalar>(t, w.oMi, w.bias, qd, nullptr, fext, w.r, pi);
  for (const int c : t.items(0, NV)) w.r[c] = tau[c] - w.r[c];
  t.sync();
  matrix_vector<Robot, Scalar>(t, w.Minv, w.r, qdd);
}

// d tau/dq, d tau/dqd in the convention C (qd, qdd in Pinocchio's) from W, set up at (q, qd, qdd, fext), by
// team t (the MuJoCo reframe by its leader, once both are whole); without Zero, the entries between branches
// of the tree are left as they were (the reframe mixes a free joint's rows and columns, related to every dof
// of its tree). The free joints' columns of M come from the derivatives' composite inertias. All written when
// every lane returns.
template <class Robot, class Scalar, int C, bool Zero = true, class Team>
TG_HD void inverse_dynamics_derivatives_from(const Team& t, const RneaDerivativesWork<Robot, Scalar>& W, const Scalar* qd, const Scalar* qdd,
                                             const Conv<Robot, Scalar, C>& cv, Scalar* dtau_dq, Scalar* dtau_dqd) {
  rnea_derivatives<Robot, Scalar, Zero>(t, W, dtau_dq, dtau_dqd);
  t.sync();
  if constexpr (Conv<Robot, Scalar, C>::active) {
    if (t.leader()) {
      Scalar tau[Robot::NV], Mb[Robot::NV * Conv<Robot, Scalar, C>::NB3];
      rnea_torques<Robot, Scalar>(W, tau);
      mass_base_columns<Robot, Scalar>(W, Mb);
      cv.inverse_dynamics_derivatives_out(qd, qdd, tau, Mb, dtau_dq, dtau_dqd);
    }
    t.sync();
  }
}

// The same at (q, qd, qdd, fext). Its workspace lives in this function's frame, which a GPU thread's stack
// holds only while it runs (not beside the caller's minv).
template <class Robot, class Scalar, int C, bool Zero = true>
TG_HD void inverse_dynamics_derivatives(const Placements<Robot, Scalar>& K, const Scalar* qd, const Scalar* qdd, const Scalar* fext,
                                        const Conv<Robot, Scalar, C>& cv, Scalar* dtau_dq, Scalar* dtau_dqd,
                                        const InertialParameters<Robot, Scalar>& pi = {}) {
  RneaDerivativesWork<Robot, Scalar> W;
  rnea_derivatives_setup<Robot, Scalar>(K, qd, qdd, fext, W, pi);
  inverse_dynamics_derivatives_from<Robot, Scalar, C, Zero>(Solo{}, W, qd, qdd, cv, dtau_dq, dtau_dqd);
}

// A team's shared workspace for inverse_dynamics_derivatives: the world placements and the derivatives'.
template <class Robot, class Scalar> struct InverseDynamicsDerivativesTeamWork {
  SE3<Scalar> oMi[Robot::NB];
  RneaDerivativesWork<Robot, Scalar> w;
};

template <class Robot, class Scalar, int C, class Team>
TG_HD void inverse_dynamics_derivatives(const Team& t, InverseDynamicsDerivativesTeamWork<Robot, Scalar>& tw, const Scalar* q, const Scalar* qd,
                                        const Scalar* qdd, const Scalar* fext, const Conv<Robot, Scalar, C>& cv, Scalar* dtau_dq,
                                        Scalar* dtau_dqd, const InertialParameters<Robot, Scalar>& pi = {}) {
  world_placements<Robot, Scalar>(t, q, tw.oMi);
  rnea_derivatives_setup<Robot, Scalar>(t, tw.oMi, qd, qdd, fext, tw.w, pi);
  inverse_dynamics_derivatives_from<Robot, Scalar, C>(t, tw.w, qd, qdd, cv, dtau_dq, dtau_dqd);
}

// X <- -M^-1 X for each X zero between dofs on different branches (d tau/dq, d tau/dqd) and a symmetric
// M^-1. On a branched tree on a CPU, as (X^T M^-1)^T: each block of X^T's rows runs over its related
// columns alone (tree_products); on a chain, or a GPU thread (whose stack would hold the NV x NV
// temporary), the dense product in blocks of columns.
template <class Robot, class Scalar> TG_HD void negate_minv_products(const Scalar* Minv, Scalar* X0, Scalar* X1) {
  constexpr int NV = Robot::NV;
#if !TG_DEVICE_PATH
  const TreeBlocks<Robot, Scalar>& tb = tree_blocks<Robot, Scalar>();
  if (tb.sparse) {
    Scalar T[NV * NV];
    const Scalar* x[1] = {Minv};
    const Scalar w[1] = {Scalar(-1)};
    Scalar* const Xs[2] = {X0, X1};
    for (Scalar* X : Xs) {
      const Scalar* g[1] = {X};
      tree_products<Robot, NV, NV, NV, false, true>(tb, 1, g, w, x, T);
      for (int r = 0; r < NV; ++r)
        for (int c = 0; c < NV; ++c) X[NV * r + c] = T[NV * c + r];
    }
    return;
  }
#endif
  negate_left_multiply<Robot, Scalar, NV>(Minv, X0);
  negate_left_multiply<Robot, Scalar, NV>(Minv, X1);
}

// What forward_dynamics_derivatives computes in: minv's workspace, then, in the same place, the RNEA
// derivatives' and tau - b (a GPU thread's stack or a team's shared memory holds the larger alone).
template <class Robot, class Scalar, bool ByDepth = TG_DEVICE_PATH != 0> struct ForwardDynamicsDerivativesWork {
  struct Rnea {
    RneaDerivativesWork<Robot, Scalar> W;
    Scalar r[Robot::NV];
  };
  union {
    MinvWork<Robot, Scalar, ByDepth> minv;
    Rnea rnea;
  };
};

// Since ID(q, qd, FD(q, qd, tau)) = tau, dqdd/dx = -M^-1 dtau/dx at qdd = FD(q, qd, tau), and dqdd/dtau = M^-1,
// in either convention. By team t at the world placements oMi: dtau = M^-1 (in the convention), dq and dqd
// left as dtau/dq and dtau/dqd (for the caller to finish as -M^-1 X), and qdd (in Pinocchio's convention).
// The RNEA derivatives' pass, run at qdd = 0, gives the bias b = S^T F, so qdd = M^-1 (tau - b); the pass then
// moves to qdd (rnea_derivatives_accelerate). All written when every lane returns.
template <class Robot, class Scalar, int C, bool ByDepth, class Team>
TG_HD void forward_dynamics_derivatives(const Team& t, const SE3<Scalar>* oMi, ForwardDynamicsDerivativesWork<Robot, Scalar, ByDepth>& w,
                                        const Scalar* qd, const Scalar* tau, const Scalar* fext, const Conv<Robot, Scalar, C>& cv,
                                        Scalar* dq, Scalar* dqd, Scalar* dtau, Scalar* qdd, const InertialParameters<Robot, Scalar>& pi) {
  constexpr int NV = Robot::NV;
  const auto& d = data<Robot, Scalar>();
  minv<Robot, Scalar>(t, oMi, w.minv, dtau, pi);
  RneaDerivativesWork<Robot, Scalar>& W = w.rnea.W;
  Scalar* const r = w.rnea.r;
  if (t.leader())
    for (int k = 0; k < NV; ++k) qdd[k] = Scalar(0);
  rnea_derivatives_setup<Robot, Scalar>(t, oMi, qd, qdd, fext, W, pi);
  // r = tau - b, then qdd = M^-1 r by rows
  for (const int i : t.items(0, Robot::NB))
    for (int l = 0; l < d.nvj[i]; ++l) r[d.vi[i] + l] = tau[d.vi[i] + l] - dot(W.s[d.vi[i] + l], W.F[i]);
  t.sync();
  matrix_vector<Robot, Scalar>(t, dtau, r, qdd);
  if (t.leader()) rnea_derivatives_accelerate<Robot, Scalar>(qdd, W);
  t.sync();
  inverse_dynamics_derivatives_from<Robot, Scalar, C>(t, W, qd, qdd, cv, dq, dqd);
  if (t.leader()) cv.congruence_out(dtau);
  t.sync();
}

// dqdd/dq, dqdd/dqd, dqdd/dtau (NV x NV each, in the convention) and qdd (in Pinocchio's) by one thread.
// Without Product, dq and dqd are left as dtau/dq and dtau/dqd, for the caller to finish as -M^-1 X.
template <class Robot, class Scalar, int C, bool Product = true>
TG_HD void forward_dynamics_derivatives(const Placements<Robot, Scalar>& K, const Scalar* qd, const Scalar* tau, const Scalar* fext,
                                     const Conv<Robot, Scalar, C>& cv, Scalar* dq, Scalar* dqd, Scalar* dtau, Scalar* qdd,
                                     const InertialParameters<Robot, Scalar>& pi = {}) {
  ForwardDynamicsDerivativesWork<Robot, Scalar> w;
  forward_dynamics_derivatives<Robot, Scalar>(Solo{}, K.oMi, w, qd, tau, fext, cv, dq, dqd, dtau, qdd, pi);
  if constexpr (Product) negate_minv_products<Robot, Scalar>(dtau, dq, dqd);
}

// A team's shared workspace for forward_dynamics_derivatives: the world placements, the above (by depth on
// the host too: team_launch sizes it) and qdd.
template <class Robot, class Scalar> struct ForwardDynamicsDerivativesTeamWork {
  SE3<Scalar> oMi[Robot::NB];
  ForwardDynamicsDerivativesWork<Robot, Scalar, true> w;
  Scalar qdd[Robot::NV];
};

template <class Robot, class Scalar, int C, class Team>
TG_HD void forward_dynamics_derivatives(const Team& t, ForwardDynamicsDerivativesTeamWork<Robot, Scalar>& tw, const Scalar* q, const Scalar* qd,
                                        const Scalar* tau, const Scalar* fext, const Conv<Robot, Scalar, C>& cv, Scalar* dq, Scalar* dqd,
                                        Scalar* dtau, const InertialParameters<Robot, Scalar>& pi = {}) {
  world_placements<Robot, Scalar>(t, q, tw.oMi);
  forward_dynamics_derivatives<Robot, Scalar>(t, tw.oMi, tw.w, qd, tau, fext, cv, dq, dqd, dtau, tw.qdd, pi);
}

// H = G M G^T + h D in the convention (M as crba leaves it; D the joint damping, zero on free joints, so that
// G D G^T = D), factored in place (ltdl_factor): MuJoCo's Euler step's M + dt D, a Runge-Kutta stage's M (h = 0).
template <class Robot, class Scalar, int C> TG_HD void factor_mass(const Conv<Robot, Scalar, C>& cv, Scalar h, Scalar* H) {
  constexpr int NV = Robot::NV;
  const auto& d = data<Robot, Scalar>();
  cv.congruence_out(H);
  for (int k = 0; k < NV; ++k) H[(NV + 1) * k] += h * Scalar(d.damping[k]);
  ltdl_factor<Robot, Scalar>(H);
}

// qdd = G^T H_c^-1 G f, H_c factored by factor_mass and f a generalized force, both in Pinocchio's convention: f
// overwritten; qdd may be f itself.
template <class Robot, class Scalar, int C> TG_HD void solve_mass(const Conv<Robot, Scalar, C>& cv, const Scalar* H, Scalar* f, Scalar* qdd) {
  cv.force_out(f);
  ltdl_solve<Robot, Scalar>(H, f);
  const Scalar* const a = cv.velocity(f, qdd);  // in place where it converts
  if (a != qdd)
    for (int k = 0; k < Robot::NV; ++k) qdd[k] = a[k];
}

// (M + dt D) qdd = tau + p - b(q, qd): the acceleration of MuJoCo's Euler step, the joint damping D taken
// implicitly (mj_Euler), p the passive forces (passive.h). Differentiating ID(q, qd, qdd) + dt D qdd - p = tau
// at that qdd, with H = M + dt D: dqdd/dx = -H^-1 (dID/dx - dp/dx), dqdd/dtau = H^-1. H is factored in the
// convention (H_c = G H G^T, D being zero on free joints), as a Runge-Kutta stage's M (rk_stage).
// damped_acceleration: H, factored (factor_mass), and qdd in Pinocchio's convention.
template <class Robot, class Scalar, int C>
TG_HD void damped_acceleration(const Placements<Robot, Scalar>& K, const Conv<Robot, Scalar, C>& cv, const Scalar* q, const Scalar* qd,
                               const Scalar* tau, const Scalar* fext, Scalar h, Scalar* H, Scalar* qdd,
                               const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV;
  Scalar f[NV], zero[NV];
  crba<Robot, Scalar>(K, H, pi);
  factor_mass<Robot, Scalar>(cv, h, H);
  // f = tau + p - b, then qdd = H^-1 f
  for (int k = 0; k < NV; ++k) zero[k] = Scalar(0);
  rnea<Robot, Scalar>(K, qd, zero, fext, f, pi);
  for (int k = 0; k < NV; ++k) f[k] = tau[k] - f[k];
  add_passive<Robot, Scalar>(q, qd, f);
  solve_mass<Robot, Scalar>(cv, H, f, qdd);
}

// A team's shared workspace for damped_acceleration: the world placements, H and tau + p - b, crba's axes and then,
// in the same place, the bias's workspace.
template <class Robot, class Scalar> struct DampedAccelerationTeamWork {
  SE3<Scalar> oMi[Robot::NB];
  Scalar H[Robot::NV * Robot::NV], f[Robot::NV];
  union {
    CrbaAxes<Robot, Scalar> crba;
    RneaTeamWork<Robot, Scalar> bias;
  };
};

// damped_acceleration by team t: M by crba's team path, made H and factored by the leader, the bias b by rnea's
// team path at qdd = 0, then qdd = H^-1 (tau + p - b) by the leader (in Pinocchio's convention). All of qdd written
// when every lane returns.
template <class Robot, class Scalar, int C, class Team>
TG_HD void damped_acceleration(const Team& t, DampedAccelerationTeamWork<Robot, Scalar>& w, const Conv<Robot, Scalar, C>& cv, const Scalar* q,
                               const Scalar* qd, const Scalar* tau, const Scalar* fext, Scalar h, Scalar* qdd,
                               const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV;
  world_placements<Robot, Scalar>(t, q, w.oMi);
  crba<Robot, Scalar>(t, w.oMi, w.crba, w.H, pi);
  if (t.leader()) factor_mass<Robot, Scalar>(cv, h, w.H);
  rnea<Robot, Scalar>(t, w.oMi, w.bias, qd, nullptr, fext, w.f, pi);
  // f = tau + p - b, then qdd = H^-1 f
  if (t.leader()) {
    for (int k = 0; k < NV; ++k) w.f[k] = tau[k] - w.f[k];
    add_passive<Robot, Scalar>(q, qd, w.f);
    solve_mass<Robot, Scalar>(cv, w.H, w.f, qdd);
  }
  t.sync();
}

// damped_dynamics_derivatives: dqdd/dq, dqdd/dqd, dqdd/dtau (NV x NV each, in the convention) and qdd (in
// Pinocchio's).
template <class Robot, class Scalar, int C>
TG_HD void damped_dynamics_derivatives(const Placements<Robot, Scalar>& K, const Conv<Robot, Scalar, C>& cv, const Scalar* q, const Scalar* qd,
                                    const Scalar* tau, const Scalar* fext, Scalar h, Scalar* dq, Scalar* dqd, Scalar* dtau, Scalar* qdd,
                                    const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV;
  Scalar H[NV * NV];
  damped_acceleration<Robot, Scalar, C>(K, cv, q, qd, tau, fext, h, H, qdd, pi);
  // the derivatives: -H^-1 (dID/dx + [K D]), and H^-1 from the identity's columns
  inverse_dynamics_derivatives<Robot, Scalar>(K, qd, qdd, fext, cv, dq, dqd, pi);
  add_passive_diagonals<Robot, Scalar>(dq, dqd);
  for (int r = 0; r < NV; ++r)
    for (int c = 0; c < NV; ++c) dtau[NV * r + c] = Scalar(r == c), dq[NV * r + c] = -dq[NV * r + c], dqd[NV * r + c] = -dqd[NV * r + c];
  ltdl_solve_rows<Robot, NV>(H, dq);
  ltdl_solve_rows<Robot, NV>(H, dqd);
  ltdl_solve_rows<Robot, NV>(H, dtau);
}

// A team's shared workspace for the dynamics in M's factored form (factored_dynamics_derivatives): the world
// placements, crba's axes and then, in the same place, the RNEA derivatives' with tau (+ p) - b and qdd.
template <class Robot, class Scalar> struct FactoredDynamicsTeamWork {
  struct Rnea {
    RneaDerivativesWork<Robot, Scalar> W;
    Scalar r[Robot::NV], qdd[Robot::NV];
  };
  SE3<Scalar> oMi[Robot::NB];
  union {
    CrbaAxes<Robot, Scalar> crba;
    Rnea rnea;
  };
};

// The forward dynamics and inverse-dynamics derivatives at (q, qd, tau) by team t, as a Runge-Kutta stage
// (rk_stage) and the damped Euler step (damped_acceleration) compute them one thread a sample: H = M + h D (h = 0:
// M itself) in the convention, by crba's team path, in memory of the caller's, factored by the leader
// (factor_mass); the bias b from the RNEA derivatives' pass at qdd = 0; qdd = H^-1 (tau (+ p) - b) by the leader
// (in Pinocchio's convention, into w.rnea.qdd); the pass moved to qdd and dq, dqd the derivatives of ID (- p) there,
// in the convention. All written when every lane returns.
template <class Robot, class Scalar, int C, class Team>
TG_HD void factored_dynamics_derivatives(const Team& t, FactoredDynamicsTeamWork<Robot, Scalar>& w, const Conv<Robot, Scalar, C>& cv,
                                         const Scalar* q, const Scalar* qd, const Scalar* tau, const Scalar* fext, Scalar h, bool passive,
                                         Scalar* dq, Scalar* dqd, Scalar* H, const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV;
  const auto& d = data<Robot, Scalar>();
  RneaDerivativesWork<Robot, Scalar>& W = w.rnea.W;
  Scalar* const r = w.rnea.r;
  Scalar* const qdd = w.rnea.qdd;
  world_placements<Robot, Scalar>(t, q, w.oMi);
  crba<Robot, Scalar>(t, w.oMi, w.crba, H, pi);
  if (t.leader()) {
    factor_mass<Robot, Scalar>(cv, h, H);
    for (int k = 0; k < NV; ++k) qdd[k] = Scalar(0);
  }
  t.sync();
  rnea_derivatives_setup<Robot, Scalar>(t, w.oMi, qd, qdd, fext, W, pi);
  // r = tau - b, then, by the leader, qdd = H^-1 (r + p)
  for (const int i : t.items(0, Robot::NB))
    for (int l = 0; l < d.nvj[i]; ++l) r[d.vi[i] + l] = tau[d.vi[i] + l] - dot(W.s[d.vi[i] + l], W.F[i]);
  t.sync();
  if (t.leader()) {
    if (passive) add_passive<Robot, Scalar>(q, qd, r);
    solve_mass<Robot, Scalar>(cv, H, r, qdd);
    rnea_derivatives_accelerate<Robot, Scalar>(qdd, W);
  }
  t.sync();
  inverse_dynamics_derivatives_from<Robot, Scalar, C>(t, W, qd, qdd, cv, dq, dqd);
  if (passive && t.leader()) add_passive_diagonals<Robot, Scalar>(dq, dqd);
  t.sync();
}

// damped_dynamics_derivatives by team t, H (NV x NV) in memory of the caller's: the above with the damping and
// the passive forces, then dq, dqd, dtau <- -H^-1 dq, -H^-1 dqd, H^-1 a column a lane. w.rnea.qdd holds qdd. All
// written when every lane returns.
template <class Robot, class Scalar, int C, class Team>
TG_HD void damped_dynamics_derivatives(const Team& t, FactoredDynamicsTeamWork<Robot, Scalar>& w, const Conv<Robot, Scalar, C>& cv, const Scalar* q,
                                       const Scalar* qd, const Scalar* tau, const Scalar* fext, Scalar h, Scalar* dq, Scalar* dqd,
                                       Scalar* dtau, Scalar* H, const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV;
  factored_dynamics_derivatives<Robot, Scalar>(t, w, cv, q, qd, tau, fext, h, true, dq, dqd, H, pi);
  for (const int c : t.items(0, NV)) {
    for (int k = 0; k < NV; ++k) dtau[NV * k + c] = Scalar(k == c), dq[NV * k + c] = -dq[NV * k + c], dqd[NV * k + c] = -dqd[NV * k + c];
    ltdl_solve_columns<Robot, NV, 1>(H, dq, c);
    ltdl_solve_columns<Robot, NV, 1>(H, dqd, c);
    ltdl_solve_columns<Robot, NV, 1>(H, dtau, c);
  }
  t.sync();
}

// forward_dynamics_derivatives at FD(q, qd, tau + p) with passive (1) and dq -= M^-1 K, dqd -= M^-1 D (passive.h);
// without (0), at tau.
template <class Robot, class Scalar, int C>
TG_HD void passive_dynamics_derivatives(const Placements<Robot, Scalar>& K, const Conv<Robot, Scalar, C>& cv, const Scalar* q, const Scalar* qd,
                                     const Scalar* tau, const Scalar* fext, int passive, Scalar* dq, Scalar* dqd, Scalar* dtau, Scalar* qdd,
                                     const InertialParameters<Robot, Scalar>& pi = {}) {
  Scalar tau_p[Robot::NV];
  for (int k = 0; k < Robot::NV; ++k) tau_p[k] = tau[k];
  if (passive) add_passive<Robot, Scalar>(q, qd, tau_p);
  forward_dynamics_derivatives<Robot, Scalar>(K, qd, tau_p, fext, cv, dq, dqd, dtau, qdd, pi);
  if (passive) add_passive_columns<Robot, Scalar>(dtau, dq, dqd);
}

}  // namespace tg
