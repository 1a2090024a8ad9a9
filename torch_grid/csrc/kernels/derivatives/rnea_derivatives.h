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

#include <type_traits>

#include "kernels/spatial/joints.h"
#include "kernels/spatial/team.h"

namespace tg {

// What the Coriolis matrix and M's base columns read: world axes and velocities, and the subtree
// sums Yc and B.
template <class Robot, class Scalar> struct VelocityWork {
  const SE3<Scalar>* oMi;      // the Placements pass
  Sv<Scalar> v[Robot::NB];         // world velocity
  Inertia<Scalar> Yc[Robot::NB];   // subtree inertia, world frame
  M6<Scalar> B[Robot::NB];         // subtree sum of dI + [. x* h]
  Sv<Scalar> s[Robot::NV];         // per column: its world axis
};

// Everything the derivatives read: the above, the subtree forces and the per-column terms.
template <class Robot, class Scalar> struct RneaDerivativesWork : VelocityWork<Robot, Scalar> {
  Sv<Scalar> F[Robot::NB];                                   // subtree force
  Sv<Scalar> w[Robot::NV], u[Robot::NV], alpha[Robot::NV];           // per column, see above
};

// The 6x6 matrix of x -> dI x + x x* h with dI = v x* I - I v x and h = I v: the rate of change of
// the momentum I v of a body when its velocity v changes by x while it moves with velocity v.
template <class Scalar> TG_HD M6<Scalar> momentum_rate_matrix(const Inertia<Scalar>& I, const Sv<Scalar>& v) {
  M6<Scalar> B = inertia_rate_matrix(I, v);
  // x x* h = [-h_lin x x_ang; -h_lin x x_lin - h_ang x x_ang]
  const Sv<Scalar> h = mul(I, v);
  const Mat3<Scalar> Hl = skew(lin(h)), Ha = skew(ang(h));
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      B.m[6 * r + 3 + c] -= Hl.m[3 * r + c];
      B.m[6 * (3 + r) + c] -= Hl.m[3 * r + c];
      B.m[6 * (3 + r) + 3 + c] -= Ha.m[3 * r + c];
    }
  return B;
}

// Body i's own terms, which read no other body: its world axes and its world inertia (summed over subtrees
// by subtree_sums).
template <class Robot, class Scalar> TG_HD_INLINE void body_terms(int i, const SE3<Scalar>* oMi, VelocityWork<Robot, Scalar>& W,
                                                                 const InertialParameters<Robot, Scalar>& pi) {
  const auto& d = data<Robot, Scalar>();
  for (int k = 0; k < d.nvj[i]; ++k) W.s[d.vi[i] + k] = act_motion(oMi[i], joint_axis<Robot, Scalar>(i, k));
  W.Yc[i] = act(oMi[i], pi[i]);
}

// Body i's world velocity, from its parent's: v_i = v_p + S_i qd_i.
template <class Robot, class Scalar> TG_HD_INLINE void body_velocity(int i, const Scalar* qd, VelocityWork<Robot, Scalar>& W) {
  const auto& d = data<Robot, Scalar>();
  const int p = d.parent[i], vi = d.vi[i];
  W.v[i] = p < 0 ? sv_zero<Scalar>() : W.v[p];
  for (int k = 0; k < d.nvj[i]; ++k) W.v[i] = W.v[i] + qd[vi + k] * W.s[vi + k];
}

// Yc, B (and F where W has it) summed over subtrees: by one thread body by body, each sum whole; by a team,
// each of their 13 + 36 (+ 6) entries by one lane over every body (the same sums, in the same order).
template <class Robot, class Scalar, class Work, class Team> TG_HD void subtree_sums(const Team& t, Work& W) {
  const auto& d = data<Robot, Scalar>();
  constexpr bool forces = std::is_base_of_v<RneaDerivativesWork<Robot, Scalar>, Work>;
  if constexpr (Team::lanes == 1) {
    for (int i = Robot::NB - 1; i > 0; --i) {
      const int p = d.parent[i];
      if (p < 0) continue;
      W.Yc[p] = W.Yc[p] + W.Yc[i];
      for (int k = 0; k < 36; ++k) W.B[p].m[k] += W.B[i].m[k];
      if constexpr (forces) W.F[p] = W.F[p] + W.F[i];
    }
  } else {
    subtree_entry_sums<Robot, Scalar>(t, forces ? 55 : 49, [&W](int i, int e) -> Scalar& {
      if constexpr (forces)
        if (e >= 49) return W.F[i].v[e - 49];
      return e < 13 ? inertia_entry(W.Yc[i], e) : W.B[i].m[e - 13];
    });
  }
}

