"""The plant step as one op while torch.compile traces it.

Eagerly, `step` is the torch composition of the robot's ops (integrators.py), which autograd,
torch.func and forward-mode AD see through. Traced by torch.compile, that composition is a couple of
hundred graph nodes per step (the quaternion joints' integrate, the passive forces, the stages), and a
rollout of many steps takes minutes to compile. There the step is instead one custom op per robot,
opaque to the compiler: its value is the step's kernel path and its backward a second op, the
vector-Jacobian product of the same composition (autograd run inside it, eagerly: the ops' own backward
kernels, O(n) per sample). Both ops have a vmap rule (one broadcast call). torch.compile differentiates
a graph once; for a double backward (a Hessian-vector product) step is called eagerly. A custom op has
no forward-mode rule and no torch.func.grad rule, so inside torch.func.grad, jvp or jacfwd, or on
forward-mode dual tensors, a traced step is the composition again (`opaque`).

The ops are defined once per robot configuration (kernels, passive forces, eulerdamp), in the
namespace "torch_grid_step".
"""
from __future__ import annotations

import torch

from ..ops.levels import traced_transform

NAMESPACE = "torch_grid_step"
_ROBOTS: dict[str, object] = {}
# The trailing (per-sample) dimensions of the ops' tensor arguments, in order: q, qd, tau, dt, f_ext, and the
# vector-Jacobian product's cotangents of q' and qd'.
_TRAILING = (1, 1, 1, 0, 2, 1, 1)


def opaque() -> bool:
    """Whether a step traced by torch.compile can be the step op: no torch.func transform is active but
    vmap (the op's rule then asks again one level down) and no forward-mode dual level is open (the op has
    rules for backward and vmap only)."""
    return not traced_transform()


def compiled_step(view, q, qd, tau, dt, integrator: str, f_ext):
    """(q', qd') of view.step through the robot's step op (for torch.compile's traces)."""
    robot = view._robot
    op = step_op(robot)
    dt = dt if isinstance(dt, torch.Tensor) else torch.full((), float(dt), dtype=q.dtype, device=q.device)
    return op(q, qd, tau, dt, f_ext, integrator, view._convention)


def _key(robot) -> str:
    """What the step depends on beyond the kernels: the passive forces, eulerdamp, a mimic coupling (which the
    kernels' model leaves out: the whole model's hash tells two couplings of one tree apart)."""
    options = (robot._with_passive, robot._implicit_damping, robot._coupling is not None)
    coupling = "" if robot._coupling is None else "_" + robot.model.hash[:16]
    return robot._ops.name + "_" + "".join(str(int(x)) for x in options) + coupling


def _view(key: str, convention: int):
    robot = _ROBOTS[key]
    return robot.mujoco if convention else robot.pin


