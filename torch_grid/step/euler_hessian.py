"""The Hessian of the Euler schemes' step, from the forward-dynamics second derivatives.

With z = [dq; dqd; dtau], a(z) = forward_dynamics(q (+) dq, qd + dqd, tau + dtau), G = da/dz and
Ha = d2a/dz2 (symmetric; its q-q block is the symmetric part of d2qdd_dq2, whose tangent-space
derivatives differ from it by a Lie bracket, which is antisymmetric):
  qd'(z) = qd + dqd + dt a(z)                                  Hessian dt Ha
  q'(z)  = (q (+) dq) (+) w(z),  w = dt qd'(z) (semi-implicit) or dt (qd + dqd) (euler)
On a scalar joint the q' row is dq + w - w0, Hessian dt^2 Ha (none for euler). On a quaternion joint,
with E = exp and w0 = w(0), difference(q', q'(z)) = log(E(X) E(psi)) = X + psi + [X, psi] / 2 + ...
where X = Ad(E(w0)^-1) dq = J_q dq and psi = log(E(w0)^-1 E(w)) = J_r dw + dw^T Hpsi dw / 2, J_r the
right Jacobian (d_integrate's J_v) and Hpsi[m, a, b] = sym_ab dJ_r[m, a] / dw_b (differentiate
J_r(psi) psi' = J_r(w0 + t u) u once: J_r(psi) = I - ad(psi) / 2 + ..., and ad(x) x = 0). The
bracket is the cross product on SO(3), SE(3)'s ad on Pinocchio's free joint, zero on MuJoCo's free
position.
"""
from __future__ import annotations

import torch

from ..space.lie import d_integrate_blocks, d_integrate_v_block, dt_column
from .passive import damped_acceleration_second_derivatives


def euler_step_hessian(view, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, dt, f_ext, semi: bool) -> torch.Tensor:
    """(..., 2 nv, 3 nv, 3 nv): step_second_derivatives of euler (semi False) or semi_implicit_euler."""
    space, convention, nv = view._robot._space, view._convention, qd.shape[-1]
    h = dt_column(dt, qd)
    if semi and view._robot._implicit_damping:  # MuJoCo's Euler step: (M + dt D) a = tau + p - b
        a, G, second = damped_acceleration_second_derivatives(view, q, qd, tau, h, f_ext)
    else:
        a, G = view.forward_dynamics(q, qd, tau, f_ext), view.forward_dynamics_derivatives(q, qd, tau, f_ext)
        second = view.forward_dynamics_second_derivatives(q, qd, tau, f_ext)
    G = torch.cat(G, dim=-1)
    batch = torch.broadcast_shapes(second[0].shape[:-3], h.shape[:-1])
    hh = h.reshape(*h.shape[:-1], 1, 1, 1)
    # written in place: the tensor is 2 nv (3 nv)^2 numbers per sample (6 MB on a humanoid)
    out = torch.empty(*batch, 2 * nv, 3 * nv, 3 * nv, dtype=qd.dtype, device=qd.device)
    scaled_acceleration_hessian(second, hh, out[..., nv:, :, :])
    if semi:
        torch.mul(out[..., nv:, :, :], hh, out=out[..., :nv, :, :])
    else:
        out[..., :nv, :, :] = 0
    # dw/dz = dt (dqd'/dz) or dt [0 I 0]; w's Hessian (dt^2 Ha or none) is already on q' rows
    zero, eye = torch.zeros(nv, nv, dtype=qd.dtype, device=qd.device), torch.eye(nv, dtype=qd.dtype, device=qd.device)
    e_v, h2 = torch.cat([zero, eye, zero], dim=-1), h.unsqueeze(-1)
    dw = h2 * (e_v + h2 * G) if semi else (h2 * e_v).expand(*batch, nv, 3 * nv)
    w = (h * (qd + h * a) if semi else h * qd).expand(*batch, nv)
    chart_hessian(convention, d_integrate_blocks(space, w, 1.0, convention), w, dw, out[..., :nv, :, :])
    return out


def chart_jacobian(blocks: list, dw: torch.Tensor) -> torch.Tensor:
    """(..., nv, 3 nv): the Jacobian at z = 0 of e(z) = difference(q (+) w(0), (q (+) dq) (+) w(z)) from
    dw = dw/dz (..., nv, 3 nv), with blocks = d_integrate_blocks at (q, w, dt = 1): [I 0 0] + dw on the
    scalar coordinates, J_q [I 0 0] + J_r dw on a quaternion joint's."""
    nv = dw.shape[-2]
    out = dw.clone()
    out[..., :nv] += torch.eye(nv, dtype=dw.dtype, device=dw.device)
    for vi, j_q, j_r in blocks:
        n = j_q.shape[-1]
        out[..., vi:vi + n, :] = j_r @ dw[..., vi:vi + n, :]
        out[..., vi:vi + n, vi:vi + n] += j_q
    return out