template <class Robot, class Scalar> TG_HD void velocity_setup(const Placements<Robot, Scalar>& K, const Scalar* qd, VelocityWork<Robot, Scalar>& W,
                          const InertialParameters<Robot, Scalar>& pi = {}) {
  W.oMi = K.oMi;
  for (int i = 0; i < Robot::NB; ++i) {
    body_terms<Robot, Scalar>(i, K.oMi, W, pi);
    body_velocity<Robot, Scalar>(i, qd, W);
    W.B[i] = momentum_rate_matrix(W.Yc[i], W.v[i]);
  }
  subtree_sums<Robot, Scalar>(Solo{}, W);
}

// By team t at the world placements oMi: each body's axes and inertia; the leader's pass down the tree
// (velocities, accelerations, the per-column terms and the body forces); each body's B; then the subtree
// sums Yc, B, F. All of W written when every lane returns.
template <class Robot, class Scalar, class Team>
TG_HD void rnea_derivatives_setup(const Team& t, const SE3<Scalar>* oMi, const Scalar* qd, const Scalar* qdd, const Scalar* fext,
                                  RneaDerivativesWork<Robot, Scalar>& W, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  using L = Levels<Robot>;
  if (t.leader()) W.oMi = oMi;
  for (const int i : t.items(0, Robot::NB)) body_terms<Robot, Scalar>(i, oMi, W, pi);
  t.sync();
  if (t.leader()) {
    Sv<Scalar> a[L::N];  // world accelerations (gravity included), only for the children
    for (int i = 0; i < Robot::NB; ++i) {
      body_velocity<Robot, Scalar>(i, qd, W);
      const int p = d.parent[i], n = d.nvj[i], vi = d.vi[i];
      const Sv<Scalar> vp = p < 0 ? sv_zero<Scalar>() : W.v[p];
      const Sv<Scalar> ap = p < 0 ? base_acceleration<Robot, Scalar>() : a[L::parent(d, i)];
      Sv<Scalar>& ai = a[L::of(d, i)];
      ai = ap;
      for (int k = 0; k < n; ++k) ai = ai + qdd[vi + k] * W.s[vi + k] + qd[vi + k] * cross_motion(W.v[i], W.s[vi + k]);
      for (int k = 0; k < n; ++k) {
        const Sv<Scalar>& s = W.s[vi + k];
        W.w[vi + k] = cross_motion(vp, s);
        W.u[vi + k] = cross_motion(ap, s) + cross_motion(vp, W.w[vi + k]);
        W.alpha[vi + k] = cross_motion(vp + W.v[i], s);
      }
      W.F[i] = mul(W.Yc[i], ai) + cross_force(W.v[i], mul(W.Yc[i], W.v[i]));
      if (fext) {
        const Sv<Scalar> fe = {{fext[6 * i], fext[6 * i + 1], fext[6 * i + 2], fext[6 * i + 3], fext[6 * i + 4], fext[6 * i + 5]}};
        W.F[i] = W.F[i] - act_force(oMi[i], fe);
      }
    }
  }
  t.sync();
  for (const int i : t.items(0, Robot::NB)) W.B[i] = momentum_rate_matrix(W.Yc[i], W.v[i]);
  t.sync();
  subtree_sums<Robot, Scalar>(t, W);
  t.sync();
}

template <class Robot, class Scalar>
TG_HD void rnea_derivatives_setup(const Placements<Robot, Scalar>& K, const Scalar* qd, const Scalar* qdd, const Scalar* fext,
                                  RneaDerivativesWork<Robot, Scalar>& W, const InertialParameters<Robot, Scalar>& pi = {}) {
  rnea_derivatives_setup<Robot, Scalar>(Solo{}, K.oMi, qd, qdd, fext, W, pi);
}

