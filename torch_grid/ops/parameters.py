"""Gradients with respect to the bodies' inertial parameters pi (..., nbodies, 10), Pinocchio's order.

Inverse dynamics is linear in pi: tau = Y(q, qd, qdd) pi + (terms free of pi: the rotors' armature,
the external forces), with Y the inverse-dynamics regressor, in either convention (MuJoCo's Y is
G Y, as its tau is G tau). So is M(q) a = ID(q, 0, a) - ID(q, 0, 0) for any a, and the energies
(KE = Yk . pi + armature, PE = Yp . pi). The gradients here are regressor products: lam^T Y for a
cotangent lam, or, for the derivative of such a gradient along a direction of (q, qd), lam^T Ydot from
the regressor's dual-number Jacobian-vector product; those of weighted mass matrices <W, M> go through
the bodies' Jacobians instead (M = sum_k J_k^T I_k J_k), nv times cheaper than nv regressors.
"""
from __future__ import annotations

import torch

from ..space.conventions import ball_joints, free_joints, q_mujoco_to_pin, v_mujoco_to_pin
from ..space.tangent import tangent_directions


def _per_body(g: torch.Tensor) -> torch.Tensor:
    """(..., 10 nbodies) as (..., nbodies, 10)."""
    return g.unflatten(-1, (-1, 10))


def repeat_params(params: torch.Tensor | None) -> torch.Tensor | None:
    """params for a call whose q was repeated along a new dimension ahead of its own (autograd.repeat):
    the same dimension, of size 1, ahead of the parameters' (nbodies, 10)."""
    return None if params is None else params.unsqueeze(-3)


def regressor_vjp(ops, q, qd, qdd, lam, convention) -> torch.Tensor:
    """lam^T d tau / d pi = lam^T Y(q, qd, qdd), (..., nbodies, 10)."""
    y = ops.inverse_dynamics_regressor(q, qd, qdd, convention)
    return _per_body((lam.unsqueeze(-2) @ y).squeeze(-2))


def regressor_vjp_tangent(ops, q, qd, qdd, lam, t_q, t_qd, convention) -> torch.Tensor:
    """lam^T (D Y) pi's gradient: lam^T times the derivative of Y(q, qd, qdd) along (t_q, t_qd), t_q a
    direction of q's coordinates (either may be None), (..., nbodies, 10)."""
    pairs = ops.inverse_dynamics_regressor_jvp(q, qd, qdd, t_q, t_qd, None, convention)
    return _per_body((lam.unsqueeze(-2) @ pairs[..., 1]).squeeze(-2))


def mass_product_parameter_vjp(ops, model, q, a, lam, convention, t_q=None) -> torch.Tensor:
    """The pi-gradient of sum_m lam_m^T M(q) a_m, a and lam (..., m, nv): <W, M> for W = sum_m lam_m a_m^T.
    With t_q, its derivative along that direction of q's coordinates: M a = ID(q, 0, a) - ID(q, 0, 0) holds
    in both conventions, so sum_m lam_m^T D Y(q, 0, a_m) - (sum_m lam_m)^T D Y(q, 0, 0)."""
    if t_q is None:
        return inertia_parameter_vjp(ops, model, q, lam.mT @ a, convention)
    m = a.shape[-2]
    zero = torch.zeros_like(a)
    Q = q.unsqueeze(-2).expand(*q.shape[:-1], m, q.shape[-1])
    T = t_q.unsqueeze(-2).expand(*t_q.shape[:-1], m, t_q.shape[-1])
    products = regressor_vjp_tangent(ops, Q, zero, a, lam, T, None, convention)
    rest = regressor_vjp_tangent(ops, q, zero[..., 0, :], zero[..., 0, :], lam.sum(-2), t_q, None, convention)
    return products.sum(-3) - rest


