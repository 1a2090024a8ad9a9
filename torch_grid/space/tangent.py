"""The tangent space of a configuration and the ambient coordinates of q.

The derivative kernels differentiate along the tangent space (nv directions); a caller's q has nq
coordinates. They differ at the quaternion joints:
  - a free joint moves by Pinocchio's local increment (position + R dv_lin) or by mj_integratePos's
    (position + dv_lin, world frame); both turn its quaternion by the local rotation;
  - a ball joint turns its quaternion by the local rotation, in both conventions.
The quaternion is xyzw in Pinocchio's convention and wxyz in MuJoCo's.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..model.description import RobotModel
from .constants import constant
from .conventions import quaternion_rotation, unit_quaternion


@dataclass(frozen=True)
class QuaternionJoint:
    free: bool  # a free joint (position first), else a ball joint
    qi: int  # first configuration coordinate
    vi: int  # first velocity coordinate

    @property
    def quat(self) -> int:
        """First coordinate of the quaternion."""
        return self.qi + 3 if self.free else self.qi

    @property
    def angular(self) -> int:
        """First velocity coordinate of the local angular velocity."""
        return self.vi + 3 if self.free else self.vi


@dataclass(frozen=True)
class Layout:
    quaternions: tuple[QuaternionJoint, ...]
    scalar_q: tuple[int, ...]  # q coordinate of each one-dof joint
    scalar_v: tuple[int, ...]  # its velocity coordinate

    @property
    def scalar_runs(self) -> tuple[tuple[int, int, int], ...]:
        """The one-dof joints as runs (first q coordinate, first velocity coordinate, length) that are
        contiguous in both, so that a run moves between q and the tangent space as one slice."""
        runs: list[list[int]] = []
        for qi, vi in zip(self.scalar_q, self.scalar_v):
            if runs and runs[-1][0] + runs[-1][2] == qi and runs[-1][1] + runs[-1][2] == vi:
                runs[-1][2] += 1
            else:
                runs.append([qi, vi, 1])
        return tuple(map(tuple, runs))


_LAYOUTS: dict[str, Layout] = {}


def layout(model: RobotModel) -> Layout:
    """Where each joint's coordinates sit in q and in the tangent space (cached per model)."""
    found = _LAYOUTS.get(model.hash)
    if found is None:
        quats, sq, sv = [], [], []
        for j, qi, vi in zip(model.joints, model.q_index, model.v_index):
            if j.type in ("free", "ball"):
                quats.append(QuaternionJoint(j.type == "free", qi, vi))
            else:
                sq.append(qi)
                sv.append(vi)
        found = _LAYOUTS[model.hash] = Layout(tuple(quats), tuple(sq), tuple(sv))
    return found


def _xyzw(q: torch.Tensor, j: QuaternionJoint, convention: int) -> tuple[torch.Tensor, torch.Tensor, int, slice]:
    """(xyz (..., 3), w (..., 1), the index of w, the slice of xyz) of joint j's quaternion in q."""
    a = j.quat
    if convention:
        return q[..., a + 1:a + 4], q[..., a:a + 1], a, slice(a + 1, a + 4)
    return q[..., a:a + 3], q[..., a + 3:a + 4], a + 3, slice(a, a + 3)


