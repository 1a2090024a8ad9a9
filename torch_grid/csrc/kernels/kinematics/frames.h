// Frame placements, poses and Jacobians (Pinocchio's framesForwardKinematics, getFrameJacobian).
#pragma once

#include "kernels/spatial/joints.h"

namespace tg {

enum Reference : int { WORLD = 0, LOCAL = 1, LOCAL_WORLD_ALIGNED = 2 };

// Positions (NF x 3) and rotations (NF x 3 x 3) of every frame.
template <class Robot, class Scalar> TG_HD void frames_forward_kinematics(const Scalar* q, Scalar* pos, Scalar* rot) {
  SE3<Scalar> liMi[Robot::NB], oMi[Robot::NB];
  forward_kinematics<Robot, Scalar>(q, liMi, oMi);
  for (int f = 0; f < Robot::NF; ++f) {
    const SE3<Scalar> X = frame_placement<Robot, Scalar>(f, oMi);
    store3(X.p, pos + 3 * f);
    for (int k = 0; k < 9; ++k) rot[9 * f + k] = X.R.m[k];
  }
}

// Roll-pitch-yaw angles with R = Rz(yaw) Ry(pitch) Rx(roll), pitch in [-pi/2, pi/2]. Roll is read from
// Rz(-yaw) R = Ry(pitch) Rx(roll), not from R's last row: at pitch +-pi/2 that row and R's first column are
// rounding noise, and the two angles taken apart from them would not give back R (which fixes only
// roll -+ yaw there).
template <class Scalar> TG_HD Vec3<Scalar> rpy(const Mat3<Scalar>& R) {
  const Scalar p = atan2(-R.m[6], sqrt(R.m[7] * R.m[7] + R.m[8] * R.m[8]));
  const Scalar y = atan2(R.m[3], R.m[0]);
  const Scalar sy = sin(y), cy = cos(y);
  const Scalar r = atan2(sy * R.m[2] - cy * R.m[5], cy * R.m[4] - sy * R.m[1]);
  return v3(r, p, y);
}

// [xyz, rpy] of the n frames listed in `frames`, out is (n x 6).
template <class Robot, class Scalar> TG_HD void end_effector_pose(const Scalar* q, const int* frames, int n, Scalar* out) {
  SE3<Scalar> liMi[Robot::NB], oMi[Robot::NB];
  forward_kinematics<Robot, Scalar>(q, liMi, oMi);
  for (int k = 0; k < n; ++k) {
    const SE3<Scalar> X = frame_placement<Robot, Scalar>(frames[k], oMi);
    store3(X.p, out + 6 * k);
    store3(rpy(X.R), out + 6 * k + 3);
  }
}

// Jacobian (6 x NV, rows [linear; angular]) of frame f in the given reference, from the world
// placements oMi of (at least) the bodies supporting the frame. `zeroed`: J holds zeros outside the
// columns of the frame's chain already.
template <class Robot, class Scalar>
TG_HD void frame_jacobian(const SE3<Scalar>* oMi, int f, int reference, Scalar* J, bool zeroed = false) {
  const auto& d = data<Robot, Scalar>();
  const SE3<Scalar> oMf = frame_placement<Robot, Scalar>(f, oMi);
  if (!zeroed)
    for (int k = 0; k < 6 * Robot::NV; ++k) J[k] = Scalar(0);
  // Each joint on the chain contributes its world axis, expressed as asked. An axis e about which joint
  // j turns moves the point o the linear rows are taken at (the world origin, or the frame's origin) by
  // e x (o - p_j); one it slides along moves every point by e.
  const Scalar zero(0);
  const Vec3<Scalar> o = reference == WORLD ? v3(zero, zero, zero) : oMf.p;
  for (int j = d.fparent[f]; j >= 0; j = d.parent[j]) {
    const SE3<Scalar>& X = oMi[j];
    const Vec3<Scalar> r = o - X.p;
    for (int k = 0; k < d.nvj[j]; ++k) {
      Vec3<Scalar> l, w;
      const AxisColumn a = axis_column<Robot, Scalar>(j, k);
      if (a.c < 0) {
        const Sv<Scalar> s = placed_axis<Robot, Scalar>(X, j, k);
        w = ang(s), l = lin(s) + cross(w, o);
      } else {
        const Vec3<Scalar> e = v3(X.R.m[a.c], X.R.m[3 + a.c], X.R.m[6 + a.c]);
        if (a.rotation)
          w = e, l = cross(e, r);
        else
          l = e, w = v3(zero, zero, zero);
      }
      if (reference == LOCAL) l = mulT(oMf.R, l), w = mulT(oMf.R, w);
      for (int row = 0; row < 3; ++row) {
        J[Robot::NV * row + d.vi[j] + k] = l.x[row];
        J[Robot::NV * (3 + row) + d.vi[j] + k] = w.x[row];
      }
    }
  }
}

// The same from q: only the bodies supporting the frame are placed.
template <class Robot, class Scalar> TG_HD void frame_jacobian(const Scalar* q, int f, int reference, Scalar* J, bool zeroed = false) {
  const auto& d = data<Robot, Scalar>();
  int chain[Robot::NB], n = 0;  // support chain, frame's body first
  for (int j = d.fparent[f]; j >= 0; j = d.parent[j]) chain[n++] = j;
  SE3<Scalar> oMi[Robot::NB];
  chain_placements<Robot, Scalar>(q, chain, n, oMi);
  frame_jacobian<Robot, Scalar>(oMi, f, reference, J, zeroed);
}

// The gradient along the tangent of <G, J(q)> for frame f's Jacobian J in the given reference and a
// weight G (6 x NV, as J). A world axis S_j turns with every joint above it and with the other axes of
// its own joint: dS_j/dq_k = S_k x S_j, and G_j . (S_k x S_j) = (S_j x* G_j) . S_k. So with F_j the
// weight as a world force (WORLD: G_j; LOCAL_WORLD_ALIGNED: G_j moved from the frame origin p; LOCAL:
// also turned by the frame's rotation) and P_k the sum of S_j x* F_j over the columns at or below
// k's joint, T that over the whole chain:
//   WORLD                  grad_k = S_k . P_k
//   LOCAL_WORLD_ALIGNED    grad_k = S_k . P_k + c . (linear velocity of p under S_k), c = sum_j G_lin,j x w_j
//   LOCAL                  grad_k = S_k . (P_k - T)   (a local column moves with the joints below it only)
template <class Robot, class Scalar> TG_HD void frame_jacobian_vjp(const Scalar* q, int f, int reference, const Scalar* G, Scalar* out) {
  const auto& d = data<Robot, Scalar>();
  for (int k = 0; k < Robot::NV; ++k) out[k] = Scalar(0);
  int chain[Robot::NB], n = 0;  // support chain, frame's body first
  for (int j = d.fparent[f]; j >= 0; j = d.parent[j]) chain[n++] = j;
  SE3<Scalar> oMi[Robot::NB];
  chain_placements<Robot, Scalar>(q, chain, n, oMi);
  const SE3<Scalar> oMf = frame_placement<Robot, Scalar>(f, oMi);
  // from the frame's body up: P sums S x* F over the columns of this joint and of the joints below
  // it; c sums G_lin x w over the chain (LOCAL_WORLD_ALIGNED)
  Sv<Scalar> P = sv_zero<Scalar>();
  Vec3<Scalar> c = v3(Scalar(0), Scalar(0), Scalar(0));
  for (int m = 0; m < n; ++m) {
    const int j = chain[m];
    for (int k = 0; k < d.nvj[j]; ++k) {
      const int col = d.vi[j] + k;
      const Sv<Scalar> s = placed_axis<Robot, Scalar>(oMi[j], j, k);
      const Vec3<Scalar> gl = v3(G[col], G[Robot::NV + col], G[2 * Robot::NV + col]);
      const Vec3<Scalar> ga = v3(G[3 * Robot::NV + col], G[4 * Robot::NV + col], G[5 * Robot::NV + col]);
      const Sv<Scalar> F = reference == WORLD ? sv(gl, ga) : reference == LOCAL ? act_force(oMf, sv(gl, ga))
                                                                             : sv(gl, ga + cross(oMf.p, gl));
      P = P + cross_force(s, F);
      c = c + cross(gl, ang(s));
    }
    for (int k = 0; k < d.nvj[j]; ++k) out[d.vi[j] + k] = dot(placed_axis<Robot, Scalar>(oMi[j], j, k), P);
  }
  // the whole chain's terms: T = P at the root (LOCAL), c (LOCAL_WORLD_ALIGNED)
  if (reference != WORLD)
    for (int m = 0; m < n; ++m)
      for (int k = 0; k < d.nvj[chain[m]]; ++k) {
        const Sv<Scalar> s = placed_axis<Robot, Scalar>(oMi[chain[m]], chain[m], k);
        out[d.vi[chain[m]] + k] += reference == LOCAL ? -dot(s, P) : dot(c, lin(s) + cross(ang(s), oMf.p));
      }
}

// Kinematic Hessian H (6 x NV x NV, [r][j][k] at NV (NV r + j) + k) of frame f: H[:, j, k] = d J[:, j] / dq_k
// along the tangent, J = frame_jacobian in the given reference. A world axis S_j turns with the joints
// above it and with the other axes of its own joint, dS_j/dq_k = S_k x S_j; the frame origin p moves
// with column k of the local-world-aligned Jacobian; a local column turns with the frame, so only the
// joints below j move it.
template <class Robot, class Scalar> TG_HD void frame_kinematic_hessian(const Scalar* q, int f, int reference, Scalar* H) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NV = Robot::NV;
  for (int k = 0; k < 6 * NV * NV; ++k) H[k] = Scalar(0);
  int chain[Robot::NB], n = 0;  // support chain, frame's body first
  for (int j = d.fparent[f]; j >= 0; j = d.parent[j]) chain[n++] = j;
  SE3<Scalar> oMi[Robot::NB];
  chain_placements<Robot, Scalar>(q, chain, n, oMi);
  const SE3<Scalar> oMf = frame_placement<Robot, Scalar>(f, oMi);
  auto put = [&](int j, int k, const Sv<Scalar>& x) {
    for (int r = 0; r < 6; ++r) H[NV * (NV * r + j) + k] = x.v[r];
  };
  for (int mj = 0; mj < n; ++mj)
    for (int lj = 0; lj < d.nvj[chain[mj]]; ++lj) {
      const int bj = chain[mj], j = d.vi[bj] + lj;
      const Sv<Scalar> Sj = placed_axis<Robot, Scalar>(oMi[bj], bj, lj);
      for (int mk = 0; mk < n; ++mk)
        for (int lk = 0; lk < d.nvj[chain[mk]]; ++lk) {
          const int bk = chain[mk], k = d.vi[bk] + lk;
          const Sv<Scalar> Sk = placed_axis<Robot, Scalar>(oMi[bk], bk, lk);
          const bool turns = mk >= mj;  // k's joint is j's or above it
          const Sv<Scalar> dS = cross_motion(Sk, Sj);
          if (reference == WORLD) {
            if (turns) put(j, k, dS);
          } else if (reference == LOCAL) {
            // Ad(oMf^-1) (dS_j - S_k x S_j): zero unless k's joint is below j's
            if (!turns) {
              const Vec3<Scalar> l = mulT(oMf.R, Scalar(-1) * (lin(dS) + cross(ang(dS), oMf.p))), a = mulT(oMf.R, Scalar(-1) * ang(dS));
              put(j, k, sv(l, a));
            }
          } else {
            // [dS_lin + dS_ang x p + w_j x pdot_k; dS_ang], pdot_k the origin's velocity under column k
            const Vec3<Scalar> pdot = lin(Sk) + cross(ang(Sk), oMf.p);
            Vec3<Scalar> l = cross(ang(Sj), pdot), a = v3(Scalar(0), Scalar(0), Scalar(0));
            if (turns) {
              l = l + lin(dS) + cross(ang(dS), oMf.p);
              a = ang(dS);
            }
            put(j, k, sv(l, a));
          }
        }
    }
}