// The NV x NV matrix (row-major) with, for every joint j and each joint m on its support chain
// (j included), per-column motions X, Y:
//   row m, column j:  S_m^T (Yc_m X_j + B_m Y_j)                        (m below or at j)
//   row m, column j:  S_m^T (Yc_j X_j + B_j Y_j [+ s_j x* F_j])          (m strictly above j)
// Entries of unrelated branches are zero (left as they were without Zero, for a reader of the tree's
// entries alone). HalfY takes Y / 2 for Y (exactly, without its storage). By team t: body i's rows (the
// first loop) and columns (the second) are i's lane's, entries that no other body's lane writes.
template <bool ForceTerm, bool HalfY, class Robot, class Scalar, class Work, bool Zero = true, class Team>
TG_HD void ancestor_pairs(const Team& t, const Work& W, const Sv<Scalar>* X, const Sv<Scalar>* Y, Scalar* out) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  if constexpr (Zero) {
    for (const int r : t.items(0, NV))
      for (int c = 0; c < NV; ++c) out[NV * r + c] = Scalar(0);
    t.sync();
  }
  for (const int i : t.items(0, Robot::NB)) {
    // Rows of joint i, columns of its ancestors and itself.
    for (int l = 0; l < d.nvj[i]; ++l) {
      const int row = d.vi[i] + l;
      const Sv<Scalar> P = mul(W.Yc[i], W.s[d.vi[i] + l]);
      Sv<Scalar> Q = mul_transpose(W.B[i], W.s[d.vi[i] + l]);
      if constexpr (HalfY) Q = Scalar(0.5) * Q;
      for (int j = i; j >= 0; j = d.parent[j])
        for (int c = 0; c < d.nvj[j]; ++c) {
          const int col = d.vi[j] + c;
          out[NV * row + col] = dot(X[col], P) + dot(Y[col], Q);
        }
    }
    // Columns of joint i, rows of its strict ancestors.
    for (int c = 0; c < d.nvj[i]; ++c) {
      const int col = d.vi[i] + c;
      Sv<Scalar> BY = mul(W.B[i], Y[col]);
      if constexpr (HalfY) BY = Scalar(0.5) * BY;
      Sv<Scalar> dF = mul(W.Yc[i], X[col]) + BY;
      if constexpr (ForceTerm) dF = dF + cross_force(W.s[col], W.F[i]);
      for (int m = d.parent[i]; m >= 0; m = d.parent[m])
        for (int l = 0; l < d.nvj[m]; ++l) out[NV * (d.vi[m] + l) + col] = dot(W.s[d.vi[m] + l], dF);
    }
  }
}

// W set up at qdd = 0 moved to qdd, in one forward pass: the world accelerations change by
// da_i = da_p + ds_i with ds_i = S_i qdd_i, u by da_p x s, and the subtree force F_i by
// sum_{j in subtree(i)} I_j da_j = Yc_i da_i + sum_{m strictly below i} Yc_m ds_m (Yc being the subtree
// inertias): body m adds Yc_m ds_m to each strict ancestor's.
template <class Robot, class Scalar> TG_HD void rnea_derivatives_accelerate(const Scalar* qdd, RneaDerivativesWork<Robot, Scalar>& W) {
  const auto& d = data<Robot, Scalar>();
  using L = Levels<Robot>;
  Sv<Scalar> da[L::N];  // only for the children
  for (int i = 0; i < Robot::NB; ++i) {
    const int p = d.parent[i], vi = d.vi[i];
    const Sv<Scalar> dap = p < 0 ? sv_zero<Scalar>() : da[L::parent(d, i)];
    Sv<Scalar> ds = sv_zero<Scalar>();
    for (int k = 0; k < d.nvj[i]; ++k) {
      W.u[vi + k] = W.u[vi + k] + cross_motion(dap, W.s[vi + k]);
      ds = ds + qdd[vi + k] * W.s[vi + k];
    }
    da[L::of(d, i)] = dap + ds;
    W.F[i] = W.F[i] + mul(W.Yc[i], da[L::of(d, i)]);
    const Sv<Scalar> f = mul(W.Yc[i], ds);
    for (int a = p; a >= 0; a = d.parent[a]) W.F[a] = W.F[a] + f;
  }
}

// tau = S^T F (NV) at the (q, qd, qdd, fext) W was set up at.
template <class Robot, class Scalar> TG_HD void rnea_torques(const RneaDerivativesWork<Robot, Scalar>& W, Scalar* tau) {
  const auto& d = data<Robot, Scalar>();
  for (int i = 0; i < Robot::NB; ++i)
    for (int l = 0; l < d.nvj[i]; ++l) tau[d.vi[i] + l] = dot(W.s[d.vi[i] + l], W.F[i]);
}

