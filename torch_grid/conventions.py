"""Pinocchio <-> MuJoCo convention transforms in plain torch: the readable oracle that the fused
kernel twins are tested against.

Only a free-flyer root differs between the conventions:
  - configuration: MuJoCo's quaternion is wxyz, Pinocchio's xyzw;
  - velocity: MuJoCo's base linear velocity is in the world frame, Pinocchio's in the base frame.
With R the base rotation and G = blockdiag(R, I), v_mjx = G v_pin; generalized forces transform
like velocities (G orthogonal), M -> G M G^T, Jacobians J -> J G^T. An acceleration also picks up
the rate of change of G: a_lin_mjx = R (a_lin_pin + w x v_lin_pin).

Every function takes any leading batch shape. `q_pin` is a configuration in Pinocchio's layout.
Pass floating=False for a fixed-base robot: every transform is then the identity.
"""
from __future__ import annotations

import torch

__all__ = [
    "unit_quaternion", "base_rotation", "q_mjx_to_pin", "q_pin_to_mjx", "v_mjx_to_pin", "v_pin_to_mjx", "a_mjx_to_pin",
    "a_pin_to_mjx", "covector_mjx_to_pin", "covector_pin_to_mjx", "congruence_pin_to_mjx", "columns_pin_to_mjx",
]

_WXYZ_TO_XYZW = [0, 1, 2, 4, 5, 6, 3]
_XYZW_TO_WXYZ = [0, 1, 2, 6, 3, 4, 5]


def unit_quaternion(quat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(quat / |quat|, |quat|) for (..., 4) xyzw quaternions, each (..., 4) and (..., 1). A quaternion
    of zero or non-finite norm reads as the identity of norm 1, as MuJoCo's mj_normalizeQuat does."""
    norm = quat.norm(dim=-1, keepdim=True)
    valid = (norm > 0) & torch.isfinite(norm)
    identity = torch.zeros_like(quat)
    identity[..., 3] = 1
    return torch.where(valid, quat / torch.where(valid, norm, 1), identity), torch.where(valid, norm, 1)


def base_rotation(q_pin: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation of the normalised base quaternion q_pin[..., 3:7] (xyzw); the identity for
    a quaternion of zero or non-finite norm."""
    x, y, z, w = unit_quaternion(q_pin[..., 3:7])[0].unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(*q_pin.shape[:-1], 3, 3)


def q_mjx_to_pin(q: torch.Tensor, floating: bool = True) -> torch.Tensor:
    """MuJoCo qpos (quaternion wxyz) -> Pinocchio q (xyzw)."""
    return _reorder(q, _WXYZ_TO_XYZW) if floating else q


def q_pin_to_mjx(q: torch.Tensor, floating: bool = True) -> torch.Tensor:
    """Pinocchio q (quaternion xyzw) -> MuJoCo qpos (wxyz)."""
    return _reorder(q, _XYZW_TO_WXYZ) if floating else q


def v_mjx_to_pin(q_pin: torch.Tensor, v: torch.Tensor, floating: bool = True) -> torch.Tensor:
    """qvel -> Pinocchio v: v_lin = R^T v_lin_mjx."""
    return _base_lin(v, _mul(base_rotation(q_pin).transpose(-1, -2), v[..., :3])) if floating else v


def v_pin_to_mjx(q_pin: torch.Tensor, v: torch.Tensor, floating: bool = True) -> torch.Tensor:
    """Pinocchio v -> qvel: v_lin_mjx = R v_lin."""
    return _base_lin(v, _mul(base_rotation(q_pin), v[..., :3])) if floating else v


covector_mjx_to_pin = v_mjx_to_pin  # G orthogonal: G^-T = G, forces transform as velocities
covector_pin_to_mjx = v_pin_to_mjx


def a_mjx_to_pin(q_pin: torch.Tensor, v_pin: torch.Tensor, a: torch.Tensor, floating: bool = True) -> torch.Tensor:
    """qacc -> Pinocchio a: a_lin = R^T a_lin_mjx - w x v_lin (v_pin in Pinocchio's convention)."""
    if not floating:
        return a
    lin = _mul(base_rotation(q_pin).transpose(-1, -2), a[..., :3]) - torch.cross(v_pin[..., 3:6], v_pin[..., :3], dim=-1)
    return _base_lin(a, lin)


def a_pin_to_mjx(q_pin: torch.Tensor, v_pin: torch.Tensor, a_pin: torch.Tensor, floating: bool = True) -> torch.Tensor:
    """Pinocchio a -> qacc: a_lin_mjx = R (a_lin + w x v_lin)."""
    if not floating:
        return a_pin
    lin = _mul(base_rotation(q_pin), a_pin[..., :3] + torch.cross(v_pin[..., 3:6], v_pin[..., :3], dim=-1))
    return _base_lin(a_pin, lin)


def congruence_pin_to_mjx(q_pin: torch.Tensor, M: torch.Tensor, floating: bool = True) -> torch.Tensor:
    """(..., nv, nv) G M G^T: mass matrix and its inverse."""
    return _rows(q_pin, columns_pin_to_mjx(q_pin, M, floating), floating)


def columns_pin_to_mjx(q_pin: torch.Tensor, J: torch.Tensor, floating: bool = True) -> torch.Tensor:
    """(..., rows, nv) J G^T: base-linear columns right-multiplied by R^T (Jacobians, centroidal map)."""
    if not floating:
        return J
    cols = J[..., :, :3] @ base_rotation(q_pin).transpose(-1, -2)
    return torch.cat([cols, J[..., :, 3:]], dim=-1)


def _rows(q_pin: torch.Tensor, X: torch.Tensor, floating: bool) -> torch.Tensor:
    if not floating:
        return X
    return torch.cat([base_rotation(q_pin) @ X[..., :3, :], X[..., 3:, :]], dim=-2)


def _reorder(q: torch.Tensor, index: list[int]) -> torch.Tensor:
    return torch.cat([q[..., index], q[..., 7:]], dim=-1)


def _mul(R: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    return (R @ x.unsqueeze(-1)).squeeze(-1)


def _base_lin(x: torch.Tensor, lin: torch.Tensor) -> torch.Tensor:
    return torch.cat([lin, x[..., 3:]], dim=-1)
