"""The ops under torch.func transforms (grad, vjp, jacrev, vmap, functional_call and their compositions).

torch.func needs an autograd.Function with a `setup_context` and a `vmap` rule, which the dispatcher's
registered autograd (torch.library.register_autograd, used by backward() and torch.compile) does
not have. Under a transform, `Robot` calls each op through `FuncOps`: one such Function per op whose
forward calls the op one transform level down, whose backward is the op's own formula
(autograd.py) with its inner ops called the same way (so a transform of a transform nests), and
whose vmap rule moves the batched dimension to the front and makes one batched call, which the ops
broadcast, and whose jvp (forward mode: jvp, jacfwd, hessian, torch.autograd.forward_ad) is the
derivative of the backward with respect to its cotangents.
"""
from __future__ import annotations

from typing import Callable

import torch
from torch.autograd import forward_ad

from ..model.description import RobotModel
from ..space.tangent import tangent_direction
from .autograd import backward_formula, mass_product_jvp, repeat
from .levels import dual, transforming
from .mujoco_second_order import kinematic_hessian_from_ops, second_order_from_ops
from .parameters import repeat_params
from .saving import save, saved
from .table import KERNEL_JVP, OPS


# Why an op inside a backward has no derivative of its own, in the words of the function the user called.
_THIRD = (" (it computes a derivative inside a backward: differentiating it again is a third derivative, or the "
          "second derivative of a function whose outputs are derivatives, such as frame_jacobian or "
          "inverse_dynamics_derivatives)")


class FuncOps:
    """One robot build's ops, each through an autograd.Function that torch.func can transform."""

    def __init__(self, ops, model: RobotModel):
        self._ops, self._model = ops, model
        self._functions: dict[str, type] = {}

    def __getattr__(self, name: str) -> Callable:
        if name.startswith("_") or name not in OPS:
            raise AttributeError(name)
        return lambda *args: self.call(name, *args)

    def call(self, name: str, *args):
        """op `name` at the current transform level: through its Function while one is active."""
        if not transforming() and not dual(args):
            return getattr(self._ops, name)(*args)
        if name not in self._functions:
            self._functions[name] = self._function(name)
        return self._functions[name].apply(*args)

    def _function(self, name: str) -> type:
        spec, model, outer = OPS[name], self._model, self
        trailing = [len(a.trailing) if a.is_tensor else 0 for a in spec.args] + [0]  # and the convention
        formula = backward_formula(spec)
        several = len(spec.outputs) > 1

        def forward(*args):
            return outer.call(name, *args)

        def setup_context(ctx, inputs, output):
            outs = output if several else (output,)
            save(ctx, inputs, outs)
            ctx.save_for_forward(*[inputs[k] for k in ctx.tensor_positions], *outs)

        def unpacked(ctx, tensors=None):
            inputs, outs = saved(ctx, tensors)
            return inputs, outs if several else outs[0]

        def backward(ctx, *grads):
            if formula is None:
                raise NotImplementedError(f"torch_grid: {name} has no derivative; it cannot be back-propagated through"
                                          f"{_THIRD}")
            inputs, output = unpacked(ctx)
            return formula(outer, model, ctx.needs_input_grad, grads, output, *inputs)

        def jvp(ctx, *tangents):
            # The backward is linear in its cotangents u, <J^T u, t> = <u, J t>: the Jacobian-vector
            # product is the gradient of <backward(u), t> with respect to u (at u = 0).
            if formula is None:
                raise NotImplementedError(f"torch_grid: {name} has no forward-mode derivative{_THIRD}")
            # The saved tensors carry this forward-mode level's tangents: their primals, so that the ops
            # below are not differentiated by it again.
            level = torch._C._functorch.maybe_current_level()
            tensors = tuple(forward_ad.unpack_dual(t).primal if level is None else
                            torch._C._functorch._unwrap_for_grad(t, level) for t in ctx.saved_tensors)
            inputs, output = unpacked(ctx, tensors)
            if spec.jvp in ("rule", "dual"):
                return _JVPS[name](outer, output, *inputs, *tangents)
            outs = output if several else (output,)
            needs = tuple(t is not None for t in tangents)

            def paired(*us):
                grads = formula(outer, model, needs, us, output, *inputs)
                terms = [(g * t).sum() for g, t in zip(grads, tangents) if g is not None and t is not None]
                return sum(terms[1:], terms[0]) if terms else us[0].sum() * 0

            # torch.func.grad, not autograd: this runs inside a torch.func transform too
            result = torch.func.grad(paired, argnums=tuple(range(len(outs))))(*(torch.zeros_like(o) for o in outs))
            return result if several else result[0]

        def vmap(info, in_dims, *args):
            # Every op broadcasts leading batch dimensions: the vmapped one goes first, ahead of the
            # others' batch dimensions (right-aligned, as torch broadcasts).
            ranks = [x.dim() - (d is not None) - t for x, d, t in zip(args, in_dims, trailing) if isinstance(x, torch.Tensor)]
            moved = []
            for x, d, t in zip(args, in_dims, trailing):
                if isinstance(x, torch.Tensor) and d is not None:  # a list argument (frames) has nested dims
                    x = x.movedim(d, 0)
                    x = x.reshape(x.shape[0], *[1] * (max(ranks) - (x.dim() - 1 - t)), *x.shape[1:])
                moved.append(x)
            out = outer.call(name, *moved)
            return out, (0,) * len(spec.outputs) if several else 0

        return type(f"{name}_function", (torch.autograd.Function,), {
            "forward": staticmethod(forward), "setup_context": staticmethod(setup_context),
            "backward": staticmethod(backward), "jvp": staticmethod(jvp), "vmap": staticmethod(vmap)})


