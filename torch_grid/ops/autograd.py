"""Autograd for the ops, as each op's table entry declares (OpSpec.backward, ops/table.py).

"formula": the formulas of BACKWARDS, mostly through the O(n) vector-Jacobian product of inverse
dynamics. Those kernels give derivatives along the tangent space; the gradient with respect to q is
mapped to the ambient coordinates the caller passed (a quaternion through its normalisation:
space/tangent.py). "dual": `<op>_backward`, the op's own kernel on dual numbers, for outputs that are
already derivatives; its q gradient is already in ambient coordinates. "composed": formulas over other
ops: the inverse-dynamics gradient's backward differentiates the gradient of lam . tau along 2 nv
directions (forward over reverse, the jvp kernels); the forward-dynamics derivatives, the
external-force derivative of inverse dynamics and the operational-space inertia are products of other
ops' outputs and back-propagate through those. The others raise a clear error when back-propagated
through, as does differentiating any backward a second time.
"""
from __future__ import annotations

from typing import Callable

import torch

from ..model.description import RobotModel
from ..space.constants import constant
from ..space.rpy import rpy_rate_transpose_solve
from ..space.tangent import (
    ambient_direction,
    bracket_term,
    bracket_term_outer,
    has_brackets,
    tangent_directions,
)
from .levels import differentiated
from .lie_backward import difference_backward, integrate_backward, to_ambient
from .mujoco_second_order import crba_vjp as mujoco_crba_vjp
from .parameters import (
    derivatives_parameter_vjp,
    energy_parameter_vjp,
    inertia_parameter_vjp,
    mass_product_parameter_vjp,
    regressor_vjp,
    regressor_vjp_tangent,
    repeat_params,
)
from .saving import save, saved
from .table import OPS, OpSpec


def backward_formula(spec: OpSpec) -> Callable | None:
    """The op's backward, formula(ops, model, needs, grads, output, *inputs), as its table entry declares
    (spec.backward), or None if it has none."""
    if spec.backward in ("formula", "composed"):
        return BACKWARDS[spec.name]
    return _forward_mode(spec) if spec.backward == "dual" else None


def register_autograd(namespace: str, model: RobotModel) -> None:
    """Attach a backward to every op of one robot build."""
    ops = getattr(torch.ops, namespace)
    for spec in OPS.values():
        backward = backward_formula(spec)
        if backward is None:
            torch.library.register_autograd(f"{namespace}::{spec.name}", no_backward(spec.name),
                                            setup_context=_save_nothing)
        else:
            torch.library.register_autograd(f"{namespace}::{spec.name}", _backward(backward, ops, model),
                                            setup_context=_save_inputs)


def _save_nothing(ctx, inputs, output) -> None:
    pass


def _save_inputs(ctx, inputs, output) -> None:
    ctx.several = isinstance(output, tuple)
    save(ctx, inputs, output if ctx.several else (output,))


def no_backward(name: str) -> Callable:
    # Every op without a backward computes derivatives (a backward's kernels, the second-order tensors):
    # differentiating it is a third derivative, or the second of an op whose outputs are derivatives.
    # The fused kernels are the fast paths of step, step_derivatives, d_integrate and d_difference, which compose
    # their value in torch whenever autograd is to see it.
    message = (f"torch_grid: {name} has no derivative: the op whose derivative it computes cannot be differentiated "
               "once more (a third derivative, or the second derivative of an op whose outputs are derivatives)")
    if OPS[name].backward == "step":
        method = name if name in ("step", "d_integrate", "d_difference") else "step_derivatives"
        what = "the Jacobians" if name.startswith("d_") else "the step"
        message = (f"torch_grid: the {name} kernel has no derivative; differentiate Robot.{method}, which then "
                   f"composes {what} in torch")

    def backward(ctx, *grads):
        raise NotImplementedError(message)

    return backward


def _backward(formula: Callable, ops, model: RobotModel) -> Callable:
    """formula(ops, model, needs, grads, output, *inputs) -> one gradient (or None) per input, where
    needs[i] says whether input i's gradient is wanted (ctx.needs_input_grad). Under create_graph=True
    the formula's ops are recorded, so it is differentiated by their own backwards."""

    def backward(ctx, *grads):
        inputs, outputs = saved(ctx)
        return formula(ops, model, ctx.needs_input_grad, grads, outputs if ctx.several else outputs[0], *inputs)

    return backward


