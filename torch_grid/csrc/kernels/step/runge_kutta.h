// The explicit Runge-Kutta steps in Munthe-Kaas's form (MuJoCo's mj_RungeKutta; torch_grid/step/integrators.py
// holds the same in torch) and their tangent Jacobians, from each stage's inverse-dynamics derivatives.
// Stage i (tableau a, weights b; every vector in the call's convention):
//   u_i = dt sum_j a_ij c_j,  q_i = q (+) u_i,  v_i = qd + dt sum_j a_ij acc_j,  acc_i = FD(q_i, v_i, tau)
//   c_i = dexp(u_i)^-1 v_i   (the stage velocity carried to q's chart; v_i at a vector-space joint)
// and the step q' = q (+) u', u' = dt sum_j b_j c_j, qd' = qd + dt sum_j b_j acc_j. FD's derivatives are
// -M^-1 [D_q D_v -I], with D_q, D_v the stage's d tau/dq, d tau/dqd at acc_i and M its mass matrix.
// The Jacobians are taken in reverse: one adjoint column per output row (2 NV of them, against 3 NV input
// directions), from the last stage to the first. With abar_i, cbar_i the adjoints of acc_i and c_i:
//   mu = M^-1 abar_i,  taubar += mu,  qbar_i = -D_q^T mu,  vbar_i = -D_v^T mu + D_v'^T cbar_i,
//   ubar_i = Jv^T qbar_i + D_u^T cbar_i,  qbar += Jq^T qbar_i,  qdbar += vbar_i,
//   cbar_j += dt a_ij ubar_i,  abar_j += dt a_ij vbar_i   (j < i)
// (Jq, Jv: integrate's tangent Jacobians at u_i; D_v', D_u: dexp^-1's along v and u; all the identity, or
// zero for D_u, at a vector-space joint). A stage thus costs a solve by M's L^T D L factor and products of
// D_q^T and D_v^T, zero between branches of the tree, with 2 NV columns: never the dense M^-1 D.
#pragma once

#include "kernels/derivatives/dynamics_derivatives.h"
#include "kernels/derivatives/forward_mode.h"
#include "kernels/dynamics/aba.h"
#include "kernels/dynamics/crba.h"
#include "kernels/dynamics/ltdl.h"
#include "kernels/dynamics/passive.h"
#include "kernels/dynamics/products.h"
#include "kernels/dynamics/rnea.h"
#include "kernels/step/step.h"

