"""A robot function's op call, down to its kernel: `dispatch(view, "crba", q, params)`.

`view` is a Robot or one of its RobotViews: it carries `_convention` (0 pin, 1 mujoco), `_params` (the
inertial parameters bound by with_parameters, or None) and `_robot`, whose `_ops` are the robot's
registered torch ops, `_func` the same under torch.func transforms (func.FuncOps), `_eager` in eager
reverse mode (eager.EagerOps), `_tensor_args`
each op's tensor arguments for the checks, and `_coupling` its mimic coupling (mimic.Coupling) or None.
The arguments are the op's, in its table order (table.py), the convention left out.
"""
from __future__ import annotations

import torch

from .arguments import checked, forward_mode
from .eager import kernel_keyset
from .func import FORWARD_MODE, FuncOps
from .levels import miscompiled_vjp, traced_transform
from .table import INERTIA_FREE, OPS

# The ops a view of with_parameters runs: those that take the inertial parameters, and those free of them.
_WITH_PARAMETERS = frozenset(name for name, spec in OPS.items()
                             if any(a.kind == "parameters" for a in spec.args)
                             or (spec.forward_mode_of or spec.jvp_of or name) in INERTIA_FREE)


def dispatch(view, name: str, *args):
    """Op `name` in the view's convention, in the robot's own coordinates (reduced, for mimic joints)."""
    coupling = view._robot._coupling
    if coupling is None:
        return kernel_call(view, name, *args)
    return coupling.call(lambda op, *full: kernel_call(view, op, *full), name,
                         checked(name, coupling.tensor_args[name], args))


def kernel_call(view, name: str, *args):
    """Op `name` of the kernels (every joint independent), in the view's convention."""
    robot = view._robot
    op = getattr(robot._ops, name)
    convention = view._convention
    if view._params is not None and name not in _WITH_PARAMETERS:
        # the kernel would compute with the robot's own parameters
        raise NotImplementedError(f"torch_grid: {name} does not take inertial parameters, so a view of with_parameters "
                                  "cannot compute it")
    if torch.compiler.is_compiling():
        if traced_transform():
            return _func_call_eagerly(robot._func, name, *checked(name, robot._tensor_args[name], args), convention)
        return op(*checked(name, robot._tensor_args[name], args), convention)
    stack = torch._C._functorch.get_interpreter_stack()
    forward = forward_mode(args, stack)
    if forward and name not in FORWARD_MODE:
        # without this check forward mode would return zero tangents
        raise NotImplementedError(f"torch_grid: {name} has no forward-mode derivative (torch.func.jvp, jacfwd, "
                                  "hessian, torch.autograd.forward_ad); use reverse mode (backward, torch.func.jacrev)")
    if stack and miscompiled_vjp(stack):
        raise NotImplementedError(
            f"torch_grid: {name} under torch.func.vjp or jacrev inside torch.compile: torch {torch.__version__} compiles "
            "that vjp's backward wrongly (zero gradients) where the function breaks the graph, as torch_grid's functions "
            "do under a transform; torch 2.12 computes it right. Upgrade torch, or call vjp or jacrev outside "
            "torch.compile (torch.func.grad and backward() compile right)")
    if stack or forward:  # each op through an autograd.Function that torch.func and forward AD transform
        return robot._func.call(name, *checked(name, robot._tensor_args[name], args), convention)
    if torch.is_grad_enabled() and torch._C._any_requires_grad(*args):
        # reverse mode: the op's Function without torch.library's Python wrapper around it (eager.py)
        return robot._eager.call(name, *checked(name, robot._tensor_args[name], args), convention)
    # Nothing to differentiate: go straight to the CPU or CUDA kernel, past the (Python) autograd
    # kernel that is most of a small call's cost, and let the glue check the arguments and broadcast
    # their batch shapes. Only when it refuses them are they checked here, to word the error (the
    # argument, what was expected and what was received).
    keyset = kernel_keyset(args[0])
    if keyset is None:
        return op(*checked(name, robot._tensor_args[name], args), convention)
    try:
        return op.default.redispatch(keyset, *args, convention)
    except RuntimeError:
        args = checked(name, robot._tensor_args[name], args)
    return op.default.redispatch(keyset, *args, convention)


@torch._disable_dynamo  # torch.compiler.disable, made at the first call: importing torch._dynamo takes most of a second
def _func_call_eagerly(func: FuncOps, name: str, *args):
    """An op under torch.func's grad or jvp, or on forward-mode dual tensors, while torch.compile traces:
    through its autograd.Function, run eagerly (torch.compile traces neither that Function's transforms
    nor the op's registered autograd under them: the op alone would fail, or return a wrong tangent)."""
    return func.call(name, *args)
