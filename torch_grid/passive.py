"""Joint damping and stiffness: MuJoCo's passive joint forces, per dof.

    qfrc_passive = -damping * qd - stiffness * (q - springref)

on hinge and slide joints, and damping alone on each dof of a ball joint (a free joint has neither;
a ball's stiffness is refused by the model). Elementwise in torch, so autograd, vmap and
torch.compile see through it; the rigid-body functions that include it (`load(...,
passive_forces=...)`) add it to the generalized forces around their kernels.
"""
from __future__ import annotations

import torch

from .model import RobotModel


class PassiveForces:
    """One model's passive-force coefficients, as float64 CPU tensors and per (dtype, device) copies."""

    def __init__(self, model: RobotModel):
        nv = model.nv
        damping, stiffness, springref = (torch.zeros(nv, dtype=torch.float64) for _ in range(3))
        q_index, v_index = [], []
        for joint, iq, iv in zip(model.joints, model.q_index, model.v_index):
            damping[iv:iv + joint.nv] = joint.damping
            if joint.nv == 1:
                q_index.append(iq)
                v_index.append(iv)
                stiffness[iv], springref[iv] = joint.stiffness, joint.springref
        self.nv = nv
        self.any = bool(damping.any() or stiffness.any())
        self._q_index, self._v_index = torch.tensor(q_index, dtype=torch.long), torch.tensor(v_index, dtype=torch.long)
        self._coefficients = (damping, stiffness, springref)
        self._cache: dict[tuple[torch.dtype, torch.device], tuple[torch.Tensor, ...]] = {}

    def _on(self, like: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """(damping, stiffness, springref, q_index, v_index) in like's dtype (the coefficients) and device."""
        key = (like.dtype, like.device)
        if key not in self._cache:
            self._cache[key] = tuple(c.to(dtype=like.dtype, device=like.device) for c in self._coefficients) + (
                self._q_index.to(like.device), self._v_index.to(like.device))
        return self._cache[key]

    def coefficients(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(damping, stiffness, springref), each (nv,), in like's dtype and device."""
        return self._on(like)[:3]

    def __call__(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """qfrc_passive (..., nv) from q (..., nq) and qd (..., nv)."""
        damping, stiffness, springref, q_index, v_index = self._on(q)
        # The 1-dof joints' positions at their dofs; 0 on a free or ball joint's, whose stiffness is 0.
        q_dof = torch.zeros(*q.shape[:-1], self.nv, dtype=q.dtype, device=q.device)
        q_dof = q_dof.index_copy(-1, v_index, q.index_select(-1, q_index))
        return -(damping * qd + stiffness * (q_dof - springref))
