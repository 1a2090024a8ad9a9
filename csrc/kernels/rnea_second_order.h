// Second-order derivatives of inverse dynamics (Singh, Russell & Wensing's second-order IDSVA, the
// algorithm of Pinocchio's ComputeRNEASecondOrderDerivatives), in the world frame, along the same
// tangent as rnea_derivatives.h:
//   d2tau_dq2[i][j][k]   = d/dq_k  (d tau_i / dq_j)       d2tau_dqd2[i][j][k] = d/dqd_k (d tau_i / dqd_j)
//   d2tau_dqdqd[i][j][k] = d/dqd_k (d tau_i / dq_j)       dM_dq[i][j][k]      = d/dq_k M[i][j]
//
// It reads the first-order workspace: per column the world axis S, its rates psid = v_p x S (`w`)
// and psidd = a_p x S + v_p x psid (`u`), and psid + phid = (v_p + v_i) x S (`alpha`); per body the
// subtree inertia IC (`Yc`), the subtree sum BC of dI + [. x* h] (`B`) and the subtree force f (`F`).
// Every non-zero entry belongs to three columns on one support chain, a in body i, b in an ancestor
// j of i (or i), c in an ancestor k of j (or j); one visit of each triple fills the entries of all
// their index permutations. With [x]f the matrix y -> y x* x of a force x:
//   D    = dI(IC, S_a) = S_a x* IC - IC S_a x     (the rate of IC along S_a)
//   Bs   = D + [IC S_a]f                          (BC's counterpart for the velocity S_a)
//   dB   = BC's rate along q_a: dI(IC, psid_a) + [IC psid_a]f + S_a x* BC - BC S_a x
//   f2   = BC psid_a + IC psidd_a + S_a x* f      (the subtree force's second-order rate)
//   f3   = BC S_a + IC (psid_a + phid_a)
#pragma once

#include "rnea_derivatives.h"

