"""Second derivatives in MuJoCo's convention, from Pinocchio's.

The conventions differ on free joints only (a ball joint's quaternion order aside): G = blockdiag(R_f on
each free joint's linear dofs, I elsewhere) maps Pinocchio's velocity to MuJoCo's, and a direction k of
MuJoCo's tangent is Pinocchio's direction Gi e_k (Gi = G^T). Holding qvel and qacc fixed in MuJoCo's
frame, a step of q along k also changes Pinocchio's inputs: with t the MuJoCo direction,

    tau_mujoco(q, v, a) = G(q) tau(q, V(q, v), A(q, v, a)),   V = G^T v,   A_lin = R^T a_lin - w x V_lin,

so a direction k of q moves Pinocchio's (q, v, a) by (Dq, Dv, Da) e_k = (Gi, Jv, Ja) e_k, Jv and Ja
non-zero in each free joint's (linear rows, angular columns) block only (docs/guides/conventions.md). A direction
of qvel moves (v, a) by (Gi, Jav) e_k, one of qacc moves a by Gi e_k. Every second derivative is then
the derivative of MuJoCo's first derivative (the last index the direction, as Pinocchio's), by the
product rule: Pinocchio's second-order tensors contracted with those maps, plus the terms where the
maps themselves (and G) turn with the base. The maps are identities or 3 x 3 blocks, so each
contraction costs O(nv^3).
"""
from __future__ import annotations

import torch

from ..space.conventions import a_mujoco_to_pin, ball_joints, free_joints, q_mujoco_to_pin, quaternion_rotation, v_mujoco_to_pin
from ..space.lie import skew


class _Free:
    """One free joint at a configuration: its v index, R, and Pinocchio's v_lin, w, R^T a_lin_mujoco."""

    def __init__(self, q_pin, qi: int, vi: int, v_pin=None, a_mujoco=None):
        self.vi = vi
        self.R = quaternion_rotation(q_pin[..., qi + 3:qi + 7])
        if v_pin is not None:
            self.v, self.w = v_pin[..., vi:vi + 3], v_pin[..., vi + 3:vi + 6]
            self.aR = (self.R.mT @ a_mujoco[..., vi:vi + 3].unsqueeze(-1)).squeeze(-1)

    @property
    def lin(self) -> slice:
        return slice(self.vi, self.vi + 3)

    @property
    def ang(self) -> slice:
        return slice(self.vi + 3, self.vi + 6)


def _unit_skews(like: torch.Tensor) -> torch.Tensor:
    """(3, 3, 3) [e_c]x for c = 0, 1, 2."""
    return skew(torch.eye(3, dtype=like.dtype, device=like.device))


def _rotate(X: torch.Tensor, dim: int, frees: list[_Free]) -> torch.Tensor:
    """X with each free joint's linear slice along `dim` (counted from the end) turned by R: G X along
    a row index, X Gi along a column index (the same map, G^T = Gi)."""
    X = X.movedim(dim, -1)
    parts, k = [], 0
    for f in frees:
        parts += [X[..., k:f.vi], (X[..., f.lin].unsqueeze(-2) @ _expand(f.R.mT, X.dim() + 1)).squeeze(-2)]
        k = f.vi + 3
    return torch.cat(parts + [X[..., k:]], dim=-1).movedim(-1, dim)


def _block(X: torch.Tensor, dim: int, rows: slice, cols: slice, D: torch.Tensor) -> torch.Tensor:
    """X contracted along `dim` with an nv x nv map that is the 3 x 3 block D (..., 3, 3) at (rows, cols)."""
    X = X.movedim(dim, -1)
    value = (X[..., rows].unsqueeze(-2) @ _expand(D, X.dim() + 1)).squeeze(-2)
    return _padded(value, (cols,), X.shape[-1:]).movedim(-1, dim)


def _padded(value: torch.Tensor, where: tuple[slice, ...], size) -> torch.Tensor:
    """value placed at the slices `where` of its last dimensions, zero elsewhere, those dimensions of the
    given size: out of place, so that vmap batches it whether or not value is batched."""
    pads = []
    for s, n in zip(reversed(where), reversed(tuple(size))):
        r = range(n)[s]
        pads += [r.start, n - r.stop]
    return torch.nn.functional.pad(value, pads)


def _expand(D: torch.Tensor, dims: int) -> torch.Tensor:
    """A per-sample (batch..., 3, 3) block with singleton dimensions before its last two, up to `dims`:
    it then multiplies (batch..., other dims..., 1, 3) rows."""
    while D.dim() < dims:
        D = D.unsqueeze(-3)
    return D


