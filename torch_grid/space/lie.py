"""The configuration space: integrate, difference and their tangent-space Jacobians, in torch.

pin convention, Pinocchio's Lie groups (pin.integrate, difference, dIntegrate, dDifference): a free
joint is SE(3), q (+) v = M exp6(v) (the linear velocity in the body frame); a ball joint is SO(3),
Q exp3(w); the others add, and a continuous joint's angle differs by the shortest turn, in (-pi, pi]
(as Pinocchio's (cos, sin) joint; MuJoCo has no continuous joint, its hinge is a revolute one).
mujoco convention, mj_integratePos / mj_differentiatePos: a free joint's position adds in the world
frame; its quaternion and a ball joint's turn by the local rotation.
Quaternions are read normalised, as the kernels read them (MuJoCo normalises them too).

The Jacobians are (..., nv, nv) along the tangent spaces: a configuration moves by q (+) dq, the
result is compared by difference, as Pinocchio's. Per quaternion joint, with Jr the right Jacobian of
SO(3), R(w) = exp3(w) and (in Pinocchio's convention) Ad the adjoint of SE(3):
  d(q (+) v)/dq = R(v)^T (Ad(exp6(v)^-1)),   d(q (+) v)/dv = Jr(v) (Jexp6(v)),
  d diff(q0, q1)/dq1 = Jr(d)^-1 (Jexp6(d)^-1),   d diff/dq0 = -Jr(d)^-1 R(d)^T (-Jexp6(d)^-1 Ad(exp6(d)^-1)),
with a free joint's position block the identity in MuJoCo's convention. Everything is torch, so
autograd, torch.compile and torch.func see through it; near a zero angle the coefficients are their
Taylor series (smooth to second order).
"""
from __future__ import annotations

from dataclasses import dataclass

import math

import torch

from .constants import scalar_or_tensor
from .conventions import quaternion_rotation, unit_quaternion
from .tangent import broadcast_batch


@dataclass(frozen=True)
class Space:
    """Joint kinds ("free", "ball" or "scalar") in q's order, with each one's first q and v index, and the q
    indices of the continuous joints' angles (scalars whose difference wraps)."""
    kinds: tuple[str, ...]
    qi: tuple[int, ...]
    vi: tuple[int, ...]
    nq: int
    nv: int
    angles: frozenset[int] = frozenset()

    @classmethod
    def of(cls, joint_types: list[str]) -> "Space":
        kinds = tuple(t if t in ("free", "ball") else "scalar" for t in joint_types)
        qi, vi, nq, nv = [], [], 0, 0
        for k in kinds:
            qi.append(nq)
            vi.append(nv)
            nq += {"free": 7, "ball": 4}.get(k, 1)
            nv += {"free": 6, "ball": 3}.get(k, 1)
        angles = frozenset(i for i, t in zip(qi, joint_types) if t == "continuous")
        return cls(kinds, tuple(qi), tuple(vi), nq, nv, angles)


def integrate(space: Space, q: torch.Tensor, v: torch.Tensor, dt, convention: int) -> torch.Tensor:
    """(..., nq): q (+) v dt, for q (..., nq), v (..., nv) and dt a number or a (...,) tensor."""
    q, v = broadcast_batch(q, v * dt_column(dt, v))  # dt's batch may reach beyond q's and v's
    parts = []
    for kind, qi, vi in zip(space.kinds, space.qi, space.vi):
        if kind == "scalar":
            parts.append(q[..., qi:qi + 1] + v[..., vi:vi + 1])
            continue
        quat = _quaternion(q, kind, qi, convention)
        w = v[..., _angular(kind, vi):_angular(kind, vi) + 3]
        e = _exp3(w)
        turned = _mul(quat, e)
        if kind == "free":
            p, v_lin = q[..., qi:qi + 3], v[..., vi:vi + 3]
            if convention:
                parts.append(p + v_lin)
            else:  # M exp6(v): p + R V(w) v_lin; the quaternion in the input's hemisphere, as Pinocchio's
                parts.append(p + apply_matrix(quaternion_rotation(quat), apply_matrix(_left_jacobian(w), v_lin)))
                turned = torch.where(e[..., 3:] < 0, -turned, turned)
        parts.append(turned[..., [3, 0, 1, 2]] if convention else turned)
    return torch.cat(parts, dim=-1)


