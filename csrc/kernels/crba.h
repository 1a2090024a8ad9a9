// Composite rigid-body algorithm: the joint-space inertia matrix M(q), full and symmetric.
// Featherstone's HandC (spatial_v2) / Pinocchio's crba, in joint frames.
#pragma once

#include "joints.h"

namespace tg {

template <class M, class S> TG_HD void crba(const S* q, S* Mout) {
  const auto& d = M::data();
  SE3<S> liMi[M::NB];
  Inertia<S> Ic[M::NB];
  for (int k = 0; k < M::NV * M::NV; ++k) Mout[k] = S(0);  // entries of unrelated branches stay zero
  for (int i = 0; i < M::NB; ++i) {
    liMi[i] = joint_placement<M, S>(i, q);
    Ic[i] = body_inertia<M, S>(i);
  }
  // Backward pass: composite inertia of each subtree, then the columns of M it produces.
  for (int i = M::NB - 1; i >= 0; --i) {
    for (int k = 0; k < d.nvj[i]; ++k) {
      const int col = d.vi[i] + k;
      // F: force needed to accelerate subtree i along S_i[:, k], carried up the support chain.
      Sv<S> F = mul(Ic[i], joint_axis<M, S>(i, k));
      for (int j = i;;) {
        for (int l = 0; l < d.nvj[j]; ++l) {
          const int row = d.vi[j] + l;
          const S m = dot(joint_axis<M, S>(j, l), F);
          Mout[M::NV * row + col] = m;
          Mout[M::NV * col + row] = m;
        }
        if (d.parent[j] < 0) break;
        F = act_force(liMi[j], F);
        j = d.parent[j];
      }
    }
    if (d.parent[i] >= 0) Ic[d.parent[i]] = Ic[d.parent[i]] + act(liMi[i], Ic[i]);
  }
}

}  // namespace tg