def _forward_mode(spec: OpSpec) -> Callable:
    """The backward of an op whose kernel is differentiated in forward mode by `<op>_backward`. Its
    q gradient is already with respect to the coordinates passed (through any normalisation)."""

    tensors = [k for k, a in enumerate(spec.args) if a.is_tensor]

    def formula(ops, model, needs, grads, output, *inputs):
        mask = sum(1 << i for i, k in enumerate(tensors) if needs[k])
        result = getattr(ops, f"{spec.name}_backward")(*inputs[:-1], *grads, mask, inputs[-1])
        result = result if isinstance(result, tuple) else (result,)
        gradients = [None] * len(inputs)
        for i, k in enumerate(tensors):
            gradients[k] = result[i] if needs[k] else None
        return tuple(gradients)

    return formula


def _inverse_dynamics(ops, model, needs, grads, output, q, qd, qdd, f_ext, params, convention):
    """tau = ID(q, qd, qdd, f_ext; pi): d/dq and d/dqd as one O(n) vector-Jacobian product, d/dqdd = M,
    d/df_ext = -J^T, d/dpi = Y (the regressor). With all three of q or qd and qdd, a plain backward takes M grad
    from the same pass (inverse_dynamics_vjp_full, which has no derivative of its own) rather than building M,
    for a robot without rotor armature (that pass's M is the bodies' alone)."""
    grad = grads[0]
    dq = dqd = dqdd = df = dparams = None
    if needs[0] or needs[1]:
        if needs[2] and not model.has_armature and not differentiated((q, qd, qdd, grad)):
            g_q, g_qd, dqdd, _ = ops.inverse_dynamics_vjp_full(q, qd, qdd, f_ext, grad, params, convention)
        else:
            g_q, g_qd = ops.inverse_dynamics_vjp(q, qd, qdd, f_ext, grad, params, convention)
        dq = to_ambient(ops, model, q, g_q, convention) if needs[0] else None
        dqd = g_qd if needs[1] else None
    if needs[2] and dqdd is None:
        dqdd = _vjp(ops.crba(q, params, convention), grad)
    if needs[3]:
        # d tau / d f_k = -J_k^T (J_k: body k's Jacobian in its frame), so the gradient is -J_k grad:
        # minus the velocity of body k under the joint velocity grad.
        df = -ops.body_velocities(q, grad, convention)
    if needs[4]:
        dparams = regressor_vjp(ops, q, qd, qdd, grad, convention)
    return dq, dqd, dqdd, df, dparams, None


def _forward_dynamics(ops, model, needs, grads, output, q, qd, tau, f_ext, params, convention):
    """qdd = FD(q, qd, tau, f_ext; pi) solves ID(q, qd, qdd, f_ext; pi) = tau, so with lambda = M^-1 grad:
    d/dx = -lambda^T d tau/dx for x = q, qd, pi (at the saved qdd; one O(n) product, and the regressor
    for pi), d/dtau = lambda and d/df_ext = J lambda."""
    lam = ops.inertia_solve(q, grads[0], params, convention)
    dq = dqd = dparams = None
    if needs[0] or needs[1]:
        g_q, g_qd = ops.inverse_dynamics_vjp(q, qd, output, f_ext, lam, params, convention)
        dq = to_ambient(ops, model, q, -g_q, convention) if needs[0] else None
        dqd = -g_qd if needs[1] else None
    df = ops.body_velocities(q, lam, convention) if needs[3] else None
    if needs[4]:
        dparams = -regressor_vjp(ops, q, qd, output, lam, convention)
    return dq, dqd, lam if needs[2] else None, df, dparams, None


def _inverse_dynamics_vjp(ops, model, needs, grads, output, q, qd, qdd, f_ext, lam, params, convention):
    """(g_q, g_qd) = lam^T d tau / d(q, qd), the tangent gradient of s = lam . tau. With cotangents
    (u_q, u_qd), h = u_q . g_q + u_qd . g_qd = D_u s is the derivative of s along u, and its gradient
    is forward over reverse: D_u of the gradient of s, plus along q the Lie bracket sum_j u_j
    [e_k, e_j] s of the quaternion joints. d h / d qdd = D_u (M lam), d h / d f_ext = -D_u (J lam),
    d h / d lam = d tau / dq u_q + d tau / dqd u_qd = D_u tau: all but f_ext's from one jvp kernel.
    h is linear in pi: d h / d pi = lam^T D_u Y, the regressor's derivative along u."""
    zero = torch.zeros_like(qd)
    u_q, u_qd = (zero if g is None else g for g in grads)
    t_u = ambient_direction(model, q, u_q, convention)
    dq = dqd = dqdd = df = dlam = dparams = None
    if needs[0] or needs[1] or needs[2] or needs[4]:
        d_gq, d_gqd, d_mlam, d_tau = ops.inverse_dynamics_vjp_full_jvp(q, qd, qdd, f_ext, lam, params, t_u, u_qd,
                                                                        convention)
        if needs[0]:
            if has_brackets(model):
                d_gq = d_gq + bracket_term_outer(model, u_q, output[0], convention)
            dq = to_ambient(ops, model, q, d_gq, convention)
        dqd = d_gqd if needs[1] else None
        dqdd = d_mlam if needs[2] else None
        dlam = d_tau if needs[4] else None
    if needs[3]:
        df = -ops.body_velocities_jvp(q, lam, t_u, convention)
    if needs[5]:
        dparams = regressor_vjp_tangent(ops, q, qd, qdd, lam, t_u, u_qd, convention)
    return dq, dqd, dqdd, df, dlam, dparams, None