def _mix(X: torch.Tensor, dim: int, frees: list[_Free], blocks) -> torch.Tensor:
    """X contracted along `dim` with the sum over free joints of the blocks(f) -> [(rows, cols, D)]."""
    out = torch.zeros_like(X)
    for f in frees:
        for rows, cols, D in blocks(f):
            out = out + _block(X, dim, rows, cols, D)
    return out


def _dv(f: _Free):
    """Jv: Pinocchio's v_lin under a base rotation e_a, -(e_a x v_lin) = [v_lin]x e_a."""
    return [(f.lin, f.ang, skew(f.v))]


def _da(f: _Free):
    """Ja: Pinocchio's a_lin under a base rotation e_a, -e_a x aR + w x (e_a x v_lin)."""
    return [(f.lin, f.ang, skew(f.aR) - skew(f.w) @ skew(f.v))]


def _dav(f: _Free):
    """Jav: Pinocchio's a_lin under qvel: -w x R^T e_a (linear), -(e_a x v_lin) (angular)."""
    return [(f.lin, f.lin, -skew(f.w) @ f.R.mT), (f.lin, f.ang, skew(f.v))]


def _put(out: torch.Tensor, rows: slice, j: slice, k: slice, value: torch.Tensor) -> torch.Tensor:
    """out[..., rows, j, k] += value (..., len(rows), 3, 3) (out of place)."""
    return out + _padded(value, (rows, j, k), out.shape[-3:])


def _lin_times(X: torch.Tensor, f: _Free, E: torch.Tensor) -> torch.Tensor:
    """sum_m X[..., :, lin m] E[..., m, j, k] for a (..., 3, 3, 3) block E: (..., nv, 3, 3)."""
    return torch.einsum("...im,...mjk->...ijk", X[..., :, f.lin], E)


def _turn(f: _Free, e: torch.Tensor) -> torch.Tensor:
    """d(Gi e_b)/dq_c on a free joint's linear rows, [m, b, c] = -(e_c x R^T e_b) (b linear, c angular):
    Gi's change under a base rotation, and the same block of the qvel-to-qacc map's change under qvel."""
    return -torch.einsum("cab,...bd->...adc", e, f.R.mT)


