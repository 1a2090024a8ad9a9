"""Roll-pitch-yaw angles: the map between their rates and the world angular velocity, for the
end-effector pose's derivatives (ops/pose.py) and its backward (ops/autograd.py)."""
from __future__ import annotations

import torch


# E(rpy), with world angular velocity w = E d(roll, pitch, yaw)/dt, R = Rz(y) Ry(p) Rx(r):
#   E = [[cy cp, -sy, 0], [sy cp, cy, 0], [-sp, 0, 1]],  det E = cp (singular at pitch = +-pi/2, as rpy).
# Its solves in closed form: torch.linalg.solve returned garbage under vmap of jacfwd (torch 2.13).


def rpy_rate_solve(rpy: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """E(rpy)^-1 x, rpy (..., 3), x (..., 3, k): the first two rows turn back by yaw, the third adds sp r_x."""
    p, y = rpy[..., 1:2], rpy[..., 2:3]
    sp, cy, sy = torch.sin(p), torch.cos(y), torch.sin(y)
    r_x = (cy * x[..., 0, :] + sy * x[..., 1, :]) / torch.cos(p)
    return torch.stack([r_x, cy * x[..., 1, :] - sy * x[..., 0, :], x[..., 2, :] + sp * r_x], dim=-2)


def rpy_rate_transpose_solve(rpy: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """E(rpy)^-T g, rpy and g (..., 3): w_z = g_z, and (w_x, w_y) turned by yaw."""
    p, y = rpy[..., 1], rpy[..., 2]
    sp, cy, sy = torch.sin(p), torch.cos(y), torch.sin(y)
    a, b = (g[..., 0] + sp * g[..., 2]) / torch.cos(p), g[..., 1]
    return torch.stack([cy * a - sy * b, sy * a + cy * b, g[..., 2]], dim=-1)
