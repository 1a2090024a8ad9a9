"""The configuration space inside backwards: a tangent gradient carried to q's coordinates (every op's backward ends
with it), and the backwards of the integrate and difference ops (autograd.py's formulas for them).

With A(q) the change of q's coordinates along its tangent space (tangent.ambient_direction) and T(q) the
tangent's change along q's coordinates, through a quaternion's normalisation (whose transpose is
tangent.tangent_to_ambient):
  q' = q (+) u, u = dt v:   g = A(q')^T grad,  d/dq = T(q)^T J_q^T g,  d/dv = dt J_u^T g,  d/ddt = v . J_u^T g
  v = difference(q0, q1):   d/dq0 = T(q0)^T J_q0^T grad,  d/dq1 = T(q1)^T J_q1^T grad
(J_q, J_u: the tangent Jacobians of q (+) u at dt = 1; J_q0, J_q1: difference's). A plain backward runs one kernel
for each (tangent_to_ambient, integrate_vjp, difference_vjp); a backward that is itself differentiated (create_graph,
the torch.func transforms, forward-mode AD) runs the torch composition (space/tangent.py, space/lie.py), which autograd
differentiates once more. So does a CUDA call in MuJoCo's convention of a robot with quaternion joints, as for the
step kernels (levels.kernels_kept_off).
"""
from __future__ import annotations

import torch

from ..model.description import RobotModel
from ..space import lie
from ..space.tangent import ambient_to_tangent, layout, tangent_to_ambient
from .levels import differentiated, kernels_kept_off


def to_ambient(ops, model: RobotModel, q: torch.Tensor, g: torch.Tensor, convention: int) -> torch.Tensor:
    """T(q)^T g: a gradient g (..., nv) along the tangent space as one in q's coordinates (..., nq)."""
    if not layout(model).quaternions:
        return g
    if _kernel_runs(model, convention, q, g):
        return ops.tangent_to_ambient(q, g, convention)
    return tangent_to_ambient(model, q, g, convention)


def integrate_backward(ops, model: RobotModel, needs, grads, output, q, v, dt, convention):
    """The gradients of q' = integrate(q, v, dt) (dt the op's (..., 1) column)."""
    if not any(needs[:3]):
        return None, None, None, None
    if _kernel_runs(model, convention, q, v, dt, grads[0]):
        g_q, g_v, g_dt = ops.integrate_vjp(q, v, dt, grads[0], convention)
        return g_q if needs[0] else None, g_v if needs[1] else None, g_dt if needs[2] else None, None
    g = ambient_to_tangent(model, output, grads[0], convention)
    j_q, j_u = lie.d_integrate(_space(model), q, v * dt, 1.0, convention)
    g_u = _transposed_times(j_u, g)
    return (tangent_to_ambient(model, q, _transposed_times(j_q, g), convention) if needs[0] else None,
            dt * g_u if needs[1] else None, (v * g_u).sum(-1, keepdim=True) if needs[2] else None, None)


def difference_backward(ops, model: RobotModel, needs, grads, output, q0, q1, convention):
    """The gradients of v = difference(q0, q1)."""
    if not any(needs[:2]):
        return None, None, None
    if _kernel_runs(model, convention, q0, q1, grads[0]):
        g_0, g_1 = ops.difference_vjp(q0, q1, grads[0], convention)
        return g_0 if needs[0] else None, g_1 if needs[1] else None, None
    j_0, j_1 = lie.d_difference(_space(model), q0, q1, convention)
    return (tangent_to_ambient(model, q0, _transposed_times(j_0, grads[0]), convention) if needs[0] else None,
            tangent_to_ambient(model, q1, _transposed_times(j_1, grads[0]), convention) if needs[1] else None, None)


def _kernel_runs(model: RobotModel, convention: int, *tensors: torch.Tensor) -> bool:
    """Whether a backward's kernel computes this map: nothing differentiates the backward itself, and the kernels
    are not kept off the call (levels.kernels_kept_off; tensors[0] is q)."""
    return not differentiated(tensors) and not kernels_kept_off(model, convention, tensors[0])


def _transposed_times(j: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """J^T g for J (..., n, n) and g (..., n)."""
    return (g.unsqueeze(-2) @ j).squeeze(-2)


def _space(model: RobotModel) -> lie.Space:
    """The kernels' configuration space: the model's joints in q's order."""
    return lie.Space.of([joint.type for _, joint in sorted(zip(model.q_index, model.joints), key=lambda x: x[0])])