def _gdot(f: _Free, x: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
    """Gdot_c x = R (e_c x x_lin) on the linear rows, for each c: (..., 3, c, n) for x (..., nv, n)."""
    return torch.einsum("...ab,cbd,...dn->...acn", f.R, e, x[..., f.lin, :])


def inverse_dynamics_second_derivatives(model, q_pin, v_pin, a_mujoco, tau, A, B, M, second):
    """MuJoCo's (d2tau_dq2, d2tau_dqd2, d2tau_dqdqd, dM_dq) from Pinocchio's at the converted state:
    tau, A = dtau/dq, B = dtau/dqd, M and `second` (Pinocchio's four tensors), a_mujoco MuJoCo's qacc."""
    T_qq, T_vv, T_qv, T_M = second
    frees = [_Free(q_pin, qi, vi, v_pin, a_mujoco) for qi, vi in free_joints(model)]
    e = _unit_skews(q_pin)
    P = T_M.transpose(-1, -2)   # P[i, j, m] = d/da_m A[i, j]
    Q = T_qv.transpose(-1, -2)  # Q[i, j, n] = d/dq_n B[i, j]
    rot = lambda X, dim: _rotate(X, dim, frees)  # noqa: E731
    mix = lambda X, dim, blocks: _mix(X, dim, frees, blocks)  # noqa: E731

    # d/dq_k of (A Dq + B Dv + M Da) e_j, Pinocchio's tensors through the maps
    dA_q = rot(T_qq, -1) + mix(T_qv, -1, _dv) + mix(P, -1, _da)
    d2q = rot(dA_q, -2) + mix(rot(Q, -1) + mix(T_vv, -1, _dv), -2, _dv) + mix(rot(T_M, -1), -2, _da)
    # d/dqd_k: (v, a) move by (Gi, Jav) e_k
    dA_v = rot(T_qv, -1) + mix(P, -1, _dav)
    dB_v = rot(T_vv, -1)
    dqdv = rot(dA_v, -2) + mix(dB_v, -2, _dv)
    d2v = rot(dB_v, -2)
    dM = rot(rot(T_M, -1), -2)
    t_q = rot(A, -1) + mix(B, -1, _dv) + mix(M, -1, _da)  # Pinocchio's tau per MuJoCo q direction
    t_v = rot(B, -1) + mix(M, -1, _dav)
    for f in frees:
        lin, ang = f.lin, f.ang
        # the maps turn with the base: d/dq_d of Gi e_b, Jv e_c, Ja e_c (d, c angular, b linear)
        E_q = _turn(f, e)  # [m, j=b, k=c]
        ev = torch.einsum("cab,dbe,...e->...acd", e, e, f.v)  # e_c x (e_d x v), [m, c, d]
        ea = torch.einsum("cab,dbe,...e->...acd", e, e, f.aR)
        E_a = ea - torch.einsum("...ab,...bcd->...acd", skew(f.w), ev)
        d2q = _put(d2q, slice(None), lin, ang, _lin_times(A, f, E_q))
        d2q = _put(d2q, slice(None), ang, ang, _lin_times(B, f, ev) + _lin_times(M, f, E_a))
        dM = _put(dM, slice(None), lin, ang, _lin_times(M, f, E_q))
        # d/dqd_k of Jv e_c, Ja e_c: k linear b: -(e_c x R^T e_b), w x (e_c x R^T e_b); k angular d: e_d x (e_c x v)
        Ev = E_q.transpose(-1, -2)  # [m, c, b]
        Ea_lin = torch.einsum("...ab,...bcd->...acd", skew(f.w), Ev).neg()
        dqdv = _put(dqdv, slice(None), ang, lin, _lin_times(B, f, Ev) + _lin_times(M, f, Ea_lin))
        dqdv = _put(dqdv, slice(None), ang, ang, _lin_times(M, f, ev.transpose(-1, -2)))  # e_d x (e_c x v)
        # d/dqd_k of Jav e_j: j linear a, k angular d: -(e_d x R^T e_a); j angular a, k linear b: -(e_a x R^T e_b)
        d2v = _put(d2v, slice(None), lin, ang, _lin_times(M, f, E_q))
        d2v = _put(d2v, slice(None), ang, lin, _lin_times(M, f, Ev))
    # G on tau's index, then the terms of G's own turning: Gdot_c = R [e_c]x on the linear rows
    d2q, d2v, dqdv, dM = (rot(T, -3) for T in (d2q, d2v, dqdv, dM))
    MG = rot(M, -1)
    for f in frees:
        lin, ang, every = f.lin, f.ang, slice(None)
        # (d/dq_d Gdot_c) tau = R (e_d x (e_c x tau_lin)), [a, c, d]
        d2q = _put(d2q, lin, ang, ang, torch.einsum("...ab,dbe,cef,...f->...acd", f.R, e, e, tau[..., lin]))
        d2q = _put(d2q, lin, ang, every, _gdot(f, t_q, e))  # Gdot_j (d tau / dq_k)
        d2q = _put(d2q, lin, every, ang, _gdot(f, t_q, e).transpose(-1, -2))  # Gdot_k (d tau / dq_j)
        dqdv = _put(dqdv, lin, ang, every, _gdot(f, t_v, e))
        dM = _put(dM, lin, every, ang, _gdot(f, MG, e).transpose(-1, -2))  # Gdot_k M Gi
    return d2q, d2v, dqdv, dM


def kinematic_hessian(model, q_pin, J, H):
    """MuJoCo's kinematic Hessian of a frame, d/dq_k of J Gi (J = frame_jacobian) from Pinocchio's J and
    H: H with both tangent indices through Gi, plus J d(Gi e_j)/dq_k on a free joint's rotations."""
    frees = [_Free(q_pin, qi, vi) for qi, vi in free_joints(model)]
    e = _unit_skews(q_pin)
    out = _rotate(_rotate(H, -1, frees), -2, frees)
    for f in frees:
        out = _put(out, slice(None), f.lin, f.ang, _lin_times(J, f, _turn(f, e)))
    return out


def inverse_dynamics_second_derivatives_mujoco(robot, q, qd, qdd, f_ext, params=None):
    """Robot.mujoco.inverse_dynamics_second_derivatives of a robot with quaternion joints."""
    return second_order_from_ops(_PinCalls(robot.pin), _model(robot, "inverse_dynamics_second_derivatives"), q, qd, qdd, f_ext,
                                 params)


def second_order_from_ops(ops, model, q, qd, qdd, f_ext, params=None):
    """MuJoCo's four tensors at MuJoCo's (q, qd, qdd), from Pinocchio's ops (convention 0) at the
    converted state. Passive joint forces (hinge and slide) do not reach them: they are linear, and
    no term here reads their rows."""
    # one batch shape for the state: the reframes below combine q's and the velocities' per sample
    batch = torch.broadcast_shapes(q.shape[:-1], qd.shape[:-1], qdd.shape[:-1], () if f_ext is None else f_ext.shape[:-2],
                                   () if params is None else params.shape[:-2])
    q, qd, qdd = (x.expand(*batch, x.shape[-1]) for x in (q, qd, qdd))
    free = free_joints(model)
    q_pin = q_mujoco_to_pin(q, balls=ball_joints(model), free=free)
    v_pin = v_mujoco_to_pin(q_pin, qd, free=free)
    a_pin = a_mujoco_to_pin(q_pin, v_pin, qdd, free=free)
    tau = ops.inverse_dynamics(q_pin, v_pin, a_pin, f_ext, params, 0)
    A, B = ops.inverse_dynamics_derivatives(q_pin, v_pin, a_pin, f_ext, params, 0)
    second = ops.inverse_dynamics_second_derivatives(q_pin, v_pin, a_pin, f_ext, params, 0)
    return inverse_dynamics_second_derivatives(model, q_pin, v_pin, qdd, tau, A, B, ops.crba(q_pin, params, 0), second)


def frame_kinematic_hessian(robot, q, frame: int, reference: int):
    """Robot.mujoco.frame_kinematic_hessian of a robot with quaternion joints."""
    return kinematic_hessian_from_ops(_PinCalls(robot.pin), _model(robot, "frame_kinematic_hessian"), q, frame, reference)


def kinematic_hessian_from_ops(ops, model, q, frame: int, reference: int):
    """MuJoCo's kinematic Hessian of a frame at MuJoCo's q, from Pinocchio's ops (convention 0)."""
    q_pin = q_mujoco_to_pin(q, balls=ball_joints(model), free=free_joints(model))
    J = ops.frame_jacobian(q_pin, frame, reference, 0)
    return kinematic_hessian(model, q_pin, J, ops.frame_kinematic_hessian(q_pin, frame, reference, 0))


class _PinCalls:
    """The ops as the pin view calls them (the trailing convention, 0, dropped): through their torch.func
    rules under vmap and the other transforms, and refused where forward mode has no rule (a raw op under
    torch.func.jvp would return wrong tangents)."""

    def __init__(self, view):
        self._view = view

    def __getattr__(self, name: str):
        return lambda *args: self._view._kernel_call(name, *args[:-1])


def _model(robot, name: str):
    if robot._coupling is not None:
        raise NotImplementedError(f"torch_grid: {name} in the MuJoCo convention is not implemented for a robot with "
                                  "mimic joints and free or ball joints; call it in the pin convention (robot.pin)")
    return robot.model


def crba_vjp(ops, model, q, W, M, params=None):
    """The gradient along MuJoCo's tangent of <W, M_mujoco(q)>, M_mujoco = G M G^T the op's output: Pinocchio's
    kernel for <G^T W G, M> mapped by G (a MuJoCo direction k is Pinocchio's G^T e_k), plus, for a free
    joint's rotation c, G's own turn: 2 <sym(W), Gdot_c M G^T> = 2 tr([e_c]x C), C = (M G^T)_lin sym(W)_lin^T R.
    Beyond G^T W G, only 3 x nv products."""
    free = free_joints(model)
    q_pin = q_mujoco_to_pin(q, balls=ball_joints(model), free=free)
    frees = [_Free(q_pin, qi, vi) for qi, vi in free]
    # G^T W G: the free joints' rows, then their columns (each stage reads the one before)
    rows = W.clone()
    for f in frees:
        rows[..., f.lin, :] = f.R.mT @ W[..., f.lin, :]
    inner = rows.clone()
    for f in frees:
        inner[..., :, f.lin] = rows[..., :, f.lin] @ f.R
    g = ops.crba_vjp(q_pin, inner, params, 0)
    parts, k = [], 0
    for f in frees:
        MGt = f.R.mT @ M[..., f.lin, :]  # rows of G^T M_mujoco = M G^T
        C = MGt @ (W[..., f.lin, :] + W[..., :, f.lin].mT).mT @ f.R  # 2 (M G^T)_lin sym(W)_lin^T R
        turn = torch.stack([C[..., 1, 2] - C[..., 2, 1], C[..., 2, 0] - C[..., 0, 2], C[..., 0, 1] - C[..., 1, 0]], -1)
        lin = (f.R @ g[..., f.lin].unsqueeze(-1)).squeeze(-1)
        parts += [g[..., k:f.vi], lin, g[..., f.vi + 3:f.vi + 6] + turn]
        k = f.vi + 6
    return torch.cat(parts + [g[..., k:]], dim=-1)
