// The explicit Runge-Kutta steps in Munthe-Kaas's form (MuJoCo's mj_RungeKutta; torch_grid/integrators.py
// holds the same in torch) and their tangent Jacobians, from each stage's inverse-dynamics derivatives.
// Stage i (tableau a, weights b; every vector in the call's convention):
//   theta_i = sum_j a_ij c_j,  q_i = q (+) dt theta_i,  v_i = qd + dt sum_j a_ij acc_j,  acc_i = FD(q_i, v_i, tau)
//   c_i = dexp(dt theta_i)^-1 v_i   (the stage velocity carried to q's chart; v_i at a vector-space joint)
// and the step q' = q (+) dt sum_j b_j c_j, qd' = qd + dt sum_j b_j acc_j. Along z = [dq; dqd; dtau] (each
// derivative an NV x 3 NV row-major matrix), with D_q, D_v the stage's d tau/dq, d tau/dqd at acc_i and M
// its mass matrix (FD's derivatives are -M^-1 [D_q D_v -I]):
//   M dacc_i = [0 0 I] - D_q dq_i - D_v dv_i,   dv_i = [0 I 0] + dt sum_j a_ij dacc_j
// At a vector-space joint's rows dc_j = dv_j, so that dq_i = [I 0 0] + dt sum_j a_ij dc_j there is
//   dq_i = [I, dt c_i I, 0] + dt^2 sum_l (a a)_il dacc_l                  (c_i = sum_j a_ij)
// and at a quaternion joint's (n x n blocks: Jq, Jv integrate's tangent Jacobians at dt theta_i, D dexp^-1's)
//   dq_i = Jq [I 0 0] + dt Jv dtheta_i,  dtheta_i = sum_j a_ij dc_j,  dc_i = D_v dv_i + dt D_theta dtheta_i.
// A stage thus costs products of D_q and D_v, zero between branches of the tree, with earlier dacc_l, and a
// solve by M's L^T D L factor: never the dense M^-1 D. The step's rows: qd' = [0 I 0] + dt sum_l b_l dacc_l;
// q' = [I, dt I, 0] + dt^2 sum_l (b a)_l dacc_l at a vector-space joint, Jq [I 0 0] + dt Jv sum_j b_j dc_j at
// a quaternion joint (at the step's dt theta).
#pragma once

#include "crba.h"
#include "forward_mode.h"
#include "ltdl.h"
#include "products.h"
#include "rnea.h"
#include "step.h"