def _frame_jacobian(ops, model, needs, grads, output, q, frame, reference, convention):
    """<G, J(q)> differentiated by an O(n) kernel along the chain (csrc/kernels/kinematics/frames.h), in
    Pinocchio's convention, or where the conventions agree; MuJoCo's twin reframes J with G(q), so
    there the op's kernel runs on dual numbers."""
    if convention and model.conventions_differ:
        return _forward_mode(OPS["frame_jacobian"])(ops, model, needs, grads, output, q, frame, reference, convention)
    g = ops.frame_jacobian_vjp(q, _unexpanded(grads[0], 2), frame, reference, convention)
    return to_ambient(ops, model, q, g, convention), None, None, None


def _inertia_solve(ops, model, needs, grads, output, q, x, params, convention):
    """y = M^-1 x: d/dx <g, y> = M^-1 g = mu; d/dq and d/dpi = -<mu, dM y>, mass-matrix product gradients."""
    mu = ops.inertia_solve(q, grads[0], params, convention)
    dq = dparams = None
    if needs[0]:
        dq = -_mass_product_vjp(ops, model, q, output.unsqueeze(-2), mu.unsqueeze(-2), params, convention)
        dq = to_ambient(ops, model, q, dq, convention)
    if needs[2]:
        dparams = -mass_product_parameter_vjp(ops, model, q, output.unsqueeze(-2), mu.unsqueeze(-2), convention)
    return dq, mu if needs[1] else None, dparams, None


def _crba(ops, model, needs, grads, output, q, params, convention):
    """<G, M(q)> differentiated by an O(n d) kernel (csrc/kernels/dynamics/crba.h); MuJoCo's twin with quaternion
    joints reframes M with G(q), whose own turn adds a term (mujoco_second_order.crba_vjp)."""
    dq = dparams = None
    if needs[0]:
        if convention and model.conventions_differ:
            if output is None:  # minv's backward passes no M
                output = ops.crba(q, params, convention)
            dq = mujoco_crba_vjp(ops, model, q, grads[0], output, params)
        else:
            dq = ops.crba_vjp(q, _unexpanded(grads[0], 2), params, convention)
        dq = to_ambient(ops, model, q, dq, convention)
    if needs[1]:
        dparams = inertia_parameter_vjp(ops, model, q, grads[0], convention)
    return dq, dparams, None


def _unexpanded(x: torch.Tensor, trailing: int) -> torch.Tensor:
    """x with each broadcast (stride-0) batch dimension cut to one entry: the ops broadcast batches, so a
    gradient such as that of out.sum() is not copied sample by sample."""
    for d in range(x.dim() - trailing):
        if x.stride(d) == 0 and x.shape[d] > 1:
            x = x.narrow(d, 0, 1)
    return x


def _crba_vjp(ops, model, needs, grads, output, q, weight, params, convention):
    """g = the tangent gradient of <W, M(q)>, so <u, g> = D_u <W, M>: d/dW = D_u M, d/dpi the derivative
    along u of <W, M>'s pi-gradient, and d/dq is forward over reverse through M e_m = ID(q, 0, e_m) - g(q)
    (the backward of those ID products)."""
    nv, u = model.nv, grads[0]
    unit = torch.eye(nv, dtype=q.dtype, device=q.device).expand(*q.shape[:-1], nv, nv)
    zero = torch.zeros_like(unit)
    Q, lam = repeat(q, nv, 1), weight.mT  # product m: at qdd = e_m, cotangent W[:, m]
    dq = dw = dparams = None
    if needs[0]:
        rest = (zero[..., 0, :], zero[..., 0, :], lam.sum(-2))
        products = ((Q, zero, unit, lam, repeat(u, nv, 1), repeat_params(params)), (q, *rest, u, params))
        terms = []
        for x, v, a, c, cot, p in products:
            g = (ops.inverse_dynamics_vjp(x, v, a, None, c, p, convention)[0], None) if has_brackets(model) else None
            terms.append(_inverse_dynamics_vjp(ops, model, (True,) + (False,) * 6, (cot, None), g, x, v, a, None, c, p,
                                               convention)[0])
        dq = terms[0].sum(-2) - terms[1]
    t_u = ambient_direction(model, q, u, convention) if needs[1] or needs[2] else None
    if needs[1]:
        dw = mass_product_jvp(ops, Q, unit, repeat(t_u, nv, 1), repeat_params(params), convention)  # rows: D_u M e_m
    if needs[2]:
        dparams = inertia_parameter_vjp(ops, model, q, weight, convention, t_u)
    return dq, dw, dparams, None


