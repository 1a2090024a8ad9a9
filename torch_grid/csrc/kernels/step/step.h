// The plant step's two Euler schemes and their tangent Jacobians, from the forward-dynamics
// derivatives in one pass (torch_grid/step/integrators.py holds every scheme in torch). With
// a = FD(q, qd, tau, f_ext) and G = [da/dq, da/dqd, da/dtau], all in the call's convention:
//   euler                (scheme 0)  qd' = qd + dt a,  q' = q (+) dt qd
//   semi_implicit_euler  (scheme 1)  qd' = qd + dt a,  q' = q (+) dt qd'
// Along z = [dq; dqd; dtau]: dqd'/dz = dt G + [0 I 0] and dq'/dz = Jq [I 0 0] + dt Jv dw/dz, w the
// velocity integrated (qd or qd'), Jq and Jv the tangent Jacobians of q (+) u, u = dt w. Both are
// the identity but at quaternion joints, where, with R = exp3(u_ang) and Jr SO(3)'s right Jacobian:
//   ball joint, MuJoCo's free joint (its position: identity)   Jq = R^T,  Jv = Jr
//   Pinocchio's free joint, SE(3), q (+) u = M exp6(u)          Jq = Ad(exp6(u)^-1) = [[R^T, -R^T [V u_lin]], [0, R^T]]
//                                                               Jv = [[Jr, Q(u)], [0, Jr]]
// (linear rows first; V = Jr(-u_ang) = Jl, Q Barfoot's coupling block at -u).
#pragma once

#include "kernels/derivatives/dynamics_derivatives.h"
#include "kernels/spatial/convention.h"