def _inverse_dynamics_vjp_jvp(ops, _out, q, qd, qdd, f_ext, lam, params, convention, t_q, t_qd, t_qdd, t_f, t_lam,
                              t_params, _):
    """The tangent of (g_q, g_qd) = lam^T d tau / d(q, qd): along q and qd by the dual-number kernel;
    it is linear in lam; along qdd and f_ext, the q-gradient of lam . (M t_qdd) and of lam . (-J^T t_f),
    inverse dynamics at rest less gravity (they do not depend on qd); along pi, the same vector-Jacobian
    product with the parameters t_pi, less that of the terms free of pi (at zero parameters)."""
    zero = torch.zeros_like(qd)
    d_q, d_qd = ops.inverse_dynamics_vjp_full_jvp(q, qd, qdd, f_ext, lam, params, t_q, t_qd, convention)[:2]
    if t_lam is not None:
        g_q, g_qd = ops.inverse_dynamics_vjp(q, qd, qdd, f_ext, t_lam, params, convention)
        d_q, d_qd = d_q + g_q, d_qd + g_qd
    if t_params is not None:  # linear in pi, less the terms free of it (MuJoCo's turns the armature's)
        g_q, g_qd = ops.inverse_dynamics_vjp(q, qd, qdd, None, lam, t_params, convention)
        r_q, r_qd = ops.inverse_dynamics_vjp(q, qd, qdd, None, lam, torch.zeros_like(t_params), convention)
        d_q, d_qd = d_q + g_q - r_q, d_qd + g_qd - r_qd
    if t_qdd is not None or t_f is not None:
        rest = ops.inverse_dynamics_vjp(q, zero, zero, None, lam, params, convention)[0]
        if t_qdd is not None:
            d_q = d_q + ops.inverse_dynamics_vjp(q, zero, t_qdd, None, lam, params, convention)[0] - rest
        if t_f is not None:
            d_q = d_q + ops.inverse_dynamics_vjp(q, zero, zero, t_f, lam, params, convention)[0] - rest
    return d_q, d_qd