def _minv(ops, model, needs, grads, output, q, params, convention):
    """d(M^-1) = -M^-1 dM M^-1, so the gradient is the crba one for -M^-T G M^-T, from the saved M^-1."""
    inner = -output.transpose(-1, -2) @ grads[0] @ output.transpose(-1, -2)
    return _crba(ops, model, needs, (inner,), None, q, params, convention)


def _mass_product_vjp(ops, model, q, a, lam, params, convention):
    """d/dq sum_m lam_m^T M(q) a_m along the tangent, (..., nv), for a and lam of shape (..., m, nv): one O(n)
    kernel per pair where it runs (Pinocchio's convention, or where the conventions agree). Otherwise
    ID(q, 0, a) = M a + g(q), so the ID products at (0, a_m) with cotangents lam_m, less one gravity
    product at (0, 0) with cotangent sum_m lam_m."""
    m = a.shape[-2]
    if not (convention and model.conventions_differ):
        return ops.mass_product_vjp(repeat(q, m, 1), a, lam, repeat_params(params), convention).sum(-2)
    zero = torch.zeros_like(a)
    products, _ = ops.inverse_dynamics_vjp(repeat(q, m, 1), zero, a, None, lam, repeat_params(params), convention)
    gravity, _ = ops.inverse_dynamics_vjp(q, zero[..., 0, :], zero[..., 0, :], None, lam.sum(-2), params, convention)
    return products.sum(-2) - gravity


def _mass_product_vjp_op(ops, model, needs, grads, output, q, a, lam, params, convention):
    """g = the tangent gradient of lam . M(q) a = lam . (ID(q, 0, a) - ID(q, 0, 0)): the backwards of those
    two inverse-dynamics products (forward over reverse), so d/da = D_u(M) lam, d/dlam = D_u(M) a and
    d/dpi the derivative along u of lam . M a's pi-gradient."""
    zero = torch.zeros_like(a)
    terms = []
    for acc, want in ((a, (needs[0], False, needs[1], False, needs[2], False)),
                      (zero, (needs[0], False, False, False, needs[2], False))):
        g = (ops.inverse_dynamics_vjp(q, zero, acc, None, lam, params, convention)[0], None) if has_brackets(model) else None
        terms.append(_inverse_dynamics_vjp(ops, model, want, (grads[0], None), g, q, zero, acc, None, lam, params,
                                           convention))
    dq = terms[0][0] - terms[1][0] if needs[0] else None
    dlam = terms[0][4] - terms[1][4] if needs[2] else None
    dparams = None
    if needs[3]:
        t_u = ambient_direction(model, q, grads[0], convention)
        dparams = mass_product_parameter_vjp(ops, model, q, a.unsqueeze(-2), lam.unsqueeze(-2), convention, t_u)
    return dq, terms[0][2] if needs[1] else None, dlam, dparams, None


def mass_product_jvp(ops, q, x, t, params, convention):
    """The derivative of M(q) x along the direction t of q's coordinates, (..., nv): ID(q, 0, x) =
    M x + g(q) in either convention, so the dual-number ID product at (0, x) less the one at (0, 0)."""
    zero = torch.zeros_like(x)
    return (ops.inverse_dynamics_jvp(q, zero, x, None, params, t, None, convention) -
            ops.inverse_dynamics_jvp(q, zero, zero, None, params, t, None, convention))


