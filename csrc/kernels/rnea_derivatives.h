// Analytic derivatives of inverse dynamics, d tau / dq and d tau / dqd (Carpentier & Mansard,
// RSS 2018; as Pinocchio's computeRNEADerivatives), in the world frame.
//
// q moves along its tangent: a free root by the local increment q (+) dq, as Pinocchio. Moving
// joint j's coordinate along its world axis s carries its whole subtree by the twist s: every
// world quantity X of the subtree changes by s x X, except that the parent's velocity and
// acceleration do not move with it. That leaves, per column of joint j with parent p:
//   w = v_p x s,   u = a_p x s + v_p x w          (d/dq)     alpha = (v_p + v_j) x s   (d/dqd)
// and, with Yc the composite inertia, F the composite force and B = sum (dI + [. x* h]) over a
// subtree (dI = v x* I - I v x, the inertia's rate, h = I v):
//   rows m above j:          d tau_m / dq_j  = S_m^T (Yc_j u + B_j w + s x* F_j)
//   rows m in j's subtree:   d tau_m / dq_j  = u . (Yc_m S_m) + w . (B_m^T S_m)
//   and for qd:              alpha replaces u, s replaces w, and no s x* F term.
// Pinocchio's Coriolis matrix has the same pairs with dS/dt = v x S in place of alpha, S / 2 for s.
#pragma once

#include "joints.h"

namespace tg {

// What the Coriolis matrix and M's base columns read: world axes and velocities, and the subtree
// sums Yc and B.
template <class M, class S> struct VelocityWork {
  const SE3<S>* oMi;      // the Placements pass
  Sv<S> v[M::NB];         // world velocity
  Inertia<S> Yc[M::NB];   // subtree inertia, world frame
  M6<S> B[M::NB];         // subtree sum of dI + [. x* h]
  Sv<S> s[M::NV];         // per column: its world axis
};

// Everything the derivatives read: the above, the subtree forces and the per-column terms.
template <class M, class S> struct RneaDerivativesWork : VelocityWork<M, S> {
  Sv<S> F[M::NB];                                   // subtree force
  Sv<S> w[M::NV], u[M::NV], alpha[M::NV];           // per column, see above
};

// The 6x6 matrix of x -> dI x + x x* h with dI = v x* I - I v x and h = I v: the rate of change of
// the momentum I v of a body when its velocity v changes by x while it moves with velocity v.
template <class S> TG_HD M6<S> momentum_rate_matrix(const Inertia<S>& I, const Sv<S>& v) {
  M6<S> B = inertia_rate_matrix(I, v);
  // x x* h = [-h_lin x x_ang; -h_lin x x_lin - h_ang x x_ang]
  const Sv<S> h = mul(I, v);
  const Mat3<S> Hl = skew(lin(h)), Ha = skew(ang(h));
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      B.m[6 * r + 3 + c] -= Hl.m[3 * r + c];
      B.m[6 * (3 + r) + c] -= Hl.m[3 * r + c];
      B.m[6 * (3 + r) + 3 + c] -= Ha.m[3 * r + c];
    }
  return B;
}

// Body i's velocity terms: its world axes and velocity, and its own world inertia and B (summed
// over subtrees by velocity_sums).
template <class M, class S> TG_HD void velocity_step(int i, const S* qd, VelocityWork<M, S>& W) {
  const auto& d = data<M, S>();
  const int p = d.parent[i], vi = d.vi[i];
  W.v[i] = p < 0 ? sv_zero<S>() : W.v[p];
  for (int k = 0; k < d.nvj[i]; ++k) {
    W.s[vi + k] = act_motion(W.oMi[i], joint_axis<M, S>(i, k));
    W.v[i] = W.v[i] + qd[vi + k] * W.s[vi + k];
  }
  W.Yc[i] = act(W.oMi[i], body_inertia<M, S>(i));
  W.B[i] = momentum_rate_matrix(W.Yc[i], W.v[i]);
}

template <class M, class S> TG_HD void velocity_sums(VelocityWork<M, S>& W) {
  const auto& d = data<M, S>();
  for (int i = M::NB - 1; i > 0; --i) {
    const int p = d.parent[i];
    if (p < 0) continue;
    W.Yc[p] = W.Yc[p] + W.Yc[i];
    for (int k = 0; k < 36; ++k) W.B[p].m[k] += W.B[i].m[k];
  }
}

