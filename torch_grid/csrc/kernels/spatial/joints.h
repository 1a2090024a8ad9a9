// Joint models and the kinematic forward pass shared by every algorithm.
//
// A generated robot header provides a type `M` with compile-time sizes (NB bodies, NQ, NV, NF
// frames, ND tree levels, NFREE free joints, BALLS) and `data<Robot, Scalar>()` (spatial.h), the tree, axes, placements and inertias as constants.
// Body i is moved by joint i; parent[i] < i (depth-first order), -1 is the world.
#pragma once

#include "kernels/spatial/spatial.h"
#include "kernels/spatial/team.h"
#include "kernels/spatial/trig.h"

namespace tg {

// A ball joint is a free joint without translation: q a quaternion, qd the local angular velocity.
enum JointType : int { FREE = 0, REVOLUTE = 1, PRISMATIC = 2, BALL = 3 };

template <class Scalar> struct CosSin {
  Scalar c, s;
};
// A revolute angle's cosine and sine: computed when asked (sincos_n of one angle: the same values as a
// pass over every joint's, joint_sincos, and on vector lanes as on one sample), or taken from that pass.
template <class Scalar> struct TrigOf {
  const Scalar* t;
  TG_HD CosSin<Scalar> operator()() const {
    CosSin<Scalar> cs;
    sincos_n(1, t, &cs.s, &cs.c);
    return cs;
  }
};
template <class Scalar> struct TrigFrom {
  Scalar c, s;
  TG_HD CosSin<Scalar> operator()() const { return {c, s}; }
};

// Placement of joint i's frame in its parent's frame, liMi = placement * Mj(q). q is Pinocchio's
// layout: a free joint reads [pos(3), quat xyzw(4)], a ball joint [quat xyzw(4)]; trig() gives a revolute joint's cosine and
// sine. Always inlined where i is a constant (the forward kinematics), so that it folds to the
// joint's own case.
template <class Robot, class Scalar, class Trig> TG_HD_INLINE SE3<Scalar> joint_placement_inline(int i, const Scalar* q, const Trig& trig) {
  const auto& d = data<Robot, Scalar>();
  SE3<Scalar> X;
  for (int k = 0; k < 9; ++k) X.R.m[k] = Scalar(d.R[i][k]);
  X.p = v3(Scalar(d.p[i][0]), Scalar(d.p[i][1]), Scalar(d.p[i][2]));
  const Scalar* qi = q + d.qi[i];
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
      const CosSin<Scalar> cs = trig();
      const Scalar c = cs.c, s = cs.s;
      if (k >= 0) {
        // R Rot(e_k, t) mixes only the two columns other than k.
        const int a = (k + 1) % 3, b = (k + 2) % 3;
        for (int r = 0; r < 3; ++r) {
          const Scalar ra = X.R.m[3 * r + a], rb = X.R.m[3 * r + b];
          X.R.m[3 * r + a] = c * ra + s * rb;
          X.R.m[3 * r + b] = c * rb - s * ra;
        }
      } else {
        X.R = mul(X.R, axis_rotation(v3(Scalar(d.axis[i][0]), Scalar(d.axis[i][1]), Scalar(d.axis[i][2])), c, s));
      }
      break;
    }
    default:  // PRISMATIC
      X.p = X.p + mul(X.R, qi[0] * v3(Scalar(d.axis[i][0]), Scalar(d.axis[i][1]), Scalar(d.axis[i][2])));
      break;
  }
  return X;
}

template <class Robot, class Scalar> TG_HD SE3<Scalar> joint_placement(int i, const Scalar* q) {
  return joint_placement_inline<Robot, Scalar>(i, q, TrigOf<Scalar>{q + data<Robot, Scalar>().qi[i]});
}