def _ccrba(ops, model, needs, grads, output, q, qd, params, convention):
    """(A, h = A qd): d h/dqd = A, d h/dq = dccrba; A e_j = h(q, e_j), so <G_A, A> differentiates along q
    as sum_j G_A[:, j] . dccrba(q, e_j). Made of ccrba and dccrba, so that h (a momentum, not a
    derivative) has a second derivative, by dccrba's own backward. d/dpi: the kernel on dual numbers."""
    g_A, g_h = grads
    dq = dqd = dparams = None
    if needs[0]:
        nv = model.nv
        unit = torch.eye(nv, dtype=q.dtype, device=q.device).expand(*q.shape[:-1], nv, nv)
        columns = ops.dccrba(repeat(q, nv, 1), unit, repeat_params(params), convention)  # [..., j] = d(A e_j)/dq
        g = torch.einsum("...rj,...jrk->...k", g_A, columns)
        g = g + (g_h.unsqueeze(-2) @ ops.dccrba(q, qd, params, convention)).squeeze(-2)
        dq = to_ambient(ops, model, q, g, convention)
    if needs[1]:
        dqd = (output[0].mT @ g_h.unsqueeze(-1)).squeeze(-1)
    if needs[2]:
        dparams = _parameters_by_dual(OPS["ccrba"], ops, model, grads, q, qd, params, convention)
    return dq, dqd, dparams, None


def _generalized_gravity(ops, model, needs, grads, output, q, params, convention):
    """g(q) = ID(q, 0, 0)."""
    zero = torch.zeros(*q.shape[:-1], model.nv, dtype=q.dtype, device=q.device)
    dq = dparams = None
    if needs[0]:
        g_q, _ = ops.inverse_dynamics_vjp(q, zero, zero, None, grads[0], params, convention)
        dq = to_ambient(ops, model, q, g_q, convention)
    if needs[1]:
        dparams = regressor_vjp(ops, q, zero, zero, grads[0], convention)
    return dq, dparams, None


def _nonlinear_effects(ops, model, needs, grads, output, q, qd, params, convention):
    """nle(q, qd) = ID(q, qd, 0): MuJoCo's qacc = 0 in MuJoCo's convention, as the op itself."""
    dq = dqd = dparams = None
    if needs[0] or needs[1]:
        g_q, g_qd = ops.inverse_dynamics_vjp(q, qd, torch.zeros_like(qd), None, grads[0], params, convention)
        dq, dqd = to_ambient(ops, model, q, g_q, convention), g_qd
    if needs[2]:
        dparams = regressor_vjp(ops, q, qd, torch.zeros_like(qd), grads[0], convention)
    return dq, dqd, dparams, None


def _com(ops, model, needs, grads, output, q, params, convention):
    """d com / dq = J_com along the tangent; d/dpi: the kernel on dual numbers."""
    dq = dparams = None
    if needs[0]:
        dq = to_ambient(ops, model, q, _vjp(ops.jacobian_com(q, params, convention), grads[0]), convention)
    if needs[1]:
        dparams = _parameters_by_dual(OPS["com"], ops, model, grads, q, params, convention)
    return dq, dparams, None


def _parameters_by_dual(spec: OpSpec, ops, model, grads, *inputs):
    """The pi-gradient alone of an op with a <op>_backward kernel (its last tensor input is params)."""
    needs = [False] * len(inputs)
    needs[len(inputs) - 2] = True
    return _forward_mode(spec)(ops, model, needs, grads, None, *inputs)[-2]


def _energy(ops, model, needs, grads, output, q, qd, params, convention):
    """KE = qd^T M qd / 2, PE: d PE/dq = g(q); d KE/dqd = M qd; d KE/dq = qd^T d(M qd)/dq / 2; d/dpi: the
    energy regressors."""
    grad = grads[0]
    g_kinetic = grad[..., 0:1] + grad[..., 2:3]
    g_potential = grad[..., 1:2] + grad[..., 2:3]
    dq = dqd = dparams = None
    if needs[0]:
        dke_dq = 0.5 * _mass_product_vjp(ops, model, q, qd.unsqueeze(-2), qd.unsqueeze(-2), params, convention)
        dpe_dq = ops.generalized_gravity(q, params, convention)
        dq = to_ambient(ops, model, q, g_kinetic * dke_dq + g_potential * dpe_dq, convention)
    if needs[1]:
        dqd = g_kinetic * _vjp(ops.crba(q, params, convention), qd)
    if needs[2]:
        dparams = energy_parameter_vjp(ops, q, qd, grad, convention)
    return dq, dqd, dparams, None