template <class M, class S> TG_HD void velocity_setup(const Placements<M, S>& K, const S* qd, VelocityWork<M, S>& W) {
  W.oMi = K.oMi;
  for (int i = 0; i < M::NB; ++i) velocity_step<M, S>(i, qd, W);
  velocity_sums<M, S>(W);
}

// Forward pass (world placements, axes, velocities, accelerations, body forces and the per-column
// terms), then the subtree sums Yc, B, F.
template <class M, class S>
TG_HD void rnea_derivatives_setup(const Placements<M, S>& K, const S* qd, const S* qdd, const S* fext,
                                  RneaDerivativesWork<M, S>& W) {
  const auto& d = data<M, S>();
  using L = Levels<M>;
  Sv<S> a[L::N];  // world accelerations (gravity included), only for the children
  W.oMi = K.oMi;
  for (int i = 0; i < M::NB; ++i) {
    velocity_step<M, S>(i, qd, W);
    const int p = d.parent[i], n = d.nvj[i], vi = d.vi[i];
    const Sv<S> vp = p < 0 ? sv_zero<S>() : W.v[p];
    const Sv<S> ap = p < 0 ? base_acceleration<M, S>() : a[L::parent(d, i)];
    Sv<S>& ai = a[L::of(d, i)];
    ai = ap;
    for (int k = 0; k < n; ++k) ai = ai + qdd[vi + k] * W.s[vi + k] + qd[vi + k] * cross_motion(W.v[i], W.s[vi + k]);
    for (int k = 0; k < n; ++k) {
      const Sv<S>& s = W.s[vi + k];
      W.w[vi + k] = cross_motion(vp, s);
      W.u[vi + k] = cross_motion(ap, s) + cross_motion(vp, W.w[vi + k]);
      W.alpha[vi + k] = cross_motion(vp + W.v[i], s);
    }
    W.F[i] = mul(W.Yc[i], ai) + cross_force(W.v[i], mul(W.Yc[i], W.v[i]));
    if (fext) {
      const Sv<S> fe = {{fext[6 * i], fext[6 * i + 1], fext[6 * i + 2], fext[6 * i + 3], fext[6 * i + 4], fext[6 * i + 5]}};
      W.F[i] = W.F[i] - act_force(W.oMi[i], fe);
    }
  }
  velocity_sums<M, S>(W);
  for (int i = M::NB - 1; i > 0; --i)
    if (d.parent[i] >= 0) W.F[d.parent[i]] = W.F[d.parent[i]] + W.F[i];
}

// The NV x NV matrix (row-major) with, for every joint j and each joint m on its support chain
// (j included), per-column motions X, Y:
//   row m, column j:  S_m^T (Yc_m X_j + B_m Y_j)                        (m below or at j)
//   row m, column j:  S_m^T (Yc_j X_j + B_j Y_j [+ s_j x* F_j])          (m strictly above j)
// Entries of unrelated branches are zero. HalfY takes Y / 2 for Y (exactly, without its storage).
template <bool ForceTerm, bool HalfY, class M, class S, class Work>
TG_HD void ancestor_pairs(const Work& W, const Sv<S>* X, const Sv<S>* Y, S* out) {
  const auto& d = data<M, S>();
  constexpr int NV = M::NV;
  for (int k = 0; k < NV * NV; ++k) out[k] = S(0);
  for (int i = 0; i < M::NB; ++i) {
    // Rows of joint i, columns of its ancestors and itself.
    for (int l = 0; l < d.nvj[i]; ++l) {
      const int row = d.vi[i] + l;
      const Sv<S> P = mul(W.Yc[i], W.s[d.vi[i] + l]);
      Sv<S> Q = mul_transpose(W.B[i], W.s[d.vi[i] + l]);
      if constexpr (HalfY) Q = S(0.5) * Q;
      for (int j = i; j >= 0; j = d.parent[j])
        for (int c = 0; c < d.nvj[j]; ++c) {
          const int col = d.vi[j] + c;
          out[NV * row + col] = dot(X[col], P) + dot(Y[col], Q);
        }
    }
    // Columns of joint i, rows of its strict ancestors.
    for (int c = 0; c < d.nvj[i]; ++c) {
      const int col = d.vi[i] + c;
      Sv<S> BY = mul(W.B[i], Y[col]);
      if constexpr (HalfY) BY = S(0.5) * BY;
      Sv<S> dF = mul(W.Yc[i], X[col]) + BY;
      if constexpr (ForceTerm) dF = dF + cross_force(W.s[col], W.F[i]);
      for (int m = d.parent[i]; m >= 0; m = d.parent[m])
        for (int l = 0; l < d.nvj[m]; ++l) out[NV * (d.vi[m] + l) + col] = dot(W.s[d.vi[m] + l], dF);
    }
  }
}