// dtau_dq and dtau_dqd (NV x NV, row-major) there, by team t; without Zero, the entries between branches
// are left as they were.
template <class Robot, class Scalar, bool Zero = true, class Team>
TG_HD void rnea_derivatives(const Team& t, const RneaDerivativesWork<Robot, Scalar>& W, Scalar* dtau_dq, Scalar* dtau_dqd) {
  using Work = RneaDerivativesWork<Robot, Scalar>;
  ancestor_pairs<true, false, Robot, Scalar, Work, Zero>(t, W, W.u, W.w, dtau_dq);
  ancestor_pairs<false, false, Robot, Scalar, Work, Zero>(t, W, W.alpha, W.s, dtau_dqd);
}

// lambda^T d tau / dq and lambda^T d tau / dqd (NV each) in O(n), the pairs above summed over their rows
// first, which leaves no 6x6 subtree sum B. With y_k the sum of lambda_m S_m over the columns at or
// above body k, L_j that of j's parent, and the subtree sums Z_j of I_k y_k and R_j of B_k^T y_k (each
// body's own inertia I, velocity v and momentum h = I v: B^T y = v x* I y - I (v x y) - y x* h),
//   (lambda^T d tau/dq)_j = u_j . Z_j + w_j . R_j + L_j . (s_j x* F_j),   (lambda^T d tau/dqd)_j = alpha_j . Z_j + s_j . R_j,
// and tau_j = s_j . F_j, (M lambda)_j = s_j . Z_j (written where Mlam is not null). Rest: at qd = 0
// without gravity or fext (qd and fext are not read), where tau = M qdd and h, R and w vanish: the
// gradient of lambda^T M(q) qdd (mass_product_vjp).
template <bool Rest = false, class Robot, class Scalar>
TG_HD void rnea_vjp(const Placements<Robot, Scalar>& K, const Scalar* qd, const Scalar* qdd, const Scalar* fext, const Scalar* lambda, Scalar* tau,
                    Scalar* g_q, Scalar* g_qd, Scalar* Mlam = nullptr, const InertialParameters<Robot, Scalar>& pi = {}) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NB = Robot::NB;
  Sv<Scalar> s[Robot::NV], v[NB], a[NB], h[NB], F[NB], y[NB], Z[NB], R[NB];
  Inertia<Scalar> I[NB];
  // forward: world axes, velocities, accelerations (gravity included) and body forces
  for (int i = 0; i < NB; ++i) {
    const int p = d.parent[i], vi = d.vi[i];
    v[i] = p < 0 ? sv_zero<Scalar>() : v[p];
    for (int k = 0; k < d.nvj[i]; ++k) {
      s[vi + k] = act_motion(K.oMi[i], joint_axis<Robot, Scalar>(i, k));
      if constexpr (!Rest) v[i] = v[i] + qd[vi + k] * s[vi + k];
    }
    a[i] = p >= 0 ? a[p] : Rest ? sv_zero<Scalar>() : base_acceleration<Robot, Scalar>();
    for (int k = 0; k < d.nvj[i]; ++k) a[i] = a[i] + qdd[vi + k] * s[vi + k];
    if constexpr (!Rest)
      for (int k = 0; k < d.nvj[i]; ++k) a[i] = a[i] + qd[vi + k] * cross_motion(v[i], s[vi + k]);
    I[i] = act(K.oMi[i], pi[i]);
    F[i] = mul(I[i], a[i]);
    if constexpr (!Rest) {
      h[i] = mul(I[i], v[i]);
      F[i] = F[i] + cross_force(v[i], h[i]);
    }
    if (!Rest && fext) {
      const Sv<Scalar> fe = {{fext[6 * i], fext[6 * i + 1], fext[6 * i + 2], fext[6 * i + 3], fext[6 * i + 4], fext[6 * i + 5]}};
      F[i] = F[i] - act_force(K.oMi[i], fe);
    }
  }
  for (int i = NB - 1; i > 0; --i)
    if (d.parent[i] >= 0) F[d.parent[i]] = F[d.parent[i]] + F[i];
  // down: y; each body's I y and B^T y
  for (int i = 0; i < NB; ++i) {
    y[i] = d.parent[i] < 0 ? sv_zero<Scalar>() : y[d.parent[i]];
    for (int c = d.vi[i]; c < d.vi[i] + d.nvj[i]; ++c) y[i] = y[i] + lambda[c] * s[c];
    Z[i] = mul(I[i], y[i]);
    if constexpr (!Rest) R[i] = cross_force(v[i], Z[i]) - mul(I[i], cross_motion(v[i], y[i])) - cross_force(y[i], h[i]);
  }
  for (int i = NB - 1; i > 0; --i)
    if (d.parent[i] >= 0) {
      Z[d.parent[i]] = Z[d.parent[i]] + Z[i];
      if constexpr (!Rest) R[d.parent[i]] = R[d.parent[i]] + R[i];
    }
  // per column: w = v_p x s, u = a_p x s + v_p x w, alpha = (v_p + v_i) x s
  for (int i = 0; i < NB; ++i) {
    const int p = d.parent[i];
    const Sv<Scalar> vp = p < 0 ? sv_zero<Scalar>() : v[p], L = p < 0 ? sv_zero<Scalar>() : y[p];
    const Sv<Scalar> ap = p >= 0 ? a[p] : Rest ? sv_zero<Scalar>() : base_acceleration<Robot, Scalar>();
    for (int c = d.vi[i]; c < d.vi[i] + d.nvj[i]; ++c) {
      tau[c] = dot(s[c], F[i]);
      if (Mlam) Mlam[c] = dot(s[c], Z[i]);
      if constexpr (Rest) {
        g_q[c] = dot(cross_motion(ap, s[c]), Z[i]) + dot(L, cross_force(s[c], F[i]));
      } else {
        const Sv<Scalar> w = cross_motion(vp, s[c]), u = cross_motion(ap, s[c]) + cross_motion(vp, w);
        g_q[c] = dot(u, Z[i]) + dot(w, R[i]) + dot(L, cross_force(s[c], F[i]));
        g_qd[c] = dot(cross_motion(vp + v[i], s[c]), Z[i]) + dot(s[c], R[i]);
      }
    }
  }
}