def tangent_directions(model: RobotModel, q: torch.Tensor, convention: int) -> torch.Tensor:
    """(..., nv, nq): row j is the change of q along its tangent direction j (Pinocchio's local
    increment, or mj_integratePos's), d/de (q + e_j e) in the coordinates of q."""
    lay = layout(model)
    nq = q.shape[-1]
    # entries (row, column) and their values, placed out of place (torch.func.vmap batches that)
    flat, values = [], []
    if lay.scalar_q:
        flat += [r * nq + c for r, c in zip(lay.scalar_v, lay.scalar_q)]
        values.append(torch.ones_like(q[..., :1]).expand(*q.shape[:-1], len(lay.scalar_q)))
    eye = torch.eye(3, dtype=q.dtype, device=q.device)
    for j in lay.quaternions:
        xyz, w, iw, ixyz = _xyzw(q, j, convention)
        if j.free:  # position + v (MuJoCo, world frame) or + R v (Pinocchio)
            block = eye.expand(*q.shape[:-1], 3, 3) if convention else quaternion_rotation(torch.cat([xyz, w], dim=-1)).mT
            flat += [(j.vi + r) * nq + j.qi + c for r in range(3) for c in range(3)]
            values.append(block.reshape(*q.shape[:-1], 9))
        # dQ = Q (x) (w_k, 0) / 2 for the unit rotation rate w_k: d xyz = (w e_k + xyz x e_k) / 2, d w = -xyz_k / 2
        for k in range(3):
            e = eye[k].expand_as(xyz)
            flat += [(j.angular + k) * nq + c for c in range(ixyz.start, ixyz.stop)] + [(j.angular + k) * nq + iw]
            values += [0.5 * (w * e + torch.cross(xyz, e, dim=-1)), -0.5 * xyz[..., k:k + 1]]
    t = torch.zeros(*q.shape[:-1], model.nv * nq, dtype=q.dtype, device=q.device)
    index = constant(tuple(flat), torch.long, q.device)
    return t.index_copy(-1, index, torch.cat(values, dim=-1)).unflatten(-1, (model.nv, nq))


