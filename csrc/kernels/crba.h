// Composite rigid-body algorithm: the joint-space inertia matrix M(q), full and symmetric.
// Featherstone's HandC (spatial_v2) / Pinocchio's crba. Composite inertias build up in joint
// frames; each column's force F = Ic S is moved to the world once, where every entry of the
// column is a dot product with a joint axis (also moved once), without a frame change per level.
#pragma once

#include "joints.h"

namespace tg {

template <class M, class S> TG_HD void crba(const S* q, S* Mout) {
  const auto& d = data<M, S>();
  // Joint and world placements; on a GPU thread only the world ones are kept (its stack) and liMi
  // is rebuilt where the backward pass needs it, without trigonometry.
  const Placements<M, S> K(q);
  Inertia<S> Ic[M::NB];
  Sv<S> Sw[M::NV];  // joint axes in the world frame, per dof (joint i's k-th at vi + k)
  for (int k = 0; k < M::NV * M::NV; ++k) Mout[k] = S(0);  // entries of unrelated branches stay zero
  for (int i = 0; i < M::NB; ++i) {
    Ic[i] = body_inertia<M, S>(i);
    for (int k = 0; k < d.nvj[i]; ++k) Sw[d.vi[i] + k] = act_motion(K.oMi[i], joint_axis<M, S>(i, k));
  }
  // Backward pass: composite inertia of each subtree, then the column entries it produces on
  // the support chain: M[j, i] = S_j^T F for every ancestor j of i (i included).
  for (int i = M::NB - 1; i >= 0; --i) {
    for (int k = 0; k < d.nvj[i]; ++k) {
      const int col = d.vi[i] + k;
      const Sv<S> F = act_force(K.oMi[i], mul(Ic[i], joint_axis<M, S>(i, k)));
      for (int j = i; j >= 0; j = d.parent[j])
        for (int l = 0; l < d.nvj[j]; ++l) {
          const int row = d.vi[j] + l;
          const S m = dot(Sw[row], F);
          Mout[M::NV * row + col] = m;
          Mout[M::NV * col + row] = m;
        }
    }
    const int p = d.parent[i];
    if (p >= 0) Ic[p] = Ic[p] + act(K.local(i), Ic[i]);
  }
}

}  // namespace tg