// tau (NV), dtau_dq and dtau_dqd (NV x NV, row-major) at the (q, qd, qdd, fext) W was set up at.
template <class M, class S>
TG_HD void rnea_derivatives(const RneaDerivativesWork<M, S>& W, S* tau, S* dtau_dq, S* dtau_dqd) {
  const auto& d = data<M, S>();
  for (int i = 0; i < M::NB; ++i)
    for (int l = 0; l < d.nvj[i]; ++l) tau[d.vi[i] + l] = dot(W.s[d.vi[i] + l], W.F[i]);
  ancestor_pairs<true, false, M, S>(W, W.u, W.w, dtau_dq);
  ancestor_pairs<false, false, M, S>(W, W.alpha, W.s, dtau_dqd);
}

// lambda^T d tau / dq and lambda^T d tau / dqd (NV each) without forming the matrices, in O(n):
// over the pairs above, with P_j, Q_j the subtree sums of lambda_m Yc_m S_m and lambda_m B_m^T S_m
// and L_j the sum of lambda_m S_m over j's strict ancestors,
//   (lambda^T d tau/dq)_j = u_j . P_j + w_j . Q_j + L_j . (Yc_j u_j + B_j w_j + s_j x* F_j)
// and alike for qd with alpha and s. tau is written too, and M lambda where Mlam is not null:
//   (M lambda)_j = S_j . (Yc_j L_j + P_j)   (the columns above j's body, then those at or below it).
template <class M, class S>
TG_HD void rnea_vjp(const RneaDerivativesWork<M, S>& W, const S* lambda, S* tau, S* g_q, S* g_qd, S* Mlam = nullptr) {
  const auto& d = data<M, S>();
  using Lv = Levels<M>;
  Sv<S> P[M::NB], Q[M::NB], L[Lv::N];  // L per tree level: only a body's ancestors' are needed
  for (int i = 0; i < M::NB; ++i) {
    P[i] = Q[i] = sv_zero<S>();
    for (int l = 0; l < d.nvj[i]; ++l) {
      const S lam = lambda[d.vi[i] + l];
      tau[d.vi[i] + l] = dot(W.s[d.vi[i] + l], W.F[i]);
      P[i] = P[i] + lam * mul(W.Yc[i], W.s[d.vi[i] + l]);
      Q[i] = Q[i] + lam * mul_transpose(W.B[i], W.s[d.vi[i] + l]);
    }
  }
  for (int i = M::NB - 1; i >= 0; --i)
    if (d.parent[i] >= 0) {
      P[d.parent[i]] = P[d.parent[i]] + P[i];
      Q[d.parent[i]] = Q[d.parent[i]] + Q[i];
    }
  for (int i = 0; i < M::NB; ++i) {
    const int p = d.parent[i];
    Sv<S>& Li = L[Lv::of(d, i)];
    if (p >= 0) {
      Li = L[Lv::parent(d, i)];
      for (int l = 0; l < d.nvj[p]; ++l) Li = Li + lambda[d.vi[p] + l] * W.s[d.vi[p] + l];
    } else {
      Li = sv_zero<S>();
    }
    const Sv<S> ML = Mlam ? mul(W.Yc[i], Li) + P[i] : sv_zero<S>();
    for (int c = 0; c < d.nvj[i]; ++c) {
      const int col = d.vi[i] + c;
      const Sv<S>& s = W.s[col];
      if (Mlam) Mlam[col] = dot(s, ML);
      const Sv<S> dFq = mul(W.Yc[i], W.u[col]) + mul(W.B[i], W.w[col]) + cross_force(s, W.F[i]);
      const Sv<S> dFv = mul(W.Yc[i], W.alpha[col]) + mul(W.B[i], s);
      g_q[col] = dot(W.u[col], P[i]) + dot(W.w[col], Q[i]) + dot(Li, dFq);
      g_qd[col] = dot(W.alpha[col], P[i]) + dot(s, Q[i]) + dot(Li, dFv);
    }
  }
}

