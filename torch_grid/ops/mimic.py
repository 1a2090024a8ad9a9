"""Mimic joints coupled in reduced coordinates (load(..., mimic=True)).

A mimic joint follows its master: q_mimic = multiplier * q_master + offset (a master may itself be a
mimic joint: the chain is followed to an independent joint). The reduced coordinates
are those of the independent joints; the full ones (every joint, what the kernels take) are

    q_full = expand(q),   qd_full = G qd,   qdd_full = G qdd,

with G = d q_full / d q the constant (nv_full, nv) matrix: the identity on the independent joints and
the multiplier from each master to its mimic joint. The coupled dynamics are the projection of the
uncoupled ones (virtual work):

    tau = G^T tau_full,   M = G^T M_full G,   J = J_full G,   d tau / dq = G^T (d tau_full / dq_full) G,

and what inverts M (forward dynamics, M^-1 and their derivatives, the operational-space inertia)
solves with the reduced M. Every function is made of the full robot's kernels and torch, so autograd
and torch.compile see through it.
"""
from __future__ import annotations

from typing import Callable

import torch

from ..model.description import Mimic, RobotModel
from .fd_second_order import cholesky_or_nan
from .table import OPS, model_sizes

# How each kernel output in full coordinates becomes the coupled one: "rows" G^T X (X's nv axis of
# generalized forces), "columns" X G (its last, tangent axis), "both" G^T X G, "all" G on each of the
# three axes of an (nv, nv, nv) tensor, "last2" on the last two (a Hessian's), "plain" unchanged.
_OUTPUTS = {
    "inverse_dynamics": ("rows",), "generalized_gravity": ("rows",), "nonlinear_effects": ("rows",),
    "crba": ("both",), "energy": ("plain",), "com": ("plain",), "jacobian_com": ("columns",),
    "ccrba": ("columns", "plain"), "forward_kinematics": ("plain", "plain"), "end_effector_pose": ("plain",),
    "frame_jacobian": ("columns",), "frame_jacobian_dot": ("columns",), "body_velocities": ("plain",),
    "inverse_dynamics_derivatives": ("both", "both"), "inverse_dynamics_second_derivatives": ("all",) * 4,
    "frame_kinematic_hessian": ("last2",), "inverse_dynamics_external_force_derivatives": ("rows",),
    "cmm_time_variation": ("columns",), "dccrba": ("columns",), "coriolis_matrix": ("both",),
    "inverse_dynamics_regressor": ("rows",), "kinetic_energy_regressor": ("plain",),
    "potential_energy_regressor": ("plain",),
}


