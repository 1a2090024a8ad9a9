"""The configuration-space functions of a robot's views: the neutral and random configurations, integrate, difference
and their tangent Jacobians, each one kernel call, else the composition of space/lie.py, which autograd and the
torch.func transforms see through.
integrate and difference of a robot with quaternion joints run their kernels under autograd's reverse mode too,
their backwards one kernel each (differentiable_kernel_runs); the Jacobians' kernels run only
when nothing differentiates them (fused_kernel_runs)."""
from __future__ import annotations

import math

import torch

from ..model.description import Joint
from ..ops.arguments import check_arguments, check_batch_shape, check_dt
from ..space import lie
from .integrators import differentiable_kernel_runs, fused_kernel_runs


def _drawn_range(joint: Joint) -> tuple[float, float]:
    """The range random_configuration draws a one-dof joint from: its limits, a width 2 pi (a revolute joint) or 2
    (a prismatic one) from its one bound when the other is infinite, and [-pi, pi] or [-1, 1] when both are (or the
    range is too wide to draw from)."""
    half = math.pi if joint.type != "prismatic" else 1.0
    lo, hi = joint.lower, joint.upper
    if math.isfinite(lo) and not math.isfinite(hi):
        hi = lo + 2 * half
    elif math.isfinite(hi) and not math.isfinite(lo):
        lo = hi - 2 * half
    if not math.isfinite(hi - lo):
        lo, hi = -half, half
    return lo, hi


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
        # their batch shapes named here, before dt's check (or torch) could blame another argument
        check_arguments(op, [("q0" if second[0] == "q1" else "q", q, (space.nq,)), (second[0], x, second[1])])
        check_dt(op, dt, q, x)
        return q, x

    def neutral_configuration(self, *batch_shape: int, dtype: torch.dtype = torch.float64,
                              device="cpu") -> torch.Tensor:
        """Zero joint positions, identity ball orientations and, for a floating base, the identity
        orientation at the origin, in this view's convention (quaternion order). For a model read from
        MJCF that is qpos = 0, not MuJoCo's qpos0 (which holds each joint's ref and each free body's
        initial pose): take `MjModel.qpos0` for that.

        Args:
            *batch_shape: leading batch sizes (none: a single configuration).
            dtype, device: of the result (keyword arguments).
        Returns:
            (*batch_shape, nq), every row the same configuration.
        """
        batch_shape = check_batch_shape("neutral_configuration", batch_shape)
        _check_dtype("neutral_configuration", dtype)
        model = self._robot.model
        q = torch.zeros(*batch_shape, model.nq, dtype=dtype, device=device)
        for joint, qi in zip(model.joints, model.q_index):
            if joint.type in ("free", "ball"):
                quat = qi + (3 if joint.type == "free" else 0)
                q[..., quat if self._convention else quat + 3] = 1.0  # w, first in MuJoCo's wxyz, last in xyzw
        return self._reduced(q)

    def random_configuration(self, *batch_shape: int, dtype: torch.dtype = torch.float64, device="cpu",
                             generator: torch.Generator | None = None) -> torch.Tensor:
        """Joints uniform within their limits ([-pi, pi] or [-1, 1] when unbounded, a width of 2 pi or 2
        from the one bound of a joint bounded on one side), a base position in
        [-1, 1]^3 and uniformly random unit quaternions (free and ball joints), in this view's convention.

        Args:
            *batch_shape: leading batch sizes (none: a single configuration).
            dtype, device: of the result (keyword arguments); drawn in float64 on the CPU.
            generator: the CPU torch.Generator to draw from (None: torch's default).
        Returns:
            (*batch_shape, nq).
        """
        batch_shape = check_batch_shape("random_configuration", batch_shape)
        _check_dtype("random_configuration", dtype)
        model, cols = self._robot.model, []
        for joint in model.joints:
            if joint.type in ("free", "ball"):
                if joint.type == "free":
                    cols.append(2 * torch.rand(*batch_shape, 3, dtype=torch.float64, generator=generator) - 1)
                quat = torch.randn(*batch_shape, 4, dtype=torch.float64, generator=generator)
                quat = quat / quat.norm(dim=-1, keepdim=True)
                cols.append(quat[..., [3, 0, 1, 2]] if self._convention else quat)
                continue
            lo, hi = _drawn_range(joint)
            cols.append(lo + (hi - lo) * torch.rand(*batch_shape, 1, dtype=torch.float64, generator=generator))
        return self._reduced(torch.cat(cols, dim=-1).to(dtype=dtype, device=device))

    def _reduced(self, q: torch.Tensor) -> torch.Tensor:
        """The coordinates of q that are the robot's own (a coupled mimic joint has none)."""
        coupling = self._robot._coupling
        return q if coupling is None else coupling.reduce_q(q)


def _check_dtype(op: str, dtype) -> None:
    """A sampler's dtype: float32 or float64, as every function takes (an integer dtype truncated the draws, the
    unit quaternions to zero)."""
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"{op}: dtype must be torch.float32 or torch.float64, got {dtype}")
