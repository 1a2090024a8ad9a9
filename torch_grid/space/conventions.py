"""Pinocchio <-> MuJoCo convention transforms in plain torch: the readable oracle that the fused
kernel twins are tested against.

Only quaternion joints differ between the conventions:
  - configuration: MuJoCo's quaternions (free and ball joints) are wxyz, Pinocchio's xyzw;
  - velocity: a free joint's linear velocity is in the world frame in MuJoCo's, in the body frame in
    Pinocchio's (angular velocities, a ball joint's included, are local in both).
With R_f free joint f's rotation and G = blockdiag(R_f on each free joint's linear dofs, I elsewhere),
v_mujoco = G v_pin; generalized forces transform like velocities (G orthogonal), M -> G M G^T,
Jacobians J -> J G^T. An acceleration also picks up the rate of change of G:
a_lin_mujoco = R_f (a_lin_pin + w x v_lin_pin).

Every function takes any leading batch shape. `q_pin` is a configuration in Pinocchio's layout.
`free` lists each free joint's (first q index, first v index); by default one free root at (0, 0)
when floating, none when floating=False. `balls` lists each ball joint's first q index. A robot's
own lists: `free_joints(model)`, `ball_joints(model)`; `of(robot)` gives the transforms with them filled in.
"""
from __future__ import annotations

import warnings
from typing import Sequence

import torch

from ..model.description import RobotModel

__all__ = [
    "free_joints", "ball_joints", "unit_quaternion", "quaternion_rotation", "base_rotation", "q_mujoco_to_pin",
    "q_pin_to_mujoco", "v_mujoco_to_pin", "v_pin_to_mujoco", "a_mujoco_to_pin", "a_pin_to_mujoco", "covector_mujoco_to_pin",
    "covector_pin_to_mujoco", "congruence_pin_to_mujoco", "columns_pin_to_mujoco", "of", "RobotConversions",
]
# The former names (`mjx` for MuJoCo's convention), kept for one release (CHANGELOG.md).
FORMER_NAMES = {name.replace("mujoco", "mjx"): name for name in __all__ if "mujoco" in name}

Free = Sequence[tuple[int, int]]


def free_joints(model) -> list[tuple[int, int]]:
    """(first q index, first v index) of each free joint of a RobotModel."""
    return [(qi, vi) for j, qi, vi in zip(model.joints, model.q_index, model.v_index) if j.type == "free"]


def ball_joints(model) -> list[int]:
    """First q index of each ball joint of a RobotModel."""
    return [qi for j, qi in zip(model.joints, model.q_index) if j.type == "ball"]


QUAT_MIN_NORM = 1e-15  # MuJoCo's mjMINVAL: below it mj_normalizeQuat (and the kernels) read the identity