namespace tg {

// SO(3)'s coefficients at the angle t = |u|, by their Taylor series near 0 (truncation ~ t^6), else from one
// sine and cosine of t / 2.
template <class Scalar> struct So3Coefficients {
  Scalar sin_half, cos_half;  // sin(t/2) / t, cos(t/2): exp3(u) = [sin_half u; cos_half] (xyzw)
  Scalar a, b;                // (1 - cos t) / t^2, (t - sin t) / t^3
  Scalar c2, c3;              // (t^2 + 2 cos t - 2) / (2 t^4), (2 t - 3 sin t + t cos t) / (2 t^5)
  Scalar beta;                // (1 - (t/2) cot(t/2)) / t^2: Jr(u)^-1 = I + [u] / 2 + beta [u]^2
};

template <class Scalar> TG_HD So3Coefficients<Scalar> so3_coefficients(Vec3<Scalar> u) {
  const Scalar t2 = dot(u, u), t4 = t2 * t2;
  const auto small = t2 < Scalar(1e-4);
  const So3Coefficients<Scalar> series = {
      Scalar(0.5) - t2 / Scalar(48) + t4 / Scalar(3840), Scalar(1) - t2 / Scalar(8) + t4 / Scalar(384),
      Scalar(0.5) - t2 / Scalar(24) + t4 / Scalar(720), Scalar(1) / Scalar(6) - t2 / Scalar(120) + t4 / Scalar(5040),
      Scalar(1) / Scalar(24) - t2 / Scalar(720) + t4 / Scalar(40320), Scalar(1) / Scalar(120) - t2 / Scalar(2520) + t4 / Scalar(120960),
      Scalar(1) / Scalar(12) + t2 / Scalar(720) + t4 / Scalar(30240)};
  if (all(small)) return series;
  const Scalar t = sqrt(t2), sh = sin(t / Scalar(2)), ch = cos(t / Scalar(2));
  const Scalar s = Scalar(2) * sh * ch, c = Scalar(1) - Scalar(2) * sh * sh;  // sin t, cos t
  const So3Coefficients<Scalar> closed = {
      sh / t, ch, Scalar(2) * sh * sh / t2, (t - s) / (t2 * t), (t2 + Scalar(2) * c - Scalar(2)) / (Scalar(2) * t4),
      (Scalar(2) * t - Scalar(3) * s + t * c) / (Scalar(2) * t4 * t), (Scalar(1) - t * ch / (Scalar(2) * sh)) / t2};
  if (!any(small)) return closed;
  // lanes of samples on both sides of the threshold: each its own
  return {select(small, series.sin_half, closed.sin_half), select(small, series.cos_half, closed.cos_half),
          select(small, series.a, closed.a), select(small, series.b, closed.b), select(small, series.c2, closed.c2),
          select(small, series.c3, closed.c3), select(small, series.beta, closed.beta)};
}

template <class Scalar> TG_HD Mat3<Scalar> lincomb3(Scalar x, const Mat3<Scalar>& A, Scalar y, const Mat3<Scalar>& B) {
  Mat3<Scalar> C;
  for (int k = 0; k < 9; ++k) C.m[k] = x * A.m[k] + y * B.m[k];
  return C;
}

template <class Scalar> TG_HD Mat3<Scalar> transpose3(const Mat3<Scalar>& A) {
  return {{A.m[0], A.m[3], A.m[6], A.m[1], A.m[4], A.m[7], A.m[2], A.m[5], A.m[8]}};
}

// I + x [u] + y [u]^2
template <class Scalar> TG_HD Mat3<Scalar> so3_terms(Vec3<Scalar> u, Scalar x, Scalar y) {
  const Mat3<Scalar> U = skew(u);
  return lincomb3(Scalar(1), identity3<Scalar>(), Scalar(1), lincomb3(x, U, y, mul(U, U)));
}

// Quaternion product a b (xyzw).
template <class Scalar> TG_HD void quat_mul(const Scalar* a, const Scalar* b, Scalar* out) {
  const Vec3<Scalar> av = load3(a), bv = load3(b);
  store3(a[3] * bv + b[3] * av + cross(av, bv), out);
  out[3] = a[3] * b[3] - dot(av, bv);
}

// Barfoot's Q(rho, w) of SE(3)'s left Jacobian, the coupling block of the right one at (-rho, -w).
template <class Scalar> TG_HD Mat3<Scalar> se3_coupling(Vec3<Scalar> rho, Vec3<Scalar> w, const So3Coefficients<Scalar>& k) {
  const Mat3<Scalar> P = skew(Scalar(-1) * rho), W = skew(Scalar(-1) * w);
  const Mat3<Scalar> WP = mul(W, P), PW = mul(P, W), WPW = mul(WP, W);
  const Mat3<Scalar> first = lincomb3(Scalar(1), lincomb3(Scalar(1), WP, Scalar(1), PW), Scalar(1), WPW);
  const Mat3<Scalar> second = lincomb3(Scalar(1), lincomb3(Scalar(1), mul(W, WP), Scalar(1), mul(PW, W)), Scalar(-3), WPW);
  const Mat3<Scalar> third = lincomb3(Scalar(1), mul(WPW, W), Scalar(1), mul(W, WPW));
  return lincomb3(Scalar(1), lincomb3(Scalar(0.5), P, k.b, first), Scalar(1), lincomb3(k.c2, second, k.c3, third));
}

// Q(rho, w) y by cross products from the right (P z = -rho x z, W z = -w x z), where only its product with
// one vector is needed.
template <class Scalar> TG_HD Vec3<Scalar> se3_coupling_times(Vec3<Scalar> rho, Vec3<Scalar> w, const So3Coefficients<Scalar>& k, Vec3<Scalar> y) {
  const Vec3<Scalar> r = Scalar(-1) * rho, m = Scalar(-1) * w;
  const Vec3<Scalar> Py = cross(r, y), Wy = cross(m, y), WPy = cross(m, Py), PWy = cross(r, Wy);
  const Vec3<Scalar> WPWy = cross(m, PWy), WWy = cross(m, Wy);
  const Vec3<Scalar> first = WPy + PWy + WPWy;
  const Vec3<Scalar> second = cross(m, WPy) + cross(r, WWy) - Scalar(3) * WPWy;
  const Vec3<Scalar> third = cross(m, cross(r, WWy)) + cross(m, WPWy);
  return Scalar(0.5) * Py + k.b * first + k.c2 * second + k.c3 * third;
}

// L(w, y) with Q(rho, w) y = L(w, y) rho (Q is linear in rho): each P = [-rho] of Q's terms, applied to the
// vector z after it, is [z] rho, so with y1 = W y, y2 = W y1 and S_m = [y_m],
// L = S0 / 2 + b S1 + c2 S2 + W (b S0 + (b - 3 c2) S1 + c3 S2 + W (c2 S0 + c3 S1)).
template <class Scalar> TG_HD Mat3<Scalar> se3_coupling_along_rho(Vec3<Scalar> w, Vec3<Scalar> y, const So3Coefficients<Scalar>& k) {
  const Mat3<Scalar> W = skew(Scalar(-1) * w);
  const Vec3<Scalar> y1 = mul(W, y), y2 = mul(W, y1);
  const Mat3<Scalar> S0 = skew(y), S1 = skew(y1), S2 = skew(y2);
  const Mat3<Scalar> inner = mul(W, lincomb3(k.c2, S0, k.c3, S1));
  const Mat3<Scalar> outer = lincomb3(k.b, S0, Scalar(1), lincomb3(k.b - Scalar(3) * k.c2, S1, k.c3, S2));
  const Mat3<Scalar> own = lincomb3(Scalar(0.5), S0, Scalar(1), lincomb3(k.b, S1, k.c2, S2));
  return lincomb3(Scalar(1), own, Scalar(1), mul(W, lincomb3(Scalar(1), outer, Scalar(1), inner)));
}

// n x n block (n = 3 or 6, row-major, stride n) from 3 x 3 blocks at (r, c).
template <class Scalar> TG_HD void put3(Scalar* X, int n, int r, int c, const Mat3<Scalar>& B) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) X[n * (r + i) + c + j] = B.m[3 * i + j];
}

