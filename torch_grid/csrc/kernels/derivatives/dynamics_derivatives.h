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
template <class M, class S, int COLS, int W> TG_HD void negate_left_multiply_block(const S* A, S* X, int c0) {
  constexpr int NV = M::NV;
  S T[NV * W];
  const S* g[1] = {A};
  const S* x[1] = {X + c0};
  const S w[1] = {S(-1)};
  products<NV, W, COLS, W, false>(1, NV, g, NV, w, x, T);
  for (int r = 0; r < NV; ++r)
    for (int c = 0; c < W; ++c) X[COLS * r + c0 + c] = T[W * r + c];
}

// X <- -A X in blocks of at most 16 columns: the temporary stays small on a GPU thread.
template <class M, class S, int COLS> TG_HD void negate_left_multiply(const S* A, S* X) {
  constexpr int W = COLS < 16 ? COLS : 16, R = COLS % W;
  for (int c0 = 0; c0 + W <= COLS; c0 += W) negate_left_multiply_block<M, S, COLS, W>(A, X, c0);
  if constexpr (R > 0) negate_left_multiply_block<M, S, COLS, R>(A, X, COLS - R);
}

// qdd = M^-1 (tau - nle(q, qd, f_ext)) from a computed M^-1 (Pinocchio's convention).
template <class M, class S> TG_HD void forward_dynamics_from_minv(const Placements<M, S>& K, const S* qd, const S* tau,
                                                                 const S* fext, const S* Minv, S* qdd) {
  S zero[M::NV], nle[M::NV];
  for (int k = 0; k < M::NV; ++k) zero[k] = S(0);
  rnea<M, S>(K, qd, zero, fext, nle);
  for (int r = 0; r < M::NV; ++r) {
    S acc = 0;
    for (int k = 0; k < M::NV; ++k) acc += Minv[M::NV * r + k] * (tau[k] - nle[k]);
    qdd[r] = acc;
  }
}

// d tau/dq, d tau/dqd in the convention C (qd, qdd in Pinocchio's); without Zero, the entries between
// branches of the tree are left as they were (the reframe mixes a free joint's rows and columns, related to
// every dof of its tree). The free joints' columns of M come from the derivatives' composite inertias. Its
// workspace lives in this function's frame, which a GPU thread's stack holds only while it runs (not beside
// the caller's minv).
template <class M, class S, int C, bool Zero = true>
TG_HD void inverse_dynamics_derivatives(const Placements<M, S>& K, const S* qd, const S* qdd, const S* fext,
                                        const Conv<M, S, C>& cv, S* dtau_dq, S* dtau_dqd) {
  RneaDerivativesWork<M, S> W;
  rnea_derivatives_setup<M, S>(K, qd, qdd, fext, W);
  S tau[M::NV];
  rnea_derivatives<M, S, Zero>(W, tau, dtau_dq, dtau_dqd);
  if constexpr (Conv<M, S, C>::active) {
    S Mb[M::NV * Conv<M, S, C>::NB3];
    mass_base_columns<M, S>(W, Mb);
    cv.inverse_dynamics_derivatives_out(qd, qdd, tau, Mb, dtau_dq, dtau_dqd);
  }
}

// Since ID(q, qd, FD(q, qd, tau)) = tau, dqdd/dx = -M^-1 dtau/dx at qdd = FD(q, qd, tau), and
// dqdd/dtau = M^-1, in either convention. Minv, RNEA (for qdd) and the RNEA derivatives share the
// Placements pass.
// dqdd/dq, dqdd/dqd, dqdd/dtau (NV x NV each, in the convention) and qdd (in Pinocchio's).
template <class M, class S, int C>
TG_HD void forward_dynamics_derivatives(const Placements<M, S>& K, const S* qd, const S* tau, const S* fext,
                                     const Conv<M, S, C>& cv, S* dq, S* dqd, S* dtau, S* qdd) {
  minv<M, S>(K, dtau);  // needed anyway, so qdd comes from it rather than from ABA
  forward_dynamics_from_minv<M, S>(K, qd, tau, fext, dtau, qdd);
  inverse_dynamics_derivatives<M, S>(K, qd, qdd, fext, cv, dq, dqd);
  cv.congruence_out(dtau);
  negate_left_multiply<M, S, M::NV>(dtau, dq);
  negate_left_multiply<M, S, M::NV>(dtau, dqd);
}