def _forward_kinematics(ops, model, needs, grads, output, q, convention):
    """Frame positions move with the linear rows of their LOCAL_WORLD_ALIGNED Jacobians; a rotation
    R moves by dR = [w]x R with w the angular rows, so <G, dR> = w . axial(R G^T - G R^T)."""
    g_pos, g_rot = grads
    rotations = output[1]
    zero = torch.zeros(*q.shape[:-1], len(model.frames), 3, dtype=q.dtype, device=q.device)
    w_rot = zero
    if g_rot is not None:
        A = rotations @ g_rot.transpose(-1, -2)
        w_rot = torch.stack([A[..., 1, 2] - A[..., 2, 1], A[..., 2, 0] - A[..., 0, 2], A[..., 0, 1] - A[..., 1, 0]], dim=-1)
    weights = torch.cat([zero if g_pos is None else g_pos, w_rot], dim=-1)
    return to_ambient(ops, model, q, ops.frames_vjp(q, weights, convention), convention), None


def _end_effector_pose(ops, model, needs, grads, output, q, frames, convention):
    """[xyz, rpy] of the listed frames: xyz as forward_kinematics; the world angular velocity is
    w = E(rpy) d(rpy)/dt, so the rpy gradient maps to w through E^-T."""
    grad = grads[0]
    weights = torch.zeros(*q.shape[:-1], len(model.frames), 6, dtype=q.dtype, device=q.device)
    index = constant(tuple(frames), torch.long, q.device)
    w_ang = rpy_rate_transpose_solve(output[..., 3:], grad[..., 3:])
    weights = weights.index_add(-2, index, torch.cat([grad[..., :3], w_ang], dim=-1))
    return to_ambient(ops, model, q, ops.frames_vjp(q, weights, convention), convention), None, None


def _forward_dynamics_derivatives(ops, model, needs, grads, output, q, qd, tau, f_ext, params, convention):
    """(-M^-1 dtau/dq, -M^-1 dtau/dqd, M^-1) at qdd = FD(q, qd, tau, f_ext; pi): back through that
    composition, each part by its own backward (the ID gradient's is second order)."""
    g_dq, g_dqd, g_minv = grads
    minv = output[2]
    qdd = ops.forward_dynamics(q, qd, tau, f_ext, params, convention)
    d_q, d_qd = ops.inverse_dynamics_derivatives(q, qd, qdd, f_ext, params, convention)
    g_id = tuple(None if g is None else -minv @ g for g in (g_dq, g_dqd))  # M^-1 is symmetric
    g_m = _sum(g_minv, None if g_dq is None else -g_dq @ d_q.mT, None if g_dqd is None else -g_dqd @ d_qd.mT)
    dq, dqd, g_qdd, df, dp_id, _ = _inverse_dynamics_derivatives(
        ops, model, (needs[0], needs[1], True, needs[3], needs[4], False), g_id, None, q, qd, qdd, f_ext, params, convention)
    fd = _forward_dynamics(ops, model, needs, (g_qdd,), qdd, q, qd, tau, f_ext, params, convention)
    dq_m = dp_m = None
    if g_m is not None and (needs[0] or needs[4]):
        dq_m, dp_m = _minv(ops, model, (needs[0], needs[4]), (g_m,), minv, q, params, convention)[:2]
    return _sum(dq, fd[0], dq_m), _sum(dqd, fd[1]), fd[2], _sum(df, fd[3]), _sum(dp_id, fd[4], dp_m), None


def _inverse_dynamics_derivatives(ops, model, needs, grads, output, q, qd, qdd, f_ext, params, convention):
    """<Gq, dtau/dq> + <Gqd, dtau/dqd> differentiated with respect to every input by one O(n d) kernel,
    the second-order recursion contracted with G (csrc/kernels/derivatives/rnea_second_order.h), in Pinocchio's
    convention or where the conventions agree; in MuJoCo's convention of a robot with quaternion joints,
    forward over reverse (_inverse_dynamics_derivatives_jvps). d/dpi: the regressor's derivatives along
    the same directions (derivatives_parameter_vjp)."""
    dparams = derivatives_parameter_vjp(ops, model, q, qd, qdd, *grads, convention) if needs[4] else None
    if convention and model.conventions_differ:
        return _inverse_dynamics_derivatives_jvps(ops, model, needs, grads, output, q, qd, qdd, f_ext, params,
                                                  convention) + (dparams, None)
    if not (needs[0] or needs[1] or needs[2] or needs[3]):
        return None, None, None, None, dparams, None
    nv, batch = model.nv, q.shape[:-1]
    zero = torch.zeros(*batch, nv, nv, dtype=q.dtype, device=q.device)
    g_q, g_qd = (zero if g is None else _unexpanded(g, 2) for g in grads)
    dq, dqd, dqdd, df = ops.inverse_dynamics_derivatives_vjp(q, qd, qdd, f_ext, g_q, g_qd, params, convention)
    dq = to_ambient(ops, model, q, dq, convention) if needs[0] else None
    return dq, dqd if needs[1] else None, dqdd if needs[2] else None, df if needs[3] else None, dparams, None


