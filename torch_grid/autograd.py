"""Autograd for the ops, backed by the analytic derivative kernels.

inverse_dynamics and forward_dynamics differentiate with respect to every tensor input. Their
kernels give derivatives along the tangent space; the gradient with respect to q is mapped to
the ambient coordinates the caller passed (a free-flyer quaternion through its normalisation).
Ops without derivative kernels yet raise a clear error when back-propagated through, as does
differentiating any backward a second time.
"""
from __future__ import annotations

from typing import Callable

import torch

from .model import RobotModel
from .ops import OPS


def register_autograd(namespace: str, model: RobotModel) -> None:
    """Attach a backward to every op of one robot build."""
    ops = getattr(torch.ops, namespace)
    for spec in OPS.values():
        backward = _BACKWARDS.get(spec.name)
        if backward is None:
            torch.library.register_autograd(f"{namespace}::{spec.name}", _no_backward(spec.name),
                                            setup_context=_save_nothing)
        else:
            torch.library.register_autograd(f"{namespace}::{spec.name}", _backward(spec.name, backward, ops, model),
                                            setup_context=_save_inputs)


def _save_nothing(ctx, inputs, output) -> None:
    pass


def _save_inputs(ctx, inputs, output) -> None:
    ctx.inputs = inputs


def _no_backward(name: str) -> Callable:
    def backward(ctx, *grads):
        raise NotImplementedError(f"torch_grid: {name} has no derivative yet; its outputs cannot be back-propagated through")

    return backward


def _backward(name: str, formula: Callable, ops, model: RobotModel) -> Callable:
    def backward(ctx, grad):
        if torch.is_grad_enabled():
            raise NotImplementedError(
                f"torch_grid: the backward of {name} is not differentiable yet (second derivatives); "
                "call backward without create_graph=True"
            )
        return formula(ops, model, grad, *ctx.inputs)

    return backward


def _inverse_dynamics(ops, model, grad, q, qd, qdd, f_ext, convention):
    """tau = ID(q, qd, qdd, f_ext): d/dq and d/dqd from the kernel, d/dqdd = M, d/df_ext = -J^T."""
    needs = _needs(q, qd, qdd, f_ext)
    dq = dqd = dqdd = df = None
    if needs[0] or needs[1]:
        dtau_dq, dtau_dqd = ops.inverse_dynamics_gradient(q, qd, qdd, f_ext, convention)
        dq = _tangent_to_ambient(model, q, _vjp(dtau_dq, grad), convention) if needs[0] else None
        dqd = _vjp(dtau_dqd, grad) if needs[1] else None
    if needs[2]:
        dqdd = _vjp(ops.crba(q, convention), grad)
    if needs[3]:
        # d tau / d f_k = -J_k^T (J_k: body k's Jacobian in its frame), so the gradient is -J_k grad:
        # minus the velocity of body k under the joint velocity grad.
        df = -ops.body_velocities(q, grad, convention)
    return dq, dqd, dqdd, df, None


def _forward_dynamics(ops, model, grad, q, qd, tau, f_ext, convention):
    """qdd = FD(q, qd, tau, f_ext): from the kernel; d/df_ext = M^-1 J^T since d/dtau = M^-1."""
    needs = _needs(q, qd, tau, f_ext)
    dqdd_dq, dqdd_dqd, minv = ops.forward_dynamics_gradient(q, qd, tau, f_ext, convention)
    dq = _tangent_to_ambient(model, q, _vjp(dqdd_dq, grad), convention) if needs[0] else None
    dqd = _vjp(dqdd_dqd, grad) if needs[1] else None
    dtau = _vjp(minv, grad) if needs[2] or needs[3] else None
    df = ops.body_velocities(q, dtau, convention) if needs[3] else None
    return dq, dqd, dtau if needs[2] else None, df, None


_BACKWARDS = {"inverse_dynamics": _inverse_dynamics, "forward_dynamics": _forward_dynamics}


def _needs(*inputs) -> list[bool]:
    return [isinstance(x, torch.Tensor) and x.requires_grad for x in inputs]


def _vjp(jacobian: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
    """grad^T J for a batch of (n, m) Jacobians: (..., m)."""
    return (grad.unsqueeze(-2) @ jacobian).squeeze(-2)


def _tangent_to_ambient(model: RobotModel, q: torch.Tensor, g: torch.Tensor, convention: int) -> torch.Tensor:
    """Gradient along the tangent space (..., nv) -> gradient in the coordinates of q (..., nq).

    A floating base moves by Pinocchio's local increment (position R dv_lin) or by MuJoCo's
    (position + dv_lin, world frame); both turn the quaternion Q by the local rotation
    dw = 2 vec(conj(Q/|Q|) (x) dQ) / |Q|, whose transpose maps the angular gradient to dQ.
    """
    if not model.floating_base:
        return g
    if convention:  # MuJoCo: position in the world frame, quaternion wxyz
        w, xyz = q[..., 3:4], q[..., 4:7]
    else:
        xyz, w = q[..., 3:6], q[..., 6:7]
    norm = torch.cat([xyz, w], dim=-1).norm(dim=-1, keepdim=True)
    xyz_n, w_n = xyz / norm, w / norm
    g_lin, g_ang = g[..., :3], g[..., 3:6]
    if convention:
        g_pos = g_lin
    else:
        from .conventions import base_rotation

        g_pos = (base_rotation(q) @ g_lin.unsqueeze(-1)).squeeze(-1)
    g_xyz = 2 / norm * (w_n * g_ang + torch.cross(xyz_n, g_ang, dim=-1))
    g_w = -2 / norm * (xyz_n * g_ang).sum(-1, keepdim=True)
    g_quat = torch.cat([g_w, g_xyz], dim=-1) if convention else torch.cat([g_xyz, g_w], dim=-1)
    return torch.cat([g_pos, g_quat, g[..., 6:]], dim=-1)
