"""Autograd for the ops. Analytic derivative kernels are not implemented yet, so every op's
backward raises a clear error instead of silently dropping the gradient path."""
from __future__ import annotations

import torch

from .ops import OPS


def register_autograd(namespace: str) -> None:
    """Attach a backward to every op of one robot build."""
    for spec in OPS.values():
        torch.library.register_autograd(f"{namespace}::{spec.name}", _no_backward(spec.name), setup_context=_no_context)


def _no_context(ctx, inputs, output) -> None:
    pass


def _no_backward(name: str):
    def backward(ctx, *grads):
        raise NotImplementedError(
            f"torch_grid: {name} has no derivative yet; its outputs cannot be back-propagated through"
        )

    return backward