def _inverse_dynamics_derivatives_jvps(ops, model, needs, grads, output, q, qd, qdd, f_ext, params, convention):
    """<Gq, dtau/dq> + <Gqd, dtau/dqd> = sum_j D_j (lam_j . tau) + D'_j (mu_j . tau), with lam_j, mu_j
    the columns of Gq, Gqd, D_j the derivative along q's tangent j and D'_j along qd_j. Its gradient
    is forward over reverse: the derivatives along those 2 nv directions of the gradient of
    lam . tau (O(n) each: inverse_dynamics_vjp_full, -J lam), by the dual-number jvp kernels; for
    q, plus the Lie-bracket term of each quaternion joint, whose tangent derivatives do not commute.
    The gradients of (q, qd, qdd, f_ext)."""
    nv, batch = model.nv, q.shape[:-1]
    zero = torch.zeros(*batch, nv, nv, dtype=q.dtype, device=q.device)
    g_q, g_qd = (zero if g is None else g for g in grads)
    t = tangent_directions(model, q, convention)
    lam = torch.cat([g_q.mT, g_qd.mT], dim=-2)  # (..., 2 nv, nv): one cotangent per direction
    t_q = torch.cat([t, torch.zeros_like(t)], dim=-2)
    t_qd = torch.cat([zero, torch.eye(nv, dtype=q.dtype, device=q.device).expand_as(zero)], dim=-2)
    Q, QD, QDD = (repeat(x, 2 * nv, 1) for x in (q, qd, qdd))
    F = None if f_ext is None else repeat(f_ext, 2 * nv, 2)
    dq = dqd = dqdd = df = None
    if needs[0] or needs[1] or needs[2]:
        P = repeat_params(params)
        d_gq, d_gqd, d_mlam, _ = ops.inverse_dynamics_vjp_full_jvp(Q, QD, QDD, F, lam, P, t_q, t_qd, convention)
        if needs[0]:
            tangent = d_gq.sum(-2)
            if has_brackets(model):
                g_tan, _ = ops.inverse_dynamics_vjp(Q[..., :nv, :], QD[..., :nv, :], QDD[..., :nv, :],
                                                    None if F is None else F[..., :nv, :, :], g_q.mT, P, convention)
                tangent = tangent + bracket_term(model, g_tan, convention)
            dq = to_ambient(ops, model, q, tangent, convention)
        dqd = d_gqd.sum(-2) if needs[1] else None
        dqdd = d_mlam.sum(-2) if needs[2] else None  # M lam does not depend on qd: its last nv rows are 0
    if needs[3]:  # d/df_ext (lam . tau) = -J lam does not depend on qd
        df = -ops.body_velocities_jvp(Q[..., :nv, :], g_q.mT, t, convention).sum(-3)
    return dq, dqd, dqdd, df


def repeat(x: torch.Tensor, n: int, trailing: int) -> torch.Tensor:
    """x (..., *tail) with `trailing` tail dimensions, as (..., n, *tail) without a copy."""
    return x.unsqueeze(-trailing - 1).expand(*x.shape[:-trailing], n, *x.shape[-trailing:])


def _inverse_dynamics_external_force_derivatives(ops, model, needs, grads, output, q, convention):
    """Row i of d tau / d f_ext is minus the body velocities at qd = e_i (-J_k e_i), so the gradient
    is that of -sum_i <G[i], body_velocities(q, e_i)>, by body_velocities' backward."""
    nv, batch = model.nv, q.shape[:-1]
    unit = torch.eye(nv, dtype=q.dtype, device=q.device).expand(*batch, nv, nv)
    dq = _forward_mode(OPS["body_velocities"])(ops, model, (True, False, False), (-grads[0],), None,
                                               repeat(q, nv, 1), unit, convention)[0]
    return dq.sum(-2), None


def _forward_dynamics_external_force_derivatives(ops, model, needs, grads, output, q, params, convention):
    """-M^-1 (d tau / d f_ext): back through the product."""
    minv = ops.minv(q, params, convention)
    e = ops.inverse_dynamics_external_force_derivatives(q, convention)
    g = grads[0].flatten(-2)
    dq = None
    if needs[0]:
        g_e = (-minv @ g).reshape(e.shape)
        dq = _inverse_dynamics_external_force_derivatives(ops, model, needs, (g_e,), e, q, convention)[0]
    dq_m, dparams, _ = _minv(ops, model, needs, (-g @ e.flatten(-2).mT,), minv, q, params, convention)
    return _sum(dq, dq_m), dparams, None