def _crba_vjp_jvp(ops, _out, q, weight, params, convention, t_q, t_w, t_params, _):
    """The tangent of g = the tangent gradient of <W, M(q)>: linear in W and in pi (M less the armature,
    which q does not move, is linear in pi); along q, that of the ID products M e_m = ID(q, 0, e_m) - g(q)
    with cotangents W[:, m] (the dual-number kernel)."""
    nv = weight.shape[-1]
    batch = torch.broadcast_shapes(q.shape[:-1], weight.shape[:-2])
    d = q.new_zeros(*batch, nv) if t_w is None else ops.crba_vjp(q, t_w, params, convention)
    if t_params is not None:
        d = d + ops.crba_vjp(q, weight, t_params, convention)
    if t_q is not None:
        unit = torch.eye(nv, dtype=q.dtype, device=q.device).expand(*q.shape[:-1], nv, nv)
        zero = torch.zeros_like(unit)
        lam = weight.mT
        products = ops.inverse_dynamics_vjp_full_jvp(repeat(q, nv, 1), zero, unit, None, lam, repeat_params(params),
                                                     repeat(t_q, nv, 1), None, convention)[0]
        rest = ops.inverse_dynamics_vjp_full_jvp(q, zero[..., 0, :], zero[..., 0, :], None, lam.sum(-2), params, t_q,
                                                 None, convention)[0]
        d = d + products.sum(-2) - rest
    return d


def _mass_product_vjp_jvp(ops, _out, q, a, lam, params, convention, t_q, t_a, t_lam, t_params, _):
    """g = the q-gradient of lam . (ID(q, 0, a) - ID(q, 0, 0)): the tangents of those two products."""
    zero = torch.zeros_like(a)
    d = _inverse_dynamics_vjp_jvp(ops, None, q, zero, a, None, lam, params, convention, t_q, None, t_a, None, t_lam,
                                  t_params, None)[0]
    rest = _inverse_dynamics_vjp_jvp(ops, None, q, zero, zero, None, lam, params, convention, t_q, None, None, None, t_lam,
                                     t_params, None)[0]
    return d - rest


def _inertia_solve_jvp(ops, y, q, x, params, convention, t_q, t_x, t_params, _):
    """y = M^-1 x: dy = M^-1 (t_x - D_t(M) y), D_t(M) y along pi being (Y(q, 0, y) - Y(q, 0, 0)) t_pi."""
    rhs = torch.zeros_like(x) if t_x is None else t_x
    if t_q is not None:
        rhs = rhs - mass_product_jvp(ops, q, y, t_q, params, convention)
    if t_params is not None:
        zero = torch.zeros_like(y)
        t = t_params.flatten(-2).unsqueeze(-1)
        rhs = rhs - ((ops.inverse_dynamics_regressor(q, zero, y, convention) -
                      ops.inverse_dynamics_regressor(q, zero, zero, convention)) @ t).squeeze(-1)
    return ops.inertia_solve(q, rhs, params, convention)


def _tangent_space(model, q, t_q, convention):
    """A tangent t_q of q's coordinates as a direction of the tangent space (..., nv) (tangent_direction); zero
    for None."""
    if t_q is None:
        return torch.zeros(*q.shape[:-1], model.nv, dtype=q.dtype, device=q.device)
    return tangent_direction(model, q, t_q, convention)


def _frame_jacobian_jvp(ops, J, q, frame, reference, convention, t_q, _f, _r, _c):
    """dJ = H t, H the frame's kinematic Hessian and t the tangent of q along the tangent space."""
    model = ops._model
    if t_q is None:
        return torch.zeros_like(J)
    t = _tangent_space(model, q, t_q, convention)
    if convention and model.conventions_differ:  # MuJoCo's Hessian from Pinocchio's
        H = kinematic_hessian_from_ops(ops, model, q, frame, reference)
    else:
        H = ops.frame_kinematic_hessian(q, frame, reference, convention)
    return (H @ t.unsqueeze(-1).unsqueeze(-3)).squeeze(-1)