class Coupling:
    """The map between the reduced and the full coordinates of a model with mimic joints."""

    def __init__(self, model: RobotModel):
        mimic = {m.joint: _resolved(m, model.mimics) for m in model.mimics}
        independent = [j for j in model.joints if j.name not in mimic]
        self.joint_names = [j.name for j in independent]
        self.nq, self.nv = sum(j.nq for j in independent), sum(j.nv for j in independent)
        # each independent joint's first reduced q and dof
        reduced, nq, nv = {}, 0, 0
        for j in independent:
            reduced[j.name] = (nq, nv)
            nq, nv = nq + j.nq, nv + j.nv
        # full q coordinate k = q[q_src[k]] * q_scale[k] + q_offset[k]; full dof k = qd[v_src[k]] * v_scale[k]
        q_src, q_scale, q_offset, v_src, v_scale = [], [], [], [], []
        for j in model.joints:
            if j.name in mimic:
                m = mimic[j.name]
                q_src.append(reduced[m.master][0])
                v_src.append(reduced[m.master][1])
                q_scale.append(m.multiplier)
                q_offset.append(m.offset)
                v_scale.append(m.multiplier)
            else:
                q_src += range(reduced[j.name][0], reduced[j.name][0] + j.nq)
                v_src += range(reduced[j.name][1], reduced[j.name][1] + j.nv)
                q_scale += [1.0] * j.nq
                q_offset += [0.0] * j.nq
                v_scale += [1.0] * j.nv
        self.v_src = v_src  # the reduced dof of each full dof
        # the full q coordinates that are reduced ones, in order
        self.keep_q = [k for j, qi in zip(model.joints, model.q_index) if j.name not in mimic for k in range(qi, qi + j.nq)]
        G = torch.zeros(len(v_src), self.nv, dtype=torch.float64)
        G[torch.arange(len(v_src)), torch.tensor(v_src)] = torch.tensor(v_scale, dtype=torch.float64)
        self._base = (torch.tensor(q_src), torch.tensor(q_scale, dtype=torch.float64),
                      torch.tensor(q_offset, dtype=torch.float64), G)
        self._cache: dict = {}
        sizes = {**model_sizes(model.kernel_model), "nq": self.nq, "nv": self.nv}
        # op -> (position, trailing shape) of each tensor argument, in reduced coordinates
        self.tensor_args = {name: [(k, torch.Size(sizes.get(d, d) for d in a.trailing))
                                   for k, a in enumerate(spec.args) if a.is_tensor] for name, spec in OPS.items()}

    def _on(self, like: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """(q_src, q_scale, q_offset, G) on like's device, the floats in its dtype."""
        key = (like.dtype, like.device)
        if key not in self._cache:
            src, scale, offset, G = self._base
            self._cache[key] = (src.to(like.device), scale.to(like), offset.to(like), G.to(like))
        return self._cache[key]

    # -- coordinates ---------------------------------------------------------------------------
    def q(self, q: torch.Tensor) -> torch.Tensor:
        """(..., nq) -> (..., nq_full)."""
        src, scale, offset, _ = self._on(q)
        return q.index_select(-1, src) * scale + offset

    def v(self, x: torch.Tensor) -> torch.Tensor:
        """A velocity or acceleration (..., nv) -> G x (..., nv_full)."""
        return x @ self._on(x)[3].mT

    def rows(self, x: torch.Tensor, axis: int) -> torch.Tensor:
        """G^T X along X's axis `axis` (negative) of generalized forces."""
        G = self._on(x)[3]
        return torch.tensordot(x.movedim(axis, -1), G, dims=1).movedim(-1, axis)

    def columns(self, x: torch.Tensor) -> torch.Tensor:
        """X G along the last axis."""
        return x @ self._on(x)[3]

    def both(self, x: torch.Tensor) -> torch.Tensor:
        """G^T X G for X (..., nv_full, nv_full)."""
        G = self._on(x)[3]
        return G.mT @ x @ G

    def reduce_q(self, q_full: torch.Tensor) -> torch.Tensor:
        """The independent joints' coordinates of a full q."""
        return q_full[..., self.keep_q]

    # -- functions -------------------------------------------------------------------------------
    def call(self, kernel_call: Callable, name: str, args: tuple):
        """Op `name` in reduced coordinates, from `kernel_call(name, *full_args)` (the full robot's op)."""
        special = _SPECIAL.get(name)
        if special is not None:
            return special(self, kernel_call, *args)
        spec = OPS[name]
        full = [self.q(x) if a.kind == "configuration" else self.v(x) if a.kind in ("velocity", "acceleration") and
                x is not None else x for a, x in zip(spec.args, args)]
        out = kernel_call(name, *full)
        outs = out if isinstance(out, tuple) else (out,)
        projected = tuple(self._project(how, o, spec_out.shape) for how, o, spec_out in zip(_OUTPUTS[name], outs, spec.outputs))
        return projected if isinstance(out, tuple) else projected[0]

    def _project(self, how: str, x: torch.Tensor, shape: tuple) -> torch.Tensor:
        if how == "rows":
            return self.rows(x, shape.index("nv") - len(shape))
        if how == "columns":
            return self.columns(x)
        if how == "both":
            return self.both(x)
        if how == "last2":
            G = self._on(x)[3]
            return torch.einsum("...bc,bj,ck->...jk", x, G, G)
        if how == "all":
            G = self._on(x)[3]
            return torch.einsum("...abc,ai,bj,ck->...ijk", x, G, G, G)
        return x

    def inverse_inertia(self, kernel_call: Callable, q: torch.Tensor, params=None) -> torch.Tensor:
        """(G^T M_full G)^-1 (..., nv, nv), by a Cholesky factorisation. A solve against the identity, not
        torch.cholesky_inverse, whose forward-mode derivative is wrong (torch 2.13: jvp, jacfwd)."""
        L = cholesky_or_nan(self.both(kernel_call("crba", self.q(q), params)))
        return torch.cholesky_solve(torch.eye(self.nv, dtype=L.dtype, device=L.device), L)


def _resolved(m: Mimic, mimics: tuple[Mimic, ...]) -> Mimic:
    """m with its master followed to an independent joint: a mimic of a mimic of q_a is affine in q_a,
    multiplier2 (multiplier1 q_a + offset1) + offset2."""
    by_joint = {x.joint: x for x in mimics}
    while m.master in by_joint:
        up = by_joint[m.master]
        m = Mimic(m.joint, up.master, m.multiplier * up.multiplier, m.multiplier * up.offset + m.offset)
    return m


def _forward_dynamics(c: Coupling, call: Callable, q, qd, tau, f_ext=None, params=None):
    """M qdd = tau - (ID(q, qd, 0) in reduced coordinates): the bias includes gravity and f_ext."""
    q_full, qd_full = c.q(q), c.v(qd)
    M = c.both(call("crba", q_full, params))
    bias = c.rows(call("inverse_dynamics", q_full, qd_full, torch.zeros_like(qd_full), f_ext, params), -1)
    # by Cholesky (M is symmetric positive definite): torch.linalg.solve returned garbage under vmap of
    # jacfwd (torch 2.13)
    return torch.cholesky_solve((tau - bias).unsqueeze(-1), cholesky_or_nan(M)).squeeze(-1)


def _minv(c: Coupling, call: Callable, q, params=None):
    return c.inverse_inertia(call, q, params)


def _forward_dynamics_derivatives(c: Coupling, call: Callable, q, qd, tau, f_ext=None, params=None):
    """d qdd / dx = -M^-1 d tau / dx at qdd = FD(q, qd, tau); d qdd / d tau = M^-1."""
    qdd = _forward_dynamics(c, call, q, qd, tau, f_ext, params)
    dq, dqd = call("inverse_dynamics_derivatives", c.q(q), c.v(qd), c.v(qdd), f_ext, params)
    minv = c.inverse_inertia(call, q, params)
    return -minv @ c.both(dq), -minv @ c.both(dqd), minv


def _forward_dynamics_external_force_derivatives(c: Coupling, call: Callable, q, params=None):
    """d qdd / d f_ext = -M^-1 d tau / d f_ext."""
    dtau = c.rows(call("inverse_dynamics_external_force_derivatives", c.q(q)), -3)
    minv = c.inverse_inertia(call, q, params)
    return -(minv @ dtau.flatten(-2)).unflatten(-1, dtau.shape[-2:])


def _forward_dynamics_parameter_derivatives(c: Coupling, call: Callable, q, qd, tau, params=None):
    """-M^-1 Y(q, qd, qdd) at qdd = FD(q, qd, tau)."""
    qdd = _forward_dynamics(c, call, q, qd, tau, None, params)
    Y = c.rows(call("inverse_dynamics_regressor", c.q(q), c.v(qd), c.v(qdd)), -2)
    return -c.inverse_inertia(call, q, params) @ Y


def _osc_inertia(c: Coupling, call: Callable, q, frame: int, reference: int, params=None):
    """(J M^-1 J^T)^-1 with the reduced J and M."""
    J = c.columns(call("frame_jacobian", c.q(q), frame, reference))
    return torch.linalg.inv(J @ c.inverse_inertia(call, q, params) @ J.mT)


_SPECIAL = {
    "forward_dynamics": _forward_dynamics, "minv": _minv, "forward_dynamics_derivatives": _forward_dynamics_derivatives,
    "forward_dynamics_external_force_derivatives": _forward_dynamics_external_force_derivatives,
    "forward_dynamics_parameter_derivatives": _forward_dynamics_parameter_derivatives, "osc_inertia": _osc_inertia,
}