// dexp(theta)^-1 (n x n, row-major; n = 3 or 6), the inverse of integrate_joint's Jv at theta: Jr(w)^-1 = I + [w] / 2
// + beta [w]^2 on a rotation w (MuJoCo's free joint: its position rows the identity); on Pinocchio's free joint SE(3)'s
// [[Jr^-1, -Jr^-1 Q Jr^-1], [0, Jr^-1]]; k: So3Coefficients at the rotation w.
template <class Scalar, int C> TG_HD void dexp_inverse_matrix(int n, const Scalar* theta, const So3Coefficients<Scalar>& k, Scalar* Dx) {
  const Vec3<Scalar> w = load3(theta + n - 3);
  const Mat3<Scalar> Ji = so3_terms(w, Scalar(0.5), k.beta);
  for (int e = 0; e < n * n; ++e) Dx[e] = Scalar(0);
  put3(Dx, n, n - 3, n - 3, Ji);
  if (n != 6) return;
  if constexpr (C == MUJOCO) {
    put3(Dx, 6, 0, 0, identity3<Scalar>());
  } else {
    const Mat3<Scalar> JQJ = mul(Ji, mul(se3_coupling(load3(theta), w, k), Ji));
    put3(Dx, 6, 0, 0, Ji);
    for (int r = 0; r < 3; ++r)
      for (int m = 0; m < 3; ++m) Dx[6 * r + 3 + m] = Scalar(-1) * JQJ.m[3 * r + m];
  }
}

// A quaternion read normalised, xyzw: a norm below QUAT_MIN_NORM is the identity, a NaN or infinite one NaN in
// every component (q / inf would leave finite zeros beside an infinite entry's NaN). Returns the norm read: 1 for
// the identity.
template <class Scalar> TG_HD Scalar unit_quat(Scalar x, Scalar y, Scalar z, Scalar w, Scalar* out) {
  const Scalar in[4] = {x, y, z, w};
  const Scalar norm = sqrt(x * x + y * y + z * z + w * w);
  const auto zero = norm < Scalar(QUAT_MIN_NORM);
  const Scalar scale = select(norm < Scalar(INFINITY), norm, norm * Scalar(NAN));
  for (int c = 0; c < 4; ++c) out[c] = select(zero, Scalar(c == 3), in[c] / scale);
  return select(zero, Scalar(1), norm);
}

