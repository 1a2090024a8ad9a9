"""The backwards of the integrate and difference ops (autograd.py's formulas for them), from the tangent
Jacobians of the d_integrate and d_difference kernels.

With A(q) the change of q's coordinates along its tangent space (tangent.ambient_direction) and T(q) the
tangent's change along q's coordinates, through a quaternion's normalisation (whose transpose is
tangent.tangent_to_ambient):
  q' = q (+) u, u = dt v:   g = A(q')^T grad,  d/dq = T(q)^T J_q^T g,  d/dv = dt J_u^T g,  d/ddt = v . J_u^T g
  v = difference(q0, q1):   d/dq0 = T(q0)^T J_q0^T grad,  d/dq1 = T(q1)^T J_q1^T grad
(J_q, J_u: d_integrate's at dt = 1; J_q0, J_q1: d_difference's). Under create_graph the Jacobians come from
the torch composition (space/lie.py), which autograd differentiates once more; otherwise from the kernels.
"""
from __future__ import annotations

import torch

from ..model.description import RobotModel
from ..space import lie
from ..space.tangent import ambient_to_tangent, tangent_to_ambient


def integrate_backward(ops, model: RobotModel, needs, grads, output, q, v, dt, convention):
    """The gradients of q' = integrate(q, v, dt) (dt the op's (..., 1) column)."""
    if not any(needs[:3]):
        return None, None, None, None
    g = ambient_to_tangent(model, output, grads[0], convention)
    u = v * dt
    if torch.is_grad_enabled():
        j_q, j_u = lie.d_integrate(_space(model), q, u, 1.0, convention)
    else:
        j_q, j_u = ops.d_integrate(q, u, torch.ones_like(dt), convention)
    g_u = _transposed_times(j_u, g)
    return (tangent_to_ambient(model, q, _transposed_times(j_q, g), convention) if needs[0] else None,
            dt * g_u if needs[1] else None, (v * g_u).sum(-1, keepdim=True) if needs[2] else None, None)


def difference_backward(ops, model: RobotModel, needs, grads, output, q0, q1, convention):
    """The gradients of v = difference(q0, q1)."""
    if not any(needs[:2]):
        return None, None, None
    if torch.is_grad_enabled():
        j_0, j_1 = lie.d_difference(_space(model), q0, q1, convention)
    else:
        j_0, j_1 = ops.d_difference(q0, q1, convention)
    return (tangent_to_ambient(model, q0, _transposed_times(j_0, grads[0]), convention) if needs[0] else None,
            tangent_to_ambient(model, q1, _transposed_times(j_1, grads[0]), convention) if needs[1] else None, None)


def _transposed_times(j: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """J^T g for J (..., n, n) and g (..., n)."""
    return (g.unsqueeze(-2) @ j).squeeze(-2)


def _space(model: RobotModel) -> lie.Space:
    """The kernels' configuration space: the model's joints in q's order."""
    return lie.Space.of([joint.type for _, joint in sorted(zip(model.q_index, model.joints), key=lambda x: x[0])])
