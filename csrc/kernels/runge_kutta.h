// The explicit Runge-Kutta steps in Munthe-Kaas's form (MuJoCo's mj_RungeKutta; torch_grid/integrators.py
// holds the same in torch) and their tangent Jacobians, with each stage's forward-dynamics derivatives.
// Stage i (tableau a, weights b; every vector in the call's convention):
//   theta_i = sum_j a_ij c_j,  q_i = q (+) dt theta_i,  v_i = qd + dt sum_j a_ij acc_j,  acc_i = FD(q_i, v_i, tau)
//   c_i = dexp(dt theta_i)^-1 v_i   (the stage velocity carried to q's chart; c_0 = qd)
// and the step q' = q (+) dt sum_j b_j c_j, qd' = qd + dt sum_j b_j acc_j. Along z = [dq; dqd; dtau]
// (each derivative an NV x 3 NV row-major matrix):
//   dv_i = [0 I 0] + dt sum_j a_ij dacc_j,   dtheta_i = sum_j a_ij dc_j
//   dq_i = Jq [I 0 0] + dt Jv dtheta_i                  (Jq, Jv: integrate's tangent Jacobians at dt theta_i)
//   dacc_i = G_q dq_i + G_v dv_i + [0 0 G_tau]          (G: forward_dynamics_gradient at stage i)
//   dc_i = D_v dv_i + D_theta dt dtheta_i               (D: dexp^-1's derivatives, at quaternion joints)
// The stages' dc_j and dacc_j live in the op's workspace; the sums over b_j build up in A and B's rows.
#pragma once

#include "forward_mode.h"
#include "products.h"
#include "step.h"