// Where component c of a quaternion's xyzw sits among its four coordinates in layout L (MuJoCo's wxyz).
template <int L> TG_HD_INLINE int quat_slot(int c) { return L == MUJOCO ? (c + 1) & 3 : c; }

// n of a quaternion joint's n x n blocks (6: free, 3: ball), 0 at any other joint.
template <class Robot, class Scalar> TG_HD_INLINE int quaternion_dofs(int jn) {
  const int t = data<Robot, Scalar>().jtype[jn];
  return t == FREE ? 6 : t == BALL ? 3 : 0;
}

// Joint i's part of q' = q (+) u (q in Pinocchio's layout, q' in the convention's) and, at a
// quaternion joint, its n x n blocks Jq, Jv unless Jq is null (n = 3 or 6; returns n, 0 at the other joints).
template <class Robot, class Scalar, int C> TG_HD int integrate_joint(int i, const Scalar* q, const Scalar* u, Scalar* q_next, Scalar* Jq, Scalar* Jv) {
  const auto& d = data<Robot, Scalar>();
  const int qi = d.qi[i], vi = d.vi[i], t = d.jtype[i];
  if (t != FREE && t != BALL) {
    q_next[qi] = q[qi] + u[vi];
    return 0;
  }
  const int n = t == FREE ? 6 : 3, qa = t == FREE ? qi + 3 : qi;
  const Vec3<Scalar> w = load3(u + vi + n - 3);
  const So3Coefficients<Scalar> k = so3_coefficients(w);
  Scalar quat[4], e[4], turned[4];
  unit_quat(q[qa], q[qa + 1], q[qa + 2], q[qa + 3], quat);
  store3(k.sin_half * w, e);
  e[3] = k.cos_half;
  quat_mul(quat, e, turned);
  Mat3<Scalar> Rt, Jr;
  if (Jq) {
    Rt = transpose3(quat_rotation(e[0], e[1], e[2], e[3])), Jr = so3_terms(w, -k.a, k.b);
    for (int r = 0; r < n * n; ++r) Jq[r] = Jv[r] = Scalar(0);
    put3(Jq, n, n - 3, n - 3, Rt);
    put3(Jv, n, n - 3, n - 3, Jr);
  }
  if (t == FREE) {
    const Vec3<Scalar> p = load3(q + qi), ul = load3(u + vi);
    if constexpr (C == MUJOCO) {
      store3(p + ul, q_next + qi);
      if (Jq) put3(Jq, 6, 0, 0, identity3<Scalar>()), put3(Jv, 6, 0, 0, identity3<Scalar>());
    } else {  // M exp6(u): p + R V u_lin, the quaternion kept in the input's hemisphere as Pinocchio's
      const Vec3<Scalar> Vu = mul(so3_terms(w, k.a, k.b), ul);
      store3(p + mul(quat_rotation(quat[0], quat[1], quat[2], quat[3]), Vu), q_next + qi);
      const auto flip = e[3] < Scalar(0);
      for (int c = 0; c < 4; ++c) turned[c] = select(flip, -turned[c], turned[c]);
      if (Jq) {
        put3(Jq, 6, 0, 0, Rt);
        put3(Jq, 6, 0, 3, mul(Rt, skew(Scalar(-1) * Vu)));
        put3(Jv, 6, 0, 0, Jr);
        put3(Jv, 6, 0, 3, se3_coupling(ul, w, k));
      }
    }
  }
  Scalar* out = q_next + qa;
  if constexpr (C == MUJOCO) {  // wxyz
    out[0] = turned[3]; out[1] = turned[0]; out[2] = turned[1]; out[3] = turned[2];
  } else {
    for (int c = 0; c < 4; ++c) out[c] = turned[c];
  }
  return n;
}