def inertia_parameter_vjp(ops, model, q, W, convention, t_q=None) -> torch.Tensor:
    """The pi-gradient of <W, M(q)>, W (..., nv, nv). M = sum_k J_k^T I_k J_k (plus the armature, free of pi),
    J_k body k's Jacobian in its joint frame, so the gradient with respect to body k's spatial inertia is
    J_k W J_k^T, mapped to its ten parameters (inertia_vjp); MuJoCo's M is G M G^T, so W is first turned
    into Pinocchio's G^T W G. With t_q, the derivative along that direction of q's coordinates."""
    nv = W.shape[-1]
    unit = torch.eye(nv, dtype=W.dtype, device=W.device).expand(*W.shape[:-2], nv, nv)
    if t_q is not None:
        return mass_product_parameter_vjp(ops, model, q, unit, W.mT, convention, t_q)
    if convention and model.conventions_differ:
        free = free_joints(model)
        q = q_mujoco_to_pin(q, balls=ball_joints(model), free=free)
        rows = lambda X: v_mujoco_to_pin(q.unsqueeze(-2), X, free=free)  # X G, G acting on each row  # noqa: E731
        W = rows(rows(W.mT).mT)  # G^T W G
    J = ops.body_velocities(q.unsqueeze(-2).expand(*q.shape[:-1], nv, q.shape[-1]), unit, 0)  # [m, k] = J_k e_m
    return inertia_vjp(torch.einsum("...mki,...mn,...nkj->...kij", J, W, J))


def inertia_vjp(Wk: torch.Tensor) -> torch.Tensor:
    """(..., nbodies, 10): the pi-gradient of sum_k <W_k, I_k(pi_k)> for spatial weights W_k (..., nbodies, 6, 6),
    I = [[m 1, -[h]x], [[h]x, I_o]] in [linear; angular] order (force = I motion)."""
    A = Wk[..., 3:, :3] - Wk[..., :3, 3:]  # <A, [h]x> = h . (A_21 - A_12, A_02 - A_20, A_10 - A_01)
    h = torch.stack([A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0], A[..., 1, 0] - A[..., 0, 1]], -1)
    Wa = Wk[..., 3:, 3:]
    inertia = torch.stack([Wa[..., 0, 0], Wa[..., 0, 1] + Wa[..., 1, 0], Wa[..., 1, 1], Wa[..., 0, 2] + Wa[..., 2, 0],
                           Wa[..., 1, 2] + Wa[..., 2, 1], Wa[..., 2, 2]], -1)
    mass = Wk[..., :3, :3].diagonal(dim1=-2, dim2=-1).sum(-1, keepdim=True)
    return torch.cat([mass, h, inertia], -1)


def energy_parameter_vjp(ops, q, qd, grad, convention) -> torch.Tensor:
    """The pi-gradient of <grad, [KE, PE, KE + PE]>: KE - armature = Yk . pi and PE = Yp . pi."""
    g_kinetic = grad[..., 0:1] + grad[..., 2:3]
    g_potential = grad[..., 1:2] + grad[..., 2:3]
    yk = ops.kinetic_energy_regressor(q, qd, convention)
    yp = ops.potential_energy_regressor(q, convention)
    return _per_body(g_kinetic * yk + g_potential * yp)


def derivatives_parameter_vjp(ops, model, q, qd, qdd, g_q, g_qd, convention) -> torch.Tensor:
    """The pi-gradient of <Gq, dtau/dq> + <Gqd, dtau/dqd>: dtau/dq and dtau/dqd are linear in pi (the terms
    free of it aside), the derivatives of Y pi along each tangent direction of q and each qd_j, so
    sum_j Gq[:, j]^T D_j Y + Gqd[:, j]^T D'_j Y (either G may be None)."""
    nv = model.nv
    t = tangent_directions(model, q, convention)  # (..., nv, nq): direction j in q's coordinates
    zero = torch.zeros(*q.shape[:-1], nv, nv, dtype=q.dtype, device=q.device)
    lam = torch.cat([(zero if g_q is None else g_q).mT, (zero if g_qd is None else g_qd).mT], dim=-2)
    t_q = torch.cat([t, torch.zeros_like(t)], dim=-2)
    t_qd = torch.cat([zero, torch.eye(nv, dtype=q.dtype, device=q.device).expand_as(zero)], dim=-2)
    Q, QD, QDD = (x.unsqueeze(-2).expand(*x.shape[:-1], 2 * nv, x.shape[-1]) for x in (q, qd, qdd))
    return regressor_vjp_tangent(ops, Q, QD, QDD, lam, t_q, t_qd, convention).sum(-3)
