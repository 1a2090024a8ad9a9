"""What an op's autograd.Function keeps for its backward (the registered autograd, autograd.py; the eager
Functions, eager.py; torch.func's, func.py)."""
from __future__ import annotations

import torch


def save(ctx, inputs, outputs) -> None:
    """The tensor inputs and the outputs through save_for_backward: an input modified in place before the backward
    is then refused by autograd (the backward would differentiate at the modified value), and in a double
    backward the outputs are the graph's, whose gradients reach the op's own backward (a plain attribute would
    hold them as constants). The other inputs (numbers, None) as they are."""
    ctx.tensor_positions = [k for k, x in enumerate(inputs) if isinstance(x, torch.Tensor)]
    ctx.others = [None if isinstance(x, torch.Tensor) else x for x in inputs]
    ctx.save_for_backward(*[inputs[k] for k in ctx.tensor_positions], *outputs)


def saved(ctx, tensors: tuple | None = None) -> tuple[list, tuple]:
    """The inputs and the outputs `save` kept: ctx.saved_tensors, or `tensors` in their place (the same unwrapped)."""
    tensors = ctx.saved_tensors if tensors is None else tensors
    inputs = list(ctx.others)
    for k, t in zip(ctx.tensor_positions, tensors):
        inputs[k] = t
    return inputs, tensors[len(ctx.tensor_positions):]