// The rotation vector of the shortest rotation of a unit quaternion r (xyzw): 2 atan2(s, w) / s times its vector part,
// s = |xyz|, w >= 0; below s^2 = 1e-4 the factor's series in s / w.
template <class Scalar> TG_HD Vec3<Scalar> log3(const Scalar* r) {
  const auto flip = r[3] < Scalar(0);
  const Scalar m(-1);
  const Scalar x = select(flip, m * r[0], r[0]), y = select(flip, m * r[1], r[1]), z = select(flip, m * r[2], r[2]),
               w = select(flip, m * r[3], r[3]);
  const Scalar s2 = x * x + y * y + z * z;
  const auto small = s2 < Scalar(1e-4);
  const Scalar s = sqrt(select(small, Scalar(1), s2)), r2 = s2 / (w * w);
  const Scalar factor = select(small, Scalar(2) / w * (Scalar(1) - r2 / Scalar(3) + r2 * r2 / Scalar(5)), Scalar(2) * atan2(s, w) / s);
  return v3(factor * x, factor * y, factor * z);
}

// Joint i's part of v = difference(q0, q1), q0 (+) v = q1 with the shortest rotation (q0 in Pinocchio's layout, q1
// and v in the convention's): w = log3(conj(Q0) Q1); a free joint's position (q1 - q0), rotated into q0's frame
// and by Jl(w)^-1 in Pinocchio's convention (log6(M0^-1 M1)).
template <class Robot, class Scalar, int C> TG_HD void difference_joint(int i, const Scalar* q0, const Scalar* q1, Scalar* v) {
  const auto& d = data<Robot, Scalar>();
  const int qi = d.qi[i], vi = d.vi[i], t = d.jtype[i];
  if (t != FREE && t != BALL) {
    const Scalar dq = q1[qi] - q0[qi];
    v[vi] = d.angle[i] ? atan2(sin(dq), cos(dq)) : dq;  // a continuous joint: the shorter way round, as Pinocchio's
    return;
  }
  const int n = t == FREE ? 6 : 3, qa = t == FREE ? qi + 3 : qi;
  Scalar a[4], b[4], r[4];
  unit_quat(q0[qa], q0[qa + 1], q0[qa + 2], q0[qa + 3], a);
  if constexpr (C == MUJOCO)  // wxyz
    unit_quat(q1[qa + 1], q1[qa + 2], q1[qa + 3], q1[qa], b);
  else
    unit_quat(q1[qa], q1[qa + 1], q1[qa + 2], q1[qa + 3], b);
  const Scalar conj[4] = {Scalar(-1) * a[0], Scalar(-1) * a[1], Scalar(-1) * a[2], a[3]};
  quat_mul(conj, b, r);
  const Vec3<Scalar> w = log3(r);
  store3(w, v + vi + n - 3);
  if (t == FREE) {
    const Vec3<Scalar> dp = load3(q1 + qi) - load3(q0 + qi);
    if constexpr (C == MUJOCO) {
      store3(dp, v + vi);
    } else {
      const Mat3<Scalar> Rt = transpose3(quat_rotation(a[0], a[1], a[2], a[3]));
      store3(mul(so3_terms(w, Scalar(-0.5), so3_coefficients(w).beta), mul(Rt, dp)), v + vi);
    }
  }
}

// ---------------------------------------------------------------------------------------------------------------
// Tangent Jacobians and gradients between q's coordinates and its tangent space (torch_grid/space/tangent.py holds
// the same maps in torch). At a quaternion joint, with Q = (xyz, w) xyzw:
//   A(q)    the change of q along a tangent direction: dQ = Q (x) (u, 0) / 2, a free joint's position R u_lin
//           (Pinocchio's local increment) or u_lin (MuJoCo's, world frame);
//   T(q)^T  a tangent gradient carried to q's coordinates through Q's normalisation: the rotation
//           u = 2 vec(conj(Q/|Q|) (x) dQ) / |Q| transposed, R g_lin or g_lin at a free joint's position.
// Every other joint: the identity.
// ---------------------------------------------------------------------------------------------------------------

// A free joint's 3 x 3 blocks of J_q0 that are structurally zero (below the diagonal; and above it in MuJoCo's
// convention): difference_jacobians keeps them exact zeros whatever the others hold.
template <int C> TG_HD bool zero_block(int n, int r, int c) {
  return n == 6 && ((r >= 3 && c < 3) || (C == MUJOCO && r < 3 && c >= 3));
}