def difference(space: Space, q0: torch.Tensor, q1: torch.Tensor, convention: int) -> torch.Tensor:
    """(..., nv): the tangent v with q0 (+) v = q1 (the shortest rotation)."""
    q0, q1 = broadcast_batch(q0, q1)
    parts = []
    for kind, qi in zip(space.kinds, space.qi):
        if kind == "scalar":
            d = q1[..., qi:qi + 1] - q0[..., qi:qi + 1]
            parts.append(torch.atan2(torch.sin(d), torch.cos(d)) if qi in space.angles else d)
            continue
        a, b = _quaternion(q0, kind, qi, convention), _quaternion(q1, kind, qi, convention)
        w = log3(_mul(_conjugate(a), b))
        if kind == "free":
            dp = q1[..., qi:qi + 3] - q0[..., qi:qi + 3]
            # log6(M0^-1 M1) = (V(w)^-1 R0^T dp, w)
            parts.append(dp if convention else apply_matrix(left_jacobian_inverse(w), apply_matrix(quaternion_rotation(a).mT, dp)))
        parts.append(w)
    return torch.cat(parts, dim=-1)


def d_integrate(space: Space, q: torch.Tensor, v: torch.Tensor, dt, convention: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(J_q, J_v), each (..., nv, nv): the tangent Jacobians of q (+) v dt."""
    h = dt_column(dt, v)
    batch = torch.broadcast_shapes(q.shape[:-1], v.shape[:-1], h.shape[:-1])  # dt's may reach beyond q's and v's
    v = v.expand(*batch, v.shape[-1])
    blocks = d_integrate_blocks(space, v, dt, convention)
    eye = torch.eye(space.nv, dtype=v.dtype, device=v.device).expand(*batch, space.nv, space.nv)
    return tangent_map(blocks, 0, eye), tangent_map(blocks, 1, eye) * h.unsqueeze(-1)


def d_integrate_blocks(space: Space, v: torch.Tensor, dt, convention: int) -> list:
    """d_integrate without the nv x nv matrices: per quaternion joint (its first velocity index, J_q's
    block, J_v's block / dt); both Jacobians are the identity on the scalar coordinates (J_v: dt)."""
    v = v * dt_column(dt, v)
    blocks = []
    for kind, vi in zip(space.kinds, space.vi):
        if kind == "scalar":
            continue
        w = v[..., _angular(kind, vi):_angular(kind, vi) + 3]
        rot_t, j_v = _rotation(w).mT, d_integrate_v_block(kind, v[..., vi:vi + (6 if kind == "free" else 3)], convention)
        if kind == "ball":
            blocks.append((vi, rot_t, j_v))
        elif convention:
            eye = torch.eye(3, dtype=v.dtype, device=v.device).expand_as(rot_t)
            blocks.append((vi, block_diagonal(eye, rot_t), j_v))
        else:
            blocks.append((vi, _adjoint_exp6_inverse(v[..., vi:vi + 3], w, rot_t), j_v))
    return blocks


def d_integrate_v_block(kind: str, u: torch.Tensor, convention: int) -> torch.Tensor:
    """d(q (+) u)/du of one quaternion joint ("free" or "ball"), u (..., 6 or 3): the right Jacobian Jr on a
    rotation, the identity on MuJoCo's free position, SE(3)'s [[Jr, Q], [0, Jr]] on Pinocchio's free joint."""
    jr = _right_jacobian(u[..., -3:])
    if kind == "ball":
        return jr
    if convention:
        return block_diagonal(torch.eye(3, dtype=u.dtype, device=u.device).expand_as(jr), jr)
    return _upper(jr, _q_right(u[..., :3], u[..., 3:]), jr)


def tangent_map(blocks: list, which: int, x: torch.Tensor) -> torch.Tensor:
    """(..., nv, k): x (..., nv, k) mapped by a block-diagonal matrix given by its quaternion joints'
    blocks (d_integrate_blocks, d_dexp_inverse_blocks; which: the first or second of each pair), the
    identity outside them."""
    if not blocks:
        return x
    parts, start = [], 0
    for vi, *pair in blocks:
        block = pair[which]
        n = block.shape[-1]
        parts += [x[..., start:vi, :], block @ x[..., vi:vi + n, :]]
        start = vi + n
    return torch.cat(parts + [x[..., start:, :]], dim=-2)


def d_difference(space: Space, q0: torch.Tensor, q1: torch.Tensor, convention: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(J_q0, J_q1), each (..., nv, nv): the tangent Jacobians of difference(q0, q1); J_q0 is minus the
    identity on the scalar coordinates, J_q1 the identity."""
    q0, q1 = broadcast_batch(q0, q1)
    d = difference(space, q0, q1, convention)
    blocks = []  # per quaternion joint: (vi, -J_q0's block, J_q1's block)
    for kind, vi in zip(space.kinds, space.vi):
        if kind == "scalar":
            continue
        w = d[..., _angular(kind, vi):_angular(kind, vi) + 3]
        rot_t = _rotation(w).mT
        if kind == "free" and not convention:
            # Jexp6(d)^-1 = [[Jr^-1, -Jr^-1 Q Jr^-1], [0, Jr^-1]], then Ad(exp6(d)^-1) as in d_integrate
            log = dexp_inverse_block(kind, d[..., vi:vi + 6], convention)
            blocks.append((vi, log @ _adjoint_exp6_inverse(d[..., vi:vi + 3], w, rot_t), log))
            continue
        jinv = _right_jacobian_inverse(w)
        if kind == "ball":
            blocks.append((vi, jinv @ rot_t, jinv))
        else:
            eye = torch.eye(3, dtype=d.dtype, device=d.device).expand_as(jinv)
            blocks.append((vi, block_diagonal(eye, jinv @ rot_t), block_diagonal(eye, jinv)))
    eye = torch.eye(space.nv, dtype=d.dtype, device=d.device).expand(*d.shape[:-1], space.nv, space.nv)
    return -tangent_map(blocks, 0, eye), tangent_map(blocks, 1, eye)


def dexp_inverse(space: Space, theta: torch.Tensor, v: torch.Tensor, convention: int) -> torch.Tensor:
    """(..., nv): a tangent velocity v at q (+) theta carried to the chart at q, dexp(theta)^-1 v, with
    dexp(theta) the J_v of d_integrate (dt = 1): the rate of theta for which q (+) theta(t) moves with v
    (Munthe-Kaas's Runge-Kutta stages). Per quaternion joint Jr(w)^-1 on the rotation; in Pinocchio's
    convention SE(3)'s Jexp6(theta)^-1 on a free joint; the other coordinates unchanged."""
    theta, v = broadcast_batch(theta, v)
    parts = []
    for kind, vi in zip(space.kinds, space.vi):
        n = {"free": 6, "ball": 3}.get(kind, 1)
        parts.append(v[..., vi:vi + n] if kind == "scalar" else
                     apply_matrix(carry_block(kind, theta[..., vi:vi + n], convention), v[..., vi:vi + n]))
    return torch.cat(parts, dim=-1)


def d_dexp_inverse_blocks(space: Space, theta: torch.Tensor, v: torch.Tensor, convention: int,
                          outer: bool = False) -> list:
    """Per quaternion joint (its first velocity index, d/dtheta block, d/dv block) of dexp_inverse; d/dv
    is the identity elsewhere, d/dtheta zero. d/dtheta by forward-mode AD of the block's closed form, or,
    with `outer` (theta or v carry a torch.autograd.forward_ad tangent, a level torch.func.jacfwd may not
    nest in), by reverse mode with create_graph, whose own forward-mode derivative the outer level takes."""
    theta, v = broadcast_batch(theta, v)
    blocks = []
    for kind, vi in zip(space.kinds, space.vi):
        if kind == "scalar":
            continue
        n = 6 if kind == "free" else 3
        t_b, v_b = theta[..., vi:vi + n], v[..., vi:vi + n]

        def carried(t, x, kind=kind):
            return apply_matrix(carry_block(kind, t, convention), x)

        if outer:
            jac = _reverse_jacobian(carried, t_b, v_b)
        else:
            # contiguous: forward AD cannot write tangents into a broadcast (stride-0) batch
            # reverse mode while torch.compile traces, whose forward-mode AD inside vmap fails an internal check
            jacobian = torch.func.jacrev if torch.compiler.is_compiling() else torch.func.jacfwd
            jac = torch.func.vmap(jacobian(carried))(t_b.reshape(-1, n).contiguous(),
                                                               v_b.reshape(-1, n).contiguous())
        blocks.append((vi, jac.reshape(*theta.shape[:-1], n, n), carry_block(kind, t_b, convention)))
    return blocks


def _reverse_jacobian(fn, t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """(..., n, n): d fn(t, x) / dt of a function acting on the last dimension, one reverse pass per row."""
    t = t.clone()
    if not t.requires_grad:
        t.requires_grad_(True)
    with torch.enable_grad():
        out = fn(t, x)
        rows = [torch.autograd.grad(out[..., m].sum(), t, create_graph=True)[0] for m in range(out.shape[-1])]
    return torch.stack(rows, dim=-2)


def carry_block(kind: str, theta: torch.Tensor, convention: int) -> torch.Tensor:
    """The block of dexp_inverse: dexp_inverse_block at the stage's rotation as MuJoCo's Runge-Kutta turns by
    it, the short way round (|w| <= pi, its quaternion difference's), in MuJoCo's convention; at theta itself
    in Pinocchio's (csrc/kernels/step/runge_kutta.h: stage_turn)."""
    if convention:
        rotation = shortest_turn(theta[..., -3:])
        theta = rotation if kind == "ball" else torch.cat([theta[..., :3], rotation], dim=-1)
    return dexp_inverse_block(kind, theta, convention)


def shortest_turn(w: torch.Tensor) -> torch.Tensor:
    """Rotation vectors (..., 3) with whole turns taken off, |w| <= pi: the same rotation, the short way round
    (piecewise smooth: the number of turns is constant between the odd multiples of pi)."""
    t = torch.linalg.vector_norm(w, dim=-1, keepdim=True)
    turns = torch.round(t.detach() / (2 * math.pi))
    return torch.where(turns > 0, w * (1 - 2 * math.pi * turns / torch.where(turns > 0, t, torch.ones_like(t))), w)


def dexp_inverse_block(kind: str, theta: torch.Tensor, convention: int) -> torch.Tensor:
    """dexp(theta)^-1 of one quaternion joint, (..., n, n)."""
    if kind == "ball":
        return _right_jacobian_inverse(theta)
    jinv = _right_jacobian_inverse(theta[..., 3:])
    if convention:
        return block_diagonal(torch.eye(3, dtype=theta.dtype, device=theta.device).expand_as(jinv), jinv)
    return _upper(jinv, -jinv @ _q_right(theta[..., :3], theta[..., 3:]) @ jinv, jinv)


# -- SO(3) and SE(3) pieces, batched over leading dimensions -------------------------------------------

_SMALL = 1e-4  # below this angle squared, the Taylor series (error ~ angle^6) are exact in float64


def _coefficients(w: torch.Tensor, exact, series) -> torch.Tensor:
    """exact(theta) where the angle |w| is large enough, series(theta^2) near zero: both evaluated only
    where they are safe, so that gradients through the other branch stay finite. exact runs in float64
    for a float32 w: its forms cancel (1 - cos t, t - sin t) just above the series' range, and their
    derivatives the more, which lost float32 most of its digits there."""
    t2 = (w * w).sum(-1, keepdim=True)
    small = t2 < _SMALL
    theta = torch.sqrt(torch.where(small, torch.ones_like(t2), t2).to(torch.float64))
    return torch.where(small, series(t2), exact(theta).to(t2.dtype))


def skew(w: torch.Tensor) -> torch.Tensor:
    x, y, z = w.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).unflatten(-1, (3, 3))


def _exp3(w: torch.Tensor) -> torch.Tensor:
    """The unit quaternion (xyzw) of the rotation vector w."""
    half = _coefficients(w, lambda t: torch.sin(t / 2) / t, lambda t2: 0.5 - t2 / 48 + t2 * t2 / 3840)
    cos = _coefficients(w, lambda t: torch.cos(t / 2), lambda t2: 1 - t2 / 8 + t2 * t2 / 384)
    return torch.cat([half * w, cos], dim=-1)


def log3(quat: torch.Tensor) -> torch.Tensor:
    """The rotation vector of the shortest rotation of a unit quaternion (xyzw)."""
    quat = torch.where(quat[..., 3:] < 0, -quat, quat)
    xyz, w = quat[..., :3], quat[..., 3:]
    # |log| = 2 atan2(s, w), s = |xyz|: the factor 2 atan2(s, w) / s, near s = 0 its series in s / w
    s2 = (xyz * xyz).sum(-1, keepdim=True)
    small = s2 < _SMALL
    s = torch.sqrt(torch.where(small, torch.ones_like(s2), s2))
    w_small = torch.where(small, w, torch.ones_like(w))  # w = 0 at a half turn: 2 / w there would make gradients NaN
    r2 = s2 / (w_small * w_small)
    factor = torch.where(small, 2 / w_small * (1 - r2 / 3 + r2 * r2 / 5), 2 * torch.atan2(s, w) / s)
    return factor * xyz


def _rotation(w: torch.Tensor) -> torch.Tensor:
    """R(w) = exp3(w), (..., 3, 3)."""
    return quaternion_rotation(_exp3(w))


def _so3_terms(w: torch.Tensor, a, a_series, b, b_series) -> torch.Tensor:
    """I + a(theta) [w] + b(theta) [w]^2."""
    W = skew(w)
    ca = _coefficients(w, a, a_series).unsqueeze(-1)
    cb = _coefficients(w, b, b_series).unsqueeze(-1)
    return torch.eye(3, dtype=w.dtype, device=w.device) + ca * W + cb * (W @ W)


def _one_minus_cos(t):
    return (1 - torch.cos(t)) / (t * t)


def _one_minus_cos_series(t2):
    return 0.5 - t2 / 24 + t2 * t2 / 720


def _minus_sin(t):
    return (t - torch.sin(t)) / (t * t * t)


def _minus_sin_series(t2):
    return 1 / 6 - t2 / 120 + t2 * t2 / 5040


def _cot_term(t):
    # cot as cos / sin: tan's derivatives at a half turn (tan(t / 2) -> inf) cancel to nothing
    return (1 - t / 2 * torch.cos(t / 2) / torch.sin(t / 2)) / (t * t)


def _cot_series(t2):
    return 1 / 12 + t2 / 720 + t2 * t2 / 30240


def _right_jacobian(w):
    """Jr(w) = I - (1 - cos)/t^2 [w] + (t - sin)/t^3 [w]^2: exp3(w + dw) = exp3(w) exp3(Jr dw)."""
    return _so3_terms(w, lambda t: -_one_minus_cos(t), lambda t2: -_one_minus_cos_series(t2), _minus_sin, _minus_sin_series)


def _left_jacobian(w):
    """Jl(w) = Jr(-w) = V(w), the linear part of exp6."""
    return _so3_terms(w, _one_minus_cos, _one_minus_cos_series, _minus_sin, _minus_sin_series)


def _right_jacobian_inverse(w):
    return _so3_terms(w, lambda t: 0.5 * torch.ones_like(t), lambda t2: 0.5 * torch.ones_like(t2), _cot_term, _cot_series)


def left_jacobian_inverse(w):
    return _so3_terms(w, lambda t: -0.5 * torch.ones_like(t), lambda t2: -0.5 * torch.ones_like(t2), _cot_term, _cot_series)


def _adjoint_exp6_inverse(rho: torch.Tensor, w: torch.Tensor, rot_t: torch.Tensor) -> torch.Tensor:
    """Ad(exp6(rho, w)^-1) (linear first), with rot_t = R(w)^T: exp6 = (R(w), V(w) rho)."""
    p = apply_matrix(_left_jacobian(w), rho)
    return _upper(rot_t, -rot_t @ skew(p), rot_t)


def _q_right(rho: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """The coupling block of SE(3)'s right Jacobian [[Jr, Q], [0, Jr]] (linear first): Barfoot's left
    Q(rho, w) at (-rho, -w)."""
    P, W = skew(-rho), skew(-w)
    c1 = _coefficients(w, _minus_sin, _minus_sin_series).unsqueeze(-1)
    c2 = _coefficients(w, lambda t: (t * t + 2 * torch.cos(t) - 2) / (2 * t ** 4),
                       lambda t2: 1 / 24 - t2 / 720 + t2 * t2 / 40320).unsqueeze(-1)
    c3 = _coefficients(w, lambda t: (2 * t - 3 * torch.sin(t) + t * torch.cos(t)) / (2 * t ** 5),
                       lambda t2: 1 / 120 - t2 / 2520 + t2 * t2 / 120960).unsqueeze(-1)
    WP, PW, WPW = W @ P, P @ W, W @ P @ W
    return (0.5 * P + c1 * (WP + PW + WPW) + c2 * (W @ WP + PW @ W - 3 * WPW)
            + c3 * (WPW @ W + W @ WPW))


# -- layout --------------------------------------------------------------------------------------------

def dt_column(dt, v: torch.Tensor) -> torch.Tensor:
    """dt as (..., 1) against v's batch."""
    return scalar_or_tensor(dt, v.dtype, v.device).unsqueeze(-1)


def _angular(kind: str, vi: int) -> int:
    return vi + 3 if kind == "free" else vi


def _quaternion(q: torch.Tensor, kind: str, qi: int, convention: int) -> torch.Tensor:
    """A joint's unit quaternion, xyzw."""
    a = qi + 3 if kind == "free" else qi
    quat = q[..., a:a + 4]
    return unit_quaternion(quat[..., [1, 2, 3, 0]] if convention else quat)[0]


def _mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Quaternion product a b, xyzw."""
    av, aw, bv, bw = a[..., :3], a[..., 3:], b[..., :3], b[..., 3:]
    return torch.cat([aw * bv + bw * av + torch.cross(av, bv, dim=-1), aw * bw - (av * bv).sum(-1, keepdim=True)], dim=-1)


def _conjugate(a: torch.Tensor) -> torch.Tensor:
    return torch.cat([-a[..., :3], a[..., 3:]], dim=-1)


def apply_matrix(m: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    return (m @ x.unsqueeze(-1)).squeeze(-1)


def block_diagonal(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """[[a, 0], [0, b]] of two square blocks, any sizes."""
    za = torch.zeros(*a.shape[:-1], b.shape[-1], dtype=a.dtype, device=a.device)
    zb = torch.zeros(*b.shape[:-1], a.shape[-1], dtype=b.dtype, device=b.device)
    return torch.cat([torch.cat([a, za], dim=-1), torch.cat([zb, b], dim=-1)], dim=-2)


def _upper(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """[[a, b], [0, c]] of 3 x 3 blocks."""
    return torch.cat([torch.cat([a, b], dim=-1), torch.cat([torch.zeros_like(c), c], dim=-1)], dim=-2)
