// The MuJoCo (mjx) convention, fused into every kernel: convert the inputs to Pinocchio's
// convention on entry, reframe the outputs on exit. Only the free-flyer root differs:
//   qpos quaternion wxyz (pin: xyzw); qvel = [v_lin WORLD; w LOCAL] (pin: [v_lin LOCAL; w LOCAL]).
// With G = blockdiag(R, I): v_mjx = G v_pin, forces covary (G), M -> G M G^T, J -> J G^T.
// See shared conventions reference; torch_grid/conventions.py is the same in torch.
#pragma once

#include "spatial.h"

namespace tg {

template <class M, class S, int C> struct Conv {
  static constexpr bool active = (C == MJX) && M::FLOATING;
  S q[M::NQ];  // configuration in Pinocchio's layout
  Mat3<S> R;   // base rotation (identity when inactive)

  TG_HD explicit Conv(const S* q_in) {
    for (int k = 0; k < M::NQ; ++k) q[k] = q_in[k];
    R = identity3<S>();
    if constexpr (active) {
      // wxyz -> xyzw
      q[3] = q_in[4]; q[4] = q_in[5]; q[5] = q_in[6]; q[6] = q_in[3];
      R = quat_rotation(q[3], q[4], q[5], q[6]);
    }
  }
  // Velocity or generalized force in: base-linear part R^T x.
  TG_HD void velocity(const S* in, S* v) const {
    for (int k = 0; k < M::NV; ++k) v[k] = in[k];
    if constexpr (active) store3(mulT(R, load3(in)), v);
  }
  TG_HD void force(const S* in, S* u) const { velocity(in, u); }
  // Acceleration in: a_lin = R^T a_mjx - w x v_lin (v already in Pinocchio's convention).
  TG_HD void acceleration(const S* v, const S* in, S* a) const {
    for (int k = 0; k < M::NV; ++k) a[k] = in[k];
    if constexpr (active) store3(mulT(R, load3(in)) - cross(load3(v + 3), load3(v)), a);
  }
  // Generalized force out (covector): base-linear rows R x.
  TG_HD void force_out(S* tau) const {
    if constexpr (active) store3(mul(R, load3(tau)), tau);
  }
  // Joint acceleration out: qdd_lin = R (qdd_lin + w x v_lin).
  TG_HD void acceleration_out(const S* v, S* qdd) const {
    if constexpr (active) store3(mul(R, load3(qdd) + cross(load3(v + 3), load3(v))), qdd);
  }
  // Matrix (rows x NV) out: base-linear columns right-multiplied by R^T.
  TG_HD void columns_out(S* J, int rows) const {
    if constexpr (active)
      for (int r = 0; r < rows; ++r) store3(mul(R, load3(J + M::NV * r)), J + M::NV * r);
  }
  // Symmetric NV x NV matrix out: congruence G X G^T.
  TG_HD void congruence_out(S* X) const {
    if constexpr (active) {
      columns_out(X, M::NV);
      for (int c = 0; c < M::NV; ++c) {
        const Vec3<S> col = mul(R, v3(X[c], X[M::NV + c], X[2 * M::NV + c]));
        for (int r = 0; r < 3; ++r) X[M::NV * r + c] = col.x[r];
      }
    }
  }
};

}  // namespace tg