// Joint i's part of v = difference(q0, q1) and its tangent Jacobians at a quaternion joint, the n x n blocks J0 = -Jv(v)^-1
// Jq(v) and J1 = Jv(v)^-1 = dexp(v)^-1, from q1 = q0 (+) v (integrate_joint's blocks at v); returns n (3 or 6), or 0 at the
// other joints, whose Jacobians are -1 and 1 (q0 in Pinocchio's layout, q1 and v in the convention's).
template <class Robot, class Scalar, int C>
TG_HD int difference_jacobians(int i, const Scalar* q0, const Scalar* q1, Scalar* v, Scalar* J0, Scalar* J1) {
  Scalar Jq[36], Jv[36], qs[Robot::NQ];
  difference_joint<Robot, Scalar, C>(i, q0, q1, v);
  const int n = integrate_joint<Robot, Scalar, C>(i, q0, v, qs, Jq, Jv);
  if (!n) return 0;
  const Scalar* vj = v + data<Robot, Scalar>().vi[i];
  dexp_inverse_matrix<Scalar, C>(n, vj, so3_coefficients(load3(vj + n - 3)), J1);
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) {
      Scalar s = Scalar(0);
      for (int m = 0; m < n; ++m)
        if (!zero_block<C>(n, r, m) && !zero_block<C>(n, m, c)) s += J1[n * r + m] * Jq[n * m + c];
      J0[n * r + c] = zero_block<C>(n, r, c) ? Scalar(0) : Scalar(-1) * s;
    }
  return n;
}

// Joint i's part of T(q)^T g: a gradient g along the tangent space (the convention's) as a gradient gq in q's coordinates
// (the convention's layout; q's quaternion in layout L). A norm below QUAT_MIN_NORM reads as the identity of norm 1.
template <class Robot, class Scalar, int C, int L> TG_HD void tangent_to_ambient_joint(int i, const Scalar* q, const Scalar* g, Scalar* gq) {
  const auto& d = data<Robot, Scalar>();
  const int qi = d.qi[i], vi = d.vi[i], t = d.jtype[i];
  if (t != FREE && t != BALL) {
    gq[qi] = g[vi];
    return;
  }
  const int qa = t == FREE ? qi + 3 : qi, va = t == FREE ? vi + 3 : vi;
  Scalar u[4];
  const Scalar norm = unit_quat(q[qa + quat_slot<L>(0)], q[qa + quat_slot<L>(1)], q[qa + quat_slot<L>(2)], q[qa + quat_slot<L>(3)], u);
  const Vec3<Scalar> xyz = v3(u[0], u[1], u[2]), ga = load3(g + va);
  const Scalar s = Scalar(2) / norm;
  // d xyz = 2 (w g + xyz x g) / |Q|,  d w = -2 xyz . g / |Q|
  const Vec3<Scalar> dxyz = s * (u[3] * ga + cross(xyz, ga));
  for (int c = 0; c < 3; ++c) gq[qa + quat_slot<C>(c)] = dxyz.x[c];
  gq[qa + quat_slot<C>(3)] = Scalar(-1) * s * dot(xyz, ga);
  if (t == FREE) {
    const Vec3<Scalar> gl = load3(g + vi);
    if constexpr (C == MUJOCO)
      store3(gl, gq + qi);
    else
      store3(mul(quat_rotation(u[0], u[1], u[2], u[3]), gl), gq + qi);
  }
}

