// Joint damping and springs in the step kernels: MuJoCo's passive joint forces, per dof,
//   p(q, qd) = -D qd - K (q - q_ref),   D = damping, K = stiffness (1-dof joints), q_ref = springref,
// added to the applied force, tau + p. A free joint has neither and a ball joint damping alone, so p is the
// same in both conventions (they differ at free joints' velocities and quaternion orders alone) and so are
// its derivatives, dp/dq = -K and dp/dqd = -D, diagonal along either tangent.
#pragma once

#include "kernels/spatial/spatial.h"

namespace tg {

// tau += p(q, qd); q in Pinocchio's layout (a 1-dof joint's coordinate sits at the same index in both).
template <class M, class S> TG_HD void add_passive(const S* q, const S* qd, S* tau) {
  const auto& d = data<M, S>();
  for (int k = 0; k < M::NV; ++k) {
    tau[k] -= S(d.damping[k]) * qd[k];
    if (d.dof_qi[k] >= 0) tau[k] -= S(d.stiffness[k]) * (q[d.dof_qi[k]] - S(d.springref[k]));
  }
}

// The inverse-dynamics derivatives of ID(q, qd, qdd) - p: Dq += K, Dv += D on the diagonals (NV x NV).
template <class M, class S> TG_HD void add_passive_diagonals(S* Dq, S* Dv) {
  const auto& d = data<M, S>();
  for (int k = 0; k < M::NV; ++k) {
    Dq[(M::NV + 1) * k] += S(d.stiffness[k]);
    Dv[(M::NV + 1) * k] += S(d.damping[k]);
  }
}

// The forward-dynamics derivatives of FD(q, qd, tau + p): dq -= M^-1 K, dqd -= M^-1 D (column scalings).
template <class M, class S> TG_HD void add_passive_columns(const S* Minv, S* dq, S* dqd) {
  const auto& d = data<M, S>();
  for (int r = 0; r < M::NV; ++r)
    for (int c = 0; c < M::NV; ++c) {
      dq[M::NV * r + c] -= Minv[M::NV * r + c] * S(d.stiffness[c]);
      dqd[M::NV * r + c] -= Minv[M::NV * r + c] * S(d.damping[c]);
    }
}

}  // namespace tg