// sin and cos of every revolute joint's angle (0 for the other joints), computed together (trig.h).
template <class Robot, class Scalar> TG_HD void joint_sincos(const Scalar* q, Scalar* s, Scalar* c) {
  const auto& d = data<Robot, Scalar>();
  Scalar t[Robot::NB];
  for (int i = 0; i < Robot::NB; ++i) t[i] = d.jtype[i] == REVOLUTE ? q[d.qi[i]] : Scalar(0);
  sincos_n(Robot::NB, t, s, c);
}

// Column k of joint i's motion subspace S_i, in the joint frame.
template <class Robot, class Scalar> TG_HD Sv<Scalar> joint_axis(int i, int k) {
  const auto& d = data<Robot, Scalar>();
  Sv<Scalar> s = sv_zero<Scalar>();
  switch (d.jtype[i]) {
    case FREE: s.v[k] = Scalar(1); break;
    case BALL: s.v[3 + k] = Scalar(1); break;
    case REVOLUTE: for (int c = 0; c < 3; ++c) s.v[3 + c] = Scalar(d.axis[i][c]); break;
    default: for (int c = 0; c < 3; ++c) s.v[c] = Scalar(d.axis[i][c]); break;
  }
  return s;
}

// Joint velocity vJ = S_i qd_i in the joint frame.
template <class Robot, class Scalar> TG_HD Sv<Scalar> joint_motion(int i, const Scalar* qd) {
  const auto& d = data<Robot, Scalar>();
  const Scalar* x = qd + d.vi[i];
  if (d.jtype[i] == FREE) return {{x[0], x[1], x[2], x[3], x[4], x[5]}};
  if (d.jtype[i] == BALL) return {{Scalar(0), Scalar(0), Scalar(0), x[0], x[1], x[2]}};
  return x[0] * joint_axis<Robot, Scalar>(i, 0);
}

// Joint i's k-th axis as a column of its frame's rotation: a free or ball joint's axes and a cardinal
// revolute or prismatic axis are one (column c, turning or sliding along it); c < 0 for any other axis.
struct AxisColumn {
  int c;
  bool rotation;
};
template <class Robot, class Scalar> TG_HD_INLINE AxisColumn axis_column(int i, int k) {
  const auto& d = data<Robot, Scalar>();
  const int t = d.jtype[i];
  return {t == FREE ? k % 3 : t == BALL ? k : d.axis_index[i], t == REVOLUTE || t == BALL || (t == FREE && k >= 3)};
}

// X S_ik: joint i's k-th axis moved by a placement X (world placements, mostly); a column of X.R where
// axis_column finds one, without a product by S.
template <class Robot, class Scalar> TG_HD_INLINE Sv<Scalar> placed_axis(const SE3<Scalar>& X, int i, int k) {
  const AxisColumn a = axis_column<Robot, Scalar>(i, k);
  if (a.c < 0) return act_motion(X, joint_axis<Robot, Scalar>(i, k));
  const int c = a.c;
  const Vec3<Scalar> e = v3(X.R.m[c], X.R.m[3 + c], X.R.m[6 + c]), zero = v3(Scalar(0), Scalar(0), Scalar(0));
  return a.rotation ? sv(cross(X.p, e), e) : sv(e, zero);
}

// S_i^T f: the generalized force of joint i from a spatial force f in its frame.
template <class Robot, class Scalar> TG_HD void joint_project(int i, const Sv<Scalar>& f, Scalar* out) {
  const auto& d = data<Robot, Scalar>();
  for (int k = 0; k < d.nvj[i]; ++k) out[d.vi[i] + k] = dot(joint_axis<Robot, Scalar>(i, k), f);
}