def _gradient_tangents(ops, q, qd, qdd, f_ext, params, convention, u, t_qd, t_qdd):
    """The derivatives of (dtau/dq, dtau/dqd, M) along (u in the tangent space, t_qd, t_qdd): the
    second-order kernel contracted with them; in MuJoCo's convention of a robot with quaternion
    joints, its tensors (torch_grid/ops/mujoco_second_order.py) contracted in torch."""
    model = ops._model
    if not (convention and model.conventions_differ):
        return ops.inverse_dynamics_derivatives_tangent(q, qd, qdd, f_ext, u, t_qd, t_qdd, params, convention)
    d2q, d2v, dqdv, dM = second_order_from_ops(ops, model, q, qd, qdd, f_ext, params)
    dA = (torch.einsum("...ijk,...k->...ij", d2q, u) + torch.einsum("...ijk,...k->...ij", dqdv, t_qd) +
          torch.einsum("...imj,...m->...ij", dM, t_qdd))
    dB = torch.einsum("...ijk,...k->...ij", d2v, t_qd) + torch.einsum("...ikj,...k->...ij", dqdv, u)
    return dA, dB, torch.einsum("...ijk,...k->...ij", dM, u)


def _affine(op, t, zero):
    """The tangent along one input of an op affine in it: op(t) - op(zero)."""
    with_t, without = op(t), op(zero)
    return tuple(a - b for a, b in zip(with_t, without)) if isinstance(with_t, tuple) else with_t - without


def _inverse_dynamics_derivatives_jvp(ops, _out, q, qd, qdd, f_ext, params, convention, t_q, t_qd, t_qdd, t_f, t_params,
                                      _):
    """The tangent of (dtau/dq, dtau/dqd): the second-order tensors along (q, qd, qdd), contracted in
    the kernel; dtau/dq is affine in f_ext, and both are in pi."""
    zero = torch.zeros_like(qd)
    u = _tangent_space(ops._model, q, t_q, convention)
    dA, dB, _ = _gradient_tangents(ops, q, qd, qdd, f_ext, params, convention, u, zero if t_qd is None else t_qd,
                                   zero if t_qdd is None else t_qdd)
    if t_f is not None:
        dA = dA + _affine(lambda f: ops.inverse_dynamics_derivatives(q, qd, qdd, f, params, convention), t_f, None)[0]
    if t_params is not None:
        dA_p, dB_p = _affine(lambda p: ops.inverse_dynamics_derivatives(q, qd, qdd, f_ext, p, convention), t_params,
                             torch.zeros_like(t_params))
        dA, dB = dA + dA_p, dB + dB_p
    return dA, dB


