// A Runge-Kutta step's Jacobians by a team (kernels/spatial/team.h): runge_kutta.h's stages and adjoint
// columns, shared out. Each stage's dynamics by factored_dynamics_derivatives (M by crba's team path, factored by the
// first lane, the derivatives by the RNEA derivatives' team path), M's factor in the stage's third NV x NV block of
// the workspace as rk_step keeps it; then the reverse pass a column a lane. An adjoint column (one output row)
// meets no other on the way back, so the lanes run the pass each over its own columns of A^T, B^T and the stages'
// slots, meeting only while the first lane computes a stage's joint blocks (two syncs a stage) and at the end.
#pragma once

#include "kernels/derivatives/dynamics_derivatives.h"
#include "kernels/dynamics/passive.h"
#include "kernels/spatial/team.h"
#include "kernels/step/runge_kutta.h"
#include "kernels/step/step.h"

namespace tg {

// The team's shared workspace: the stages' dynamics' (one stage at a time) and their v and tau in Pinocchio's
// convention, the stages' values as rk_step keeps them, and at each quaternion joint (n x n blocks after one
// another: 36 entries a free joint, 9 a ball joint, of which there are at most a third of the other dofs): the
// step's integrate Jacobians, and a stage's (Jq - I, Jv - I) and dexp^-1's (D_u, D_v').
template <class Robot, class Scalar> struct RkStepDerivativesTeamWork {
  static constexpr int NV = Robot::NV, NBLK = 36 * Robot::NFREE + (Robot::BALLS ? 3 * (NV - 6 * Robot::NFREE) : 0) + 1;
  FactoredDynamicsTeamWork<Robot, Scalar> dyn;
  Scalar vp[NV], tp[NV];
  RkStages<Robot, Scalar, 4> rk;
  Scalar Jq[NBLK], Jv[NBLK];
  Scalar Jqs[NBLK], Jvs[NBLK], Du[NBLK], Dx[NBLK];
  int offset[Robot::NB];  // each joint's first entry in the blocks
};

// sum_k G[k, r] x[k] over the dofs k related to r (its ancestors and its subtree), G zero between branches.
template <class Robot, class Scalar> TG_HD_INLINE Scalar related_dot(const Scalar* G, int r, const Scalar* x, int xs) {
  const auto& d = data<Robot, Scalar>();
  Scalar s = Scalar(0);
  for (const int k : d.dof_ancestors[r]) {
    if (k < 0) break;
    s += G[Robot::NV * k + r] * x[xs * k];
  }
  for (int k = r; k < d.dof_end[r]; ++k) s += G[Robot::NV * k + r] * x[xs * k];
  return s;
}

// A stage's dynamics by team t (rk_stage's): D_q, D_v and M's factor H in the convention, and acc = FD(q, v, tau
// (+ p)) in it (by the leader, written once every lane has passed the next sync); v and tau in Pinocchio's
// convention, read by the leader alone.
template <class Robot, class Scalar, int C, class Team>
TG_HD void rk_stage(const Team& t, RkStepDerivativesTeamWork<Robot, Scalar>& w, const Conv<Robot, Scalar, C>& cs, const Scalar* v,
                    const Scalar* tau, const Scalar* fext, bool passive, Scalar* Dq, Scalar* Dv, Scalar* H, Scalar* acc,
                    const InertialParameters<Robot, Scalar>& pi) {
  constexpr int NV = Robot::NV;
  if (t.leader())
    for (int k = 0; k < NV; ++k) w.vp[k] = v[k], w.tp[k] = tau[k];
  t.sync();
  factored_dynamics_derivatives<Robot, Scalar>(t, w.dyn, cs, cs.q, w.vp, w.tp, fext, Scalar(0), passive, Dq, Dv, H, pi);
  if (t.leader()) {
    for (int k = 0; k < NV; ++k) acc[k] = w.dyn.rnea.qdd[k];
    cs.acceleration_out(w.vp, acc);
  }
}

// Stage i's blocks at each quaternion joint, by the leader: Jq - I and Jv - I (integrate's tangent Jacobians at
// u_i, less the identity) and dexp(u_i)^-1's along u and v (D_u, D_v'). w.rk.qs is free by then.
template <class Robot, class Scalar, int C>
TG_HD void rk_stage_blocks(RkStepDerivativesTeamWork<Robot, Scalar>& w, const Scalar* q, const Scalar* u, const Scalar* v) {
  const auto& d = data<Robot, Scalar>();
  for (int jn = 0; jn < Robot::NB; ++jn) {
    if (!quaternion_dofs<Robot, Scalar>(jn)) continue;
    const int o = w.offset[jn], vi = d.vi[jn];
    const int n = integrate_joint<Robot, Scalar, C>(jn, q, u, w.rk.qs, w.Jqs + o, w.Jvs + o);
    Scalar c[6];
    dexp_inverse_jacobians<Scalar, C>(n, u + vi, v + vi, c, w.Du + o, w.Dx + o);
    for (int a = 0; a < n; ++a) w.Jqs[o + n * a + a] -= Scalar(1), w.Jvs[o + n * a + a] -= Scalar(1);
  }
}

// Stage i's adjoints on this lane's columns c (rk_adjoint_stage's, column by column): mu = M^-1 abar in place, by
// M's factor H (none on the last stage's q' columns, where abar is zero), taubar += mu, qbar_i = -D_q^T mu (into U),
// spread to qbar and the fed stages' cbar_j; a quaternion joint's rows mended (w's blocks of the stage, but at the
// first, at u = 0, which feeds no stage); vbar_i = cbar - D_v^T mu, spread to qdbar and abar_j.
template <class Robot, class Scalar, class Team>
TG_HD void rk_adjoint_columns(const Team& t, const RkStepDerivativesTeamWork<Robot, Scalar>& w, const Scalar* Dq, const Scalar* Dv,
                              const Scalar* H, bool first, bool last, Scalar* abar, Scalar* cbar, Scalar* U, const RkFeeds<Scalar>& f,
                              Scalar* qbar, Scalar* qdbar, Scalar* taubar) {
  constexpr int NV = Robot::NV, K2 = 2 * NV;
  const auto& d = data<Robot, Scalar>();
  // y (column c) into x's and to[k]'s: x += y, to[k] (+)= dt a_ij y (written where fresh)
  const auto spread_column = [&](const Scalar* y, Scalar* x, Scalar* const* to, int c) {
    for (int r = 0; r < NV; ++r) {
      const int e = K2 * r + c;
      x[e] += y[e];
      for (int k = 0; k < f.n; ++k) to[k][e] = (f.fresh[k] ? Scalar(0) : to[k][e]) + f.fw[k] * y[e];
    }
  };
  for (const int c : t.items(0, K2)) {
    if (last && c < NV) {
      for (int r = 0; r < NV; ++r) U[K2 * r + c] = Scalar(0);
    } else {
      ltdl_solve_columns<Robot, K2, 1>(H, abar, c, taubar);
      for (int r = 0; r < NV; ++r) U[K2 * r + c] = -related_dot<Robot, Scalar>(Dq, r, abar + c, K2);
    }
    spread_column(U, qbar, f.fc, c);
  }
  // a quaternion joint's rows: qbar += (Jq - I)^T qbar_i, cbar_j += w ((Jv - I)^T qbar_i + D_u^T cbar),
  // cbar = D_v'^T cbar
  for (int jn = 0; jn < (first ? 0 : Robot::NB); ++jn) {
    const int n = quaternion_dofs<Robot, Scalar>(jn), vi = d.vi[jn], o = w.offset[jn];
    if (!n) continue;
    const Scalar *Jq = w.Jqs + o, *Jv = w.Jvs + o, *Du = w.Du + o, *Dx = w.Dx + o;
    for (const int c : t.items(0, K2)) {
      const Scalar* const Ur = U + K2 * vi + c;
      Scalar* const Cr = cbar + K2 * vi + c;
      Scalar fed[6], turned[6];
      for (int a = 0; a < n; ++a) {
        Scalar sq = Scalar(0), sf = Scalar(0), sc = Scalar(0);
        for (int b = 0; b < n; ++b) {
          sq += Jq[n * b + a] * Ur[K2 * b];
          sf += Jv[n * b + a] * Ur[K2 * b] + Du[n * b + a] * Cr[K2 * b];
          sc += Dx[n * b + a] * Cr[K2 * b];
        }
        qbar[K2 * (vi + a) + c] += sq;
        fed[a] = sf, turned[a] = sc;
      }
      for (int a = 0; a < n; ++a) {
        for (int k = 0; k < f.n; ++k) f.fc[k][K2 * (vi + a) + c] += f.fw[k] * fed[a];
        Cr[K2 * a] = turned[a];
      }
    }
  }
  for (const int c : t.items(0, K2)) {
    if (!(last && c < NV))
      for (int r = 0; r < NV; ++r) cbar[K2 * r + c] -= related_dot<Robot, Scalar>(Dv, r, abar + c, K2);
    spread_column(cbar, qdbar, f.fa, c);
  }
}

// rk_step by team t, with its layout of the workspace and of the outputs. All written when every lane returns.
template <class Robot, class Scalar, int C, class Team>
TG_HD void rk_step(const Team& t, RkStepDerivativesTeamWork<Robot, Scalar>& w, const Conv<Robot, Scalar, C>& cv, const Scalar* qd,
                   const Scalar* tau, const Scalar* fext, Scalar h, int scheme, bool passive, Scalar* q_next, Scalar* qd_next, Scalar* A,
                   Scalar* B, Scalar* work, const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV, K2 = 2 * NV, NN = NV * NV, NA = NV * K2;
  const auto& d = data<Robot, Scalar>();
  const RkTableau T = rk_tableau(scheme);
  const int s = T.stages;
  const RkWorkspace<NV, Scalar> ws{work, s};
  Scalar* const U = ws.U();
  if (t.leader())
    for (int jn = 0, o = 0; jn < Robot::NB; ++jn) {
      const int n = quaternion_dofs<Robot, Scalar>(jn);
      w.offset[jn] = o, o += n * n;
    }
  // the stages' values (by the leader) and dynamics, then the step (q' = q (+) u', qd' = qd + dt sum_j b_j acc_j)
  // and its integrate Jacobians, by the leader
  rk_stages<Robot, Scalar>(t, w.rk, cv, qd, tau, T, h, w.vp, w.tp, qd_next,
                           [&](int i, const Conv<Robot, Scalar, C>& cs, const Scalar* v, const Scalar* f) __attribute__((always_inline)) {
                             Scalar* const Dq = ws.dynamics(i);
                             rk_stage<Robot, Scalar>(t, w, cs, v, f, fext, passive, Dq, Dq + NN, Dq + 2 * NN, w.rk.acc[i], pi);
                           });
  if (t.leader())
    for (int jn = 0, o = 0; jn < Robot::NB; ++jn) {
      const int n = integrate_joint<Robot, Scalar, C>(jn, cv.q, w.rk.un, q_next, w.Jq + o, w.Jv + o);
      o += n * n;
    }
  t.sync();
  // this lane's columns of the adjoints: qbar = Jq'^T on the q' columns, qdbar = I on the qd' ones (A's storage,
  // as A^T), taubar = 0 (B's, as B^T)
  Scalar* const qbar = A;
  Scalar* const qdbar = A + NA;
  Scalar* const taubar = B;
  for (const int c : t.items(0, K2)) {
    for (int r = 0; r < K2; ++r) A[K2 * r + c] = Scalar(0);
    for (int r = 0; r < NV; ++r) taubar[K2 * r + c] = Scalar(0);
    if (c >= NV) {
      qdbar[K2 * (c - NV) + c] = Scalar(1);
      continue;
    }
    const int jn = dof_body<Robot, Scalar>(c), n = quaternion_dofs<Robot, Scalar>(jn), vi = d.vi[jn], b = c - vi;
    for (int a = 0; a < (n ? n : d.nvj[jn]); ++a) qbar[K2 * (vi + a) + c] = n ? w.Jq[w.offset[jn] + n * b + a] : Scalar(a == b);
  }
  bool fed[4] = {false, false, false, false};
  for (int i = s - 1; i >= 0; --i) {
    Scalar* const abar = ws.slot(i);
    Scalar* const cbar = abar + NA;
    // the output's own terms: qd' = ... + dt b_i acc_i, u' = ... + dt b_i c_i
    const Scalar hb = h * Scalar(T.b[i]);
    for (const int c : t.items(0, K2)) {
      if (!fed[i])
        for (int r = 0; r < NV; ++r) abar[K2 * r + c] = cbar[K2 * r + c] = Scalar(0);
      if (c >= NV) {
        abar[K2 * (c - NV) + c] += hb;
        continue;
      }
      const int jn = dof_body<Robot, Scalar>(c), n = quaternion_dofs<Robot, Scalar>(jn), vi = d.vi[jn], b = c - vi;
      for (int a = 0; a < (n ? n : d.nvj[jn]); ++a) cbar[K2 * (vi + a) + c] += hb * (n ? w.Jv[w.offset[jn] + n * b + a] : Scalar(a == b));
    }
    const RkFeeds<Scalar> feeds(T, i, h, ws, fed);
    // the stage's joint blocks, once every lane is done with those of the stage before (i + 1)
    if (i > 0) {
      t.sync();
      if (t.leader()) rk_stage_blocks<Robot, Scalar, C>(w, cv.q, w.rk.u[i], w.rk.v[i]);
      t.sync();
    }
    const Scalar* const Dq = ws.dynamics(i);
    rk_adjoint_columns<Robot, Scalar>(t, w, Dq, Dq + NN, Dq + 2 * NN, i == 0, i == s - 1, abar, cbar, U, feeds, qbar, qdbar, taubar);
  }
  // A and B from their transposes (B through slot 0, free again)
  t.sync();
  Scalar* const Bt = ws.slot(0);
  for (const int r : t.items(0, K2)) {
    for (int c = 0; c < r; ++c) {
      const Scalar x = A[K2 * r + c];
      A[K2 * r + c] = A[K2 * c + r];
      A[K2 * c + r] = x;
    }
    for (int k = 0; k < NV; ++k) Bt[K2 * k + r] = taubar[K2 * k + r];
  }
  t.sync();
  for (const int r : t.items(0, K2))
    for (int k = 0; k < NV; ++k) B[NV * r + k] = Bt[K2 * k + r];
  t.sync();
}

}  // namespace tg
