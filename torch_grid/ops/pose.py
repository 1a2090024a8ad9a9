"""End-effector pose derivatives: the gradient and Hessian of end_effector_pose ([xyz, rpy] of frames)
along the tangent, in torch over the frame Jacobians and kinematic Hessians."""
from __future__ import annotations

from typing import Sequence

import torch

from ..space.rpy import rpy_rate_solve
from .arguments import check_tensor


class PoseDerivatives:
    """The end-effector pose derivatives of a robot's views (mixed into robot._Functions, which provides
    end_effector_pose, frame_jacobian and frame_kinematic_hessian)."""

    def end_effector_pose_derivatives(self, q, frames: Sequence[str | int]) -> torch.Tensor:
        """d end_effector_pose / dq along the tangent, (..., len(frames), 6, nv): [xyz; rpy] rows.

        xyz rows are the LOCAL_WORLD_ALIGNED linear Jacobian rows; rpy rows are E^-1 J_angular with
        E the rpy rate matrix (singular at pitch = +-pi/2, as rpy itself).
        """
        frames = _checked(self, "end_effector_pose_derivatives", q, frames)
        rpy = self.end_effector_pose(q, frames)[..., 3:]
        J = torch.stack([self.frame_jacobian(q, f, "local_world_aligned") for f in frames], dim=-3)
        return torch.cat([J[..., :3, :], rpy_rate_solve(rpy, J[..., 3:, :])], dim=-2)

    def end_effector_pose_second_derivatives(self, q, frames: Sequence[str | int]) -> torch.Tensor:
        """Second derivative of end_effector_pose along the tangent, (..., len(frames), 6, nv, nv):
        [..., r, j, k] = d/dq_k (end_effector_pose_derivatives)[..., r, j]. xyz rows are the linear rows of
        the LOCAL_WORLD_ALIGNED kinematic Hessian; rpy rows differentiate E^-1 J_angular, with E the
        rpy rate matrix: E^-1 (dJ_angular/dq_k - dE/dq_k E^-1 J_angular)."""
        frames = _checked(self, "end_effector_pose_second_derivatives", q, frames)
        rpy = self.end_effector_pose(q, frames)[..., 3:]
        J = torch.stack([self.frame_jacobian(q, f, "local_world_aligned") for f in frames], dim=-3)
        H = torch.stack([self.frame_kinematic_hessian(q, f, "local_world_aligned") for f in frames], dim=-4)
        G = rpy_rate_solve(rpy, J[..., 3:, :])  # the rpy rows of the gradient
        p, y = rpy[..., 1], rpy[..., 2]
        cp, sp, cy, sy = torch.cos(p), torch.sin(p), torch.cos(y), torch.sin(y)
        zero = torch.zeros_like(p)
        dE_dp = torch.stack([torch.stack([-cy * sp, zero, zero], -1), torch.stack([-sy * sp, zero, zero], -1),
                             torch.stack([-cp, zero, zero], -1)], dim=-2)
        dE_dy = torch.stack([torch.stack([-sy * cp, -cy, zero], -1), torch.stack([cy * cp, -sy, zero], -1),
                             torch.stack([zero, zero, zero], -1)], dim=-2)
        # dE/dq_k = dE/dp dp/dq_k + dE/dy dy/dq_k, (..., 3, 3, nv)
        dE = dE_dp.unsqueeze(-1) * G[..., 1:2, :].unsqueeze(-2) + dE_dy.unsqueeze(-1) * G[..., 2:3, :].unsqueeze(-2)
        inner = H[..., 3:, :, :] - torch.einsum("...abk,...bj->...ajk", dE, G)
        nv = J.shape[-1]
        rot = rpy_rate_solve(rpy, inner.flatten(-2)).unflatten(-1, (nv, nv))
        return torch.cat([H[..., :3, :, :], rot], dim=-3)


def _checked(view, op: str, q, frames) -> list[int]:
    """The frames' indices, q and frames refused naming `op` (end_effector_pose, which the derivatives call first,
    named itself)."""
    if isinstance(frames, (str, int)):
        raise TypeError(f"{op}: frames must be a list of frame names or indices, got {frames!r}")
    check_tensor(op, "q", q, (view.nq,), q)
    indices = [view._robot.frame_index(f, f"{op}: frames") for f in frames]
    if not indices:
        raise ValueError(f"{op}: frames must list at least one frame")
    return indices