// The bodies' inertial parameters an algorithm computes with: the robot's constants, or one sample's
// pi (NB x 10) when given, each row in Pinocchio's order [m, h = m c, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]
// with c the centre of mass and I the rotational inertia about the joint frame origin. The algorithms
// take it last, defaulting to the constants.
template <class Robot, class Scalar> struct InertialParameters {
  const Scalar* pi = nullptr;

  // Inertia of body i about its joint frame origin.
  TG_HD Inertia<Scalar> operator[](int i) const {
    if (pi) {
      const Scalar* p = pi + 10 * i;
      return {p[0], v3(p[1], p[2], p[3]), {{p[4], p[5], p[7], p[5], p[6], p[8], p[7], p[8], p[9]}}};
    }
    const auto& d = data<Robot, Scalar>();
    Inertia<Scalar> I{Scalar(d.mass[i]), v3(Scalar(d.h[i][0]), Scalar(d.h[i][1]), Scalar(d.h[i][2])), {}};
    for (int k = 0; k < 9; ++k) I.Io.m[k] = Scalar(d.Io[i][k]);
    return I;
  }
  TG_HD Scalar mass(int i) const { return pi ? pi[10 * i] : Scalar(data<Robot, Scalar>().mass[i]); }
  // First moment h = m c of body i, in its joint frame.
  TG_HD Vec3<Scalar> moment(int i) const {
    if (pi) return v3(pi[10 * i + 1], pi[10 * i + 2], pi[10 * i + 3]);
    const auto& d = data<Robot, Scalar>();
    return v3(Scalar(d.h[i][0]), Scalar(d.h[i][1]), Scalar(d.h[i][2]));
  }
  TG_HD Scalar total_mass() const {
    Scalar m = 0;
    for (int i = 0; i < Robot::NB; ++i) m += mass(i);
    return m;
  }
};

// Spatial gravity acceleration seen as a base acceleration: a_0 = -g.
template <class Robot, class Scalar> TG_HD Sv<Scalar> base_acceleration() {
  const auto& d = data<Robot, Scalar>();
  return {{-Scalar(d.gravity[0]), -Scalar(d.gravity[1]), -Scalar(d.gravity[2]), Scalar(0), Scalar(0), Scalar(0)}};
}

// Forward kinematics: local placements liMi and world placements oMi of every body.
template <class Robot, class Scalar> TG_HD void forward_kinematics(const Scalar* q, SE3<Scalar>* liMi, SE3<Scalar>* oMi) {
  const auto& d = data<Robot, Scalar>();
#if defined(__CUDACC__) || TG_DEVICE_PATH
  for (int i = 0; i < Robot::NB; ++i) {
    liMi[i] = joint_placement<Robot, Scalar>(i, q);
    oMi[i] = d.parent[i] < 0 ? liMi[i] : oMi[d.parent[i]] * liMi[i];
  }
#else
  Scalar s[Robot::NB], c[Robot::NB];
  joint_sincos<Robot, Scalar>(q, s, c);
  // Unrolled, each body's placement is specialised to its constant joint (type, axis, placement):
  // no switch, and the products by identity or zero entries fold away (10-25% of crba).
#pragma GCC unroll 128
  for (int i = 0; i < Robot::NB; ++i) {
    liMi[i] = joint_placement_inline<Robot, Scalar>(i, q, TrigFrom<Scalar>{c[i], s[i]});
    oMi[i] = d.parent[i] < 0 ? liMi[i] : oMi[d.parent[i]] * liMi[i];
  }
#endif
}