def step_op(robot):
    """The robot's step op, defined on first use (Robot.__init__, so that no trace defines it)."""
    key = _key(robot)
    if key in _ROBOTS:
        return getattr(getattr(torch.ops, NAMESPACE), f"step_{key}")
    _ROBOTS[key] = robot
    nq, nv = robot.nq, robot.nv

    @torch.library.custom_op(f"{NAMESPACE}::step_{key}", mutates_args=())
    def step(q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, dt: torch.Tensor, f_ext: torch.Tensor | None,
             integrator: str, convention: int) -> tuple[torch.Tensor, torch.Tensor]:
        with torch.no_grad():
            q_next, qd_next = _view(key, convention).step(q, qd, tau, dt, integrator, f_ext)
        return q_next.contiguous(), qd_next.contiguous()

    @step.register_fake
    def _(q, qd, tau, dt, f_ext, integrator, convention):
        batch = _batch(q, qd, tau, dt, f_ext)
        return q.new_empty(*batch, nq), q.new_empty(*batch, nv)

    @torch.library.custom_op(f"{NAMESPACE}::step_vjp_{key}", mutates_args=())
    def step_vjp(q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, dt: torch.Tensor, f_ext: torch.Tensor | None,
                 grad_q: torch.Tensor, grad_qd: torch.Tensor, integrator: str,
                 convention: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        leaves = _leaves(q, qd, tau, dt, f_ext)
        with _autograd_inside(), torch.enable_grad():
            out = _view(key, convention).step(*leaves[:4], integrator, leaves[4])
            grads = _grad(out, leaves, (grad_q, grad_qd))
        return tuple(grads)

    @step_vjp.register_fake
    def _(q, qd, tau, dt, f_ext, grad_q, grad_qd, integrator, convention):
        return tuple(torch.empty_like(x) for x in _present(q, qd, tau, dt, f_ext))

    def setup_context(ctx, inputs, output):
        q, qd, tau, dt, f_ext, integrator, convention = inputs
        ctx.save_for_backward(q, qd, tau, dt, f_ext)
        ctx.integrator, ctx.convention = integrator, convention

    def backward(ctx, grad_q, grad_qd):
        q, qd, tau, dt, f_ext = ctx.saved_tensors
        g = step_vjp(q, qd, tau, dt, f_ext, grad_q, grad_qd, ctx.integrator, ctx.convention)
        return g[0], g[1], g[2], g[3], None if f_ext is None else g[4], None, None

    def no_double_backward(ctx, *grads):
        raise NotImplementedError("torch_grid: a step traced by torch.compile has one backward (torch.compile "
                                  "does not differentiate twice); for a double backward call step eagerly")

    step.register_autograd(backward, setup_context=setup_context)
    step_vjp.register_autograd(no_double_backward, setup_context=lambda ctx, inputs, output: None)

    @step.register_vmap
    def _(info, in_dims, q, qd, tau, dt, f_ext, integrator, convention):
        q, qd, tau, dt, f_ext = _vmapped(info.batch_size, in_dims, (q, qd, tau, dt, f_ext))
        if opaque():
            return step(q, qd, tau, dt, f_ext, integrator, convention), (0, 0)
        return _view(key, convention).step(q, qd, tau, dt, integrator, f_ext), (0, 0)  # under a transform below

    @step_vjp.register_vmap
    def _(info, in_dims, q, qd, tau, dt, f_ext, grad_q, grad_qd, integrator, convention):
        inputs = (q, qd, tau, dt, f_ext, grad_q, grad_qd)
        grads = step_vjp(*_vmapped(info.batch_size, in_dims, inputs), integrator, convention)
        # each input's gradient with its own per-sample shape, behind the vmapped dimension
        shapes = [x.shape if d is None else x.shape[:d] + x.shape[d + 1:] for x, d in zip(_present(*inputs[:5]), in_dims)]
        return tuple(g.reshape(info.batch_size, *shape) for g, shape in zip(grads, shapes)), (0,) * 5

    return step


def _present(q, qd, tau, dt, f_ext) -> list[torch.Tensor]:
    """The step's tensor inputs, an absent f_ext as an empty tensor (an op's output cannot be None)."""
    return [q, qd, tau, dt, q.new_empty(0) if f_ext is None else f_ext]


def _leaves(q, qd, tau, dt, f_ext) -> list:
    """Detached copies of the inputs that record autograd (f_ext None stays None)."""
    return [x.detach().requires_grad_() for x in (q, qd, tau, dt)] + [
        None if f_ext is None else f_ext.detach().requires_grad_()]


def _grad(outputs, leaves: list, cotangents) -> list[torch.Tensor]:
    """autograd.grad over the leaves that are tensors: zeros where nothing flows, an empty tensor for an
    absent f_ext."""
    present = [x for x in leaves if x is not None]
    grads = iter(torch.autograd.grad(outputs, present, cotangents, allow_unused=True))
    out = []
    for x in leaves:
        if x is None:
            out.append(leaves[0].new_empty(0))
            continue
        g = next(grads)
        out.append(torch.zeros_like(x) if g is None else g.contiguous())
    return out


def _vmapped(size: int, in_dims, args) -> list:
    """vmap's arguments for one broadcast call: the vmapped dimension of every tensor first (expanded
    where an argument is not vmapped, so that each vmapped sample has its own gradient), then singleton
    dimensions that align the arguments' own batch dimensions to the right, as torch broadcasts."""
    ranks = [x.dim() - (d is not None) - t for x, d, t in zip(args, in_dims, _TRAILING) if x is not None]
    rank = max(ranks)
    out = []
    for x, d, t in zip(args, in_dims, _TRAILING):
        if x is None:
            out.append(x)
            continue
        x = x.unsqueeze(0).expand(size, *x.shape) if d is None else x.movedim(d, 0)
        out.append(x.reshape(size, *[1] * (rank - (x.dim() - 1 - t)), *x.shape[1:]))
    return out


def _batch(q, qd, tau, dt, f_ext) -> torch.Size:
    return torch.broadcast_shapes(q.shape[:-1], qd.shape[:-1], tau.shape[:-1], dt.shape,
                                  () if f_ext is None else f_ext.shape[:-2])


def _autograd_inside():
    """Autograd recording inside an op's kernel, where the dispatcher has turned it off (a custom op's
    kernel runs below the autograd keys): the vector-Jacobian product is autograd of the composition."""
    from contextlib import ExitStack

    stack = ExitStack()
    for key in (torch._C.DispatchKey.AutogradFunctionality, torch._C.DispatchKey.AutogradOther):
        stack.enter_context(torch._C._SetExcludeDispatchKeyGuard(key, False))
    return stack