// The gradient along the tangent of lam^T M(q) a (NV), in O(n): rnea_vjp's terms at qd = 0 without
// gravity, where tau = M a and w, alpha and B vanish: g_j = u_j . P_j + L_j . (Yc_j u_j + s_j x* F_j),
// u_j = a_p x s_j, with a the accelerations and F the subtree forces of qdd = a alone.
template <class M, class S>
TG_HD void mass_product_vjp(const Placements<M, S>& K, const S* acc, const S* lambda, S* g_q) {
  const auto& d = data<M, S>();
  using Lv = Levels<M>;
  Sv<S> s[M::NV], F[M::NB], P[M::NB], a[Lv::N], L[Lv::N];
  Inertia<S> Yc[M::NB];
  for (int i = 0; i < M::NB; ++i) {
    const int p = d.parent[i], vi = d.vi[i];
    Sv<S>& ai = a[Lv::of(d, i)];
    ai = p < 0 ? sv_zero<S>() : a[Lv::parent(d, i)];
    for (int k = 0; k < d.nvj[i]; ++k) {
      s[vi + k] = act_motion(K.oMi[i], joint_axis<M, S>(i, k));
      ai = ai + acc[vi + k] * s[vi + k];
    }
    Yc[i] = act(K.oMi[i], body_inertia<M, S>(i));
    F[i] = mul(Yc[i], ai);
  }
  for (int i = M::NB - 1; i > 0; --i)
    if (d.parent[i] >= 0) {
      Yc[d.parent[i]] = Yc[d.parent[i]] + Yc[i];
      F[d.parent[i]] = F[d.parent[i]] + F[i];
    }
  for (int i = 0; i < M::NB; ++i) {
    P[i] = sv_zero<S>();
    for (int l = 0; l < d.nvj[i]; ++l) P[i] = P[i] + lambda[d.vi[i] + l] * mul(Yc[i], s[d.vi[i] + l]);
  }
  for (int i = M::NB - 1; i >= 0; --i)
    if (d.parent[i] >= 0) P[d.parent[i]] = P[d.parent[i]] + P[i];
  // down the tree: L_i over the strict ancestors' columns, u_j from the parent's acceleration
  for (int i = 0; i < M::NB; ++i) {
    const int p = d.parent[i];
    Sv<S>& Li = L[Lv::of(d, i)];
    Li = sv_zero<S>();
    if (p >= 0) {
      Li = L[Lv::parent(d, i)];
      for (int l = 0; l < d.nvj[p]; ++l) Li = Li + lambda[d.vi[p] + l] * s[d.vi[p] + l];
    }
    const Sv<S> ap = p < 0 ? sv_zero<S>() : a[Lv::parent(d, i)];
    for (int c = d.vi[i]; c < d.vi[i] + d.nvj[i]; ++c) {
      const Sv<S> u = cross_motion(ap, s[c]);
      g_q[c] = dot(u, P[i]) + dot(Li, mul(Yc[i], u) + cross_force(s[c], F[i]));
    }
  }
}

// Coriolis matrix C (NV x NV) with C qd = nonlinear effects - gravity, Pinocchio's factorisation
// (dM/dt - 2 C skew-symmetric): the pairs above with X = dS/dt = v x S and Y = S / 2. It reads only
// the velocity terms (velocity_setup, or a derivatives workspace at any qdd and fext).
template <class M, class S> TG_HD void coriolis_matrix(const VelocityWork<M, S>& W, S* C) {
  const auto& d = data<M, S>();
  Sv<S> sdot[M::NV];
  for (int i = 0; i < M::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) sdot[d.vi[i] + k] = cross_motion(W.v[i], W.s[d.vi[i] + k]);
  ancestor_pairs<false, true, M, S>(W, sdot, W.s, C);
}

// The linear columns of M of each free joint f (NV x 3 NFREE, row-major, f's at 3f), from W's
// composite inertias: M[r, c] = S_r^T Yc_i S_c with i the body of dof r, in f's subtree (else 0).
// All a MuJoCo twin's reframe reads of M.
template <class M, class S> TG_HD void mass_base_columns(const VelocityWork<M, S>& W, S* Mb) {
  const auto& d = data<M, S>();
  constexpr int NB3 = 3 * (M::NFREE > 0 ? M::NFREE : 1);
  for (int i = 0; i < M::NB; ++i)
    for (int l = 0; l < d.nvj[i]; ++l) {
      const int r = d.vi[i] + l;
      const Sv<S> Ys = mul(W.Yc[i], W.s[r]);
      for (int f = 0; f < M::NFREE; ++f) {
        const int j = d.free_joint[f], b = d.vi[j];
        for (int c = 0; c < 3; ++c) Mb[NB3 * r + 3 * f + c] = r >= b && r < d.vend[j] ? dot(Ys, W.s[b + c]) : S(0);
      }
    }
}

}  // namespace tg
