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

#include "kernels/derivatives/rnea_derivatives.h"

namespace tg {

// Column a's terms against the subtree of its body i, dB assembled once per column (each pair then
// takes one 6x6 product with it): dB = Bw + [S_a x*] BC - BC [S_a x], Bw = dI(IC, psid_a) + [IC psid_a]f.
template <class Scalar> struct ColumnTerms {
  M6<Scalar> D, Bs, dB;
  Sv<Scalar> ICs, BCTs, f2, f3;
};

template <class Robot, class Scalar> TG_HD ColumnTerms<Scalar> column_terms(const RneaDerivativesWork<Robot, Scalar>& W, int i, int a) {
  const Inertia<Scalar>& IC = W.Yc[i];
  const M6<Scalar>& BC = W.B[i];
  const Sv<Scalar>& Sa = W.s[a];
  ColumnTerms<Scalar> t{inertia_rate_matrix(IC, Sa), momentum_rate_matrix(IC, Sa), momentum_rate_matrix(IC, W.w[a]),
                   mul(IC, Sa), mul_transpose(BC, Sa), mul(BC, W.w[a]) + mul(IC, W.u[a]) + cross_force(Sa, W.F[i]),
                   mul(BC, Sa) + mul(IC, W.alpha[a])};
  for (int c = 0; c < 6; ++c) {
    Sv<Scalar> e = sv_zero<Scalar>();
    e.v[c] = Scalar(1);
    const Sv<Scalar> col = cross_force(Sa, mul(BC, e)) - mul(BC, cross_motion(Sa, e));
    for (int r = 0; r < 6; ++r) t.dB.m[6 * r + c] += col.v[r];
  }
  return t;
}

// Column b's terms (b in body i or above it) against the subtree of a's body i, named after what
// they pair with below.
template <class Scalar> struct PairTerms {
  Sv<Scalar> dBT_Sb, DT_Sb, BsT_Sb, Sb_ICs, rate_q, rate_qv, rate_vq, rate_qv_above, Bs_Sb, D_Sb, same_body_vv, wb_part;
};

template <class Robot, class Scalar>
TG_HD PairTerms<Scalar> pair_terms(const RneaDerivativesWork<Robot, Scalar>& W, const ColumnTerms<Scalar>& A, int i, int a, int b) {
  const Sv<Scalar>& Sa = W.s[a];
  const Sv<Scalar>& Sb = W.s[b];
  const Sv<Scalar>& wb = W.w[b];
  PairTerms<Scalar> p;
  p.dBT_Sb = mul_transpose(A.dB, Sb);
  p.DT_Sb = mul_transpose(A.D, Sb);
  p.BsT_Sb = mul_transpose(A.Bs, Sb);
  p.Sb_ICs = cross_force(Sb, A.ICs);
  const Sv<Scalar> Sb_BCTs = cross_force(Sb, A.BCTs);
  p.rate_q = mul(A.dB, wb) + mul(A.D, W.u[b]) + cross_force(Sb, A.f2);
  p.rate_qv = cross_force(wb, A.ICs) - mul(A.D, wb) + Sb_BCTs;
  p.rate_vq = mul(A.Bs, wb) + cross_force(Sb, A.f3);
  p.rate_qv_above = mul(A.dB, Sb) + mul(A.D, W.alpha[b]);
  p.Bs_Sb = mul(A.Bs, Sb);
  p.D_Sb = mul(A.D, Sb);
  p.same_body_vv = p.Sb_ICs + cross_force(Sa, mul(W.Yc[i], Sb));
  p.wb_part = Sb_BCTs - mul_transpose(A.Bs, wb);
  return p;
}

// Eight values that one instruction adds or multiplies on a CPU with 512-bit vectors (GCC's vector
// extension); a plain array on a GPU thread (and in the CPU build of its paths, TG_DEVICE_PATH), and for a
// scalar that is itself a vector of samples.
template <class Scalar, class = void> struct Octet {
  Scalar x[8];
  TG_HD Scalar operator[](int l) const { return x[l]; }
  TG_HD void fma(Scalar a, const Octet& b) {
    for (int l = 0; l < 8; ++l) x[l] += a * b.x[l];
  }
  TG_HD void fma(const Octet& a, const Octet& b) {
    for (int l = 0; l < 8; ++l) x[l] += a.x[l] * b.x[l];
  }
};
#if defined(__GNUC__) && !defined(__CUDACC__) && !TG_DEVICE_PATH
template <class Scalar> struct Octet<Scalar, std::enable_if_t<std::is_floating_point_v<Scalar>>> {
  typedef Scalar V __attribute__((vector_size(8 * sizeof(Scalar))));
  V x;
  Scalar operator[](int l) const { return x[l]; }
  void fma(Scalar a, const Octet& b) { x += a * b.x; }
  void fma(const Octet& a, const Octet& b) { x += a.x * b.x; }
};
#endif
template <class Scalar> TG_HD Octet<Scalar> octet(Scalar a, Scalar b, Scalar c, Scalar d, Scalar e, Scalar f, Scalar g, Scalar h) {
  Octet<Scalar> L;
  L.x[0] = a, L.x[1] = b, L.x[2] = c, L.x[3] = d, L.x[4] = e, L.x[5] = f, L.x[6] = g, L.x[7] = h;
  return L;
}

// A pair's dot products with a column c, as two 8-lane sums over the six rows of the vectors (so that
// they vectorize): one = sum_r S_c[r] p1[r], with lanes BsT_Sb, D_Sb, dBT_Sb, rate_q, Sb_ICs,
// rate_qv, rate_vq, Bs_Sb; and two = sum_r mixed_c[r] p2[r], mixed_c[r] = (S, psid x3, psidd x2,
// alpha x2)[r] of c, with lanes (against S) rate_qv_above, or same_body_vv for a pair in one body,
// (psid) BsT_Sb, wb_part, dBT_Sb, (psidd) Sb_ICs, DT_Sb, (alpha) DT_Sb, Sb_ICs.
template <class Scalar> struct PairOctet {
  Octet<Scalar> p1[6], p2[6];
};

template <class Scalar> TG_HD void pair_octet(const PairTerms<Scalar>& P, bool same_body, PairOctet<Scalar>& L) {
  const Sv<Scalar>& above = same_body ? P.same_body_vv : P.rate_qv_above;
  for (int r = 0; r < 6; ++r) {
    L.p1[r] = octet(P.BsT_Sb.v[r], P.D_Sb.v[r], P.dBT_Sb.v[r], P.rate_q.v[r], P.Sb_ICs.v[r], P.rate_qv.v[r],
                    P.rate_vq.v[r], P.Bs_Sb.v[r]);
    L.p2[r] = octet(above.v[r], P.BsT_Sb.v[r], P.wb_part.v[r], P.dBT_Sb.v[r], P.Sb_ICs.v[r], P.DT_Sb.v[r], P.DT_Sb.v[r],
                    P.Sb_ICs.v[r]);
  }
}

// The tensors an entry belongs to.
enum SecondOrderTensor : int { D2Q = 0, D2V = 1, DQDV = 2, DADQ = 3 };

// Column c's row r in the lanes of PairOctet::p2.
template <class Robot, class Scalar> TG_HD Octet<Scalar> column_octet(const RneaDerivativesWork<Robot, Scalar>& W, int c, int r) {
  return octet(W.s[c].v[r], W.w[c].v[r], W.w[c].v[r], W.w[c].v[r], W.u[c].v[r], W.u[c].v[r], W.alpha[c].v[r], W.alpha[c].v[r]);
}

// The entries of column a (of body i) as the first index of its triples, once each: put(tensor, i, j, k, value);
// mixed(c, r) is column_octet(W, c, r).
template <class Robot, class Scalar, class Mixed, class Put>
TG_HD_INLINE void rnea_second_order_column(const RneaDerivativesWork<Robot, Scalar>& W, int i, int a, const Mixed& mixed, Put& put) {
  const auto& d = data<Robot, Scalar>();
  const ColumnTerms<Scalar> A = column_terms<Robot, Scalar>(W, i, a);
  for (int j = i; j >= 0; j = d.parent[j])
    for (int b = d.vi[j]; b < d.vi[j] + d.nvj[j]; ++b) {
      const PairTerms<Scalar> P = pair_terms<Robot, Scalar>(W, A, i, a, b);
      PairOctet<Scalar> L;
      pair_octet(P, j == i, L);
      for (int k = j; k >= 0; k = d.parent[k])
        for (int c = d.vi[k]; c < d.vi[k] + d.nvj[k]; ++c) {
          Octet<Scalar> one = octet<Scalar>(0, 0, 0, 0, 0, 0, 0, 0), two = one;
          for (int r = 0; r < 6; ++r) {
            one.fma(W.s[c].v[r], L.p1[r]);
            two.fma(mixed(c, r), L.p2[r]);
          }
          const Scalar p1 = two[1], p2 = two[4] + two[2];
          put(D2Q, a, b, c, p2);
          put(DQDV, a, c, b, -p1);
          if (j != i) {
            const Scalar q2 = two[3] + two[5];
            put(D2Q, b, c, a, q2);
            put(D2Q, b, a, c, q2);
            put(DQDV, b, c, a, p1);
            put(DQDV, b, a, c, one[2] + two[6]);
            put(D2V, b, c, a, one[0]);
            put(D2V, b, a, c, one[0]);
            put(DADQ, b, c, a, one[1]);
            if (k != j) put(DADQ, c, b, a, one[1]);  // within one body, (c, b) is another visit's (b, c)
          }
          if (k != j) {
            put(D2Q, a, c, b, p2);
            put(D2Q, c, a, b, one[3]);
            put(D2V, a, b, c, -one[0]);
            put(D2V, a, c, b, -one[0]);
            put(DQDV, a, b, c, one[5] + two[7]);
            put(DQDV, c, b, a, one[6]);
            put(DADQ, c, a, b, one[4]);
            put(DADQ, a, c, b, one[4]);
            if (j != i) {
              put(D2Q, c, b, a, one[3]);
              put(D2V, c, a, b, one[7]);
              put(D2V, c, b, a, one[7]);
              put(DQDV, c, a, b, two[0]);
            } else {
              put(D2V, c, b, a, two[0]);
            }
          } else {
            put(D2V, a, b, c, -dot(P.DT_Sb, W.s[c]));
          }
        }
    }
}

// Visits every non-zero entry of the four tensors at the (q, qd, qdd, fext) W was set up at, once
// each: put(tensor, i, j, k, value). Entries of columns on different branches are zero. One thread takes
// the columns body by body, on a CPU with a table of their octets; a team's lanes take a column each
// (its body found as they go), every entry still written once, by one lane.
template <class Robot, class Scalar, class Put, class Team = Solo>
TG_HD void rnea_second_order_visit(const RneaDerivativesWork<Robot, Scalar>& W, Put&& put, const Team& t = {}) {
  const auto& d = data<Robot, Scalar>();
  const auto direct = [&W](int c, int r) { return column_octet<Robot, Scalar>(W, c, r); };
  if constexpr (Team::lanes > 1) {
    for (const int a : t.items(0, Robot::NV)) rnea_second_order_column<Robot, Scalar>(W, dof_body<Robot, Scalar>(a), a, direct, put);
  } else {
#if TG_DEVICE_PATH
    const auto& mixed = direct;
#else
    Octet<Scalar> table[Robot::NV][6];
    for (int c = 0; c < Robot::NV; ++c)
      for (int r = 0; r < 6; ++r) table[c][r] = direct(c, r);
    const auto mixed = [&table](int c, int r) -> const Octet<Scalar>& { return table[c][r]; };
#endif
    for (int i = 0; i < Robot::NB; ++i)
      for (int a = d.vi[i]; a < d.vi[i] + d.nvj[i]; ++a) rnea_second_order_column<Robot, Scalar>(W, i, a, mixed, put);
  }
}

// The four NV x NV x NV tensors (row-major, [i][j][k] at NV (NV i + j) + k) by team t; the entries off the
// visit's fixed pattern zeroed unless they hold zeros already. All written when every lane returns.
template <class Robot, class Scalar, class Team = Solo>
TG_HD void rnea_second_order(const RneaDerivativesWork<Robot, Scalar>& W, Scalar* d2q, Scalar* d2v, Scalar* dqdv, Scalar* dadq, bool zeroed,
                             const Team& t = {}) {
  constexpr int NV = Robot::NV;
  if (!zeroed)
    for (const int n : t.items(0, NV * NV * NV)) d2q[n] = d2v[n] = dqdv[n] = dadq[n] = Scalar(0);
  t.sync();
  Scalar* const T[4] = {d2q, d2v, dqdv, dadq};
  rnea_second_order_visit<Robot, Scalar>(W, [&](int tensor, int i, int j, int k, Scalar v) { T[tensor][NV * (NV * i + j) + k] = v; }, t);
}

// The derivatives of dtau/dq, dtau/dqd and M (NV x NV each) along tangents tq (of q, along its
// tangent space), tqd and tqdd: each entry of the visit above times its direction's tangent. Mixed
// partials commute: d/dq_j (dtau_i/dqd_k) = dqdv[i][j][k], d/dqdd_j (dtau_i/dq_k) = dM_dq[i][j][k].
template <class Robot, class Scalar>
TG_HD void rnea_second_order_tangent(const RneaDerivativesWork<Robot, Scalar>& W, const Scalar* tq, const Scalar* tqd, const Scalar* tqdd, Scalar* dA,
                                     Scalar* dB, Scalar* dM) {
  constexpr int NV = Robot::NV;
  for (int n = 0; n < NV * NV; ++n) dA[n] = dB[n] = dM[n] = Scalar(0);
  rnea_second_order_visit<Robot, Scalar>(W, [&](int t, int i, int j, int k, Scalar v) {
    if (t == D2Q) {
      dA[NV * i + j] += tq[k] * v;
    } else if (t == D2V) {
      dB[NV * i + j] += tqd[k] * v;
    } else if (t == DQDV) {
      dA[NV * i + j] += tqd[k] * v;
      dB[NV * i + k] += tq[j] * v;
    } else {
      dM[NV * i + j] += tq[k] * v;
      dA[NV * i + k] += tqdd[j] * v;
    }
  });
}

// The gradient of <Gq, dtau/dq> + <Gv, dtau/dqd> (Gq, Gv: NV x NV) with respect to q (along the
// tangent), qd and qdd: every entry of the visit above weighted by its cotangent, in O(n d) for a tree
// of depth d rather than one term per triple. Mixed partials commute (qd and qdd are not on the
// manifold): d/dq_k (dtau_i/dqd_j) = dqdv[i][k][j] and d/dqdd_m (dtau_i/dq_j) = dM_dq[i][m][j]. For a
// pair (a, b), an entry's third column c runs up the chain from b's body j, and its value is a dot
// product of c's S, psid, psidd or alpha with a vector of the pair. Where the gradient's index is a or
// b, the cotangents against c's vectors are summed up the chain first (per b: over the columns at or
// above j, "all", or strictly above it, "above"; per a, as j climbs); where it is c, the pair's vectors
// weighted by its cotangents are summed per body j, then over the bodies below each column.
// f_ext enters dtau/dq only, through -J_b^T f_b: with lam_j = Gq[:, j], the gradient for f_b is minus
// the sum over j of d/dq_j of body b's velocity J_b lam_j, which turns only with the columns of lam_j
// above j's joint: X_b^-1 sum over the columns j at or above b of S_j x Y_j, Y_j = sum of Gq[c][j] S_c
// over the columns c strictly above j's joint (gf: NB x 6, in each body's frame, as f_ext).
template <class Robot, class Scalar>
TG_HD void rnea_second_order_contract(const RneaDerivativesWork<Robot, Scalar>& W, const Scalar* Gq, const Scalar* Gv, Scalar* gq, Scalar* gqd,
                                      Scalar* gqdd, Scalar* gf) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV, NB = Robot::NB;
  const auto gq_ = [&](int r, int c) { return Gq[NV * r + c]; };
  const auto gv_ = [&](int r, int c) { return Gv[NV * r + c]; };
  for (int n = 0; n < NV; ++n) gq[n] = gqd[n] = gqdd[n] = Scalar(0);
  // Per column b: Gq[b][c] psid_c, Gq[b][c] psidd_c, Gv[b][c] S_c, Gv[b][c] alpha_c over c at or above
  // b's body; Gq[c][b] S_c, Gv[c][b] S_c over c strictly above it.
  Sv<Scalar> bw[NV], bu[NV], bS[NV], bal[NV], cqS[NV], cvS[NV];
  for (int j = 0; j < NB; ++j)
    for (int b = d.vi[j]; b < d.vi[j] + d.nvj[j]; ++b) {
      bw[b] = bu[b] = bS[b] = bal[b] = cqS[b] = cvS[b] = sv_zero<Scalar>();
      for (int k = j; k >= 0; k = d.parent[k])
        for (int c = d.vi[k]; c < d.vi[k] + d.nvj[k]; ++c) {
          bw[b] = bw[b] + gq_(b, c) * W.w[c];
          bu[b] = bu[b] + gq_(b, c) * W.u[c];
          bS[b] = bS[b] + gv_(b, c) * W.s[c];
          bal[b] = bal[b] + gv_(b, c) * W.alpha[c];
          if (k != j) {
            cqS[b] = cqS[b] + gq_(c, b) * W.s[c];
            cvS[b] = cvS[b] + gv_(c, b) * W.s[c];
          }
        }
    }
  // Per body j, the vectors that c's psidd, psid (into gq[c]), S, alpha (into gqd[c]) and S (into
  // gqdd[c]) meet, for c at or above j ("all"), strictly above ("above") or in j ("same").
  Sv<Scalar> Pu[NB], Pw[NB], PS[NB], Pal[NB], PSa[NB], Pala[NB], PSs[NB], QS[NB], QSa[NB];
  for (int j = 0; j < NB; ++j) Pu[j] = Pw[j] = PS[j] = Pal[j] = PSa[j] = Pala[j] = PSs[j] = QS[j] = QSa[j] = sv_zero<Scalar>();
  for (int i = 0; i < NB; ++i)
    for (int a = d.vi[i]; a < d.vi[i] + d.nvj[i]; ++a) {
      const ColumnTerms<Scalar> A = column_terms<Robot, Scalar>(W, i, a);
      // a's sums over the columns at or above j, as j climbs from i: Gq[a][c] psid_c, Gq[a][c] psidd_c,
      // Gv[a][c] S_c, Gv[a][c] alpha_c, Gq[c][a] S_c, Gv[c][a] S_c
      Sv<Scalar> aw = sv_zero<Scalar>(), au = aw, avS = aw, aval = aw, aqS = aw, acvS = aw;
      for (int k = i; k >= 0; k = d.parent[k])
        for (int c = d.vi[k]; c < d.vi[k] + d.nvj[k]; ++c) {
          aw = aw + gq_(a, c) * W.w[c];
          au = au + gq_(a, c) * W.u[c];
          avS = avS + gv_(a, c) * W.s[c];
          aval = aval + gv_(a, c) * W.alpha[c];
          aqS = aqS + gq_(c, a) * W.s[c];
          acvS = acvS + gv_(c, a) * W.s[c];
        }
      for (int j = i; j >= 0; j = d.parent[j]) {
        // the same strictly above j
        Sv<Scalar> sw = aw, su = au, svS = avS, sval = aval, sqS = aqS, scvS = acvS;
        for (int c = d.vi[j]; c < d.vi[j] + d.nvj[j]; ++c) {
          sw = sw - gq_(a, c) * W.w[c];
          su = su - gq_(a, c) * W.u[c];
          svS = svS - gv_(a, c) * W.s[c];
          sval = sval - gv_(a, c) * W.alpha[c];
          sqS = sqS - gq_(c, a) * W.s[c];
          scvS = scvS - gv_(c, a) * W.s[c];
        }
        const bool below = j != i;
        for (int b = d.vi[j]; b < d.vi[j] + d.nvj[j]; ++b) {
          const PairTerms<Scalar> P = pair_terms<Robot, Scalar>(W, A, i, a, b);
          const Scalar qab = gq_(a, b), qba = gq_(b, a), vab = gv_(a, b), vba = gv_(b, a);
          // entries whose gradient index is a or b
          gqd[b] += -dot(P.BsT_Sb, aw);
          gq[b] += dot(P.Sb_ICs, su) + dot(P.wb_part, sw) + dot(P.rate_q, sqS) + dot(P.rate_qv, svS) +
                   dot(P.Sb_ICs, sval) + dot(P.rate_vq, scvS);
          gqd[b] += -dot(P.BsT_Sb, svS);
          gqd[a] += dot(P.rate_vq, cqS[b]);
          gqdd[a] += dot(P.Sb_ICs, cqS[b]);
          if (below) {
            gq[a] += dot(P.dBT_Sb, bw[b]) + dot(P.DT_Sb, bu[b]) + dot(P.dBT_Sb, bS[b]) + dot(P.DT_Sb, bal[b]) +
                     dot(P.rate_q, cqS[b]) + dot(P.rate_qv_above, cvS[b]);
            gqd[a] += dot(P.BsT_Sb, bw[b]) + dot(P.BsT_Sb, bS[b]) + dot(P.Bs_Sb, cvS[b]);
            gqdd[b] += dot(P.D_Sb, sqS);
            gqd[b] += dot(P.Bs_Sb, scvS) + dot(P.rate_qv_above, sqS);
          } else {
            gqd[a] += dot(P.same_body_vv, cvS[b]);
          }
          // entries whose gradient index is c
          Pu[j] = Pu[j] + qab * P.Sb_ICs;
          Pw[j] = Pw[j] + qab * P.wb_part - vab * P.BsT_Sb;
          PSa[j] = PSa[j] + qab * P.rate_qv - vab * P.BsT_Sb;
          Pala[j] = Pala[j] + qab * P.Sb_ICs;
          PSs[j] = PSs[j] - vab * P.DT_Sb;
          QSa[j] = QSa[j] + qab * P.Sb_ICs;
          if (below) {
            Pu[j] = Pu[j] + qba * P.DT_Sb;
            Pw[j] = Pw[j] + qba * P.dBT_Sb + vba * P.BsT_Sb;
            PS[j] = PS[j] + qba * P.dBT_Sb + vba * P.BsT_Sb;
            Pal[j] = Pal[j] + qba * P.DT_Sb;
            QS[j] = QS[j] + qba * P.D_Sb;
          }
        }
        aw = sw;
        au = su;
        avS = svS;
        aval = sval;
        aqS = sqS;
        acvS = scvS;
      }
    }
  // Up from the leaves: "all" vectors summed over the bodies at or below each body, "above" ones over
  // those strictly below; then each column meets its body's sums.
  Sv<Scalar> Ba[NB], Bb[NB], Bq[NB];  // strictly below: PSa, Pala, QSa
  for (int k = 0; k < NB; ++k) Ba[k] = Bb[k] = Bq[k] = sv_zero<Scalar>();
  for (int k = NB - 1; k >= 0; --k) {
    for (int c = d.vi[k]; c < d.vi[k] + d.nvj[k]; ++c) {
      gq[c] += dot(Pu[k], W.u[c]) + dot(Pw[k], W.w[c]);
      gqd[c] += dot(PS[k] + Ba[k] + PSs[k], W.s[c]) + dot(Pal[k] + Bb[k], W.alpha[c]);
      gqdd[c] += dot(QS[k] + Bq[k], W.s[c]);
    }
    const int p = d.parent[k];
    if (p >= 0) {
      Pu[p] = Pu[p] + Pu[k];
      Pw[p] = Pw[p] + Pw[k];
      PS[p] = PS[p] + PS[k];
      Pal[p] = Pal[p] + Pal[k];
      QS[p] = QS[p] + QS[k];
      Ba[p] = Ba[p] + Ba[k] + PSa[k];
      Bb[p] = Bb[p] + Bb[k] + Pala[k];
      Bq[p] = Bq[p] + Bq[k] + QSa[k];
    }
  }
  // f_ext: Z_b = sum of S_j x Y_j over the columns at or above b, down the tree
  Sv<Scalar> Z[NB];
  for (int i = 0; i < NB; ++i) {
    Z[i] = d.parent[i] >= 0 ? Z[d.parent[i]] : sv_zero<Scalar>();
    for (int j = d.vi[i]; j < d.vi[i] + d.nvj[i]; ++j) {
      Sv<Scalar> Y = sv_zero<Scalar>();
      for (int k = d.parent[i]; k >= 0; k = d.parent[k])
        for (int c = d.vi[k]; c < d.vi[k] + d.nvj[k]; ++c) Y = Y + gq_(c, j) * W.s[c];
      Z[i] = Z[i] + cross_motion(W.s[j], Y);
    }
    const Sv<Scalar> z = actinv_motion(W.oMi[i], Z[i]);
    for (int r = 0; r < 6; ++r) gf[6 * i + r] = z.v[r];
  }
}

}  // namespace tg
