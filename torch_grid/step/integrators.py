"""The plant step: x = (q, qd) advanced by dt under a torque held over the step, and its Jacobians.

Integrators, with a = forward_dynamics(q, qd, tau, f_ext) and (+) the configuration space's integrate:
  euler                qd' = qd + dt a(q, qd),   q' = q (+) dt qd
  semi_implicit_euler  qd' = qd + dt a(q, qd),   q' = q (+) dt qd'        (MuJoCo's mjINT_EULER; with the
                       joints' damping D included and the model's eulerdamp on, as MuJoCo's default,
                       (M + dt D) a = tau + passive - bias: the damping implicit, as mj_Euler)
  midpoint, rk3, rk4   explicit Runge-Kutta in Munthe-Kaas's form, as MuJoCo 4's mj_RungeKutta
                       (mjINT_RK4): stage i sits at q_i = q (+) theta_i, theta_i = dt sum_j A_ij w_j,
                       qd_i = qd + dt sum_j A_ij a_j, where w_j = dexp(theta_j)^-1 qd_j is stage j's
                       velocity carried to the chart at q (space/lie.py's dexp_inverse: the identity but
                       at quaternion joints, whose turn MuJoCo's convention takes the short way round,
                       as MuJoCo does); the step is q' = q (+) dt sum_j B_j w_j,
                       qd' = qd + dt sum_j B_j a_j (euler is the one-stage case).
The Jacobians are along the tangent spaces (the state deviation [dq; dqd], as Crocoddyl's Fx, Fu and
MuJoCo's mjd_transitionFD A, B), by the chain rule through the stages: forward_dynamics_derivatives at
each stage (passive.py's damped_acceleration_derivatives for the implicit damping), the configuration
space's d_integrate and the derivatives of dexp^-1. Everything is torch
over the robot's ops, so autograd differentiates step itself to second order; (q', qd', A, B) also come
from one kernel per call (csrc/kernels/step/step.h for the Euler schemes, csrc/kernels/step/runge_kutta.h for
Runge-Kutta), which runs when nothing differentiates them.
"""
from __future__ import annotations

import torch
from torch.autograd import forward_ad

from ..ops.arguments import check_dt, check_tensor
from ..ops.levels import dual, kernels_kept_off, transforming
from ..space.constants import scalar_or_tensor
from ..space.lie import d_dexp_inverse_blocks, d_integrate_blocks, dexp_inverse, dt_column, tangent_map
from .compiled import compiled_step, opaque
from .euler_hessian import euler_step_hessian
from .passive import damped_acceleration, damped_acceleration_derivatives
from .rk_hessian import combine as _combine
from .rk_hessian import rk_step_hessian

# (A rows below the diagonal, B) of each Runge-Kutta scheme
TABLEAUS = {
    "euler": ((), (1.0,)),
    "midpoint": (((0.5,),), (0.0, 1.0)),
    "rk3": (((0.5,), (-1.0, 2.0)), (1 / 6, 2 / 3, 1 / 6)),
    "rk4": (((0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)), (1 / 6, 1 / 3, 1 / 3, 1 / 6)),
}
INTEGRATORS = ("euler", "semi_implicit_euler", "midpoint", "rk3", "rk4")
# The schemes the kernels fuse with the forward-dynamics derivatives: step_derivatives (csrc/kernels/step/step.h)
# and rk_step_derivatives (csrc/kernels/step/runge_kutta.h); the step op takes every scheme's code
FUSED = {"euler": 0, "semi_implicit_euler": 1}
RK_FUSED = {"midpoint": 2, "rk3": 3, "rk4": 4}
SCHEMES = {**FUSED, **RK_FUSED}