def unit_quaternion(quat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(quat / |quat|, |quat|) for (..., 4) xyzw quaternions, each (..., 4) and (..., 1). A quaternion
    of norm below QUAT_MIN_NORM (zero) reads as the identity of norm 1, as MuJoCo's mj_normalizeQuat
    does; one with a NaN or infinite entry is NaN in every component, and so is its gradient, so that a
    diverged state stays visible (mj_normalizeQuat leaves a NaN too)."""
    norm = quat.norm(dim=-1, keepdim=True)
    zero = norm < QUAT_MIN_NORM
    identity = torch.zeros_like(quat)
    identity[..., 3] = 1
    # quat / inf would leave finite zeros beside an infinite entry's NaN, and a finite gradient
    scale = torch.where(zero, 1, torch.where(torch.isfinite(norm), norm, torch.nan))
    return torch.where(zero, identity, quat / scale), torch.where(zero, 1, norm)


def base_rotation(q_pin: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation of the normalised base quaternion q_pin[..., 3:7] (xyzw), as
    quaternion_rotation."""
    return quaternion_rotation(q_pin[..., 3:7])


def quaternion_rotation(quat: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation of the normalised (..., 4) xyzw quaternion; the identity for a quaternion of
    norm below QUAT_MIN_NORM, NaN for one with a NaN or infinite entry (unit_quaternion)."""
    x, y, z, w = unit_quaternion(quat)[0].unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(*quat.shape[:-1], 3, 3)


def q_mujoco_to_pin(q: torch.Tensor, floating: bool = True, balls: Sequence[int] = (), free: Free | None = None) -> torch.Tensor:
    """MuJoCo qpos (quaternions wxyz) -> Pinocchio q (xyzw)."""
    return _reorder(q, [qi + 3 for qi, _ in _free(floating, free)] + list(balls), [1, 2, 3, 0])


def q_pin_to_mujoco(q: torch.Tensor, floating: bool = True, balls: Sequence[int] = (), free: Free | None = None) -> torch.Tensor:
    """Pinocchio q (quaternions xyzw) -> MuJoCo qpos (wxyz)."""
    return _reorder(q, [qi + 3 for qi, _ in _free(floating, free)] + list(balls), [3, 0, 1, 2])


def v_mujoco_to_pin(q_pin: torch.Tensor, v: torch.Tensor, floating: bool = True, free: Free | None = None) -> torch.Tensor:
    """qvel -> Pinocchio v: each free joint's v_lin = R^T v_lin_mujoco."""
    return _linear(v, {vi: _mul(_rotation(q_pin, qi).mT, v[..., vi:vi + 3]) for qi, vi in _free(floating, free)})


def v_pin_to_mujoco(q_pin: torch.Tensor, v: torch.Tensor, floating: bool = True, free: Free | None = None) -> torch.Tensor:
    """Pinocchio v -> qvel: each free joint's v_lin_mujoco = R v_lin."""
    return _linear(v, {vi: _mul(_rotation(q_pin, qi), v[..., vi:vi + 3]) for qi, vi in _free(floating, free)})


covector_mujoco_to_pin = v_mujoco_to_pin  # G orthogonal: G^-T = G, forces transform as velocities
covector_pin_to_mujoco = v_pin_to_mujoco


def a_mujoco_to_pin(q_pin: torch.Tensor, v_pin: torch.Tensor, a: torch.Tensor, floating: bool = True,
                 free: Free | None = None) -> torch.Tensor:
    """qacc -> Pinocchio a: a_lin = R^T a_lin_mujoco - w x v_lin (v_pin in Pinocchio's convention)."""
    return _linear(a, {vi: _mul(_rotation(q_pin, qi).mT, a[..., vi:vi + 3]) - _w_cross_v(v_pin, vi)
                       for qi, vi in _free(floating, free)})


def a_pin_to_mujoco(q_pin: torch.Tensor, v_pin: torch.Tensor, a_pin: torch.Tensor, floating: bool = True,
                 free: Free | None = None) -> torch.Tensor:
    """Pinocchio a -> qacc: a_lin_mujoco = R (a_lin + w x v_lin)."""
    return _linear(a_pin, {vi: _mul(_rotation(q_pin, qi), a_pin[..., vi:vi + 3] + _w_cross_v(v_pin, vi))
                           for qi, vi in _free(floating, free)})


def congruence_pin_to_mujoco(q_pin: torch.Tensor, M: torch.Tensor, floating: bool = True,
                          free: Free | None = None) -> torch.Tensor:
    """(..., nv, nv) G M G^T: mass matrix and its inverse."""
    MGt = columns_pin_to_mujoco(q_pin, M, floating, free)
    return columns_pin_to_mujoco(q_pin, MGt.mT, floating, free).mT


def columns_pin_to_mujoco(q_pin: torch.Tensor, J: torch.Tensor, floating: bool = True,
                       free: Free | None = None) -> torch.Tensor:
    """(..., rows, nv) J G^T: each free joint's linear columns right-multiplied by R^T (Jacobians,
    centroidal map)."""
    cols = {vi: J[..., :, vi:vi + 3] @ _rotation(q_pin, qi).mT for qi, vi in _free(floating, free)}
    if not cols:
        return J
    parts, k = [], 0
    for vi in sorted(cols):
        parts += [J[..., :, k:vi], cols[vi]]
        k = vi + 3
    return _cat_broadcast(parts + [J[..., :, k:]], 2)


def _free(floating: bool, free: Free | None) -> list[tuple[int, int]]:
    return list(free) if free is not None else [(0, 0)] if floating else []


def _rotation(q_pin: torch.Tensor, qi: int) -> torch.Tensor:
    return quaternion_rotation(q_pin[..., qi + 3:qi + 7])


def _w_cross_v(v_pin: torch.Tensor, vi: int) -> torch.Tensor:
    return torch.cross(v_pin[..., vi + 3:vi + 6], v_pin[..., vi:vi + 3], dim=-1)


def _reorder(q: torch.Tensor, quats: Sequence[int], order: list[int]) -> torch.Tensor:
    """q with each quaternion (at the q indices `quats`) taken in the order `order`."""
    if not quats:
        return q
    index = list(range(q.shape[-1]))
    for b in quats:
        index[b:b + 4] = [b + k for k in order]
    return q[..., index]


def _linear(x: torch.Tensor, parts: dict[int, torch.Tensor]) -> torch.Tensor:
    """x with x[..., vi:vi + 3] replaced by parts[vi] for each key."""
    if not parts:
        return x
    pieces, k = [], 0
    for vi in sorted(parts):
        pieces += [x[..., k:vi], parts[vi]]
        k = vi + 3
    return _cat_broadcast(pieces + [x[..., k:]], 1)


def _cat_broadcast(pieces: list[torch.Tensor], trailing: int) -> torch.Tensor:
    """The pieces joined along their last dimension, each first expanded to their common batch shape (all but
    the `trailing` last dimensions): a piece of x keeps x's batch, a rotated one q_pin's and x's together."""
    batch = torch.broadcast_shapes(*(p.shape[:p.dim() - trailing] for p in pieces))
    return torch.cat([p.expand(*batch, *p.shape[p.dim() - trailing:]) for p in pieces], dim=-1)


def _mul(R: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    return (R @ x.unsqueeze(-1)).squeeze(-1)


class RobotConversions:
    """This module's transforms for one robot's layout: its free and ball joints filled in, in the layout of
    the q and v its functions take (a robot with mimic joints: its independent joints'), and each argument's
    last dimensions checked against the robot's nq and nv. Made by `of(robot)`."""

    def __init__(self, model: RobotModel):
        if model.placed_free_joint:
            raise ValueError(f"conventions.of({model.name!r}): free joint {model.placed_free_joint!r} is placed away from "
                             "the world's origin, where MuJoCo's convention has each free joint (its qpos is its world pose)")
        mimic = {m.joint for m in model.mimics}
        self.free: list[tuple[int, int]] = []
        self.balls: list[int] = []
        nq = nv = 0
        for j in model.joints:
            if j.name in mimic:
                continue
            if j.type == "free":
                self.free.append((nq, nv))
            elif j.type == "ball":
                self.balls.append(nq)
            nq, nv = nq + j.nq, nv + j.nv
        self.name, self.nq, self.nv = model.name, nq, nv

    def q_mujoco_to_pin(self, q: torch.Tensor) -> torch.Tensor:
        """MuJoCo qpos (..., nq) -> Pinocchio q (..., nq)."""
        return q_mujoco_to_pin(self._sized("q_mujoco_to_pin", "q", q, "nq"), balls=self.balls, free=self.free)

    def q_pin_to_mujoco(self, q: torch.Tensor) -> torch.Tensor:
        """Pinocchio q (..., nq) -> MuJoCo qpos (..., nq)."""
        return q_pin_to_mujoco(self._sized("q_pin_to_mujoco", "q", q, "nq"), balls=self.balls, free=self.free)

    def v_mujoco_to_pin(self, q_pin: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """qvel (..., nv) -> Pinocchio v (..., nv), at Pinocchio's q_pin."""
        return v_mujoco_to_pin(*self._state("v_mujoco_to_pin", q_pin, v), free=self.free)

    def v_pin_to_mujoco(self, q_pin: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Pinocchio v (..., nv) -> qvel (..., nv), at Pinocchio's q_pin."""
        return v_pin_to_mujoco(*self._state("v_pin_to_mujoco", q_pin, v), free=self.free)

    def covector_mujoco_to_pin(self, q_pin: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
        """MuJoCo joint forces (..., nv) -> Pinocchio's, at Pinocchio's q_pin."""
        return covector_mujoco_to_pin(*self._state("covector_mujoco_to_pin", q_pin, f, "f"), free=self.free)

    def covector_pin_to_mujoco(self, q_pin: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
        """Pinocchio joint forces (..., nv) -> MuJoCo's, at Pinocchio's q_pin."""
        return covector_pin_to_mujoco(*self._state("covector_pin_to_mujoco", q_pin, f, "f"), free=self.free)

    def a_mujoco_to_pin(self, q_pin: torch.Tensor, v_pin: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """qacc (..., nv) -> Pinocchio a (..., nv), at Pinocchio's q_pin and v_pin."""
        q_pin, v_pin = self._state("a_mujoco_to_pin", q_pin, v_pin, "v_pin")
        return a_mujoco_to_pin(q_pin, v_pin, self._sized("a_mujoco_to_pin", "a", a, "nv", q_pin), free=self.free)

    def a_pin_to_mujoco(self, q_pin: torch.Tensor, v_pin: torch.Tensor, a_pin: torch.Tensor) -> torch.Tensor:
        """Pinocchio a (..., nv) -> qacc (..., nv), at Pinocchio's q_pin and v_pin."""
        q_pin, v_pin = self._state("a_pin_to_mujoco", q_pin, v_pin, "v_pin")
        return a_pin_to_mujoco(q_pin, v_pin, self._sized("a_pin_to_mujoco", "a_pin", a_pin, "nv", q_pin), free=self.free)

    def congruence_pin_to_mujoco(self, q_pin: torch.Tensor, M: torch.Tensor) -> torch.Tensor:
        """(..., nv, nv) G M G^T at Pinocchio's q_pin: the mass matrix and its inverse."""
        q_pin = self._sized("congruence_pin_to_mujoco", "q_pin", q_pin, "nq")
        M = self._sized("congruence_pin_to_mujoco", "M", M, "nv", q_pin)
        if M.dim() < 2 or M.shape[-2] != self.nv:
            raise ValueError(f"conventions.of({self.name!r}).congruence_pin_to_mujoco: M must be (..., nv, nv) with "
                             f"nv = {self.nv}, got shape {tuple(M.shape)}")
        return congruence_pin_to_mujoco(q_pin, M, free=self.free)

    def columns_pin_to_mujoco(self, q_pin: torch.Tensor, J: torch.Tensor) -> torch.Tensor:
        """(..., rows, nv) J G^T at Pinocchio's q_pin: Jacobians, the centroidal map."""
        q_pin = self._sized("columns_pin_to_mujoco", "q_pin", q_pin, "nq")
        J = self._sized("columns_pin_to_mujoco", "J", J, "nv", q_pin)
        if J.dim() < 2:
            raise ValueError(f"conventions.of({self.name!r}).columns_pin_to_mujoco: J must be (..., rows, nv), got shape "
                             f"{tuple(J.shape)}")
        return columns_pin_to_mujoco(q_pin, J, free=self.free)

    def _state(self, function: str, q_pin: torch.Tensor, x: torch.Tensor, name: str = "v"):
        q_pin = self._sized(function, "q_pin", q_pin, "nq")
        return q_pin, self._sized(function, name, x, "nv", q_pin)

    def _sized(self, function: str, name: str, x: torch.Tensor, size: str, like: torch.Tensor | None = None) -> torch.Tensor:
        """x, whose last dimension must be the robot's `size` ("nq" or "nv"), a float tensor of like's dtype and
        device (torch promoted an integer or mixed argument in some transforms and failed inside others)."""
        n = getattr(self, size)
        where = f"conventions.of({self.name!r}).{function}: {name}"
        if not isinstance(x, torch.Tensor) or x.dim() == 0 or x.shape[-1] != n:
            got = f"shape {tuple(x.shape)}" if isinstance(x, torch.Tensor) else type(x).__name__
            raise ValueError(f"{where} must have {size} = {n} entries in its last dimension, got {got}")
        if not x.is_floating_point():
            raise TypeError(f"{where} must be a float tensor, got {x.dtype}")
        if like is not None and (x.dtype != like.dtype or x.device != like.device):
            raise TypeError(f"{where} is {x.dtype} on {x.device}, expected q_pin's {like.dtype} on {like.device}")
        return x

    def __repr__(self) -> str:
        return f"<conventions of {self.name!r}: free joints at (q, v) {self.free}, ball joints at q {self.balls}>"


def of(robot) -> RobotConversions:
    """This module's transforms for `robot` (a Robot, one of its views or a RobotModel): each function
    without `floating`, `free` and `balls`, which come from the robot, and with its arguments' sizes checked.

        cv = conventions.of(robot)
        qpos, qvel = cv.q_pin_to_mujoco(q), cv.v_pin_to_mujoco(q, v)
    """
    model = robot if isinstance(robot, RobotModel) else getattr(robot, "model", None)
    if not isinstance(model, RobotModel):
        raise TypeError(f"conventions.of: expected a Robot, a RobotView or a RobotModel, got {type(robot).__name__}")
    return RobotConversions(model)


def __getattr__(name: str):
    """A former name: the function under its name now, with a DeprecationWarning."""
    if name in FORMER_NAMES:
        warnings.warn(f"conventions.{name} is now conventions.{FORMER_NAMES[name]}; the former name goes in 0.3",
                      DeprecationWarning, stacklevel=2)
        return globals()[FORMER_NAMES[name]]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
