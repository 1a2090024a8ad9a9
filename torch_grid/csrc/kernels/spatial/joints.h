// Joint models and the kinematic forward pass shared by every algorithm.
//
// A generated robot header provides a type `M` with compile-time sizes (NB bodies, NQ, NV, NF
// frames, ND tree levels, NFREE free joints, BALLS) and `data<M, S>()` (spatial.h), the tree, axes, placements and inertias as constants.
// Body i is moved by joint i; parent[i] < i (depth-first order), -1 is the world.
#pragma once

#include "kernels/spatial/spatial.h"
#include "kernels/spatial/trig.h"

namespace tg {

// A ball joint is a free joint without translation: q a quaternion, qd the local angular velocity.
enum JointType : int { FREE = 0, REVOLUTE = 1, PRISMATIC = 2, BALL = 3 };

template <class S> struct CosSin {
  S c, s;
};
// A revolute angle's cosine and sine: computed when asked (one library call), or taken from a pass
// that computed every joint's at once (joint_sincos).
template <class S> struct TrigOf {
  const S* t;
  TG_HD CosSin<S> operator()() const { return {cos(*t), sin(*t)}; }
};
template <class S> struct TrigFrom {
  S c, s;
  TG_HD CosSin<S> operator()() const { return {c, s}; }
};

// Placement of joint i's frame in its parent's frame, liMi = placement * Mj(q). q is Pinocchio's
// layout: a free joint reads [pos(3), quat xyzw(4)], a ball joint [quat xyzw(4)]; trig() gives a revolute joint's cosine and
// sine. Always inlined where i is a constant (the forward kinematics), so that it folds to the
// joint's own case.
template <class M, class S, class Trig> TG_HD_INLINE SE3<S> joint_placement_inline(int i, const S* q, const Trig& trig) {
  const auto& d = data<M, S>();
  SE3<S> X;
  for (int k = 0; k < 9; ++k) X.R.m[k] = S(d.R[i][k]);
  X.p = v3(S(d.p[i][0]), S(d.p[i][1]), S(d.p[i][2]));
  const S* qi = q + d.qi[i];
  const int k = d.axis_index[i];  // 0, 1, 2 for a cardinal axis, -1 otherwise
  switch (d.jtype[i]) {
    case FREE:
      X.p = X.p + mul(X.R, load3(qi));
      X.R = mul(X.R, quat_rotation(qi[3], qi[4], qi[5], qi[6]));
      break;
    case BALL:
      X.R = mul(X.R, quat_rotation(qi[0], qi[1], qi[2], qi[3]));
      break;
    case REVOLUTE: {
      const CosSin<S> cs = trig();
      const S c = cs.c, s = cs.s;
      if (k >= 0) {
        // R Rot(e_k, t) mixes only the two columns other than k.
        const int a = (k + 1) % 3, b = (k + 2) % 3;
        for (int r = 0; r < 3; ++r) {
          const S ra = X.R.m[3 * r + a], rb = X.R.m[3 * r + b];
          X.R.m[3 * r + a] = c * ra + s * rb;
          X.R.m[3 * r + b] = c * rb - s * ra;
        }
      } else {
        X.R = mul(X.R, axis_rotation(v3(S(d.axis[i][0]), S(d.axis[i][1]), S(d.axis[i][2])), c, s));
      }
      break;
    }
    default:  // PRISMATIC
      X.p = X.p + mul(X.R, qi[0] * v3(S(d.axis[i][0]), S(d.axis[i][1]), S(d.axis[i][2])));
      break;
  }
  return X;
}

template <class M, class S> TG_HD SE3<S> joint_placement(int i, const S* q) {
  return joint_placement_inline<M, S>(i, q, TrigOf<S>{q + data<M, S>().qi[i]});
}

// sin and cos of every revolute joint's angle (0 for the other joints), computed together (trig.h).
template <class M, class S> TG_HD void joint_sincos(const S* q, S* s, S* c) {
  const auto& d = data<M, S>();
  S t[M::NB];
  for (int i = 0; i < M::NB; ++i) t[i] = d.jtype[i] == REVOLUTE ? q[d.qi[i]] : S(0);
  sincos_n(M::NB, t, s, c);
}

// Column k of joint i's motion subspace S_i, in the joint frame.
template <class M, class S> TG_HD Sv<S> joint_axis(int i, int k) {
  const auto& d = data<M, S>();
  Sv<S> s = sv_zero<S>();
  switch (d.jtype[i]) {
    case FREE: s.v[k] = S(1); break;
    case BALL: s.v[3 + k] = S(1); break;
    case REVOLUTE: for (int c = 0; c < 3; ++c) s.v[3 + c] = S(d.axis[i][c]); break;
    default: for (int c = 0; c < 3; ++c) s.v[c] = S(d.axis[i][c]); break;
  }
  return s;
}

// Joint velocity vJ = S_i qd_i in the joint frame.
template <class M, class S> TG_HD Sv<S> joint_motion(int i, const S* qd) {
  const auto& d = data<M, S>();
  const S* x = qd + d.vi[i];
  if (d.jtype[i] == FREE) return {{x[0], x[1], x[2], x[3], x[4], x[5]}};
  if (d.jtype[i] == BALL) return {{S(0), S(0), S(0), x[0], x[1], x[2]}};
  return x[0] * joint_axis<M, S>(i, 0);
}

// X S_ik: joint i's k-th axis moved by a placement X (world placements, mostly). A free or ball
// joint's axes and a cardinal revolute or prismatic axis are a column of X.R, without a product by S.
template <class M, class S> TG_HD Sv<S> placed_axis(const SE3<S>& X, int i, int k) {
  const auto& d = data<M, S>();
  const int t = d.jtype[i], c = t == FREE ? k % 3 : t == BALL ? k : d.axis_index[i];
  if (c < 0) return act_motion(X, joint_axis<M, S>(i, k));
  const Vec3<S> e = v3(X.R.m[c], X.R.m[3 + c], X.R.m[6 + c]), zero = v3(S(0), S(0), S(0));
  const bool rotation = t == REVOLUTE || t == BALL || (t == FREE && k >= 3);
  return rotation ? sv(cross(X.p, e), e) : sv(e, zero);
}

// S_i^T f: the generalized force of joint i from a spatial force f in its frame.
template <class M, class S> TG_HD void joint_project(int i, const Sv<S>& f, S* out) {
  const auto& d = data<M, S>();
  for (int k = 0; k < d.nvj[i]; ++k) out[d.vi[i] + k] = dot(joint_axis<M, S>(i, k), f);
}

// Inertia of body i about its joint frame origin.
template <class M, class S> TG_HD Inertia<S> body_inertia(int i) {
  const auto& d = data<M, S>();
  Inertia<S> I{S(d.mass[i]), v3(S(d.h[i][0]), S(d.h[i][1]), S(d.h[i][2])), {}};
  for (int k = 0; k < 9; ++k) I.Io.m[k] = S(d.Io[i][k]);
  return I;
}

// Spatial gravity acceleration seen as a base acceleration: a_0 = -g.
template <class M, class S> TG_HD Sv<S> base_acceleration() {
  const auto& d = data<M, S>();
  return {{-S(d.gravity[0]), -S(d.gravity[1]), -S(d.gravity[2]), S(0), S(0), S(0)}};
}

// Forward kinematics: local placements liMi and world placements oMi of every body.
template <class M, class S> TG_HD void forward_kinematics(const S* q, SE3<S>* liMi, SE3<S>* oMi) {
  const auto& d = data<M, S>();
#if defined(__CUDACC__)
  for (int i = 0; i < M::NB; ++i) {
    liMi[i] = joint_placement<M, S>(i, q);
    oMi[i] = d.parent[i] < 0 ? liMi[i] : oMi[d.parent[i]] * liMi[i];
  }
#else
  S s[M::NB], c[M::NB];
  joint_sincos<M, S>(q, s, c);
  // Unrolled, each body's placement is specialised to its constant joint (type, axis, placement):
  // no switch, and the products by identity or zero entries fold away (10-25% of crba).
#pragma GCC unroll 128
  for (int i = 0; i < M::NB; ++i) {
    liMi[i] = joint_placement_inline<M, S>(i, q, TrigFrom<S>{c[i], s[i]});
    oMi[i] = d.parent[i] < 0 ? liMi[i] : oMi[d.parent[i]] * liMi[i];
  }
#endif
}

// World placements oMi of the bodies of a support chain, chain[0] a frame's body and chain[n - 1]
// a root; the other entries of oMi are left alone.
template <class M, class S> TG_HD void chain_placements(const S* q, const int* chain, int n, SE3<S>* oMi) {
  const auto& d = data<M, S>();
#if defined(__CUDACC__)
  for (int k = n - 1; k >= 0; --k) {
    const SE3<S> liMi = joint_placement<M, S>(chain[k], q);
    oMi[chain[k]] = k == n - 1 ? liMi : oMi[chain[k + 1]] * liMi;
  }
#else
  // The revolute joints' angles, in chain order, then taken back from the root down.
  S t[M::NB], s[M::NB], c[M::NB];
  int m = 0;
  for (int k = 0; k < n; ++k)
    if (d.jtype[chain[k]] == REVOLUTE) t[m++] = q[d.qi[chain[k]]];
  if (m > 0) sincos_n(m, t, s, c);
  for (int k = n - 1; k >= 0; --k) {
    const bool revolute = d.jtype[chain[k]] == REVOLUTE;
    m -= revolute;
    const TrigFrom<S> trig{revolute ? c[m] : S(1), revolute ? s[m] : S(0)};
    const SE3<S> liMi = joint_placement_inline<M, S>(chain[k], q, trig);
    oMi[chain[k]] = k == n - 1 ? liMi : oMi[chain[k + 1]] * liMi;
  }
#endif
}

// World placement of frame f.
template <class M, class S> TG_HD SE3<S> frame_placement(int f, const SE3<S>* oMi) {
  const auto& d = data<M, S>();
  SE3<S> X;
  for (int k = 0; k < 9; ++k) X.R.m[k] = S(d.fR[f][k]);
  X.p = v3(S(d.fp[f][0]), S(d.fp[f][1]), S(d.fp[f][2]));
  return d.fparent[f] < 0 ? X : oMi[d.fparent[f]] * X;
}

// Spatial velocity of every body in its joint frame (NB x 6): v_i = X_i v_parent + S_i qd_i.
template <class M, class S> TG_HD void body_velocities(const S* q, const S* qd, S* out) {
  const auto& d = data<M, S>();
  Sv<S> v[M::NB];
  for (int i = 0; i < M::NB; ++i) {
    const Sv<S> vJ = joint_motion<M, S>(i, qd);
    v[i] = d.parent[i] < 0 ? vJ : actinv_motion(joint_placement<M, S>(i, q), v[d.parent[i]]) + vJ;
    for (int k = 0; k < 6; ++k) out[6 * i + k] = v[i].v[k];
  }
}

// Storage for what a forward pass leaves a body's children (velocity, acceleration): on a GPU thread
// one slot per tree level, since in depth-first order a body's ancestors hold the levels above its
// own (a small stack); on the host one per body, which the compiler keeps faster.
template <class M> struct Levels {
#if defined(__CUDA_ARCH__)
  static constexpr int N = M::ND;
  template <class S> TG_HD static int of(const S& d, int i) { return d.depth[i]; }
  template <class S> TG_HD static int parent(const S& d, int i) { return d.depth[i] - 1; }
#else
  static constexpr int N = M::NB;
  template <class S> TG_HD static int of(const S&, int i) { return i; }
  template <class S> TG_HD static int parent(const S& d, int i) { return d.parent[i]; }
#endif
};

// Joint placements liMi: place(i) computes one in a forward pass and [i] reads it again in a later
// pass; kept on the host, rebuilt from q on a GPU thread, where the stack they would take costs
// more than recomputing them.
template <class M, class S> struct JointPlacements {
#if defined(__CUDA_ARCH__)
  const S* q;
  TG_HD explicit JointPlacements(const S* q_) : q(q_) {}
  TG_HD SE3<S> place(int i) { return joint_placement<M, S>(i, q); }
  TG_HD SE3<S> operator[](int i) const { return joint_placement<M, S>(i, q); }
#else
  const S* q;
  SE3<S> X[M::NB];
  TG_HD explicit JointPlacements(const S* q_) : q(q_) {}
  TG_HD const SE3<S>& place(int i) { return X[i] = joint_placement<M, S>(i, q); }
  TG_HD const SE3<S>& operator[](int i) const { return X[i]; }
#endif
};

// The first named pass of an op that runs several algorithms on one sample: world placements oMi
// and joint placements liMi (local(i)), computed once from q and read by each algorithm in turn.
// A GPU thread keeps only oMi (its stack) and rebuilds liMi = oMi[parent]^-1 oMi[i], without
// trigonometry.
template <class M, class S> struct Placements {
  SE3<S> oMi[M::NB];
#if defined(__CUDA_ARCH__)
  TG_HD explicit Placements(const S* q) {
    const auto& d = data<M, S>();
    for (int i = 0; i < M::NB; ++i) {
      const SE3<S> X = joint_placement<M, S>(i, q);
      oMi[i] = d.parent[i] < 0 ? X : oMi[d.parent[i]] * X;
    }
  }
  TG_HD SE3<S> local(int i) const {
    const int p = data<M, S>().parent[i];
    return p < 0 ? oMi[i] : inverse_times(oMi[p], oMi[i]);
  }
#else
  SE3<S> liMi[M::NB];
  TG_HD explicit Placements(const S* q) { forward_kinematics<M, S>(q, liMi, oMi); }
  TG_HD const SE3<S>& local(int i) const { return liMi[i]; }
#endif
  // JointPlacements' interface: place(i) in a forward pass, [i] later.
  TG_HD decltype(auto) place(int i) const { return local(i); }
  TG_HD decltype(auto) operator[](int i) const { return local(i); }
};

}  // namespace tg
