"""The ops under torch.func transforms (grad, vjp, jacrev, vmap, functional_call and their compositions).

torch.func needs an autograd.Function with a `setup_context` and a `vmap` rule, which the dispatcher's
registered autograd (torch.library.register_autograd, used by backward() and torch.compile) does
not have. Under a transform, `Robot` calls each op through `FuncOps`: one such Function per op whose
forward calls the op one transform level down, whose backward is the op's own formula
(autograd.py) with its inner ops called the same way (so a transform of a transform nests), and
whose vmap rule moves the batched dimension to the front and makes one batched call, which the ops
broadcast. Forward mode (jvp, jacfwd, hessian) is refused by `Robot` before it gets here.
"""
from __future__ import annotations

from typing import Callable

import torch

from .autograd import backward_formula
from .model import RobotModel
from .ops import OPS


def transforming() -> bool:
    """Whether a torch.func transform is active (then ops go through FuncOps)."""
    return bool(torch._C._functorch.get_interpreter_stack())


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
        if not transforming():
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
            tensors = [k for k, x in enumerate(inputs) if isinstance(x, torch.Tensor)]
            ctx.tensor_positions = tensors
            ctx.others = [None if isinstance(x, torch.Tensor) else x for x in inputs]
            outs = output if several else (output,)
            ctx.save_for_backward(*[inputs[k] for k in tensors], *outs)

        def backward(ctx, *grads):
            saved = ctx.saved_tensors
            inputs = list(ctx.others)
            for k, t in zip(ctx.tensor_positions, saved):
                inputs[k] = t
            outs = saved[len(ctx.tensor_positions):]
            if formula is None:
                raise NotImplementedError(f"torch_grid: {name} has no derivative; it cannot be back-propagated through")
            return formula(outer, model, ctx.needs_input_grad, grads, outs if several else outs[0], *inputs)

        def vmap(info, in_dims, *args):
            # Every op broadcasts leading batch dimensions: the vmapped one goes first, ahead of the
            # others' batch dimensions (right-aligned, as torch broadcasts).
            ranks = [x.dim() - (d is not None) - t for x, d, t in zip(args, in_dims, trailing) if isinstance(x, torch.Tensor)]
            moved = []
            for x, d, t in zip(args, in_dims, trailing):
                if d is not None:
                    x = x.movedim(d, 0)
                    x = x.reshape(x.shape[0], *[1] * (max(ranks) - (x.dim() - 1 - t)), *x.shape[1:])
                moved.append(x)
            out = outer.call(name, *moved)
            return out, (0,) * len(spec.outputs) if several else 0

        return type(f"{name}_function", (torch.autograd.Function,), {
            "forward": staticmethod(forward), "setup_context": staticmethod(setup_context),
            "backward": staticmethod(backward), "vmap": staticmethod(vmap)})
