"""An nn.Module dynamics for mpc.pytorch (locuslab/mpc.pytorch), GradMethods.ANALYTIC.

mpc.pytorch linearises x' = f(x, u) in plain coordinates: x = [q; qd] (n_state = nq + nv), u = tau.
grad_input returns R = dx'/dx, S = dx'/du there: step_derivatives' tangent-space Jacobians mapped
through the configuration's own charts (at a quaternion joint the ambient coordinates move through
the normalisation the kernels apply). Both are torch over the robot's ops, so they have a backward and
a differentiable MPC learns through them.
"""
from __future__ import annotations

import torch

from .configuration import difference, integrate


class MPCDynamics(torch.nn.Module):
    """x' = step(x, u) for mpc.pytorch: `forward(x, u)`, `grad_input(x, u) -> (R, S)`.

    view: a robot or one of its views (robot.pin, robot.mujoco); dt and integrator as `step`.
    """

    def __init__(self, view, dt: float, integrator: str = "semi_implicit_euler"):
        super().__init__()
        self.view, self.dt, self.integrator = view, dt, integrator
        robot = view._robot
        self.nq, self.nv = robot.nq, robot.nv

    def forward(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """(..., nq + nv): the next state."""
        q, qd = x[..., :self.nq], x[..., self.nq:]
        return torch.cat(self.view.step(q, qd, u, self.dt, self.integrator), dim=-1)

    def grad_input(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(R (..., n, n), S (..., n, nv)), n = nq + nv: the Jacobians of forward in x's coordinates."""
        q, qd = x[..., :self.nq], x[..., self.nq:]
        q_next, _, A, B = self.view._step_and_derivatives(q, qd, u, self.dt, self.integrator, None)
        out, into = chart_maps(self.view, q_next)[0], chart_maps(self.view, q)[1]
        nv = self.nv
        R = torch.cat([torch.cat([out @ A[..., :nv, :nv] @ into, out @ A[..., :nv, nv:]], dim=-1),
                       torch.cat([A[..., nv:, :nv] @ into, A[..., nv:, nv:]], dim=-1)], dim=-2)
        S = torch.cat([out @ B[..., :nv, :], B[..., nv:, :]], dim=-2)
        return R, S


def chart_maps(view, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(d q (+) e / d e at e = 0 (..., nq, nv), d difference(q, q + d) / d d at d = 0 (..., nv, nq)):
    between the tangent at q and q's own coordinates, by forward-mode AD of integrate and difference."""
    space, convention = view._robot._space, view._convention
    flat = q.reshape(-1, q.shape[-1])
    zero_v = torch.zeros(space.nv, dtype=q.dtype, device=q.device)
    zero_q = torch.zeros(space.nq, dtype=q.dtype, device=q.device)

    def push(qi):
        return torch.func.jacfwd(lambda e: integrate(space, qi, e, 1.0, convention))(zero_v)

    def pull(qi):
        return torch.func.jacfwd(lambda d: difference(space, qi, qi + d, convention))(zero_q)

    out, into = torch.func.vmap(push)(flat), torch.func.vmap(pull)(flat)
    return out.reshape(*q.shape[:-1], space.nq, space.nv), into.reshape(*q.shape[:-1], space.nv, space.nq)