class StepFunctions:
    """The plant step of a robot's views (mixed into robot._Functions with ConfigurationFunctions)."""

    def step(self, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, dt, integrator: str = "semi_implicit_euler",
             f_ext: torch.Tensor | None = None, params: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(q', qd') `(..., nq)`, `(..., nv)`: one step of dt (a number or a (...,) tensor) with tau (and
        f_ext) held over it; integrator one of INTEGRATORS. The joints' passive forces, when included, act
        at every stage; semi_implicit_euler takes their damping implicitly where the model's eulerdamp is
        on (MuJoCo's Euler step, `load(..., eulerdamp=...)`). params: the inertial parameters, as in
        inverse_dynamics."""
        if params is not None:
            return self._with(params, "step").step(q, qd, tau, dt, integrator, f_ext)
        _check(self, "step", integrator, q, qd, tau, dt, f_ext)
        # one op, not the composition's nodes (the op computes with the robot's own inertial parameters)
        if torch.compiler.is_compiling() and opaque() and self._params is None:
            return compiled_step(self, q, qd, tau, dt, integrator, f_ext)
        if torch.compiler.is_compiling() and forward_ad._current_level >= 0:
            return _step_eagerly(self, q, qd, tau, dt, integrator, f_ext)
        h = dt_column(dt, qd)
        if fused_kernel_runs(self, q, qd, tau, dt, f_ext):
            # one kernel call: each stage's forward dynamics and the updates of q and qd (a few hundred small torch
            # ops a stage at a floating base, whose dispatch outweighs a small batch's dynamics)
            return self._kernel_call("step", q, qd, tau, f_ext, h, self._params, SCHEMES[integrator],
                                     _passive_code(self._robot, integrator))
        if integrator == "semi_implicit_euler":
            damped = self._robot._implicit_damping
            qd_next = qd + h * (damped_acceleration(self, q, qd, tau, h, f_ext) if damped
                                else self.forward_dynamics(q, qd, tau, f_ext))
            return self.integrate(q, qd_next, dt), qd_next
        rows, weights = TABLEAUS[integrator]
        space, convention = self._robot._space, self._convention
        carried, acc = [qd], [self.forward_dynamics(q, qd, tau, f_ext)]
        for row in rows:
            theta = _combine(row, carried)
            v = qd + h * _combine(row, acc)
            acc.append(self.forward_dynamics(self.integrate(q, theta, dt), v, tau, f_ext))
            carried.append(dexp_inverse(space, h * theta, v, convention))
        qd_next = qd + h * _combine(weights, acc)
        return _on_batch(self.integrate(q, _combine(weights, carried), dt), qd_next), qd_next

    def step_derivatives(self, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, dt,
                         integrator: str = "semi_implicit_euler",
                         f_ext: torch.Tensor | None = None,
                         params: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(A `(..., 2 nv, 2 nv)`, B `(..., 2 nv, nv)`): the derivatives of step's [q'; qd'] with respect to
        [q; qd] and tau, along the tangent spaces (q' compared by difference, q moved by integrate); params
        as in step."""
        view = self if params is None else self._with(params, "step_derivatives")
        return view._step_and_derivatives(q, qd, tau, dt, integrator, f_ext)[2:]

    def _step_and_derivatives(self, q, qd, tau, dt, integrator, f_ext, op="step_derivatives"):
        """(q', qd', A, B): step and step_derivatives from one pass over the stages; in one kernel call
        when nothing asks for their derivatives (the kernels have no backward)."""
        _check(self, op, integrator, q, qd, tau, dt, f_ext)
        params = self._params  # a view's of with_parameters
        if fused_kernel_runs(self, q, qd, tau, dt, f_ext):
            h = dt_column(dt, qd)
            passive = _passive_code(self._robot, integrator)
            if integrator in FUSED:
                q_next, qd_next, A, B = self._kernel_call("step_derivatives", q, qd, tau, f_ext, h, params,
                                                          FUSED[integrator], passive)
            else:  # the stages' derivatives in a workspace: one per CPU thread, one per sample on CUDA
                q_next, qd_next, A, B, _ = self._kernel_call("rk_step_derivatives", q, qd, tau, f_ext, h, params,
                                                             RK_FUSED[integrator], passive)
            return q_next, qd_next, A.flatten(-4, -3).flatten(-2), B.flatten(-3, -2)
        return _in_chunks(op, lambda *args: self._step_derivatives(*args, integrator), q, qd, tau, dt, f_ext, params)

    def _step_derivatives(self, q, qd, tau, dt, f_ext, params, integrator):
        if params is not self._params:  # a piece of the view's parameters (_in_chunks)
            return self._with(params, "step_derivatives")._step_derivatives(q, qd, tau, dt, f_ext, params, integrator)
        h = dt_column(dt, qd)
        hh, nv = h.unsqueeze(-1), qd.shape[-1]
        space, convention = self._robot._space, self._convention
        # A derivative along z = [dq; dqd; dtau] is an (..., nv, 3 nv) matrix; the integrate and dexp^-1
        # maps are the identity but on their quaternion joints' rows, which are replaced (_with_rows).
        eye = torch.eye(nv, dtype=qd.dtype, device=qd.device)
        zero = torch.zeros_like(eye)
        start_q, start_v = torch.cat([eye, zero, zero], dim=-1), torch.cat([zero, eye, zero], dim=-1)

        def stage(qi, vi, dq, dv):
            """a at a stage and its derivative, from the stage's own (dq, dqd); None: the start."""
            if integrator == "semi_implicit_euler" and self._robot._implicit_damping:
                a, da_dq, da_dv, da_dtau = damped_acceleration_derivatives(self, qi, vi, tau, h, f_ext)
            else:
                a = self.forward_dynamics(qi, vi, tau, f_ext)
                da_dq, da_dv, da_dtau = self.forward_dynamics_derivatives(qi, vi, tau, f_ext)
            if dq is None:
                return a, torch.cat([da_dq, da_dv, da_dtau], dim=-1)
            da = da_dq @ dq + da_dv @ dv
            da[..., 2 * nv:] += da_dtau
            return a, da

        def advance(theta, dtheta):
            """The derivative of q (+) dt theta: J_q along dq, plus J_v dtheta."""
            step = hh * dtheta
            rows = {vi: j_v @ step[..., vi:vi + j_q.shape[-1], :]
                    + torch.nn.functional.pad(j_q, (vi, 3 * nv - vi - j_q.shape[-1]))
                    for vi, j_q, j_v in d_integrate_blocks(space, theta, dt, convention)}
            return _with_rows(step + start_q, rows)

        a0, da0 = stage(q, qd, None, None)
        if integrator == "semi_implicit_euler":
            qd_next, dv_next = qd + h * a0, hh * da0 + start_v
            return (self.integrate(q, qd_next, dt), qd_next) + _split(advance(qd_next, dv_next), dv_next, nv)
        rows, weights = TABLEAUS[integrator]
        carried, dcarried, acc, dacc = [qd], [start_v], [a0], [da0]
        for row in rows:
            theta, dtheta = _combine(row, carried), _combine(row, dcarried)
            v, dv = qd + h * _combine(row, acc), hh * _combine(row, dacc) + start_v
            a, da = stage(self.integrate(q, theta, dt), v, advance(theta, dtheta), dv)
            acc.append(a)
            dacc.append(da)
            # stage velocity carried to q's chart: dexp(h theta)^-1 v, with its derivative
            outer = not transforming() and dual((theta, v))  # a forward-mode level around the call
            blocks = d_dexp_inverse_blocks(space, h * theta, v, convention, outer)
            carried.append(tangent_map(blocks, 1, v.unsqueeze(-1)).squeeze(-1))
            dcarried.append(_with_rows(dv, {vi: j_v @ dv[..., vi:vi + j_v.shape[-1], :]
                                            + j_theta @ (hh * dtheta[..., vi:vi + j_v.shape[-1], :])
                                            for vi, j_theta, j_v in blocks}))
        theta = _combine(weights, carried)
        dq_next = advance(theta, _combine(weights, dcarried))
        qd_next = qd + h * _combine(weights, acc)
        return ((_on_batch(self.integrate(q, theta, dt), qd_next), qd_next)
                + _split(dq_next, hh * _combine(weights, dacc) + start_v, nv))

    def step_second_derivatives(self, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, dt,
                                integrator: str = "semi_implicit_euler",
                                f_ext: torch.Tensor | None = None, params: torch.Tensor | None = None) -> torch.Tensor:
        """(..., 2 nv, 3 nv, 3 nv): the Hessian at z = 0 of z -> [difference(q', q'(z)); qd'(z) - qd'] with
        (q'(z), qd'(z)) = step(q (+) z_q, qd + z_qd, tau + z_tau), symmetric in its last two indices. The
        Euler schemes: in closed form from forward_dynamics_second_derivatives (euler_hessian.py); the Runge-Kutta
        schemes: the second-order chain rule through the stages, from each stage's forward-dynamics gradient
        and second derivatives and the configuration space's closed forms (rk_hessian.py). params as in step."""
        if params is not None:
            return self._with(params, "step_second_derivatives").step_second_derivatives(q, qd, tau, dt, integrator, f_ext)
        _check(self, "step_second_derivatives", integrator, q, qd, tau, dt, f_ext)
        if _differentiated(q, qd, tau, dt, f_ext, self._params):
            if transforming():
                raise NotImplementedError("step_second_derivatives does not run under torch.func transforms (vmap, "
                                          "grad, jacrev, ...): it takes any leading batch shape; call it on the batch")
            raise NotImplementedError("step_second_derivatives has no derivative (a third derivative of the step): "
                                      "call it on detached inputs or under torch.no_grad()")
        if integrator in FUSED:
            return euler_step_hessian(self, q, qd, tau, dt, f_ext, semi=bool(FUSED[integrator]))
        nv = qd.shape[-1]
        batch, (q, qd, tau, h, f_ext, params) = _flattened("step_second_derivatives", q, qd, tau, dt, f_ext, self._params)
        view = self if params is None else self._with(params, "step_second_derivatives")
        return rk_step_hessian(view, TABLEAUS[integrator], q, qd, tau, h, f_ext).reshape(*batch, 2 * nv, 3 * nv, 3 * nv)


# Samples per piece of a large batch: the chain rule's (nv, nv) temporaries of a piece stay in cache
# (G1 at B = 4096: 6.7x forward_dynamics_derivatives whole, 2.3x in pieces).
CHUNK = 256


def _flattened(op: str, q, qd, tau, dt, f_ext, params=None) -> tuple[torch.Size, list]:
    """(the broadcast batch shape, [q, qd, tau, dt, f_ext, params] with that batch flattened to one
    dimension); dt becomes a (n,) tensor, an absent f_ext or params stays None. The inertial parameters'
    batch is part of the samples' (one set per sample, or shared)."""
    dt = scalar_or_tensor(dt, qd.dtype, qd.device)
    batch = _broadcast(op, q, qd, tau, dt, f_ext, params)
    n = batch.numel()
    return batch, [None if x is None else x.expand(batch + x.shape[x.dim() - k:]).reshape(n, *x.shape[x.dim() - k:])
                   for x, k in ((q, 1), (qd, 1), (tau, 1), (dt, 0), (f_ext, 2), (params, 2))]


def _broadcast(op: str, q, qd, tau, dt, f_ext, params) -> torch.Size:
    """The batch shape of a step's arguments (dt a number or a tensor), refused naming op and every shape where
    they do not broadcast."""
    shapes = [q.shape[:-1], qd.shape[:-1], tau.shape[:-1], dt.shape if isinstance(dt, torch.Tensor) else ()]
    shapes += [x.shape[:-2] for x in (f_ext, params) if x is not None]
    try:
        return torch.broadcast_shapes(*shapes)
    except RuntimeError:
        names = ["q", "qd", "tau", "dt"] + [n for n, x in (("f_ext", f_ext), ("params", params)) if x is not None]
        raise ValueError(f"{op}: the batch shapes do not broadcast: "
                         + ", ".join(f"{n} {tuple(b)}" for n, b in zip(names, shapes))) from None


def _in_chunks(op: str, fn, q, qd, tau, dt, f_ext, params):
    """fn(q, qd, tau, dt, f_ext, params) -> a tuple of tensors, over a flattened batch in pieces of CHUNK
    samples (params None, or the inertial parameters of each piece's samples)."""
    batch, flat = _flattened(op, q, qd, tau, dt, f_ext, params)
    n = batch.numel()
    if n <= CHUNK:
        return fn(q, qd, tau, dt, f_ext, params)
    pieces = [fn(*(None if x is None else x[s:s + CHUNK] for x in flat)) for s in range(0, n, CHUNK)]
    return tuple(torch.cat(parts).reshape(*batch, *parts[0].shape[1:]) for parts in zip(*pieces))


def _passive_code(robot, integrator: str) -> int:
    """The step kernels' `passive` argument: 0 the passive forces left out, 1 explicit, 2 the damping implicit
    in the semi-implicit Euler step (MuJoCo's mj_Euler)."""
    if not robot._with_passive:
        return 0
    return 2 if integrator == "semi_implicit_euler" and robot._implicit_damping else 1


def fused_kernel_runs(view, q, *args) -> bool:
    """Whether a kernel that fuses a composition (the step, its derivatives, integrate, difference) computes
    this call: nothing differentiates it, no joint mimics another, and the kernels are not kept off its
    device (_fused_kept_off)."""
    return (view._robot._coupling is None and not _differentiated(q, *args, view._params)
            and not _fused_kept_off(view, q))


def differentiable_kernel_runs(view, q, *args) -> bool:
    """Whether the integrate or difference kernel computes this call, its backward one kernel too
    (ops/lie_backward.py: integrate_vjp, difference_vjp): as fused_kernel_runs, and also when autograd's reverse mode records the
    call of a robot with quaternion joints (without them the composition is a few elementwise ops, its
    backward too); not under the torch.func transforms or forward-mode AD, nor where torch.compile traces a
    gradient, which all see the composition."""
    if view._robot._coupling is not None or _fused_kept_off(view, q):
        return False
    if not _differentiated(q, *args):
        return True
    tensors = [x for x in (q, *args) if isinstance(x, torch.Tensor)]
    return (view._robot._space.nq != view._robot._space.nv and not torch.compiler.is_compiling()
            and not (transforming() or dual(tensors)))


def _fused_kept_off(view, q) -> bool:
    """Whether the step kernels (values and derivatives) are kept off this call of a view (levels.kernels_kept_off)."""
    return kernels_kept_off(view._robot.model, view._convention, q)


def _differentiated(*args) -> bool:
    """Whether autograd records through the arguments, or a torch.func transform or forward-mode AD sees them."""
    tensors = [x for x in args if isinstance(x, torch.Tensor)]
    if torch.is_grad_enabled() and any(x.requires_grad for x in tensors):
        return True
    return not torch.compiler.is_compiling() and (transforming() or dual(tensors))


def _check(view, op: str, integrator, q, qd, tau, dt, f_ext) -> None:
    """The integrator's name, q, qd, tau, f_ext and the view's params, dt, and their batch shapes (before a
    composition's first op, or the kernel of a Runge-Kutta scheme's derivatives, could name itself)."""
    if integrator not in INTEGRATORS:
        raise ValueError(f"{op}: integrator must be one of {INTEGRATORS}, got {integrator!r}")
    for name, x, n in (("q", q, view.nq), ("qd", qd, view.nv), ("tau", tau, view.nv)):
        check_tensor(op, name, x, (n,), q)
    params = view._params
    for name, x, n in (("f_ext", f_ext, 6), ("params", params, 10)):
        if x is not None:
            check_tensor(op, name, x, (view.model.nbodies, n), q)
    batched = [x.shape[:x.dim() - k] for x, k in ((q, 1), (qd, 1), (tau, 1), (f_ext, 2), (params, 2))
               if x is not None and x.dim() > k]
    if any(shape != batched[0] for shape in batched[1:]):  # broadcast (10 µs) only where two batched shapes differ
        _broadcast(op, q, qd, tau, dt, f_ext, params)
    check_dt(op, dt, q, qd, tau)


def _with_rows(x: torch.Tensor, rows: dict) -> torch.Tensor:
    """x (..., m, k) with its rows vi.. replaced by rows[vi] (..., n, k), out of place (so that vmap batches it
    whichever of them are batched), broadcast to their common batch shape."""
    if not rows:
        return x
    batch = torch.broadcast_shapes(x.shape[:-2], *(r.shape[:-2] for r in rows.values()))
    parts, start = [], 0
    for vi in sorted(rows):
        parts += [x[..., start:vi, :], rows[vi]]
        start = vi + rows[vi].shape[-2]
    parts.append(x[..., start:, :])
    return torch.cat([p.expand(*batch, *p.shape[-2:]) for p in parts], dim=-2)


def _on_batch(q_next: torch.Tensor, qd_next: torch.Tensor) -> torch.Tensor:
    """q' expanded to qd''s batch shape, the step's: explicit Euler's q' reads q and qd alone, so without it a
    larger batch of tau, f_ext or params would leave q' on q's and qd's, unlike the fused kernel's."""
    return q_next.expand(*qd_next.shape[:-1], q_next.shape[-1])


def _split(dq: torch.Tensor, dv: torch.Tensor, nv: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(A, B) from the rows d(q')/dz, d(qd')/dz, z = [dq; dqd; dtau], broadcast to their common batch shape
    (explicit Euler's d(q')/dz, without a quaternion joint, is the same for every sample: unbatched)."""
    batch = torch.broadcast_shapes(dq.shape[:-2], dv.shape[:-2])
    rows = torch.cat([dq.expand(*batch, *dq.shape[-2:]), dv.expand(*batch, *dv.shape[-2:])], dim=-2)
    return rows[..., :2 * nv], rows[..., 2 * nv:]


@torch._disable_dynamo  # torch.compiler.disable, made at the first call (dispatch._func_call_eagerly)
def _step_eagerly(view, q, qd, tau, dt, integrator: str, f_ext):
    """The step under an open forward-mode dual level while torch.compile traces: eagerly, as a whole
    (a compiled graph drops the tangents of dual tensors it receives, so none may reach one)."""
    return view.step(q, qd, tau, dt, integrator, f_ext)
