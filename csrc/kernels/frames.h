// Frame placements, poses and Jacobians (Pinocchio's framesForwardKinematics, getFrameJacobian).
#pragma once

#include "joints.h"

namespace tg {

enum Reference : int { WORLD = 0, LOCAL = 1, LOCAL_WORLD_ALIGNED = 2 };

// Positions (NF x 3) and rotations (NF x 3 x 3) of every frame.
template <class M, class S> TG_HD void frames_forward_kinematics(const S* q, S* pos, S* rot) {
  SE3<S> liMi[M::NB], oMi[M::NB];
  forward_kinematics<M, S>(q, liMi, oMi);
  for (int f = 0; f < M::NF; ++f) {
    const SE3<S> X = frame_placement<M, S>(f, oMi);
    store3(X.p, pos + 3 * f);
    for (int k = 0; k < 9; ++k) rot[9 * f + k] = X.R.m[k];
  }
}

// Roll-pitch-yaw angles with R = Rz(yaw) Ry(pitch) Rx(roll), pitch in [-pi/2, pi/2].
template <class S> TG_HD Vec3<S> rpy(const Mat3<S>& R) {
  const S r = atan2(R.m[7], R.m[8]);
  const S p = atan2(-R.m[6], sqrt(R.m[7] * R.m[7] + R.m[8] * R.m[8]));
  const S y = atan2(R.m[3], R.m[0]);
  return v3(r, p, y);
}

// [xyz, rpy] of the n frames listed in `frames`, out is (n x 6).
template <class M, class S> TG_HD void end_effector_pose(const S* q, const int* frames, int n, S* out) {
  SE3<S> liMi[M::NB], oMi[M::NB];
  forward_kinematics<M, S>(q, liMi, oMi);
  for (int k = 0; k < n; ++k) {
    const SE3<S> X = frame_placement<M, S>(frames[k], oMi);
    store3(X.p, out + 6 * k);
    store3(rpy(X.R), out + 6 * k + 3);
  }
}

// Jacobian (6 x NV, rows [linear; angular]) of frame f in the given reference. Only the bodies
// supporting the frame are placed.
template <class M, class S> TG_HD void frame_jacobian(const S* q, int f, int reference, S* J) {
  const auto& d = M::data();
  int chain[M::NB], n = 0;  // support chain, frame's body first
  for (int j = d.fparent[f]; j >= 0; j = d.parent[j]) chain[n++] = j;
  SE3<S> oMi[M::NB];
  for (int k = n - 1; k >= 0; --k) {
    const SE3<S> liMi = joint_placement<M, S>(chain[k], q);
    oMi[chain[k]] = k == n - 1 ? liMi : oMi[chain[k + 1]] * liMi;
  }
  const SE3<S> oMf = frame_placement<M, S>(f, oMi);
  for (int k = 0; k < 6 * M::NV; ++k) J[k] = S(0);
  // Each joint on the chain contributes its world axis, expressed as asked.
  for (int c = 0; c < n; ++c) {
    const int j = chain[c];
    for (int k = 0; k < d.nvj[j]; ++k) {
      const Sv<S> s = act_motion(oMi[j], joint_axis<M, S>(j, k));
      Vec3<S> l = lin(s), w = ang(s);
      if (reference != WORLD) l = l + cross(w, oMf.p);
      if (reference == LOCAL) {
        l = mulT(oMf.R, l);
        w = mulT(oMf.R, w);
      }
      for (int r = 0; r < 3; ++r) {
        J[M::NV * r + d.vi[j] + k] = l.x[r];
        J[M::NV * (3 + r) + d.vi[j] + k] = w.x[r];
      }
    }
  }
}

}  // namespace tg