def _forward_dynamics_derivatives_jvp(ops, out, q, qd, tau, f_ext, params, convention, t_q, t_qd, t_tau, t_f, t_params, _):
    """(Z_q, Z_qd, M^-1) = (-M^-1 dtau/dq, -M^-1 dtau/dqd, M^-1) at qdd = FD: with dqdd the tangent of
    qdd and (dA, dB, dM) those of dtau/dq, dtau/dqd, M along (q, qd, dqdd, pi), dZ = -M^-1 (dA + dM Z) and
    d(M^-1) = -M^-1 dM M^-1."""
    z_q, z_qd, minv = out
    zero = torch.zeros_like(qd)
    u = _tangent_space(ops._model, q, t_q, convention)
    mv = lambda m, x: (m @ x.unsqueeze(-1)).squeeze(-1)  # noqa: E731
    dqdd = mv(z_q, u) + (zero if t_qd is None else mv(z_qd, t_qd)) + (zero if t_tau is None else mv(minv, t_tau))
    if t_f is not None:
        dqdd = dqdd + _affine(lambda f: ops.forward_dynamics(q, qd, tau, f, params, convention), t_f, None)
    qdd = ops.forward_dynamics(q, qd, tau, f_ext, params, convention)
    if t_params is not None:  # d qdd / d pi t = -M^-1 Y t
        dqdd = dqdd - mv(minv, (ops.inverse_dynamics_regressor(q, qd, qdd, convention) @ t_params.flatten(-2).unsqueeze(-1)
                                ).squeeze(-1))
    dA, dB, dM = _gradient_tangents(ops, q, qd, qdd, f_ext, params, convention, u, zero if t_qd is None else t_qd, dqdd)
    if t_f is not None:
        dA = dA + _affine(lambda f: ops.inverse_dynamics_derivatives(q, qd, qdd, f, params, convention), t_f, None)[0]
    if t_params is not None:  # at fixed qdd, dtau/dq, dtau/dqd and M are affine in pi
        zero_p = torch.zeros_like(t_params)
        dA_p, dB_p = _affine(lambda p: ops.inverse_dynamics_derivatives(q, qd, qdd, f_ext, p, convention), t_params, zero_p)
        dA, dB = dA + dA_p, dB + dB_p
        dM = dM + _affine(lambda p: ops.crba(q, p, convention), t_params, zero_p)
    return -minv @ (dA + dM @ z_q), -minv @ (dB + dM @ z_qd), -minv @ dM @ minv


def _linear_jvp(name: str) -> Callable:
    """The tangent of an op of (q, x) linear in x: its dual-number kernel `<name>_jvp` along q, plus the op
    of x's tangent."""

    def rule(ops, _out, q, x, convention, t_q, t_x, _):
        terms = ([] if t_q is None else [getattr(ops, f"{name}_jvp")(q, x, t_q, convention)]) + \
            ([] if t_x is None else [getattr(ops, name)(q, t_x, convention)])
        return sum(terms[1:], terms[0])

    return rule


def _kernel_jvp(name: str) -> Callable:
    """The tangent of an op by its dual-number kernel `<name>_jvp`, along its tensor inputs (every one of them,
    table.check_table), which come first."""
    spec = OPS[f"{name}_jvp"]
    wrt = len(spec.jvp_wrt)

    def rule(ops, _out, *args):
        n = len(args) // 2  # the inputs (the last the convention), then a tangent for each
        tangent = getattr(ops, f"{name}_jvp")(*args[:n - 1], *args[n:n + wrt], args[n - 1])
        return tangent[..., 1].contiguous() if spec.jvp_in_place else tangent  # (value, tangent) pairs

    return rule


# The forward-mode rules of the ops whose entry declares one (jvp "rule"), and the dual-number kernels'
# (jvp "dual").
_JVPS = {"inverse_dynamics_vjp": _inverse_dynamics_vjp_jvp, "inertia_solve": _inertia_solve_jvp, "crba_vjp": _crba_vjp_jvp,
         "mass_product_vjp": _mass_product_vjp_jvp,
         "inverse_dynamics_derivatives": _inverse_dynamics_derivatives_jvp,
         "forward_dynamics_derivatives": _forward_dynamics_derivatives_jvp,
         "frame_jacobian": _frame_jacobian_jvp, "frames_vjp": _linear_jvp("frames_vjp"),
         "body_velocities": _linear_jvp("body_velocities"),
         **{name: _kernel_jvp(name) for name in KERNEL_JVP}}
_DECLARED = {op.name for op in OPS.values() if op.jvp in ("rule", "dual")}
if set(_JVPS) != _DECLARED:
    raise ValueError(f"func: forward-mode rules for {sorted(set(_JVPS) - _DECLARED)} whose table entries declare none, "
                     f"none for {sorted(_DECLARED - set(_JVPS))} whose entries declare one")

# The ops with a forward-mode derivative (jvp other than "none"; the others refuse forward mode by name).
FORWARD_MODE = tuple(op.name for op in OPS.values() if op.jvp != "none")
