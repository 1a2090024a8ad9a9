"""The ops in eager reverse mode: a call whose inputs require grad, outside torch.compile and the torch.func
transforms (dispatch.py routes those elsewhere).

The registered autograd of an op (autograd.register_autograd) is a torch.autograd.Function that torch.library
wraps in Python of its own: about 70 µs a call on a CPU, where the kernel itself takes a few at one sample. Here
each op is such a Function without the wrapper: its forward calls the kernel below torch's autograd key, its backward
is the op's formula (autograd.py), the same one the registered autograd runs. Inside a plain backward (nothing
differentiates it) the formula's own ops run the same way (DirectOps); inside a differentiated one (create_graph)
they run through their registered autograd, so that autograd records them.
"""
from __future__ import annotations

import torch

from ..model.description import RobotModel
from .autograd import backward_formula, no_backward
from .saving import save, saved
from .table import OPS

_CPU, _CUDA = torch._C.DispatchKeySet(torch._C.DispatchKey.CPU), torch._C.DispatchKeySet(torch._C.DispatchKey.CUDA)


def kernel_keyset(x) -> torch._C.DispatchKeySet | None:
    """The dispatch key set of the CPU or CUDA kernel for tensors on x's device; None for anything else, and while a
    TorchDispatchMode is active (a FLOP counter, fake tensors, a spy), which sees only calls through the dispatcher."""
    if not isinstance(x, torch.Tensor) or torch._C._len_torch_dispatch_stack():
        return None
    return _CPU if x.is_cpu else _CUDA if x.is_cuda else None


def call_kernel(op, *args):
    """op on args, straight to its CPU or CUDA kernel below the autograd key where kernel_keyset allows, else through
    the dispatcher."""
    keyset = kernel_keyset(args[0])
    return op(*args) if keyset is None else op.default.redispatch(keyset, *args)


class DirectOps:
    """A robot build's ops for a backward's formula: each kernel called below the autograd key when nothing records
    the call, else the registered op. Any other attribute is the ops' own."""

    def __init__(self, ops):
        self._ops = ops

    def __getattr__(self, name: str):
        op = getattr(self._ops, name)
        if name not in OPS:
            return op

        def call(*args):
            return op(*args) if torch.is_grad_enabled() else call_kernel(op, *args)

        return call


class EagerOps:
    """One robot build's ops, each through a lean torch.autograd.Function (the module's docstring)."""

    def __init__(self, ops, model: RobotModel):
        self._ops, self._model, self._direct = ops, model, DirectOps(ops)
        self._functions: dict[str, type] = {}

    def call(self, name: str, *args):
        """Op `name` on arguments already checked and broadcast (arguments.checked), the convention last."""
        function = self._functions.get(name)
        if function is None:
            function = self._functions[name] = self._function(name)
        return function.apply(*args)

    def _function(self, name: str) -> type:
        spec = OPS[name]
        op = getattr(self._ops, name)
        formula = backward_formula(spec)
        several = len(spec.outputs) > 1
        ops, direct, model = self._ops, self._direct, self._model

        def forward(ctx, *args):
            out = call_kernel(op, *args)
            save(ctx, args, out if several else (out,))  # as the registered autograd saves them
            return out

        def backward(ctx, *grads):
            inputs, outputs = saved(ctx)
            inner = ops if torch.is_grad_enabled() else direct
            return formula(inner, model, ctx.needs_input_grad, grads, outputs if several else outputs[0], *inputs)

        return type(f"{name}_eager", (torch.autograd.Function,), {
            "forward": staticmethod(forward),
            "backward": staticmethod(backward if formula is not None else no_backward(name))})