// sum_f J_f^T w_f over every frame f (NV), J_f the LOCAL_WORLD_ALIGNED Jacobian and w (NF x 6)
// [linear; angular] weights: the gradient of sum_f w_f . (frame velocity) with respect to qd.
// Each weight acts as the spatial force [w_lin; p_f x w_lin + w_ang] at the world origin; a
// joint collects the forces of its subtree, projected on its world axes.
template <class Robot, class Scalar> TG_HD void frames_vjp(const Scalar* q, const Scalar* w, Scalar* out) {
  const auto& d = data<Robot, Scalar>();
  SE3<Scalar> liMi[Robot::NB], oMi[Robot::NB];
  forward_kinematics<Robot, Scalar>(q, liMi, oMi);
  Sv<Scalar> F[Robot::NB];
  for (int i = 0; i < Robot::NB; ++i) F[i] = sv_zero<Scalar>();
  for (int f = 0; f < Robot::NF; ++f) {
    if (d.fparent[f] < 0) continue;  // world frames do not move
    const Vec3<Scalar> p = frame_placement<Robot, Scalar>(f, oMi).p, wl = load3(w + 6 * f), wa = load3(w + 6 * f + 3);
    F[d.fparent[f]] = F[d.fparent[f]] + sv(wl, cross(p, wl) + wa);
  }
  for (int i = Robot::NB - 1; i >= 0; --i) {
    for (int k = 0; k < d.nvj[i]; ++k) out[d.vi[i] + k] = dot(placed_axis<Robot, Scalar>(oMi[i], i, k), F[i]);
    if (d.parent[i] >= 0) F[d.parent[i]] = F[d.parent[i]] + F[i];
  }
}