namespace tg {

// Scheme 2 (midpoint), 3 (rk3) or 4 (rk4): the rows of a below the diagonal and the weights b.
struct RkTableau {
  int stages;
  double a[4][3], b[4];
};

TG_HD RkTableau rk_tableau(int scheme) {
  if (scheme == 2) return {2, {{0, 0, 0}, {0.5, 0, 0}}, {0, 1}};
  if (scheme == 3) return {3, {{0, 0, 0}, {0.5, 0, 0}, {-1, 2, 0}}, {1.0 / 6, 2.0 / 3, 1.0 / 6}};
  return {4, {{0, 0, 0}, {0.5, 0, 0}, {0, 0.5, 0}, {0, 0, 1}}, {1.0 / 6, 1.0 / 3, 1.0 / 3, 1.0 / 6}};
}

// Jr(w)^-1 y = y + [w] y / 2 + beta [w]^2 y (So3Coefficients' beta at w).
template <class T> TG_HD Vec3<T> right_jacobian_inverse(Vec3<T> w, T beta, Vec3<T> y) {
  return y + T(0.5) * cross(w, y) + beta * cross(w, cross(w, y));
}

// The rotation w of a stage, as MuJoCo's Runge-Kutta carries the stage's velocity by it: the short way round
// (|w| <= pi, the turn its quaternion difference gives), each pass taking one whole turn off; Pinocchio's
// convention keeps w itself. Where no lane turns past pi, w unchanged.
template <int C, class Scalar> TG_HD Vec3<Scalar> stage_turn(Vec3<Scalar> w) {
  if constexpr (C == MUJOCO) {
    constexpr double pi = 3.14159265358979323846;
    for (int turns = 0; turns < 64; ++turns) {
      const Scalar t2 = dot(w, w);
      const auto over = t2 > Scalar(pi * pi);
      if (!any(over)) break;
      w = select(over, Scalar(1) - Scalar(2 * pi) / sqrt(select(over, t2, Scalar(1))), Scalar(1)) * w;
    }
  }
  return w;
}

// dexp(theta)^-1 x at one quaternion joint (n = 3: ball; n = 6: free, R^3 x SO(3) in MuJoCo's
// convention, SE(3) in Pinocchio's, where dexp^-1 = [[Jr^-1, -Jr^-1 Q Jr^-1], [0, Jr^-1]]), at the
// rotation stage_turn gives.
template <class T, int C> TG_HD void dexp_inverse_joint(int n, const T* theta, const T* x, T* out) {
  const Vec3<T> w = stage_turn<C>(load3(theta + n - 3));
  const So3Coefficients<T> k = so3_coefficients(w);
  const Vec3<T> xa = right_jacobian_inverse(w, k.beta, load3(x + n - 3));
  store3(xa, out + n - 3);
  if (n == 6) {
    if constexpr (C == MUJOCO) {
      store3(load3(x), out);
    } else {
      store3(right_jacobian_inverse(w, k.beta, load3(x) - se3_coupling_times(load3(theta), w, k, xa)), out);
    }
  }
}

// c = dexp(theta)^-1 x and its n x n derivatives: along x the map's matrix; along Pinocchio's free joint's
// rho, -Jr^-1 L(w, Jr^-1 x_ang) (step.h); along w, one forward-mode pass of the closed form (a dozen 3 x 3
// products) carrying the three directions. A ball joint (n = 3) or Pinocchio's free joint (n = 6):
// dexp_inverse_jacobians below adds MuJoCo's free joint.
template <class Scalar, int C> TG_HD void dexp_inverse_jacobians_lie(int n, const Scalar* theta, const Scalar* x, Scalar* c, Scalar* Dtheta, Scalar* Dx) {
  Scalar turned[6];  // theta at stage_turn's rotation; the forward-mode pass below reads theta, and turns it itself
  for (int m = 0; m < n; ++m) turned[m] = theta[m];
  store3(stage_turn<C>(load3(theta + n - 3)), turned + n - 3);
  const Vec3<Scalar> w = load3(turned + n - 3);
  const So3Coefficients<Scalar> k = so3_coefficients(w);
  const Mat3<Scalar> Ji = so3_terms(w, Scalar(0.5), k.beta);
  dexp_inverse_matrix<Scalar, C>(n, turned, k, Dx);
  if (n == 6) {
    const Mat3<Scalar> JL = mul(Ji, se3_coupling_along_rho(w, mul(Ji, load3(x + 3)), k));
    for (int r = 0; r < 3; ++r)
      for (int m = 0; m < 3; ++m) Dtheta[6 * r + m] = -JL.m[3 * r + m], Dtheta[6 * (r + 3) + m] = Scalar(0);
  }
  for (int a = 0; a < n; ++a) {
    Scalar sum = Scalar(0);
    for (int b = 0; b < n; ++b) sum += Dx[n * a + b] * x[b];
    c[a] = sum;
  }
  Jet<Scalar, 3> th[6], xx[6], out[6];
  for (int m = 0; m < n; ++m) {
    th[m] = Jet<Scalar, 3>(theta[m]), xx[m] = Jet<Scalar, 3>(x[m]);
    if (m >= n - 3) th[m].d[m - (n - 3)] = Scalar(1);
  }
  dexp_inverse_joint<Jet<Scalar, 3>, C>(n, th, xx, out);
  for (int m = 0; m < n; ++m)
    for (int k = 0; k < 3; ++k) Dtheta[n * m + n - 3 + k] = out[m].d[k];
}

// dexp_inverse_jacobians_lie, and MuJoCo's free joint: its position carried as it is, its rotation as a
// ball's. (Not by recursion: a recursive function is not inlined on a GPU, and its frames go on a call
// stack of the driver's default size, which they overflowed.)
template <class Scalar, int C> TG_HD void dexp_inverse_jacobians(int n, const Scalar* theta, const Scalar* x, Scalar* c, Scalar* Dtheta, Scalar* Dx) {
  if (C == MUJOCO && n == 6) {
    Scalar Dt3[9], Dx3[9];
    dexp_inverse_jacobians_lie<Scalar, C>(3, theta + 3, x + 3, c + 3, Dt3, Dx3);
    for (int a = 0; a < 6; ++a)
      for (int b = 0; b < 6; ++b) {
        const bool ang = a >= 3 && b >= 3;
        Dtheta[6 * a + b] = ang ? Dt3[3 * (a - 3) + b - 3] : Scalar(0);
        Dx[6 * a + b] = ang ? Dx3[3 * (a - 3) + b - 3] : Scalar(a == b);
      }
    for (int m = 0; m < 3; ++m) c[m] = x[m];
    return;
  }
  dexp_inverse_jacobians_lie<Scalar, C>(n, theta, x, c, Dtheta, Dx);
}

// out (n x COLS) (+)= sum_t G_t^T X_t for a quaternion joint's n x n blocks G_t (n = 3 or 6) and n-row X_t.
template <int COLS, class Scalar>
TG_HD void joint_adjoint(int n, int nt, const Scalar* const* G, const Scalar* const* X, Scalar* out, bool add) {
  const Scalar one[4] = {Scalar(1), Scalar(1), Scalar(1), Scalar(1)};
  if (n == 6)
    add ? products<6, COLS, COLS, COLS, true, true>(nt, 6, G, 6, one, X, out)
        : products<6, COLS, COLS, COLS, false, true>(nt, 6, G, 6, one, X, out);
  else
    add ? products<3, COLS, COLS, COLS, true, true>(nt, 3, G, 3, one, X, out)
        : products<3, COLS, COLS, COLS, false, true>(nt, 3, G, 3, one, X, out);
}

// A stage's dynamics at cs (v, tau in Pinocchio's convention): acc = FD(q, v, tau), D_q and D_v at it and
// the L^T D L factor of M (ltdl.h), all in the convention: M_c = G M G^T, so that
// M_c^-1 G (tau - bias) = G qdd. With passive, tau + p and the derivatives of ID - p (passive.h).
template <class Robot, class Scalar, int C>
TG_HD void rk_stage(const Conv<Robot, Scalar, C>& cs, const Scalar* v, const Scalar* tau, const Scalar* fext, bool passive, Scalar* Dq, Scalar* Dv, Scalar* H,
                    Scalar* acc, const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV;
  const Placements<Robot, Scalar> K(cs.q);
  Scalar zero[NV];
  crba<Robot, Scalar>(K, H, pi);
  factor_mass<Robot, Scalar>(cs, Scalar(0), H);
  for (int k = 0; k < NV; ++k) zero[k] = Scalar(0);
  rnea<Robot, Scalar>(K, v, zero, fext, acc, pi);
  for (int k = 0; k < NV; ++k) acc[k] = tau[k] - acc[k];
  if (passive) add_passive<Robot, Scalar>(cs.q, v, acc);
  solve_mass<Robot, Scalar>(cs, H, acc, acc);  // qdd, in Pinocchio's convention until the end
  // Read on the tree's entries alone, the rest left as they were (zero), except in the convention: its reframe
  // writes a free joint's rows and columns whole, so a non-finite sample would leave them NaN for the next one.
  constexpr bool reframed = Conv<Robot, Scalar, C>::active;
  inverse_dynamics_derivatives<Robot, Scalar, C, reframed>(K, v, acc, fext, cs, Dq, Dv, pi);
  if (passive) add_passive_diagonals<Robot, Scalar>(Dq, Dv);
  cs.acceleration_out(v, acc);
}

// A stage's acceleration alone, FD(q_i, v, tau) by ABA: v and tau in Pinocchio's convention, acc in the call's;
// tau + p where passive.
template <class Robot, class Scalar, int C>
TG_HD void rk_stage_acceleration(const Conv<Robot, Scalar, C>& cs, const Scalar* v, const Scalar* tau, const Scalar* fext, bool passive,
                                 Scalar* acc, const InertialParameters<Robot, Scalar>& pi) {
  constexpr int NV = Robot::NV;
  Scalar t[NV];
  for (int k = 0; k < NV; ++k) t[k] = tau[k];
  if (passive) add_passive<Robot, Scalar>(cs.q, v, t);
  aba<Robot, Scalar>(cs.q, v, t, fext, acc, pi);
  cs.acceleration_out(v, acc);
}

// Stage i's state from the stages before it: u_i = dt sum_j a_ij c_j, v_i = qd + dt sum_j a_ij acc_j, q_i = q (+) u_i
// (into qs) and c_i = dexp(u_i)^-1 v_i (v_i at a vector-space joint).
template <class Robot, class Scalar, int C>
TG_HD void rk_stage_state(const Scalar* q, const RkTableau& T, int i, Scalar h, const Scalar* v0, const Scalar (*acc)[Robot::NV],
                          Scalar (*car)[Robot::NV], Scalar* u, Scalar* v, Scalar* qs) {
  const auto& d = data<Robot, Scalar>();
  for (int k = 0; k < Robot::NV; ++k) {
    Scalar th = Scalar(0), ac = Scalar(0);
    for (int j = 0; j < i; ++j) th += Scalar(T.a[i][j]) * car[j][k], ac += Scalar(T.a[i][j]) * acc[j][k];
    u[k] = h * th;
    v[k] = v0[k] + h * ac;
  }
  for (int jn = 0; jn < Robot::NB; ++jn) {
    const int n = integrate_joint<Robot, Scalar, C>(jn, q, u, qs, nullptr, nullptr), vi = d.vi[jn];
    if (n)
      dexp_inverse_joint<Scalar, C>(n, u + vi, v + vi, car[i] + vi);
    else
      for (int a = 0; a < d.nvj[jn]; ++a) car[i][vi + a] = v[vi + a];
  }
}

// The step's tangent increment u' = dt sum_j b_j c_j and qd' = qd + dt sum_j b_j acc_j.
template <int NV, class Scalar>
TG_HD void rk_combine(const RkTableau& T, Scalar h, const Scalar* v0, const Scalar (*acc)[NV], const Scalar (*car)[NV], Scalar* un, Scalar* qd_next) {
  for (int k = 0; k < NV; ++k) {
    Scalar th = Scalar(0), ac = Scalar(0);
    for (int j = 0; j < T.stages; ++j) th += Scalar(T.b[j]) * car[j][k], ac += Scalar(T.b[j]) * acc[j][k];
    un[k] = h * th;
    qd_next[k] = v0[k] + h * ac;
  }
}

// The stages' values: qd and tau in the call's convention, each stage's acceleration and carried velocity, u_i and
// v_i (S of them: the current stage's alone for the step's values, each stage's for its Jacobians, whose reverse
// pass reads them again), q_i, and the step's tangent increment u'.
template <class Robot, class Scalar, int S> struct RkStages {
  static constexpr int NV = Robot::NV;
  Scalar v0[NV], tau_c[NV], acc[4][NV], car[4][NV], u[S][NV], v[S][NV], qs[Robot::NQ], un[NV];
};

// The stages in order, by team t (Solo: one thread): stage i's state by the leader (rk_stage_state), then its
// dynamics, stage(i, cs, v, f) at cs = Conv(q_i) with v_i and tau in Pinocchio's convention (converted by the
// leader, into vp and tp (NV each) where the conventions differ; read by the leader alone), which sets acc[i];
// then u' and qd' by the leader (rk_combine). qd and tau in Pinocchio's convention, as cv takes them.
template <class Robot, class Scalar, int C, int S, class Team, class Stage>
TG_HD void rk_stages(const Team& t, RkStages<Robot, Scalar, S>& w, const Conv<Robot, Scalar, C>& cv, const Scalar* qd, const Scalar* tau,
                     const RkTableau& T, Scalar h, Scalar* vp, Scalar* tp, Scalar* qd_next, Stage&& stage) {
  if (t.leader()) {
    for (int k = 0; k < Robot::NV; ++k) w.v0[k] = qd[k], w.tau_c[k] = tau[k];
    cv.velocity_out(w.v0);
    cv.force_out(w.tau_c);
  }
  for (int i = 0; i < T.stages; ++i) {
    Scalar* const u = w.u[S == 1 ? 0 : i];
    Scalar* const v = w.v[S == 1 ? 0 : i];
    if (t.leader()) rk_stage_state<Robot, Scalar, C>(cv.q, T, i, h, w.v0, w.acc, w.car, u, v, w.qs);
    t.sync();
    if (i == 0) {
      stage(0, cv, qd, tau);
    } else {
      const Conv<Robot, Scalar, C> cs(w.qs);
      stage(i, cs, t.leader() ? cs.velocity(v, vp) : v, t.leader() ? cs.force(w.tau_c, tp) : w.tau_c);
    }
  }
  if (t.leader()) rk_combine<Robot::NV>(T, h, w.v0, w.acc, w.car, w.un, qd_next);
}

// The step alone, without its Jacobians (rk_step below): the same stages, each acceleration by ABA. cv at q, qd and
// tau in Pinocchio's convention; q_next (NQ) and qd_next (NV) in the call's.
template <class Robot, class Scalar, int C>
TG_HD void rk_step_values(const Conv<Robot, Scalar, C>& cv, const Scalar* qd, const Scalar* tau, const Scalar* fext, Scalar h, int scheme,
                          bool passive, Scalar* q_next, Scalar* qd_next, const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NC = Conv<Robot, Scalar, C>::active ? Robot::NV : 1;
  RkStages<Robot, Scalar, 1> w;
  Scalar vp[NC], tp[NC];
  rk_stages<Robot, Scalar>(Solo{}, w, cv, qd, tau, rk_tableau(scheme), h, vp, tp, qd_next,
                           [&](int i, const Conv<Robot, Scalar, C>& cs, const Scalar* v, const Scalar* f) __attribute__((always_inline)) {
                             rk_stage_acceleration<Robot, Scalar, C>(cs, v, f, fext, passive, w.acc[i], pi);
                           });
  for (int jn = 0; jn < Robot::NB; ++jn) integrate_joint<Robot, Scalar, C>(jn, cv.q, w.un, q_next, nullptr, nullptr);
}

// rk_step's workspace (8 NV x 3 NV) for s stages: each stage's D_q, D_v and M's factor (NV x NV each), slots of
// pending adjoints abar_j, cbar_j (NV x 2 NV each; a stage's slot differs from those of the stages it feeds: rk4's
// stage i feeds stage i - 1 alone, so two slots alternate; rk3 has one a stage), then ubar_i (NV x 2 NV) and, on
// one thread, the step's Jv blocks.
template <int NV, class Scalar> struct RkWorkspace {
  static constexpr int NN = NV * NV, NA = 2 * NN;
  Scalar* work;
  int s;
  TG_HD Scalar* dynamics(int i) const { return work + 3 * NN * i; }  // D_q; D_v at + NN; the factor at + 2 NN
  TG_HD Scalar* slot(int j) const { return work + 3 * NN * s + 2 * NA * (s == 3 ? j : j % 2); }  // abar_j; cbar_j at + NA
  TG_HD Scalar* U() const { return work + 3 * NN * s + 2 * NA * (s == 3 ? 3 : 2); }
};

// The earlier stages j that stage i feeds (v_i = qd + dt sum_j a_ij acc_j, u_i = dt sum_j a_ij c_j), n of them:
// their slots' abar_j (fa) and cbar_j (fc), the weights dt a_ij (fw), and whether a slot is fresh, to be written
// rather than added to (no later stage has fed it: `fed`, which this then marks).
template <class Scalar> struct RkFeeds {
  Scalar* fa[2];
  Scalar* fc[2];
  Scalar fw[2];
  bool fresh[2];
  int n = 0;
  template <int NV> TG_HD RkFeeds(const RkTableau& T, int i, Scalar h, const RkWorkspace<NV, Scalar>& ws, bool* fed) {
    for (int j = 0; j < i; ++j)
      if (T.a[i][j] != 0) {
        fa[n] = ws.slot(j), fc[n] = ws.slot(j) + RkWorkspace<NV, Scalar>::NA, fw[n] = h * Scalar(T.a[i][j]), fresh[n++] = !fed[j];
        fed[j] = true;
      }
  }
};

// y += x and, for k < nf, to[k] += w[k] x (written, not added, where fresh), in one pass over N entries.
template <int N, class Scalar>
TG_HD void spread(const Scalar* x, Scalar* y, int nf, Scalar* const* to, const Scalar* w, const bool* fresh) {
  if (nf == 0) {
    for (int e = 0; e < N; ++e) y[e] += x[e];
  } else if (fresh[0]) {
    for (int e = 0; e < N; ++e) y[e] += x[e], to[0][e] = w[0] * x[e];
  } else {
    for (int e = 0; e < N; ++e) y[e] += x[e], to[0][e] += w[0] * x[e];
  }
  for (int k = 1; k < nf; ++k)
    for (int e = 0; e < N; ++e) to[k][e] = (fresh[k] ? Scalar(0) : to[k][e]) + w[k] * x[e];
}

// Stage i's adjoints (NV x 2 NV each, a column per output row, q' then qd'), from abar and cbar, its
// acceleration's and carried velocity's:
// mu = M^-1 abar (in place; on the last stage only the qd' columns, the q' ones being zero), taubar += mu;
// qbar_i = -D_q^T mu (into U), qbar += Jq^T qbar_i; vbar_i = -D_v^T mu + D_v'^T cbar (in place of cbar),
// qdbar += vbar_i; and for each earlier stage j it feeds (f, with w = dt a_ij), cbar_j += w ubar_i and
// abar_j += w vbar_i (written, not added, where fresh), ubar_i = Jv^T qbar_i + D_u^T cbar. At a
// vector-space joint Jq, Jv and D_v' are the identity and D_u zero, so qbar_i and vbar_i are spread as they
// are, and a quaternion joint's rows mended.
template <class Robot, class Scalar, int C>
TG_HD void rk_adjoint_stage(const TreeBlocks<Robot, Scalar>& tb, const Scalar* q, const Scalar* u, const Scalar* v, const Scalar* Dq, const Scalar* Dv,
                            const Scalar* H, bool first, bool last, Scalar* abar, Scalar* cbar, Scalar* U, const RkFeeds<Scalar>& f,
                            Scalar* qbar, Scalar* qdbar, Scalar* taubar) {
  constexpr int NV = Robot::NV, K2 = 2 * NV, NA = NV * K2;
  const auto& d = data<Robot, Scalar>();
  const Scalar minus[1] = {Scalar(-1)};
  const Scalar* gq[1] = {Dq};
  const Scalar* gv[1] = {Dv};
  if (last) {
    ltdl_solve_columns<Robot, K2, NV>(H, abar, NV, taubar);
    for (int r = 0; r < NV; ++r)
      for (int c = 0; c < NV; ++c) U[K2 * r + c] = Scalar(0);
    const Scalar* X[1] = {abar + NV};
    tree_products<Robot, NV, K2, K2, false, true>(tb, 1, gq, minus, X, U + NV);
  } else {
    ltdl_solve_rows<Robot, K2>(H, abar, taubar);
    const Scalar* X[1] = {abar};
    tree_products<Robot, K2, K2, K2, false, true>(tb, 1, gq, minus, X, U);
  }
  spread<NA>(U, qbar, f.n, f.fc, f.fw, f.fresh);
  // a quaternion joint's rows: qbar += (Jq - I)^T qbar_i, cbar_j += w (ubar_i - qbar_i), cbar = D_v'^T cbar
  // (nothing at the first stage: at u = 0 Jq, Jv and D_v' are the identity, and it feeds no stage)
  for (int jn = 0; jn < (first ? 0 : Robot::NB); ++jn) {
    Scalar Jq[36], Jv[36], Du[36], Dx[36], c[6], qs[Robot::NQ], blk[6 * K2];
    const int n = integrate_joint<Robot, Scalar, C>(jn, q, u, qs, Jq, Jv), vi = d.vi[jn];
    if (!n) continue;
    dexp_inverse_jacobians<Scalar, C>(n, u + vi, v + vi, c, Du, Dx);
    Scalar* const Ur = U + K2 * vi;
    Scalar* const Cr = cbar + K2 * vi;
    for (int a = 0; a < n; ++a) Jq[n * a + a] -= Scalar(1), Jv[n * a + a] -= Scalar(1);
    const Scalar* g1[1] = {Jq};
    const Scalar* x1[1] = {Ur};
    joint_adjoint<K2>(n, 1, g1, x1, qbar + K2 * vi, true);
    const Scalar* g2[2] = {Jv, Du};
    const Scalar* x2[2] = {Ur, Cr};
    joint_adjoint<K2>(n, 2, g2, x2, blk, false);
    for (int k = 0; k < f.n; ++k)
      for (int e = 0; e < n * K2; ++e) f.fc[k][K2 * vi + e] += f.fw[k] * blk[e];
    const Scalar* g3[1] = {Dx};
    const Scalar* x3[1] = {Cr};
    joint_adjoint<K2>(n, 1, g3, x3, blk, false);
    for (int e = 0; e < n * K2; ++e) Cr[e] = blk[e];
  }
  // vbar_i = cbar - D_v^T mu, in place
  if (last) {
    const Scalar* X[1] = {abar + NV};
    tree_products<Robot, NV, K2, K2, true, true>(tb, 1, gv, minus, X, cbar + NV);
  } else {
    const Scalar* X[1] = {abar};
    tree_products<Robot, K2, K2, K2, true, true>(tb, 1, gv, minus, X, cbar);
  }
  spread<NA>(cbar, qdbar, f.n, f.fa, f.fw, f.fresh);
}

// The step and its Jacobians. cv at q, qd and tau in Pinocchio's convention (as the binding passes them).
// Outputs: q_next (NQ), qd_next (NV), A (2 NV x 2 NV), B (2 NV x NV), in the convention, A and B holding
// their transposes (the adjoints of q, qd and tau) until the end; work laid out as RkWorkspace.
template <class Robot, class Scalar, int C>
TG_HD void rk_step(const Conv<Robot, Scalar, C>& cv, const Scalar* qd, const Scalar* tau, const Scalar* fext, Scalar h, int scheme, bool passive,
                   Scalar* q_next, Scalar* qd_next, Scalar* A, Scalar* B, Scalar* work, const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV, K2 = 2 * NV, NN = NV * NV, NA = NV * K2;
  const auto& d = data<Robot, Scalar>();
  const RkTableau T = rk_tableau(scheme);
  const int s = T.stages;
  const RkWorkspace<NV, Scalar> ws{work, s};
  Scalar* const U = ws.U();
  RkStages<Robot, Scalar, 4> w;
  Scalar vp[Conv<Robot, Scalar, C>::active ? NV : 1], tp[Conv<Robot, Scalar, C>::active ? NV : 1];
  // the stages' values and dynamics, then the step: q' = q (+) u', qd' = qd + dt sum_j b_j acc_j
  rk_stages<Robot, Scalar>(Solo{}, w, cv, qd, tau, T, h, vp, tp, qd_next,
                           [&](int i, const Conv<Robot, Scalar, C>& cs, const Scalar* v, const Scalar* f) __attribute__((always_inline)) {
                             Scalar* const Dq = ws.dynamics(i);
                             rk_stage<Robot, Scalar, C>(cs, v, f, fext, passive, Dq, Dq + NN, Dq + 2 * NN, w.acc[i], pi);
                           });
  // adjoints: qbar = Jq'^T on the q' columns, qdbar = I on the qd' ones (A's storage, as A^T), taubar (B's,
  // as B^T)
  Scalar* const qbar = A;
  Scalar* const qdbar = A + NA;
  Scalar* const taubar = B;
  for (int e = 0; e < 2 * NA; ++e) A[e] = Scalar(0);
  for (int e = 0; e < NA; ++e) taubar[e] = Scalar(0);
  for (int k = 0; k < NV; ++k) qdbar[K2 * k + NV + k] = Scalar(1);
  Scalar* const Jvs = U + NA;  // the step's Jv at each quaternion joint, n x n after one another (at most 6 NV)
  for (int jn = 0, o = 0; jn < Robot::NB; ++jn) {
    Scalar Jq[36];
    const int n = integrate_joint<Robot, Scalar, C>(jn, cv.q, w.un, q_next, Jq, Jvs + o), vi = d.vi[jn];
    for (int a = 0; a < (n ? n : d.nvj[jn]); ++a)
      for (int b = 0; b < (n ? n : d.nvj[jn]); ++b) qbar[K2 * (vi + a) + vi + b] = n ? Jq[n * b + a] : Scalar(a == b);
    o += n * n;
  }
  const auto& tb = tree_blocks<Robot, Scalar>();
  bool fed[4] = {false, false, false, false};
  for (int i = s - 1; i >= 0; --i) {
    Scalar* const abar = ws.slot(i);
    Scalar* const cbar = abar + NA;
    // the output's own terms: qd' = ... + dt b_i acc_i, u' = ... + dt b_i c_i
    if (!fed[i])
      for (int e = 0; e < 2 * NA; ++e) abar[e] = Scalar(0);
    const Scalar hb = h * Scalar(T.b[i]);
    for (int k = 0; k < NV; ++k) abar[K2 * k + NV + k] += hb;
    for (int jn = 0, o = 0; jn < Robot::NB; ++jn) {
      const int n = quaternion_dofs<Robot, Scalar>(jn), vi = d.vi[jn];
      for (int a = 0; a < (n ? n : d.nvj[jn]); ++a)
        for (int b = 0; b < (n ? n : d.nvj[jn]); ++b) cbar[K2 * (vi + a) + vi + b] += hb * (n ? Jvs[o + n * b + a] : Scalar(a == b));
      o += n * n;
    }
    const RkFeeds<Scalar> feeds(T, i, h, ws, fed);
    const Scalar* const Dq = ws.dynamics(i);
    rk_adjoint_stage<Robot, Scalar, C>(tb, cv.q, w.u[i], w.v[i], Dq, Dq + NN, Dq + 2 * NN, i == 0, i == s - 1, abar, cbar, U, feeds, qbar,
                                       qdbar, taubar);
  }
  // A and B from their transposes
  for (int r = 0; r < K2; ++r)
    for (int c = 0; c < r; ++c) {
      const Scalar x = A[K2 * r + c];
      A[K2 * r + c] = A[K2 * c + r];
      A[K2 * c + r] = x;
    }
  Scalar* const Bt = ws.slot(0);
  for (int e = 0; e < NA; ++e) Bt[e] = taubar[e];
  for (int r = 0; r < K2; ++r)
    for (int k = 0; k < NV; ++k) B[NV * r + k] = Bt[K2 * k + r];
}

}  // namespace tg