// The gradient along the tangent of lam^T M(q) a (NV): rnea_vjp at rest without gravity.
template <class Robot, class Scalar>
TG_HD void mass_product_vjp(const Placements<Robot, Scalar>& K, const Scalar* acc, const Scalar* lambda, Scalar* g_q,
                           const InertialParameters<Robot, Scalar>& pi = {}) {
  Scalar tau[Robot::NV];
  rnea_vjp<true, Robot, Scalar>(K, nullptr, acc, nullptr, lambda, tau, g_q, nullptr, nullptr, pi);
}

// Coriolis matrix C (NV x NV) with C qd = nonlinear effects - gravity, Pinocchio's factorisation
// (dM/dt - 2 C skew-symmetric): the pairs above with X = dS/dt = v x S and Y = S / 2. It reads only
// the velocity terms (velocity_setup, or a derivatives workspace at any qdd and fext).
template <class Robot, class Scalar> TG_HD void coriolis_matrix(const VelocityWork<Robot, Scalar>& W, Scalar* C) {
  const auto& d = data<Robot, Scalar>();
  Sv<Scalar> sdot[Robot::NV];
  for (int i = 0; i < Robot::NB; ++i)
    for (int k = 0; k < d.nvj[i]; ++k) sdot[d.vi[i] + k] = cross_motion(W.v[i], W.s[d.vi[i] + k]);
  ancestor_pairs<false, true, Robot, Scalar>(Solo{}, W, sdot, W.s, C);
}

// The linear columns of M of each free joint f (NV x 3 NFREE, row-major, f's at 3f), from W's
// composite inertias: M[r, c] = S_r^T Yc_i S_c with i the body of dof r, in f's subtree (else 0).
// All a MuJoCo twin's reframe reads of M.
template <class Robot, class Scalar> TG_HD void mass_base_columns(const VelocityWork<Robot, Scalar>& W, Scalar* Mb) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NB3 = 3 * (Robot::NFREE > 0 ? Robot::NFREE : 1);
  for (int i = 0; i < Robot::NB; ++i)
    for (int l = 0; l < d.nvj[i]; ++l) {
      const int r = d.vi[i] + l;
      const Sv<Scalar> Ys = mul(W.Yc[i], W.s[r]);
      for (int f = 0; f < Robot::NFREE; ++f) {
        const int j = d.free_joint[f], b = d.vi[j];
        for (int c = 0; c < 3; ++c) Mb[NB3 * r + 3 * f + c] = r >= b && r < d.vend[j] ? dot(Ys, W.s[b + c]) : Scalar(0);
      }
    }
}

}  // namespace tg