def _forward_dynamics_parameter_derivatives(ops, model, needs, grads, output, q, qd, tau, params, convention):
    """-M^-1 Y(q, qd, qdd) at qdd = FD(q, qd, tau; pi): back through the product, the regressor by its
    own backward and qdd by forward_dynamics'."""
    minv = ops.minv(q, params, convention)
    qdd = ops.forward_dynamics(q, qd, tau, None, params, convention)
    y = ops.inverse_dynamics_regressor(q, qd, qdd, convention)
    dq, dqd, g_qdd, _ = _forward_mode(OPS["inverse_dynamics_regressor"])(
        ops, model, (needs[0], needs[1], True, False), (-minv @ grads[0],), None, q, qd, qdd, convention)
    fd = _forward_dynamics(ops, model, (needs[0], needs[1], needs[2], False, needs[3]), (g_qdd,), qdd, q, qd, tau, None,
                           params, convention)
    dq_m, dp_m, _ = _minv(ops, model, (needs[0], needs[3]), (-grads[0] @ y.mT,), minv, q, params, convention)
    return _sum(dq, fd[0], dq_m), _sum(dqd, fd[1]), fd[2], _sum(fd[4], dp_m), None


def _osc_inertia(ops, model, needs, grads, output, q, frame, reference, params, convention):
    """Lambda = (J M^-1 J^T)^-1: d Lambda = -Lambda dA Lambda with A = J M^-1 J^T, then back to J (by
    frame_jacobian's backward) and to M^-1."""
    j = ops.frame_jacobian(q, frame, reference, convention)
    minv = ops.minv(q, params, convention)
    g_a = -output.mT @ grads[0] @ output.mT
    dq = None
    if needs[0]:
        g_j = g_a @ j @ minv + g_a.mT @ j @ minv
        dq = _frame_jacobian(ops, model, needs, (g_j,), None, q, frame, reference, convention)[0]
    dq_m, dparams, _ = _minv(ops, model, (needs[0], needs[3]), (j.mT @ g_a @ j,), minv, q, params, convention)
    return _sum(dq, dq_m), None, None, dparams, None


def _sum(*terms):
    """The sum of the terms that are not None (None if all are)."""
    present = [t for t in terms if t is not None]
    return sum(present[1:], present[0]) if present else None


BACKWARDS = {
    "frame_jacobian": _frame_jacobian,
    "inverse_dynamics_vjp": _inverse_dynamics_vjp,
    "inertia_solve": _inertia_solve,
    "crba": _crba,
    "crba_vjp": _crba_vjp,
    "mass_product_vjp": _mass_product_vjp_op,
    "minv": _minv,
    "forward_kinematics": _forward_kinematics,
    "end_effector_pose": _end_effector_pose,
    "inverse_dynamics": _inverse_dynamics,
    "forward_dynamics": _forward_dynamics,
    "generalized_gravity": _generalized_gravity,
    "nonlinear_effects": _nonlinear_effects,
    "com": _com,
    "ccrba": _ccrba,
    "energy": _energy,
    "inverse_dynamics_derivatives": _inverse_dynamics_derivatives,
    "forward_dynamics_derivatives": _forward_dynamics_derivatives,
    "inverse_dynamics_external_force_derivatives": _inverse_dynamics_external_force_derivatives,
    "forward_dynamics_external_force_derivatives": _forward_dynamics_external_force_derivatives,
    "forward_dynamics_parameter_derivatives": _forward_dynamics_parameter_derivatives,
    "osc_inertia": _osc_inertia,
    "integrate": integrate_backward,
    "difference": difference_backward,
}

# Ops whose backward is a formula made of other ops (their kernels, backwards or jvp kernels) rather than
# a kernel of its own on dual numbers: the formulas cover exactly the ops whose entry declares one
# (backward "formula" or "composed").
_DECLARED = {op.name for op in OPS.values() if op.backward in ("formula", "composed")}
if set(BACKWARDS) != _DECLARED:
    raise ValueError(f"autograd: formulas for {sorted(set(BACKWARDS) - _DECLARED)} whose table entries declare none, none for "
                     f"{sorted(_DECLARED - set(BACKWARDS))} whose entries declare one")


def _vjp(jacobian: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
    """grad^T J for a batch of (n, m) Jacobians: (..., m)."""
    return (grad.unsqueeze(-2) @ jacobian).squeeze(-2)
