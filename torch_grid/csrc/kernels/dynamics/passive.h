// Joint damping and springs in the step kernels: MuJoCo's passive joint forces, per dof,
//   p(q, qd) = -D qd - K (q - q_ref),   D = damping, K = stiffness (1-dof joints), q_ref = springref,
// added to the applied force, tau + p. A free joint has neither and a ball joint damping alone, so p is the
// same in both conventions (they differ at free joints' velocities and quaternion orders alone) and so are
// its derivatives, dp/dq = -K and dp/dqd = -D, diagonal along either tangent.
#pragma once

#include "kernels/spatial/spatial.h"

namespace tg {

// tau += p(q, qd); q in Pinocchio's layout (a 1-dof joint's coordinate sits at the same index in both).
template <class Robot, class Scalar> TG_HD void add_passive(const Scalar* q, const Scalar* qd, Scalar* tau) {
  const auto& d = data<Robot, Scalar>();
  for (int k = 0; k < Robot::NV; ++k) {
    tau[k] -= Scalar(d.damping[k]) * qd[k];
    if (d.dof_qi[k] >= 0) tau[k] -= Scalar(d.stiffness[k]) * (q[d.dof_qi[k]] - Scalar(d.springref[k]));
  }
}

// The inverse-dynamics derivatives of ID(q, qd, qdd) - p: Dq += K, Dv += D on the diagonals (NV x NV).
template <class Robot, class Scalar> TG_HD void add_passive_diagonals(Scalar* Dq, Scalar* Dv) {
  const auto& d = data<Robot, Scalar>();
  for (int k = 0; k < Robot::NV; ++k) {
    Dq[(Robot::NV + 1) * k] += Scalar(d.stiffness[k]);
    Dv[(Robot::NV + 1) * k] += Scalar(d.damping[k]);
  }
}

// The forward-dynamics derivatives of FD(q, qd, tau + p): dq -= M^-1 K, dqd -= M^-1 D (column scalings).
template <class Robot, class Scalar> TG_HD void add_passive_columns(const Scalar* Minv, Scalar* dq, Scalar* dqd) {
  const auto& d = data<Robot, Scalar>();
  for (int r = 0; r < Robot::NV; ++r)
    for (int c = 0; c < Robot::NV; ++c) {
      dq[Robot::NV * r + c] -= Minv[Robot::NV * r + c] * Scalar(d.stiffness[c]);
      dqd[Robot::NV * r + c] -= Minv[Robot::NV * r + c] * Scalar(d.damping[c]);
    }
}

}  // namespace tg
