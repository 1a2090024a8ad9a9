"""Joint damping and stiffness: MuJoCo's passive joint forces, per dof.

    qfrc_passive = -damping * qd - stiffness * (q - springref)

on hinge and slide joints, and damping alone on each dof of a ball joint (a free joint has neither;
a ball's stiffness is refused by the model). Elementwise in torch, so autograd, vmap and
torch.compile see through it; the rigid-body functions that include it (`load(...,
passive_forces=...)`) add it to the generalized forces around their kernels.
"""
from __future__ import annotations

import torch

from ..model.description import RobotModel
from ..ops.arguments import check_tensor
from ..ops.fd_second_order import cholesky_or_nan, second_order


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
        self.nq, self.nv = model.nq, nv
        self.any = bool(damping.any() or stiffness.any())
        self.damps = bool(damping.any())
        self.springs = bool(stiffness.any())
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

    def __call__(self, q: torch.Tensor, qd: torch.Tensor, op: str = "passive_forces") -> torch.Tensor:
        """qfrc_passive (..., nv) from q (..., nq) and qd (..., nv), checked as `op`'s arguments."""
        check_tensor(op, "q", q, (self.nq,), q)
        check_tensor(op, "qd", qd, (self.nv,), q)
        damping, stiffness, springref = self.coefficients(q)
        return -(damping * qd + stiffness * (self._stretch(q) - springref))

    def added(self, op: str, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """tau + qfrc_passive, checked as `op`'s arguments (before torch's promotion could take an integer tau)."""
        check_tensor(op, "tau", tau, (self.nv,), q)
        return tau + self(q, qd, op)

    def spring_energy(self, q: torch.Tensor) -> torch.Tensor:
        """The springs' potential energy (...,): sum of stiffness (q - springref)^2 / 2 (MuJoCo's mj_energyPos)."""
        _, stiffness, springref = self.coefficients(q)
        return (stiffness * (self._stretch(q) - springref).square()).sum(-1) / 2

    def _stretch(self, q: torch.Tensor) -> torch.Tensor:
        """The 1-dof joints' positions at their dofs (..., nv); 0 on a free or ball joint's, whose stiffness is 0."""
        q_index, v_index = self._on(q)[3:]
        q_dof = torch.zeros(*q.shape[:-1], self.nv, dtype=q.dtype, device=q.device)
        return q_dof.index_copy(-1, v_index, q.index_select(-1, q_index))


# -- MuJoCo's Euler step with the damping implicit (mj_Euler) ------------------------------------------------
# The velocity update solves (M + dt D) qdd = tau + p - b(q, qd), D the joints' damping, p the passive forces.
# Differentiating ID(q, qd, qdd) - p + dt D qdd = tau at that qdd, with H = M + dt D:
#   dqdd/dx = -H^-1 (dID/dx - dp/dx),   dqdd/dtau = H^-1,
# and, ID being linear in qdd and p linear, the second derivatives are forward dynamics' closed form with
# H^-1 in place of M^-1 (fd_second_order.py). `view` is a robot or one of its views.

def damped_factor(view, q: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """The Cholesky factor (..., nv, nv) of H = M(q) + dt D; h the step (..., 1); NaN for a sample whose H is
    not positive definite (a NaN in its state, or dt < 0 with stiff damping: cholesky_or_nan)."""
    damping = view._robot._passive.coefficients(q)[0]
    return cholesky_or_nan(view.crba(q) + torch.diag_embed(h * damping))


def damped_acceleration(view, q, qd, tau, h, f_ext=None) -> torch.Tensor:
    """qdd (..., nv) of (M + dt D) qdd = tau + p - b(q, qd); h the step (..., 1)."""
    return _damped_solve(view, q, qd, tau, h, f_ext)[1]


def _damped_solve(view, q, qd, tau, h, f_ext) -> tuple[torch.Tensor, torch.Tensor]:
    """(H's Cholesky factor, qdd)."""
    L = damped_factor(view, q, h)
    rhs = tau - view.inverse_dynamics(q, qd, torch.zeros_like(qd), f_ext)  # tau + p - b
    return L, torch.cholesky_solve(rhs.unsqueeze(-1), L).squeeze(-1)


def damped_acceleration_derivatives(view, q, qd, tau, h, f_ext=None) -> tuple[torch.Tensor, ...]:
    """(qdd (..., nv), dqdd/dq, dqdd/dqd, dqdd/dtau (..., nv, nv) each) of damped_acceleration."""
    L, qdd = _damped_solve(view, q, qd, tau, h, f_ext)
    dq, dqd = view.inverse_dynamics_derivatives(q, qd, qdd, f_ext)  # of ID - p
    nv = qd.shape[-1]
    batch = torch.broadcast_shapes(L.shape[:-2], dq.shape[:-2], dqd.shape[:-2])
    eye = torch.eye(nv, dtype=qd.dtype, device=qd.device).expand(*batch, nv, nv)
    rhs = torch.cat([-dq.expand(*batch, nv, nv), -dqd.expand(*batch, nv, nv), eye], dim=-1)
    dq, dqd, dtau = torch.cholesky_solve(rhs, L.expand(*batch, nv, nv)).split(nv, dim=-1)
    return qdd, dq, dqd, dtau


def damped_acceleration_second_derivatives(view, q, qd, tau, h, f_ext=None) -> tuple:
    """(qdd, (dqdd/dq, dqdd/dqd, dqdd/dtau), the four second-derivative tensors of
    forward_dynamics_second_derivatives's layout) of damped_acceleration, H^-1 in place of M^-1."""
    qdd, dq, dqd, dtau = damped_acceleration_derivatives(view, q, qd, tau, h, f_ext)
    second = view.inverse_dynamics_second_derivatives(q, qd, qdd, f_ext)
    return qdd, (dq, dqd, dtau), second_order(second, dq, dqd, dtau)