// Joint i's part of A(q)^T g: a gradient g in q's coordinates as one along the tangent space, gv (q, g and gv in the
// convention's layout). A's quaternion rows use Q as it is, unnormalised; a free joint's rotation R is Q/|Q|'s.
template <class Robot, class Scalar, int C> TG_HD void ambient_to_tangent_joint(int i, const Scalar* q, const Scalar* g, Scalar* gv) {
  const auto& d = data<Robot, Scalar>();
  const int qi = d.qi[i], vi = d.vi[i], t = d.jtype[i];
  if (t != FREE && t != BALL) {
    gv[vi] = g[qi];
    return;
  }
  const int qa = t == FREE ? qi + 3 : qi, va = t == FREE ? vi + 3 : vi;
  const Vec3<Scalar> xyz = v3(q[qa + quat_slot<C>(0)], q[qa + quat_slot<C>(1)], q[qa + quat_slot<C>(2)]);
  const Vec3<Scalar> gx = v3(g[qa + quat_slot<C>(0)], g[qa + quat_slot<C>(1)], g[qa + quat_slot<C>(2)]);
  const Scalar w = q[qa + quat_slot<C>(3)], gw = g[qa + quat_slot<C>(3)];
  // dxyz = (w u + xyz x u) / 2, dw = -xyz . u / 2, transposed
  store3(Scalar(0.5) * (w * gx + cross(gx, xyz) - gw * xyz), gv + va);
  if (t == FREE) {
    const Vec3<Scalar> gl = load3(g + qi);
    if constexpr (C == MUJOCO) {
      store3(gl, gv + vi);
    } else {
      Scalar u[4];
      unit_quat(xyz.x[0], xyz.x[1], xyz.x[2], w, u);
      store3(mul(transpose3(quat_rotation(u[0], u[1], u[2], u[3])), gl), gv + vi);
    }
  }
}

// The step and its Jacobians, by team t: the rows of qd' a lane each, then, once they are all written, the rows
// of q' a body a lane. On entry the rows of q' hold G (A's first NV rows: da/dq then da/dqd, NV x NV each; B's
// first NV rows: da/dtau), which the rows of qd' are made of before those rows are overwritten; v and acc are
// qd and a in the convention, q in Pinocchio's layout. Outputs: q_next (NQ), qd_next (NV), A (2 NV x 2 NV),
// B (2 NV x NV), row-major; all written when every lane returns.
template <class Robot, class Scalar, int C, class Team = Solo>
TG_HD void euler_step(const Scalar* q, const Scalar* v, const Scalar* acc, Scalar h, int scheme, Scalar* q_next, Scalar* qd_next, Scalar* A, Scalar* B,
                      const Team& t = {}) {
  constexpr int NV = Robot::NV, N2 = 2 * NV;
  const auto& d = data<Robot, Scalar>();
  const Scalar* Gq = A;
  const Scalar* Gv = A + NV * NV;
  const Scalar* Gt = B;
  // qd' = qd + dt a;  dqd'/dz = dt G + [0 I 0], the rows NV.. of A and B
  for (const int r : t.items(0, NV)) {
    qd_next[r] = v[r] + h * acc[r];
    Scalar* Ar = A + N2 * (NV + r);
    Scalar* Br = B + NV * (NV + r);
    for (int c = 0; c < NV; ++c) {
      Ar[c] = h * Gq[NV * r + c];
      Ar[NV + c] = h * Gv[NV * r + c] + (c == r ? Scalar(1) : Scalar(0));
      Br[c] = h * Gt[NV * r + c];
    }
  }
  t.sync();
  // q' = q (+) u, u = dt w;  dq'/dz = Jq [I 0 0] + dt Jv dw/dz, dw/dz = dqd'/dz (semi-implicit) or [0 I 0]
  Scalar u[NV];
  for (int r = 0; r < NV; ++r) u[r] = h * (scheme ? qd_next[r] : v[r]);
  for (const int i : t.items(0, Robot::NB)) {
    Scalar Jq[36], Jv[36];
    const int n = integrate_joint<Robot, Scalar, C>(i, q, u, q_next, Jq, Jv);
    const int vi = d.vi[i], rows = n ? n : d.nvj[i];
    for (int a = 0; a < rows; ++a) {
      Scalar* Ar = A + N2 * (vi + a);
      Scalar* Br = B + NV * (vi + a);
      for (int c = 0; c < N2; ++c) Ar[c] = Scalar(0);
      for (int c = 0; c < NV; ++c) Br[c] = Scalar(0);
      for (int b = 0; b < (n ? n : 1); ++b) {
        const Scalar jv = h * (n ? Jv[n * a + b] : Scalar(1)), jq = n ? Jq[n * a + b] : Scalar(1);
        const int row = n ? vi + b : vi + a;
        Ar[row] += jq;
        if (scheme) {
          const Scalar* Dr = A + N2 * (NV + row);
          const Scalar* Er = B + NV * (NV + row);
          for (int c = 0; c < N2; ++c) Ar[c] += jv * Dr[c];
          for (int c = 0; c < NV; ++c) Br[c] += jv * Er[c];
        } else {
          Ar[NV + row] += jv;
        }
      }
    }
  }
  t.sync();
}