def chart_hessian(convention: int, blocks: list, w: torch.Tensor, dw: torch.Tensor, out: torch.Tensor,
                  dJs: list | None = None) -> None:
    """In place: out (..., nv, 3 nv, 3 nv) holds the Hessian of w(z) and becomes that of e(z) (chart_jacobian),
    unchanged on the scalar coordinates; on a quaternion joint J_r Hw + Hpsi[dw, dw] + the bracket. dJs: each
    block's jacobian_of_j_r at w, if already computed."""
    for b, (vi, j_q, j_r) in enumerate(blocks):
        n = j_r.shape[-1]
        kind = "free" if n == 6 else "ball"
        rows, W = slice(vi, vi + n), dw[..., vi:vi + n, :]
        dJ = jacobian_of_j_r(kind, w[..., rows], convention) if dJs is None else dJs[b]
        block = torch.einsum("...mbd,...ba,...dc->...mac", 0.5 * (dJ + dJ.transpose(-1, -2)), W, W)
        block = block + torch.einsum("...mb,...bac->...mac", j_r, out[..., rows, :, :])
        X = torch.zeros(*W.shape[:-2], n, W.shape[-1], dtype=W.dtype, device=W.device)
        X[..., vi:vi + n] = j_q
        bracket = _bracket(kind, convention, X, j_r @ W)
        out[..., rows, :, :] = block + 0.5 * (bracket + bracket.transpose(-1, -2))


def scaled_acceleration_hessian(second, hh: torch.Tensor, out: torch.Tensor) -> None:
    """out (..., nv, 3 nv, 3 nv) = dt Ha from forward_dynamics_second_derivatives's tensors (mixed partials
    commute where one side is flat: Ha[i, q_j, v_k] = dqdv[i, j, k], Ha[i, tau_j, q_k] = dtaudq[i, j, k])."""
    d2q, d2v, dqdv, dtaudq = second
    nv = d2q.shape[-1]
    q, v, t = slice(0, nv), slice(nv, 2 * nv), slice(2 * nv, 3 * nv)
    # by assignment, which broadcasts the tensors' batch to out's (a dt batch beyond the state's), as mul's out= does
    block = out[..., q, q]
    block.copy_(d2q).add_(d2q.transpose(-1, -2)).mul_(0.5 * hh)
    for (r, c), x in (((q, v), dqdv), ((q, t), dtaudq.transpose(-1, -2)), ((v, q), dqdv.transpose(-1, -2)),
                      ((v, v), d2v), ((t, q), dtaudq)):
        torch.mul(x, hh, out=out[..., r, c])
    for r, c in ((v, t), (t, v), (t, t)):
        out[..., r, c] = 0


def jacobian_of_j_r(kind: str, u: torch.Tensor, convention: int) -> torch.Tensor:
    """dJ[m, a, b] = d J_r(u)[m, a] / du_b, (..., n, n, n), by forward-mode AD of the closed form."""
    n = u.shape[-1]
    # contiguous: forward AD cannot write tangents into a broadcast (stride-0) batch
    jac = torch.func.vmap(torch.func.jacfwd(lambda x: d_integrate_v_block(kind, x, convention)))(
        u.reshape(-1, n).contiguous())
    return jac.reshape(*u.shape[:-1], n, n, n)


def _levi_civita(like: torch.Tensor) -> torch.Tensor:
    eps = torch.zeros(3, 3, 3, dtype=like.dtype, device=like.device)
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        eps[i, j, k], eps[i, k, j] = 1.0, -1.0
    return eps


def _bracket(kind: str, convention: int, X: torch.Tensor, Y: torch.Tensor) -> torch.Tensor:
    """B[m, a, c] = [X e_a, Y e_c]_m, X and Y (..., n, k) columns of the joint's tangent (linear first)."""
    eps = _levi_civita(X)
    if kind == "ball":
        return torch.einsum("mij,...ia,...jc->...mac", eps, X, Y)
    ang = torch.einsum("mij,...ia,...jc->...mac", eps, X[..., 3:, :], Y[..., 3:, :])
    if convention:  # R^3 x SO(3): the position commutes
        lin = torch.zeros_like(ang)
    else:  # se(3): [(v1, w1), (v2, w2)] = (w1 x v2 - w2 x v1, w1 x w2)
        lin = (torch.einsum("mij,...ia,...jc->...mac", eps, X[..., 3:, :], Y[..., :3, :])
               - torch.einsum("mij,...ic,...ja->...mac", eps, Y[..., 3:, :], X[..., :3, :]))
    return torch.cat([lin, ang], dim=-3)