namespace tg {

// ops.h (its workspace beside minv's)
template <class M, class S, int C>
TG_HD void forward_dynamics_gradient(const Placements<M, S>& K, const S* qd, const S* tau, const S* fext,
                                     const Conv<M, S, C>& cv, S* dq, S* dqd, S* dtau, S* qdd);

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

// out = Jq [I 0 0] + h Jv X at a joint's rows (n x n blocks at a quaternion joint, n = 0: the identity),
// X's rows vi.. (stride N3), out's rows from 0.
template <int N3, class S> TG_HD void advance_rows(int n, int rows, int vi, const S* Jq, const S* Jv, S h, const S* X, S* out) {
  for (int a = 0; a < rows; ++a) {
    S* o = out + N3 * a;
    if (!n) {
      for (int c = 0; c < N3; ++c) o[c] = h * X[N3 * (vi + a) + c];
      o[vi + a] += S(1);
      continue;
    }
    for (int c = 0; c < N3; ++c) o[c] = S(0);
    for (int b = 0; b < n; ++b) {
      const S w = h * Jv[n * a + b];
      const S* x = X + N3 * (vi + b);
      for (int c = 0; c < N3; ++c) o[c] += w * x[c];
      o[vi + b] += Jq[n * a + b];
    }
  }
}

// out = w sum_j a_j X_j over the j < n with a_j != 0 (zero if none), D entries each.
template <int D, class S> TG_HD void combine(int n, const double* a, S w, S* const* X, S* out) {
  bool first = true;
  for (int j = 0; j < n; ++j) {
    if (a[j] == 0) continue;
    const S c = w * S(a[j]);
    const S* x = X[j];
    if (first)
      for (int e = 0; e < D; ++e) out[e] = c * x[e];
    else
      for (int e = 0; e < D; ++e) out[e] += c * x[e];
    first = false;
  }
  if (first)
    for (int e = 0; e < D; ++e) out[e] = S(0);
}

// acc = FD(q, v, tau) at a stage (cs at its configuration; v, tau in Pinocchio's convention) and its
// derivatives G = [G_q, G_v, G_tau] (NV x NV each), both in the convention.
template <class M, class S, int C>
TG_HD void rk_stage(const Conv<M, S, C>& cs, const S* v, const S* tau, const S* fext, S* G, S* acc) {
  constexpr int NN = M::NV * M::NV;
  forward_dynamics_gradient<M, S>(Placements<M, S>(cs.q), v, tau, fext, cs, G, G + NN, G + 2 * NN, acc);
  cs.acceleration_out(v, acc);
}

// A stage's per-joint part, with u = dt theta_i, v = v_i and the derivatives dv = dv_i, dq = dtheta_i
// (NV x 3 NV): q_i = q (+) u into qs (the convention's layout), the carried velocity c_i = dexp(u)^-1 v
// into c with its rows dc_i = D_v dv + D_theta dt dtheta (dv off quaternion joints) into dc (when kept)
// and w times onto the rows of q' in [A | B], then dq_i = Jq [I 0 0] + dt Jv dtheta in place of dtheta.
template <class M, class S, int C>
TG_HD void stage_rows(const S* q, const S* u, const S* v, S h, const S* dv, S* dq, S* dc, S w, S* A, S* B, S* qs, S* c) {
  constexpr int NV = M::NV, N3 = 3 * NV;
  const auto& d = data<M, S>();
  S blk[6 * N3];
  for (int jn = 0; jn < M::NB; ++jn) {
    S Jq[36], Jv[36], Dth[36], Dx[36];
    const int n = integrate_joint<M, S, C>(jn, q, u, qs, Jq, Jv), vi = d.vi[jn];
    if (!n) {  // vector-space joint: c_i = v_i, dc_i = dv_i, dq_i = [I 0 0] + dt dtheta_i
      for (int a = 0; a < d.nvj[jn]; ++a) {
        const S* x = dv + N3 * (vi + a);
        S* o = dq + N3 * (vi + a);
        c[vi + a] = v[vi + a];
        if (dc)
          for (int col = 0; col < N3; ++col) dc[N3 * (vi + a) + col] = x[col];
        if (w != S(0)) jacobian_row_update<NV>(A, B, vi + a, w, x, S(1));
        for (int col = 0; col < N3; ++col) o[col] *= h;
        o[vi + a] += S(1);
      }
      continue;
    }
    dexp_inverse_jacobians<S, C>(n, u + vi, v + vi, c + vi, Dth, Dx);
    for (int a = 0; a < n; ++a) {
      S* o = blk + N3 * a;
      for (int col = 0; col < N3; ++col) o[col] = S(0);
      for (int b = 0; b < n; ++b) {
        const S x = Dx[n * a + b], y = h * Dth[n * a + b];
        const S *dvb = dv + N3 * (vi + b), *dtb = dq + N3 * (vi + b);
        for (int col = 0; col < N3; ++col) o[col] += x * dvb[col] + y * dtb[col];
      }
    }
    for (int a = 0; a < n; ++a) {
      if (dc)
        for (int col = 0; col < N3; ++col) dc[N3 * (vi + a) + col] = blk[N3 * a + col];
      if (w != S(0)) jacobian_row_update<NV>(A, B, vi + a, w, blk + N3 * a, S(1));
    }
    advance_rows<N3>(n, n, vi, Jq, Jv, h, dq, blk);
    for (int a = 0; a < n; ++a)
      for (int col = 0; col < N3; ++col) dq[N3 * (vi + a) + col] = blk[N3 * a + col];
  }
}

// The step and its Jacobians. cv at q, qd and tau in Pinocchio's convention (as the binding passes them).
// Outputs: q_next (NQ), qd_next (NV), A (2 NV x 2 NV), B (2 NV x NV), in the convention; work: 8 NV x 3 NV.
template <class M, class S, int C>
TG_HD void rk_step(const Conv<M, S, C>& cv, const S* qd, const S* tau, const S* fext, S h, int scheme, S* q_next,
                   S* qd_next, S* A, S* B, S* work) {
  constexpr int NV = M::NV, N3 = 3 * NV, D = NV * N3, NN = NV * NV;
  const auto& d = data<M, S>();
  const RkTableau T = rk_tableau(scheme);
  const int s = T.stages;
  S* const dc[3] = {work, work + D, work + 2 * D};
  S* const dacc[3] = {work + 3 * D, work + 4 * D, work + 5 * D};
  S* const dq = work + 6 * D;  // a stage's dtheta, then its dq
  S* const G = work + 7 * D;
  S v0[NV], tau_c[NV], acc[4][NV], car[4][NV], v[NV], u[NV], qs[M::NQ], row[N3], blk[6 * N3];
  for (int k = 0; k < NV; ++k) v0[k] = qd[k], tau_c[k] = tau[k];
  cv.velocity_out(v0);
  cv.force_out(tau_c);
  for (int k = 0; k < NV; ++k) car[0][k] = v0[k], row[k] = S(0), row[NV + k] = S(0), row[2 * NV + k] = S(0);
  for (int r = 0; r < 2 * NV; ++r) jacobian_row_update<NV>(A, B, r, S(0), row, S(0));
  for (int i = 0; i < s; ++i) {
    const double* ai = T.a[i];
    const S bi = S(T.b[i]);
    if (i == 0) {
      rk_stage<M, S, C>(cv, qd, tau, fext, G, acc[0]);
    } else {
      // theta_i, v_i; dtheta_i into dq, dv_i into G (free until the stage's derivatives); then q_i, c_i, dc_i, dq_i
      for (int k = 0; k < NV; ++k) {
        S th = S(0), ac = S(0);
        for (int j = 0; j < i; ++j) th += S(ai[j]) * car[j][k], ac += S(ai[j]) * acc[j][k];
        u[k] = h * th;
        v[k] = v0[k] + h * ac;
      }
      combine<D>(i, ai, S(1), dc, dq);
      combine<D>(i, ai, h, dacc, G);
      for (int r = 0; r < NV; ++r) G[N3 * r + NV + r] += S(1);
      stage_rows<M, S, C>(cv.q, u, v, h, G, dq, i < s - 1 ? dc[i] : nullptr, bi, A, B, qs, car[i]);
      const Conv<M, S, C> cs(qs);
      S vb[Conv<M, S, C>::active ? NV : 1], tb[Conv<M, S, C>::active ? NV : 1];
      rk_stage<M, S, C>(cs, cs.velocity(v, vb), cs.force(tau_c, tb), fext, G, acc[i]);
    }
    // dacc_i = G_q dq_i + G_v dv_i + [0 0 G_tau], with dq_0 = [I 0 0] and dv_0 = [0 I 0]; the last stage's
    // into dc_0, no longer read
    S* const da = i < s - 1 ? dacc[i] : dc[0];
    for (int r = 0; r < NV; ++r)
      for (int c = 0; c < NV; ++c) {
        da[N3 * r + c] = i ? S(0) : G[NV * r + c];
        da[N3 * r + NV + c] = G[NN + NV * r + c];
        da[N3 * r + 2 * NV + c] = G[2 * NN + NV * r + c];
      }
    if (i) {  // the products with dq_i and with dv_i's sum over the earlier stages, in one pass over da
      const S* g[4] = {G};
      const S* X[4] = {dq};
      S w[4] = {S(1)};
      int nt = 1;
      for (int j = 0; j < i; ++j)
        if (ai[j] != 0) g[nt] = G + NN, w[nt] = h * S(ai[j]), X[nt++] = dacc[j];
      products<NV, N3, N3, N3, true>(nt, NV, g, NV, w, X, da);
    }
    if (bi != S(0))
      for (int r = 0; r < NV; ++r) jacobian_row_update<NV>(A, B, NV + r, bi, da + N3 * r, S(1));
    if (i == 0) {  // c_0 = qd: dc_0 = [0 I 0]
      for (int e = 0; e < D; ++e) dc[0][e] = S(0);
      for (int r = 0; r < NV; ++r) dc[0][N3 * r + NV + r] = S(1);
      if (bi != S(0))
        for (int r = 0; r < NV; ++r) A[2 * NV * r + NV + r] += bi;
    }
  }
  // q' = q (+) dt theta, theta = sum_j b_j c_j, whose derivative the rows of q' hold; qd' = qd + dt sum_j b_j acc_j
  for (int k = 0; k < NV; ++k) {
    S th = S(0), ac = S(0);
    for (int j = 0; j < s; ++j) th += S(T.b[j]) * car[j][k], ac += S(T.b[j]) * acc[j][k];
    u[k] = h * th;
    qd_next[k] = v0[k] + h * ac;
  }
  for (int e = 0; e < N3; ++e) row[e] = S(0);
  for (int r = 0; r < NV; ++r) {
    jacobian_row_update<NV>(A, B, NV + r, S(0), row, h);
    A[2 * NV * (NV + r) + NV + r] += S(1);
  }
  for (int jn = 0; jn < M::NB; ++jn) {
    S Jq[36], Jv[36];
    const int n = integrate_joint<M, S, C>(jn, cv.q, u, q_next, Jq, Jv), vi = d.vi[jn], rows = n ? n : d.nvj[jn];
    for (int a = 0; a < rows; ++a) jacobian_row<NV>(A, B, vi + a, dq + N3 * (vi + a));
    advance_rows<N3>(n, rows, vi, Jq, Jv, h, dq, blk);
    for (int a = 0; a < rows; ++a) jacobian_row_update<NV>(A, B, vi + a, S(1), blk + N3 * a, S(0));
  }
}

}  // namespace tg