// World placements oMi of the bodies of a support chain, chain[0] a frame's body and chain[n - 1]
// a root; the other entries of oMi are left alone.
template <class Robot, class Scalar> TG_HD void chain_placements(const Scalar* q, const int* chain, int n, SE3<Scalar>* oMi) {
  const auto& d = data<Robot, Scalar>();
#if defined(__CUDACC__) || TG_DEVICE_PATH
  for (int k = n - 1; k >= 0; --k) {
    const SE3<Scalar> liMi = joint_placement<Robot, Scalar>(chain[k], q);
    oMi[chain[k]] = k == n - 1 ? liMi : oMi[chain[k + 1]] * liMi;
  }
#else
  // The revolute joints' angles, in chain order, then taken back from the root down.
  Scalar t[Robot::NB], s[Robot::NB], c[Robot::NB];
  int m = 0;
  for (int k = 0; k < n; ++k)
    if (d.jtype[chain[k]] == REVOLUTE) t[m++] = q[d.qi[chain[k]]];
  if (m > 0) sincos_n(m, t, s, c);
  for (int k = n - 1; k >= 0; --k) {
    const bool revolute = d.jtype[chain[k]] == REVOLUTE;
    m -= revolute;
    const TrigFrom<Scalar> trig{revolute ? c[m] : Scalar(1), revolute ? s[m] : Scalar(0)};
    const SE3<Scalar> liMi = joint_placement_inline<Robot, Scalar>(chain[k], q, trig);
    oMi[chain[k]] = k == n - 1 ? liMi : oMi[chain[k + 1]] * liMi;
  }
#endif
}

// World placement of frame f.
template <class Robot, class Scalar> TG_HD SE3<Scalar> frame_placement(int f, const SE3<Scalar>* oMi) {
  const auto& d = data<Robot, Scalar>();
  SE3<Scalar> X;
  for (int k = 0; k < 9; ++k) X.R.m[k] = Scalar(d.fR[f][k]);
  X.p = v3(Scalar(d.fp[f][0]), Scalar(d.fp[f][1]), Scalar(d.fp[f][2]));
  return d.fparent[f] < 0 ? X : oMi[d.fparent[f]] * X;
}

// Spatial velocity of every body in its joint frame (NB x 6): v_i = X_i v_parent + S_i qd_i.
template <class Robot, class Scalar> TG_HD void body_velocities(const Scalar* q, const Scalar* qd, Scalar* out) {
  const auto& d = data<Robot, Scalar>();
  Sv<Scalar> v[Robot::NB];
  for (int i = 0; i < Robot::NB; ++i) {
    const Sv<Scalar> vJ = joint_motion<Robot, Scalar>(i, qd);
    v[i] = d.parent[i] < 0 ? vJ : actinv_motion(joint_placement<Robot, Scalar>(i, q), v[d.parent[i]]) + vJ;
    for (int k = 0; k < 6; ++k) out[6 * i + k] = v[i].v[k];
  }
}

// Storage for what a forward pass leaves a body's children (velocity, acceleration): on a GPU thread
// one slot per tree level, since in depth-first order a body's ancestors hold the levels above its
// own (a small stack); on the host one per body, which the compiler keeps faster. A workspace the
// host sizes for a GPU (a team's, in shared memory) asks for ByDepth itself: a CUDA unit's host pass
// has TG_DEVICE_PATH 0, and would count one slot per body.
template <class Robot, bool ByDepth = TG_DEVICE_PATH != 0> struct Levels {
  static constexpr int N = Robot::ND;
  template <class Scalar> TG_HD static int of(const Scalar& d, int i) { return d.depth[i]; }
  template <class Scalar> TG_HD static int parent(const Scalar& d, int i) { return d.depth[i] - 1; }
};
template <class Robot> struct Levels<Robot, false> {
  static constexpr int N = Robot::NB;
  template <class Scalar> TG_HD static int of(const Scalar&, int i) { return i; }
  template <class Scalar> TG_HD static int parent(const Scalar& d, int i) { return d.parent[i]; }
};

// Joint placements liMi: place(i) computes one in a forward pass and [i] reads it again in a later
// pass; kept on the host, rebuilt from q on a GPU thread, where the stack they would take costs
// more than recomputing them.
template <class Robot, class Scalar> struct JointPlacements {
#if TG_DEVICE_PATH
  const Scalar* q;
  TG_HD explicit JointPlacements(const Scalar* q_) : q(q_) {}
  TG_HD SE3<Scalar> place(int i) { return joint_placement<Robot, Scalar>(i, q); }
  TG_HD SE3<Scalar> operator[](int i) const { return joint_placement<Robot, Scalar>(i, q); }
#else
  const Scalar* q;
  SE3<Scalar> X[Robot::NB];
  TG_HD explicit JointPlacements(const Scalar* q_) : q(q_) {}
  TG_HD const SE3<Scalar>& place(int i) { return X[i] = joint_placement<Robot, Scalar>(i, q); }
  TG_HD const SE3<Scalar>& operator[](int i) const { return X[i]; }
#endif
};