// A team's shared workspace for step_derivatives: forward_dynamics_derivatives's or, with the damping implicit,
// damped_dynamics_derivatives's; qd and a in the convention, and tau + p.
template <class Robot, class Scalar> struct StepDerivativesTeamWork {
  union {
    ForwardDynamicsDerivativesTeamWork<Robot, Scalar> fd;
    FactoredDynamicsTeamWork<Robot, Scalar> damped;
  };
  Scalar v[Robot::NV], acc[Robot::NV], tau_p[Robot::NV];
};

// An Euler step's Jacobians by team t: G by forward_dynamics_derivatives's team path at tau (+ p with passive 1,
// the derivatives of ID - p then), finished as -M^-1 dtau/dx a column a lane; or, with passive 2, by
// damped_dynamics_derivatives's, H = M + dt D in B's last NV rows until euler_step writes them. Then euler_step.
// All written when every lane returns.
template <class Robot, class Scalar, int C, class Team>
TG_HD void euler_step_derivatives(const Team& t, StepDerivativesTeamWork<Robot, Scalar>& w, const Conv<Robot, Scalar, C>& cv, const Scalar* q,
                                  const Scalar* qd, const Scalar* tau, const Scalar* fext, Scalar h, int scheme, int passive,
                                  Scalar* q_next, Scalar* qd_next, Scalar* A, Scalar* B, const InertialParameters<Robot, Scalar>& pi = {}) {
  constexpr int NV = Robot::NV;
  Scalar* const dq = A;
  Scalar* const dqd = A + NV * NV;
  const Scalar* qdd = w.fd.qdd;
  bool damped = false;
  if constexpr (Robot::PASSIVE) {  // (not compiled for a robot without passive forces, whose passive is 0)
    if (passive == 2) {
      damped_dynamics_derivatives<Robot, Scalar>(t, w.damped, cv, q, qd, tau, fext, h, dq, dqd, B, B + NV * NV, pi);
      qdd = w.damped.rnea.qdd;
      damped = true;
    }
  }
  if (!damped) {
    if (passive && t.leader()) {
      for (int k = 0; k < NV; ++k) w.tau_p[k] = tau[k];
      add_passive<Robot, Scalar>(q, qd, w.tau_p);
    }
    t.sync();
    forward_dynamics_derivatives<Robot, Scalar>(t, w.fd, q, qd, passive ? w.tau_p : tau, fext, cv, dq, dqd, B, pi);
    if (passive && t.leader()) add_passive_diagonals<Robot, Scalar>(dq, dqd);
    t.sync();
    // dq, dqd <- -M^-1 dq, -M^-1 dqd (M^-1 in B's first rows): column c of both by c's lane
    for (const int c : t.items(0, NV)) {
      Scalar y[NV];
      Scalar* const Xs[2] = {dq, dqd};
      for (Scalar* X : Xs) {
        for (int r = 0; r < NV; ++r) {
          Scalar acc = Scalar(0);
          for (int k = 0; k < NV; ++k) acc += B[NV * r + k] * X[NV * k + c];
          y[r] = -acc;
        }
        for (int r = 0; r < NV; ++r) X[NV * r + c] = y[r];
      }
    }
  }
  if (t.leader()) {
    for (int k = 0; k < NV; ++k) w.v[k] = qd[k], w.acc[k] = qdd[k];
    cv.velocity_out(w.v);
    cv.acceleration_out(qd, w.acc);
  }
  t.sync();
  euler_step<Robot, Scalar, C>(q, w.v, w.acc, h, scheme, q_next, qd_next, A, B, t);
}

}  // namespace tg