// (M + dt D) qdd = tau + p - b(q, qd): the acceleration of MuJoCo's Euler step, the joint damping D taken
// implicitly (mj_Euler), p the passive forces (passive.h). Differentiating ID(q, qd, qdd) + dt D qdd - p = tau
// at that qdd, with H = M + dt D: dqdd/dx = -H^-1 (dID/dx - dp/dx), dqdd/dtau = H^-1. H is factored in the
// convention (H_c = G H G^T, D being zero on free joints), as a Runge-Kutta stage's M (rk_stage).
// dqdd/dq, dqdd/dqd, dqdd/dtau (NV x NV each, in the convention) and qdd (in Pinocchio's).
template <class M, class S, int C>
TG_HD void damped_dynamics_derivatives(const Placements<M, S>& K, const Conv<M, S, C>& cv, const S* q, const S* qd,
                                    const S* tau, const S* fext, S h, S* dq, S* dqd, S* dtau, S* qdd) {
  constexpr int NV = M::NV;
  const auto& d = data<M, S>();
  S H[NV * NV], f[NV], zero[NV], buf[Conv<M, S, C>::active ? NV : 1];
  crba<M, S>(K, H);
  cv.congruence_out(H);
  for (int k = 0; k < NV; ++k) H[(NV + 1) * k] += h * S(d.damping[k]);
  ltdl_factor<M, S>(H);
  // f = tau + p - b, then H_c^-1 G f = G qdd
  for (int k = 0; k < NV; ++k) zero[k] = S(0);
  rnea<M, S>(K, qd, zero, fext, f);
  for (int k = 0; k < NV; ++k) f[k] = tau[k] - f[k];
  add_passive<M, S>(q, qd, f);
  cv.force_out(f);
  ltdl_solve<M, S>(H, f);
  const S* a = cv.velocity(f, buf);  // G^T
  for (int k = 0; k < NV; ++k) qdd[k] = a[k];
  // the derivatives: -H^-1 (dID/dx + [K D]), and H^-1 from the identity's columns
  inverse_dynamics_derivatives<M, S>(K, qd, qdd, fext, cv, dq, dqd);
  add_passive_diagonals<M, S>(dq, dqd);
  for (int r = 0; r < NV; ++r)
    for (int c = 0; c < NV; ++c) dtau[NV * r + c] = S(r == c), dq[NV * r + c] = -dq[NV * r + c], dqd[NV * r + c] = -dqd[NV * r + c];
  ltdl_solve_rows<M, NV>(H, dq);
  ltdl_solve_rows<M, NV>(H, dqd);
  ltdl_solve_rows<M, NV>(H, dtau);
}

// forward_dynamics_derivatives at FD(q, qd, tau + p) with passive (1) and dq -= M^-1 K, dqd -= M^-1 D (passive.h);
// without (0), at tau.
template <class M, class S, int C>
TG_HD void passive_dynamics_derivatives(const Placements<M, S>& K, const Conv<M, S, C>& cv, const S* q, const S* qd,
                                     const S* tau, const S* fext, int passive, S* dq, S* dqd, S* dtau, S* qdd) {
  S tau_p[M::NV];
  for (int k = 0; k < M::NV; ++k) tau_p[k] = tau[k];
  if (passive) add_passive<M, S>(q, qd, tau_p);
  forward_dynamics_derivatives<M, S>(K, qd, tau_p, fext, cv, dq, dqd, dtau, qdd);
  if (passive) add_passive_columns<M, S>(dtau, dq, dqd);
}

}  // namespace tg