def broadcast_batch(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """a (..., n) and b (..., m) expanded to their common batch shape."""
    batch = torch.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    return a.expand(*batch, a.shape[-1]), b.expand(*batch, b.shape[-1])


def _in_q_order(pieces: list[tuple[int, torch.Tensor]]) -> torch.Tensor:
    """(first coordinate of q, its values (..., n)) for every coordinate of q once, joined in q's order: out of
    place and by slices, so that torch.func.vmap batches it and no gather runs."""
    return torch.cat([part for _, part in sorted(pieces, key=lambda piece: piece[0])], dim=-1)


def _rotate(u: torch.Tensor, w: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """R v for the rotation of the unit quaternion (u (..., 3), w (..., 1)): v + 2 w (u x v) + 2 u x (u x v); R^T v
    is the rotation of its conjugate, (-u, w)."""
    uv = torch.cross(u, v, dim=-1)
    return v + 2 * (w * uv + torch.cross(u, uv, dim=-1))


def _normalised(xyz: torch.Tensor, w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(xyz, w) of a quaternion read by _xyzw, normalised (unit_quaternion: a zero one the identity, a non-finite one
    NaN), and its norm (..., 1)."""
    unit, norm = unit_quaternion(torch.cat([xyz, w], dim=-1))
    return unit[..., :3], unit[..., 3:], norm


def ambient_direction(model: RobotModel, q: torch.Tensor, u: torch.Tensor, convention: int) -> torch.Tensor:
    """(..., nq): the change of q along the tangent vector u (..., nv), u^T tangent_directions(q)
    without the nv x nq matrix."""
    lay = layout(model)
    if not lay.quaternions:
        return u
    q, u = broadcast_batch(q, u)
    pieces = [(qi, u[..., vi:vi + n]) for qi, vi, n in lay.scalar_runs]
    for j in lay.quaternions:
        xyz, w, iw, ixyz = _xyzw(q, j, convention)
        w_ang = u[..., j.angular:j.angular + 3]
        if j.free:
            u_lin = u[..., j.vi:j.vi + 3]
            pieces.append((j.qi, u_lin if convention else _rotate(*_normalised(xyz, w)[:2], u_lin)))
        pieces.append((ixyz.start, 0.5 * (w * w_ang + torch.cross(xyz, w_ang, dim=-1))))
        pieces.append((iw, -0.5 * (xyz * w_ang).sum(-1, keepdim=True)))
    return _in_q_order(pieces)


def ambient_to_tangent(model: RobotModel, q: torch.Tensor, g: torch.Tensor, convention: int) -> torch.Tensor:
    """(..., nv): a gradient g (..., nq) in the coordinates of q carried to q's tangent space, ambient_direction's
    transpose: g . ambient_direction(q, u) = u . ambient_to_tangent(q, g) for every u."""
    lay = layout(model)
    if not lay.quaternions:
        return g
    q, g = broadcast_batch(q, g)
    pieces = [(vi, g[..., qi:qi + n]) for qi, vi, n in lay.scalar_runs]
    for j in lay.quaternions:
        xyz, w, iw, ixyz = _xyzw(q, j, convention)
        g_xyz, g_w = g[..., ixyz], g[..., iw:iw + 1]
        if j.free:
            g_lin = g[..., j.qi:j.qi + 3]
            if not convention:  # R^T g
                xyz_n, w_n, _ = _normalised(xyz, w)
                g_lin = _rotate(-xyz_n, w_n, g_lin)
            pieces.append((j.vi, g_lin))
        # dxyz = (w u + xyz x u) / 2, dw = -xyz . u / 2, transposed
        pieces.append((j.angular, 0.5 * (w * g_xyz + torch.cross(g_xyz, xyz, dim=-1) - g_w * xyz)))
    return _in_q_order(pieces)


def tangent_to_ambient(model: RobotModel, q: torch.Tensor, g: torch.Tensor, convention: int) -> torch.Tensor:
    """Gradient along the tangent space (..., nv) -> gradient in the coordinates of q (..., nq).

    A quaternion Q turns by the local rotation dw = 2 vec(conj(Q/|Q|) (x) dQ) / |Q|, whose transpose
    maps the angular gradient to dQ. A quaternion of norm below MuJoCo's mjMINVAL (zero) reads as
    the identity (the kernels do the same): its gradient is the one at the identity, so that an
    optimiser started there moves off it; one with a NaN or infinite entry gives NaN.
    """
    lay = layout(model)
    if not lay.quaternions:
        return g
    # q's batch may differ from g's (a cotangent carries a batch of its own under torch.func transforms)
    q, g = broadcast_batch(q, g)
    pieces = [(qi, g[..., vi:vi + n]) for qi, vi, n in lay.scalar_runs]
    for j in lay.quaternions:
        xyz, w, iw, ixyz = _xyzw(q, j, convention)
        xyz_n, w_n, norm = _normalised(xyz, w)
        g_ang = g[..., j.angular:j.angular + 3]
        if j.free:
            g_lin = g[..., j.vi:j.vi + 3]
            pieces.append((j.qi, g_lin if convention else _rotate(xyz_n, w_n, g_lin)))
        pieces.append((ixyz.start, 2 / norm * (w_n * g_ang + torch.cross(xyz_n, g_ang, dim=-1))))
        pieces.append((iw, -2 / norm * (xyz_n * g_ang).sum(-1, keepdim=True)))
    return _in_q_order(pieces)


def tangent_direction(model: RobotModel, q: torch.Tensor, t: torch.Tensor, convention: int) -> torch.Tensor:
    """(..., nv): a direction t (..., nq) of q's coordinates as a direction of the tangent space (a forward-mode
    tangent of q carried to where the kernels' derivatives act), tangent_to_ambient's transpose:
    t . tangent_to_ambient(q, g) = tangent_direction(q, t) . g for every g, with the same reading of a zero
    (the identity) and of a NaN or infinite quaternion (NaN)."""
    lay = layout(model)
    if not lay.quaternions:
        return t
    q, t = broadcast_batch(q, t)
    pieces = [(vi, t[..., qi:qi + n]) for qi, vi, n in lay.scalar_runs]
    for j in lay.quaternions:
        xyz, w, iw, ixyz = _xyzw(q, j, convention)
        xyz_n, w_n, norm = _normalised(xyz, w)
        t_xyz, t_w = t[..., ixyz], t[..., iw:iw + 1]
        if j.free:  # R^T t in Pinocchio's convention
            t_lin = t[..., j.qi:j.qi + 3]
            pieces.append((j.vi, t_lin if convention else _rotate(-xyz_n, w_n, t_lin)))
        # tangent_to_ambient's 2 / |Q| (w u + xyz x u, -xyz . u), transposed
        pieces.append((j.angular, 2 / norm * (w_n * t_xyz + torch.cross(t_xyz, xyz_n, dim=-1) - t_w * xyz_n)))
    return _in_q_order(pieces)


def _cross(a: list[float], b: list[float]) -> list[float]:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _bracket_constants(free: bool, convention: int) -> list:
    """c[k][j] = [e_k, e_j] for a quaternion joint's tangent basis e: for a free joint e = (v, w), in
    se(3) for Pinocchio's increments, [(v1, w1), (v2, w2)] = (w1 x v2 - w2 x v1, w1 x w2);
    mj_integratePos's position is a plain sum, so there only rotations bracket. A ball joint's e = w,
    [w1, w2] = w1 x w2."""
    if not free:
        e = [[float(r == c) for c in range(3)] for r in range(3)]
        return [[_cross(e[k], e[j]) for j in range(3)] for k in range(3)]
    e = [[float(r == c) for c in range(6)] for r in range(6)]
    c = []
    for k in range(6):
        row = []
        for j in range(6):
            (vk, wk), (vj, wj) = (e[k][:3], e[k][3:]), (e[j][:3], e[j][3:])
            lin = [0.0] * 3 if convention else [x - y for x, y in zip(_cross(wk, vj), _cross(wj, vk))]
            row.append(lin + _cross(wk, wj))
        c.append(row)
    return c


def _nested_tuple(x):
    return tuple(_nested_tuple(y) for y in x) if isinstance(x, list) else x


_BRACKET = {(free, convention): _nested_tuple(_bracket_constants(free, convention)) for free in (True, False)
            for convention in (0, 1)}


def has_brackets(model: RobotModel) -> bool:
    """Whether some tangent directions of q do not commute (a quaternion joint)."""
    return bool(layout(model).quaternions)


def bracket_term(model: RobotModel, g_tan: torch.Tensor, convention: int) -> torch.Tensor:
    """(..., nv): sum_j g_j . [e_k, e_j] over each quaternion joint's directions j, k, with g_j (rows
    of g_tan, (..., nv, nv)) the tangent gradients: the second derivative along k then j less the
    one along j then k."""
    return _brackets(model, lambda vi, n: g_tan[..., vi:vi + n, vi:vi + n], g_tan.shape[:-2] + g_tan.shape[-1:],
                     g_tan, convention)


def bracket_term_outer(model: RobotModel, u: torch.Tensor, g: torch.Tensor, convention: int) -> torch.Tensor:
    """bracket_term of the outer product u g^T (u, g (..., nv)) from its quaternion joints' blocks alone."""
    return _brackets(model, lambda vi, n: u[..., vi:vi + n, None] * g[..., None, vi:vi + n],
                     torch.broadcast_shapes(u.shape, g.shape), g, convention)


def _brackets(model: RobotModel, block, shape, like: torch.Tensor, convention: int) -> torch.Tensor:
    """bracket_term with block(vi, n) the rows and columns vi.. vi + n of g_tan, out of shape (..., nv)."""
    indices, parts = [], []
    for j in layout(model).quaternions:
        n = 6 if j.free else 3
        c = constant(_BRACKET[j.free, convention], like.dtype, like.device)
        indices += range(j.vi, j.vi + n)
        parts.append(torch.einsum("...jm,kjm->...k", block(j.vi, n), c))
    out = torch.zeros(shape, dtype=like.dtype, device=like.device)
    if not parts:
        return out
    return out.index_copy(-1, constant(tuple(indices), torch.long, like.device), torch.cat(parts, dim=-1))