namespace tg {

// ops.h (its workspace in its own frame)
template <class M, class S, int C>
TG_HD void inverse_dynamics_derivatives(const Placements<M, S>& K, const S* qd, const S* qdd, const S* fext,
                                        const Conv<M, S, C>& cv, S* dtau_dq, S* dtau_dqd);

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

// Jr(w)^-1 y = y + [w] y / 2 + beta [w]^2 y, beta = (1 - (t/2) cot(t/2)) / t^2 (a series near t = 0).
template <class T> TG_HD Vec3<T> right_jacobian_inverse(Vec3<T> w, Vec3<T> y) {
  const T t2 = dot(w, w);
  T beta;
  if (t2 < T(1e-4)) {
    beta = T(1) / T(12) + t2 / T(720) + t2 * t2 / T(30240);
  } else {
    const T half = sqrt(t2) / T(2);
    beta = (T(1) - half * cos(half) / sin(half)) / t2;
  }
  return y + T(0.5) * cross(w, y) + beta * cross(w, cross(w, y));
}

// dexp(theta)^-1 x at one quaternion joint (n = 3: ball; n = 6: free, R^3 x SO(3) in MuJoCo's
// convention, SE(3) in Pinocchio's, where dexp^-1 = [[Jr^-1, -Jr^-1 Q Jr^-1], [0, Jr^-1]]).
template <class T, int C> TG_HD void dexp_inverse_joint(int n, const T* theta, const T* x, T* out) {
  const Vec3<T> w = load3(theta + n - 3), xa = right_jacobian_inverse(w, load3(x + n - 3));
  store3(xa, out + n - 3);
  if (n == 6) {
    if constexpr (C == MJX) {
      store3(load3(x), out);
    } else {
      const Mat3<T> Q = se3_coupling(load3(theta), w, so3_coefficients(w));
      store3(right_jacobian_inverse(w, load3(x) - mul(Q, xa)), out);
    }
  }
}

// c = dexp(theta)^-1 x and its n x n derivatives along theta and x, by forward-mode differentiation of
// the joint's closed form (2n passes over a dozen 3 x 3 products).
template <class S, int C> TG_HD void dexp_inverse_jacobians(int n, const S* theta, const S* x, S* c, S* Dtheta, S* Dx) {
  Dual<S> th[6], xx[6], out[6];
  for (int k = 0; k < 2 * n; ++k) {
    for (int m = 0; m < n; ++m) {
      th[m] = Dual<S>(theta[m], S(k == m));
      xx[m] = Dual<S>(x[m], S(k == n + m));
    }
    dexp_inverse_joint<Dual<S>, C>(n, th, xx, out);
    for (int m = 0; m < n; ++m) (k < n ? Dtheta[n * m + k] : Dx[n * m + k - n]) = out[m].d;
  }
  for (int m = 0; m < n; ++m) c[m] = out[m].v;
}

// Row r of the step's Jacobian [A | B] (2 NV x 3 NV, split at column 2 NV): row = w x + beta row (beta = 0
// overwrites what the output held), and its copy out.
template <int NV, class S> TG_HD void jacobian_row_update(S* A, S* B, int r, S w, const S* x, S beta) {
  S* a = A + 2 * NV * r;
  S* b = B + NV * r;
  for (int c = 0; c < 2 * NV; ++c) a[c] = (beta != S(0) ? beta * a[c] : S(0)) + w * x[c];
  for (int c = 0; c < NV; ++c) b[c] = (beta != S(0) ? beta * b[c] : S(0)) + w * x[2 * NV + c];
}
template <int NV, class S> TG_HD void jacobian_row(const S* A, const S* B, int r, S* out) {
  for (int c = 0; c < 2 * NV; ++c) out[c] = A[2 * NV * r + c];
  for (int c = 0; c < NV; ++c) out[2 * NV + c] = B[NV * r + c];
}

// out (n x COLS) (+)= sum_t w_t g_t X_t for a quaternion joint's n x n blocks g_t (n = 3 or 6).
template <int COLS, bool ADD, class S>
TG_HD void joint_rows(int n, int nt, const S* const* g, const S* w, const S* const* X, S* out) {
  if (n == 6)
    products<6, COLS, COLS, COLS, ADD>(nt, 6, g, 6, w, X, out);
  else
    products<3, COLS, COLS, COLS, ADD>(nt, 3, g, 3, w, X, out);
}

// A stage's dynamics at cs (v, tau in Pinocchio's convention): acc = FD(q, v, tau), D_q and D_v at it and
// the L^T D L factor of M (ltdl.h), all in the convention: M_c = G M G^T, so that
// M_c^-1 G (tau - bias) = G qdd.
template <class M, class S, int C>
TG_HD void rk_stage(const Conv<M, S, C>& cs, const S* v, const S* tau, const S* fext, S* Dq, S* Dv, S* H, S* acc) {
  constexpr int NV = M::NV;
  const Placements<M, S> K(cs.q);
  S zero[NV], buf[Conv<M, S, C>::active ? NV : 1];
  crba<M, S>(K, H);
  cs.congruence_out(H);
  ltdl_factor<M, S>(H);
  for (int k = 0; k < NV; ++k) zero[k] = S(0);
  rnea<M, S>(K, v, zero, fext, acc);
  for (int k = 0; k < NV; ++k) acc[k] = tau[k] - acc[k];
  cs.force_out(acc);
  ltdl_solve<M, S>(H, acc);
  const S* qdd = cs.velocity(acc, buf);  // G^T
  inverse_dynamics_derivatives<M, S>(K, v, qdd, fext, cs, Dq, Dv);
  if (qdd != acc)
    for (int k = 0; k < NV; ++k) acc[k] = qdd[k];
  cs.acceleration_out(v, acc);
}

// The step and its Jacobians. cv at q, qd and tau in Pinocchio's convention (as the binding passes them).
// Outputs: q_next (NQ), qd_next (NV), A (2 NV x 2 NV), B (2 NV x NV), in the convention; work: 8 NV x 3 NV,
// dacc_0..3, then dc_0..2 (a quaternion joint's rows), then D_q, D_v and M's factor.
template <class M, class S, int C>
TG_HD void rk_step(const Conv<M, S, C>& cv, const S* qd, const S* tau, const S* fext, S h, int scheme, S* q_next,
                   S* qd_next, S* A, S* B, S* work) {
  constexpr int NV = M::NV, N3 = 3 * NV, D = NV * N3, NN = NV * NV;
  const auto& d = data<M, S>();
  const RkTableau T = rk_tableau(scheme);
  const int s = T.stages;
  S* const dacc[4] = {work, work + D, work + 2 * D, work + 3 * D};
  S* const dc[3] = {work + 4 * D, work + 5 * D, work + 6 * D};
  S* const Dq = work + 7 * D;
  S* const Dv = Dq + NN;
  S* const H = Dv + NN;
  S v0[NV], tau_c[NV], acc[4][NV], car[4][NV], v[NV], u[NV], qs[M::NQ], blk[6 * N3];
  for (int k = 0; k < NV; ++k) v0[k] = qd[k], tau_c[k] = tau[k];
  cv.velocity_out(v0);
  cv.force_out(tau_c);
  // q' rows: [I, dt I, 0] at vector-space joints, zero at quaternion joints (where sum_j b_j dc_j builds up);
  // qd' rows: [0 I 0]
  for (int r = 0; r < 2 * NV; ++r) {
    for (int c = 0; c < 2 * NV; ++c) A[2 * NV * r + c] = S(0);
    for (int c = 0; c < NV; ++c) B[NV * r + c] = S(0);
  }
  for (int jn = 0; jn < M::NB; ++jn) {
    const int t = d.jtype[jn];
    if (t == FREE || t == BALL) continue;
    for (int a = 0; a < d.nvj[jn]; ++a) {
      const int r = d.vi[jn] + a;
      A[2 * NV * r + r] = S(1);
      A[2 * NV * r + NV + r] = h;
    }
  }
  for (int r = 0; r < NV; ++r) A[2 * NV * (NV + r) + NV + r] = S(1);
  for (int i = 0; i < s; ++i) {
    const double* ai = T.a[i];
    // theta_i, v_i; then q_i, c_i and, at quaternion joints, dc_i = D_v dv_i + dt D_theta dtheta_i, onto the
    // rows of q' (weight b_i) and kept for the later stages
    double ci = 0, aa[4] = {0, 0, 0, 0}, ba = 0;  // sum_j a_ij, (a a)_il, (b a)_i
    for (int j = 0; j < i; ++j) {
      ci += ai[j];
      for (int l = 0; l < j; ++l) aa[l] += ai[j] * T.a[j][l];
    }
    for (int m = i + 1; m < s; ++m) ba += T.b[m] * T.a[m][i];
    for (int k = 0; k < NV; ++k) {
      S th = S(0), ac = S(0);
      for (int j = 0; j < i; ++j) th += S(ai[j]) * car[j][k], ac += S(ai[j]) * acc[j][k];
      u[k] = h * th;
      v[k] = v0[k] + h * ac;
    }
    for (int jn = 0; jn < M::NB; ++jn) {
      S Jq[36], Jv[36], Dth[36], Dx[36];
      const int n = integrate_joint<M, S, C>(jn, cv.q, u, qs, Jq, Jv), vi = d.vi[jn];
      if (!n) {
        for (int a = 0; a < d.nvj[jn]; ++a) car[i][vi + a] = v[vi + a];
        continue;
      }
      dexp_inverse_jacobians<S, C>(n, u + vi, v + vi, car[i] + vi, Dth, Dx);
      const S* g[4];
      const S* X[4];
      S w[4];
      int nt = 0;
      for (int j = 0; j < i; ++j)
        if (ai[j] != 0) {
          g[nt] = Dx, w[nt] = h * S(ai[j]), X[nt++] = dacc[j] + N3 * vi;
          g[nt] = Dth, w[nt] = h * S(ai[j]), X[nt++] = dc[j] + N3 * vi;
        }
      joint_rows<N3, false>(n, nt, g, w, X, blk);
      for (int a = 0; a < n; ++a) {
        for (int b = 0; b < n; ++b) blk[N3 * a + NV + vi + b] += Dx[n * a + b];
        if (i < s - 1)
          for (int c = 0; c < N3; ++c) dc[i][N3 * (vi + a) + c] = blk[N3 * a + c];
        if (T.b[i] != 0) jacobian_row_update<NV>(A, B, vi + a, S(T.b[i]), blk + N3 * a, S(1));
      }
    }
    // the stage's dynamics
    if (i == 0) {
      rk_stage<M, S, C>(cv, qd, tau, fext, Dq, Dv, H, acc[0]);
    } else {
      const Conv<M, S, C> cs(qs);
      S vb[Conv<M, S, C>::active ? NV : 1], tb[Conv<M, S, C>::active ? NV : 1];
      rk_stage<M, S, C>(cs, cs.velocity(v, vb), cs.force(tau_c, tb), fext, Dq, Dv, H, acc[i]);
    }
    // R = [0 0 I] - D_q dq_i - D_v dv_i into dacc_i: the identity blocks, each quaternion joint's columns of
    // D_q times its rows of dq_i (then zeroed), the products with the earlier dacc_l; dacc_i = M^-1 R
    S* const R = dacc[i];
    for (int r = 0; r < NV; ++r)
      for (int c = 0; c < NV; ++c) {
        R[N3 * r + c] = -Dq[NV * r + c];
        R[N3 * r + NV + c] = -(h * S(ci) * Dq[NV * r + c] + Dv[NV * r + c]);
        R[N3 * r + 2 * NV + c] = S(r == c);
      }
    for (int jn = 0; jn < M::NB; ++jn) {
      S Jq[36], Jv[36], P[NV * 6];  // P = D_q's columns of the joint times Jv
      const int n = integrate_joint<M, S, C>(jn, cv.q, u, qs, Jq, Jv), vi = d.vi[jn];
      if (!n) continue;
      for (int r = 0; r < NV; ++r) {
        S* dq = Dq + NV * r + vi;
        for (int b = 0; b < n; ++b) {
          S pq = S(0), pv = S(0);
          for (int a = 0; a < n; ++a) pq += dq[a] * Jq[n * a + b], pv += dq[a] * Jv[n * a + b];
          R[N3 * r + vi + b] += dq[b] - pq;  // in place of the identity blocks' D_q terms
          R[N3 * r + NV + vi + b] += h * S(ci) * dq[b];
          P[n * r + b] = pv;
        }
        for (int b = 0; b < n; ++b) dq[b] = S(0);
      }
      // - dt sum_j a_ij P dc_j at the joint's rows
      const S* g[4];
      const S* X[4];
      S w[4];
      int nt = 0;
      for (int j = 0; j < i; ++j)
        if (ai[j] != 0) g[nt] = P, w[nt] = -h * S(ai[j]), X[nt++] = dc[j] + N3 * vi;
      if (nt) products<NV, N3, N3, N3, true>(nt, n, g, n, w, X, R);
    }
    {
      const S* g[4];
      const S* X[4];
      S w[4];
      int nt = 0;
      for (int l = 0; l < i; ++l) {
        if (aa[l] != 0) g[nt] = Dq, w[nt] = -h * h * S(aa[l]), X[nt++] = dacc[l];
        if (ai[l] != 0) g[nt] = Dv, w[nt] = -h * S(ai[l]), X[nt++] = dacc[l];
      }
      if (nt) tree_products<M, N3, N3, N3, true>(nt, g, w, X, R);
    }
    ltdl_solve_rows<M, N3>(H, R);
    // onto the rows of qd' (dt b_i) and of q' at vector-space joints (dt^2 (b a)_i)
    const S wv = h * S(T.b[i]), wq = h * h * S(ba);
    if (wv != S(0))
      for (int r = 0; r < NV; ++r) jacobian_row_update<NV>(A, B, NV + r, wv, R + N3 * r, S(1));
    if (wq != S(0))
      for (int jn = 0; jn < M::NB; ++jn) {
        const int t = d.jtype[jn];
        if (t == FREE || t == BALL) continue;
        for (int a = 0; a < d.nvj[jn]; ++a) jacobian_row_update<NV>(A, B, d.vi[jn] + a, wq, R + N3 * (d.vi[jn] + a), S(1));
      }
  }
  // q' = q (+) dt theta, theta = sum_j b_j c_j, its rows Jq [I 0 0] + dt Jv dtheta at quaternion joints (dtheta
  // what their rows hold); qd' = qd + dt sum_j b_j acc_j
  for (int k = 0; k < NV; ++k) {
    S th = S(0), ac = S(0);
    for (int j = 0; j < s; ++j) th += S(T.b[j]) * car[j][k], ac += S(T.b[j]) * acc[j][k];
    u[k] = h * th;
    qd_next[k] = v0[k] + h * ac;
  }
  for (int jn = 0; jn < M::NB; ++jn) {
    S Jq[36], Jv[36];
    const int n = integrate_joint<M, S, C>(jn, cv.q, u, q_next, Jq, Jv), vi = d.vi[jn];
    if (!n) continue;
    for (int a = 0; a < n; ++a) jacobian_row<NV>(A, B, vi + a, blk + N3 * a);
    for (int a = 0; a < n; ++a) {
      jacobian_row_update<NV>(A, B, vi + a, h * Jv[n * a], blk, S(0));
      for (int b = 1; b < n; ++b) jacobian_row_update<NV>(A, B, vi + a, h * Jv[n * a + b], blk + N3 * b, S(1));
      for (int b = 0; b < n; ++b) A[2 * NV * (vi + a) + vi + b] += Jq[n * a + b];
    }
  }
}

}  // namespace tg