// World placements oMi (NB) from q, body after body, each joint placement built as it is needed.
template <class Robot, class Scalar> TG_HD void world_placements(const Scalar* q, SE3<Scalar>* oMi) {
  const auto& d = data<Robot, Scalar>();
  for (int i = 0; i < Robot::NB; ++i) {
    const SE3<Scalar> X = joint_placement<Robot, Scalar>(i, q);
    oMi[i] = d.parent[i] < 0 ? X : oMi[d.parent[i]] * X;
  }
}

// The body whose joint owns dof c (bodies own contiguous, ascending dof ranges).
template <class Robot, class Scalar> TG_HD_INLINE int dof_body(int c) {
  const auto& d = data<Robot, Scalar>();
  int b = 0;
  while (d.vi[b] + d.nvj[b] <= c) ++b;
  return b;
}

// Per-body quantities summed over subtrees by team t, entry by entry: each of the n entries (entry(i, e), a
// reference into body i's) by one lane over every body, leaves first.
template <class Robot, class Scalar, class Team, class Entry> TG_HD void subtree_entry_sums(const Team& t, int n, Entry&& entry) {
  const auto& d = data<Robot, Scalar>();
  for (const int e : t.items(0, n))
    for (int i = Robot::NB - 1; i > 0; --i)
      if (d.parent[i] >= 0) entry(d.parent[i], e) += entry(i, e);
}

// The same by team t: each lane its bodies' joint placements (their trigonometry), then the leader composes them
// down the tree in place; all of oMi written when every lane returns.
template <class Robot, class Scalar, class Team> TG_HD void world_placements(const Team& t, const Scalar* q, SE3<Scalar>* oMi) {
  const auto& d = data<Robot, Scalar>();
  for (const int i : t.items(0, Robot::NB)) oMi[i] = joint_placement<Robot, Scalar>(i, q);
  t.sync();
  if (t.leader())
    for (int i = 0; i < Robot::NB; ++i)
      if (d.parent[i] >= 0) oMi[i] = oMi[d.parent[i]] * oMi[i];
  t.sync();
}

// The first named pass of an op that runs several algorithms on one sample: world placements oMi
// and joint placements liMi (local(i)), computed once from q and read by each algorithm in turn.
// A GPU thread keeps only oMi (its stack) and rebuilds liMi = oMi[parent]^-1 oMi[i], without
// trigonometry.

template <class Robot, class Scalar> struct Placements {
  SE3<Scalar> oMi[Robot::NB];
#if TG_DEVICE_PATH
  TG_HD explicit Placements(const Scalar* q) { world_placements<Robot, Scalar>(q, oMi); }
  TG_HD SE3<Scalar> local(int i) const {
    const int p = data<Robot, Scalar>().parent[i];
    return p < 0 ? oMi[i] : inverse_times(oMi[p], oMi[i]);
  }
#else
  SE3<Scalar> liMi[Robot::NB];
  TG_HD explicit Placements(const Scalar* q) { forward_kinematics<Robot, Scalar>(q, liMi, oMi); }
  TG_HD const SE3<Scalar>& local(int i) const { return liMi[i]; }
#endif
  // JointPlacements' interface: place(i) in a forward pass, [i] later.
  TG_HD decltype(auto) place(int i) const { return local(i); }
  TG_HD decltype(auto) operator[](int i) const { return local(i); }
};

}  // namespace tg
