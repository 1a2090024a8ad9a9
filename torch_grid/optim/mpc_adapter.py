"""An nn.Module dynamics for mpc.pytorch (locuslab/mpc.pytorch), GradMethods.ANALYTIC.

mpc.pytorch linearises x' = f(x, u) in plain coordinates: x = [q; qd] (n_state = nq + nv), u = tau.
grad_input returns R = dx'/dx, S = dx'/du there: step_derivatives' tangent-space Jacobians mapped
through the configuration's own charts (at a quaternion joint the ambient coordinates move through
the normalisation the kernels apply). Both are torch over the robot's ops, so they have a backward and
a differentiable MPC learns through them.
"""
from __future__ import annotations

import torch

from ..space.conventions import quaternion_rotation, unit_quaternion
from ..space.lie import skew


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
        q, qd = self._split("forward", x)
        return torch.cat(self.view.step(q, qd, u, self.dt, self.integrator), dim=-1)

    def grad_input(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(R (..., n, n), S (..., n, nv)), n = nq + nv: the Jacobians of forward in x's coordinates."""
        q, qd = self._split("grad_input", x)
        q_next, _, A, B = self.view._step_and_derivatives(q, qd, u, self.dt, self.integrator, None)
        out, into = chart_maps(self.view, q_next)[0], chart_maps(self.view, q)[1]
        nv = self.nv
        R = torch.cat([torch.cat([out @ A[..., :nv, :nv] @ into, out @ A[..., :nv, nv:]], dim=-1),
                       torch.cat([A[..., nv:, :nv] @ into, A[..., nv:, nv:]], dim=-1)], dim=-2)
        S = torch.cat([out @ B[..., :nv, :], B[..., nv:, :]], dim=-2)
        return R, S

    def _split(self, method: str, x) -> tuple[torch.Tensor, torch.Tensor]:
        """(q, qd) of x (..., nq + nv), refused by name otherwise (a wrong size was reported as step's qd)."""
        n = self.nq + self.nv
        if not isinstance(x, torch.Tensor) or x.dim() == 0 or x.shape[-1] != n:
            got = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
            raise ValueError(f"MPCDynamics.{method}: x must have shape (..., nq + nv = {n}), got {got}")
        return x[..., :self.nq], x[..., self.nq:]


def chart_maps(view, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(d q (+) e / d e at e = 0 (..., nq, nv), d difference(q, q + d) / d d at d = 0 (..., nv, nq)):
    between the tangent at q and q's own coordinates, in closed form. The identity on scalar joints; on a
    quaternion a (unit, xyzw; |q| its norm): a (x) [e / 2; 0] out and 2 Im(a* (x) d) / |q| in (the
    normalisation's derivative lies along a, which Im(a* (x) .) does not see); a free joint's position
    moves by R e_lin in Pinocchio's convention (exp6), by e_lin in MuJoCo's."""
    space, convention = view._robot._space, view._convention
    out = torch.zeros(*q.shape[:-1], space.nq, space.nv, dtype=q.dtype, device=q.device)
    into = torch.zeros(*q.shape[:-1], space.nv, space.nq, dtype=q.dtype, device=q.device)
    order = [1, 2, 3, 0] if convention else [0, 1, 2, 3]  # xyzw's components in q's layout
    for kind, qi, vi in zip(space.kinds, space.qi, space.vi):
        if kind == "scalar":
            out[..., qi, vi] = into[..., vi, qi] = 1
            continue
        qa, va = (qi + 3, vi + 3) if kind == "free" else (qi, vi)
        raw = q[..., qa:qa + 4][..., order]
        a, norm = unit_quaternion(raw)
        av, aw = a[..., :3], a[..., 3:].unsqueeze(-1)
        eye = torch.eye(3, dtype=q.dtype, device=q.device)
        turn = torch.cat([aw * eye + skew(av), -av.unsqueeze(-2)], dim=-2) / 2  # (4, 3), xyzw rows
        back = torch.cat([aw * eye - skew(av), -av.unsqueeze(-1)], dim=-1) * (2 / norm.unsqueeze(-1))  # (3, 4)
        idx = [qa + o for o in order]  # q's index of each xyzw component
        out[..., idx, va:va + 3] = turn
        into[..., va:va + 3, idx] = back
        if kind == "free":
            R = quaternion_rotation(raw)
            out[..., qi:qi + 3, vi:vi + 3] = eye if convention else R
            into[..., vi:vi + 3, qi:qi + 3] = eye if convention else R.mT
    return out, into