namespace tg {

// dB x and dB^T x for dB = Bw + [S x*] BC - BC [S x], Bw = dI(IC, psid) + [IC psid]f.
template <class S> struct SubtreeRate {
  const M6<S>& Bw;
  const M6<S>& BC;
  const Sv<S>& s;
  TG_HD Sv<S> operator()(const Sv<S>& x) const { return mul(Bw, x) + cross_force(s, mul(BC, x)) - mul(BC, cross_motion(s, x)); }
  TG_HD Sv<S> transposed(const Sv<S>& x) const {
    return mul_transpose(Bw, x) - mul_transpose(BC, cross_motion(s, x)) + cross_force(s, mul_transpose(BC, x));
  }
};

// The tensors an entry belongs to.
enum SecondOrderTensor : int { D2Q = 0, D2V = 1, DQDV = 2, DADQ = 3 };

// Visits every non-zero entry of the four tensors at the (q, qd, qdd, fext) W was set up at, once
// each: put(tensor, i, j, k, value). Entries of columns on different branches are zero.
template <class M, class S, class Put> TG_HD void rnea_second_order_visit(const RneaDerivativesWork<M, S>& W, Put&& put) {
  const auto& d = data<M, S>();
  for (int i = 0; i < M::NB; ++i) {
    const Inertia<S>& IC = W.Yc[i];
    const M6<S>& BC = W.B[i];
    for (int la = 0; la < d.nvj[i]; ++la) {
      const int a = d.vi[i] + la;
      const Sv<S>& Sa = W.s[a];
      const M6<S> D = inertia_rate_matrix(IC, Sa), Bs = momentum_rate_matrix(IC, Sa);
      const M6<S> Bw = momentum_rate_matrix(IC, W.w[a]);
      const SubtreeRate<S> dB{Bw, BC, Sa};
      const Sv<S> ICs = mul(IC, Sa), BCTs = mul_transpose(BC, Sa);
      const Sv<S> f2 = mul(BC, W.w[a]) + mul(IC, W.u[a]) + cross_force(Sa, W.F[i]);
      const Sv<S> f3 = mul(BC, Sa) + mul(IC, W.alpha[a]);
      for (int j = i; j >= 0; j = d.parent[j])
        for (int lb = 0; lb < d.nvj[j]; ++lb) {
          const int b = d.vi[j] + lb;
          const Sv<S>& Sb = W.s[b];
          const Sv<S>& wb = W.w[b];
          // column b's terms against the subtree of i (names after what they pair with below)
          const Sv<S> dBT_Sb = dB.transposed(Sb), DT_Sb = mul_transpose(D, Sb), BsT_Sb = mul_transpose(Bs, Sb);
          const Sv<S> Sb_ICs = cross_force(Sb, ICs), Sb_BCTs = cross_force(Sb, BCTs);
          const Sv<S> rate_q = dB(wb) + mul(D, W.u[b]) + cross_force(Sb, f2);
          const Sv<S> rate_qv = cross_force(wb, ICs) - mul(D, wb) + Sb_BCTs;
          const Sv<S> rate_vq = mul(Bs, wb) + cross_force(Sb, f3);
          const Sv<S> rate_qv_above = dB(Sb) + mul(D, W.alpha[b]);
          const Sv<S> Bs_Sb = mul(Bs, Sb), D_Sb = mul(D, Sb);
          const Sv<S> same_body_vv = Sb_ICs + cross_force(Sa, mul(IC, Sb));
          const Sv<S> wb_part = Sb_BCTs - mul_transpose(Bs, wb);
          for (int k = j; k >= 0; k = d.parent[k])
            for (int lc = 0; lc < d.nvj[k]; ++lc) {
              const int c = d.vi[k] + lc;
              const Sv<S>& Sc = W.s[c];
              const Sv<S>& wc = W.w[c];
              const S p1 = dot(BsT_Sb, wc);
              const S p2 = dot(Sb_ICs, W.u[c]) + dot(wb_part, wc);
              put(D2Q, a, b, c, p2);
              put(DQDV, a, c, b, -p1);
              if (j != i) {
                const S q2 = dot(dBT_Sb, wc) + dot(DT_Sb, W.u[c]), v2 = dot(BsT_Sb, Sc), m = dot(Sc, D_Sb);
                put(D2Q, b, c, a, q2);
                put(D2Q, b, a, c, q2);
                put(DQDV, b, c, a, p1);
                put(DQDV, b, a, c, dot(dBT_Sb, Sc) + dot(DT_Sb, W.alpha[c]));
                put(D2V, b, c, a, v2);
                put(D2V, b, a, c, v2);
                put(DADQ, b, c, a, m);
                if (k != j) put(DADQ, c, b, a, m);  // within one body, (c, b) is another visit's (b, c)
              }
              if (k != j) {
                const S q3 = dot(Sc, rate_q), m = dot(Sc, Sb_ICs);
                put(D2Q, a, c, b, p2);
                put(D2Q, c, a, b, q3);
                put(D2V, a, b, c, -dot(BsT_Sb, Sc));
                put(D2V, a, c, b, -dot(BsT_Sb, Sc));
                put(DQDV, a, b, c, dot(Sc, rate_qv) + dot(Sb_ICs, W.alpha[c]));
                put(DQDV, c, b, a, dot(Sc, rate_vq));
                put(DADQ, c, a, b, m);
                put(DADQ, a, c, b, m);
                if (j != i) {
                  const S v3 = dot(Sc, Bs_Sb);
                  put(D2Q, c, b, a, q3);
                  put(D2V, c, a, b, v3);
                  put(D2V, c, b, a, v3);
                  put(DQDV, c, a, b, dot(Sc, rate_qv_above));
                } else {
                  put(D2V, c, b, a, dot(Sc, same_body_vv));
                }
              } else {
                put(D2V, a, b, c, -dot(DT_Sb, Sc));
              }
            }
        }
    }
  }
}

// The four NV x NV x NV tensors (row-major, [i][j][k] at NV (NV i + j) + k).
template <class M, class S>
TG_HD void rnea_second_order(const RneaDerivativesWork<M, S>& W, S* d2q, S* d2v, S* dqdv, S* dadq) {
  constexpr int NV = M::NV;
  for (int n = 0; n < NV * NV * NV; ++n) d2q[n] = d2v[n] = dqdv[n] = dadq[n] = S(0);
  S* const T[4] = {d2q, d2v, dqdv, dadq};
  rnea_second_order_visit<M, S>(W, [&](int t, int i, int j, int k, S v) { T[t][NV * (NV * i + j) + k] = v; });
}

// The gradient of <Gq, dtau/dq> + <Gv, dtau/dqd> (Gq, Gv: NV x NV) with respect to q (along the
// tangent), qd and qdd, each entry of the tensors contracted as it is produced (no NV^3 storage).
// Mixed partials commute (qd and qdd are not on the manifold): d/dq_k (dtau_i/dqd_j) = dqdv[i][k][j]
// and d/dqdd_m (dtau_i/dq_j) = dM_dq[i][m][j].
template <class M, class S>
TG_HD void rnea_second_order_contract(const RneaDerivativesWork<M, S>& W, const S* Gq, const S* Gv, S* gq, S* gqd,
                                      S* gqdd) {
  constexpr int NV = M::NV;
  for (int n = 0; n < NV; ++n) gq[n] = gqd[n] = gqdd[n] = S(0);
  rnea_second_order_visit<M, S>(W, [&](int t, int i, int j, int k, S v) {
    if (t == D2Q) {
      gq[k] += Gq[NV * i + j] * v;
    } else if (t == D2V) {
      gqd[k] += Gv[NV * i + j] * v;
    } else if (t == DQDV) {
      gqd[k] += Gq[NV * i + j] * v;
      gq[j] += Gv[NV * i + k] * v;
    } else {
      gqdd[j] += Gq[NV * i + k] * v;
    }
  });
}

}  // namespace tg