// Time derivative of frame_jacobian (6 x NV) at velocity qd, and the Jacobian itself (J may be
// null). A world axis S_j moves with its body: dS_j/dt = v_j x S_j (world velocities); the frame
// origin p moves at pdot, and a LOCAL Jacobian also turns with the frame's angular velocity w.
template <class Robot, class Scalar>
TG_HD void frame_jacobian_dot(const Scalar* q, const Scalar* qd, int f, int reference, Scalar* Jdot, Scalar* J) {
  const auto& d = data<Robot, Scalar>();
  int chain[Robot::NB], n = 0;  // support chain, frame's body first
  for (int j = d.fparent[f]; j >= 0; j = d.parent[j]) chain[n++] = j;
  SE3<Scalar> oMi[Robot::NB];
  Sv<Scalar> v[Robot::NB];
  chain_placements<Robot, Scalar>(q, chain, n, oMi);
  for (int k = n - 1; k >= 0; --k) {
    const int i = chain[k];
    v[i] = act_motion(oMi[i], joint_motion<Robot, Scalar>(i, qd)) + (k == n - 1 ? sv_zero<Scalar>() : v[chain[k + 1]]);
  }
  const SE3<Scalar> oMf = frame_placement<Robot, Scalar>(f, oMi);
  const Sv<Scalar> vf = n > 0 ? v[chain[0]] : sv_zero<Scalar>();
  const Vec3<Scalar> w = ang(vf), pdot = lin(vf) + cross(w, oMf.p);
  for (int k = 0; k < 6 * Robot::NV; ++k) {
    Jdot[k] = Scalar(0);
    if (J) J[k] = Scalar(0);
  }
  for (int c = 0; c < n; ++c) {
    const int j = chain[c];
    for (int k = 0; k < d.nvj[j]; ++k) {
      const Sv<Scalar> s = placed_axis<Robot, Scalar>(oMi[j], j, k), sd = cross_motion(v[j], s);
      Vec3<Scalar> l = lin(s), a = ang(s), ld = lin(sd), ad = ang(sd);
      if (reference != WORLD) {
        ld = ld + cross(ad, oMf.p) + cross(a, pdot);
        l = l + cross(a, oMf.p);
      }
      if (reference == LOCAL) {
        ld = mulT(oMf.R, ld - cross(w, l));
        ad = mulT(oMf.R, ad - cross(w, a));
        l = mulT(oMf.R, l);
        a = mulT(oMf.R, a);
      }
      for (int r = 0; r < 3; ++r) {
        Jdot[Robot::NV * r + d.vi[j] + k] = ld.x[r];
        Jdot[Robot::NV * (3 + r) + d.vi[j] + k] = ad.x[r];
        if (J) {
          J[Robot::NV * r + d.vi[j] + k] = l.x[r];
          J[Robot::NV * (3 + r) + d.vi[j] + k] = a.x[r];
        }
      }
    }
  }
}

// d tau / d f_ext (NV x NB x 6): tau = ... - sum_k J_k^T f_k with J_k body k's Jacobian in its joint
// frame, so column (k, c) is minus row c of J_k: joint j's axis seen from body k's frame.
template <class Robot, class Scalar> TG_HD void external_force_jacobian(const Placements<Robot, Scalar>& K, Scalar* out) {
  const auto& d = data<Robot, Scalar>();
  constexpr int NF6 = 6 * Robot::NB;
  const SE3<Scalar>* oMi = K.oMi;
  for (int k = 0; k < Robot::NV * NF6; ++k) out[k] = Scalar(0);
  for (int k = 0; k < Robot::NB; ++k)
    for (int j = k; j >= 0; j = d.parent[j])
      for (int l = 0; l < d.nvj[j]; ++l) {
        const Sv<Scalar> s = actinv_motion(oMi[k], placed_axis<Robot, Scalar>(oMi[j], j, l));
        for (int c = 0; c < 6; ++c) out[NF6 * (d.vi[j] + l) + 6 * k + c] = -s.v[c];
      }
}

}  // namespace tg
