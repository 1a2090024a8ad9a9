"""The configuration-space functions of a robot's views: integrate, difference and their tangent Jacobians, each one
kernel call, else the composition of space/lie.py, which autograd and the torch.func transforms see through.
integrate and difference of a robot with quaternion joints run their kernels under autograd's reverse mode too,
their backwards one kernel each (differentiable_kernel_runs); the Jacobians' kernels run only
when nothing differentiates them (fused_kernel_runs)."""
from __future__ import annotations

import torch

from ..ops.arguments import check_dt, check_tensor
from ..space import lie
from .integrators import differentiable_kernel_runs, fused_kernel_runs


class ConfigurationFunctions:
    """The configuration-space functions of a robot's views (space/lie.py), their arguments checked (mixed
    into robot._Functions, which provides `_robot` with its `_space`, and `_convention`)."""

    def integrate(self, q: torch.Tensor, v: torch.Tensor, dt=1.0) -> torch.Tensor:
        """(..., nq): q (+) v dt, Pinocchio's integrate or MuJoCo's mj_integratePos; q (..., nq), v (..., nv),
        dt a number or a (...,) tensor."""
        q, v = self._configuration_checked("integrate", q, v, dt)
        if differentiable_kernel_runs(self, q, v, dt):  # one kernel call, not the composition's small torch ops
            return self._kernel_call("integrate", q, v, lie.dt_column(dt, v))
        return lie.integrate(self._robot._space, q, v, dt, self._convention)

    def difference(self, q0: torch.Tensor, q1: torch.Tensor) -> torch.Tensor:
        """(..., nv): v with q0 (+) v = q1, Pinocchio's difference or MuJoCo's mj_differentiatePos (dt = 1)."""
        q0, q1 = self._configuration_checked("difference", q0, q1)
        if differentiable_kernel_runs(self, q0, q1):
            return self._kernel_call("difference", q0, q1)
        return lie.difference(self._robot._space, q0, q1, self._convention)

    def d_integrate(self, q: torch.Tensor, v: torch.Tensor, dt=1.0) -> tuple[torch.Tensor, torch.Tensor]:
        """(d/dq, d/dv) of integrate along the tangent spaces, each (..., nv, nv) (Pinocchio's dIntegrate)."""
        q, v = self._configuration_checked("d_integrate", q, v, dt)
        if fused_kernel_runs(self, q, v, dt):
            return self._kernel_call("d_integrate", q, v, lie.dt_column(dt, v))
        return lie.d_integrate(self._robot._space, q, v, dt, self._convention)

    def d_difference(self, q0: torch.Tensor, q1: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(d/dq0, d/dq1) of difference along the tangent spaces, each (..., nv, nv) (Pinocchio's dDifference)."""
        q0, q1 = self._configuration_checked("d_difference", q0, q1)
        if fused_kernel_runs(self, q0, q1):
            return self._kernel_call("d_difference", q0, q1)
        return lie.d_difference(self._robot._space, q0, q1, self._convention)

    def _configuration_checked(self, op: str, q: torch.Tensor, x: torch.Tensor, dt=1.0) -> tuple[torch.Tensor, torch.Tensor]:
        space = self._robot._space
        second = ("v", (space.nv,)) if op.endswith("integrate") else ("q1", (space.nq,))
        check_tensor(op, "q0" if second[0] == "q1" else "q", q, (space.nq,), q)
        check_tensor(op, second[0], x, second[1], q)
        check_dt(op, dt, q, x)
        return q, x
