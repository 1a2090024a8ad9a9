"""Tensors the torch compositions make from Python values, made so that a call can be captured in a
CUDA graph: copying host memory to a GPU cannot be captured, so index lists and constant tables are
made once per device and kept (a warm-up call before the capture makes them), and a number becomes a
tensor by a fill, which can."""
from __future__ import annotations

import numbers
from functools import lru_cache

import torch
from torch.utils import _python_dispatch


def constant(values: tuple, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """The tensor of `values` (a flat or nested tuple), made once per dtype and device and then shared:
    never write to it. Inside a trace (torch.compile, a fake or functional mode, any dispatch mode) or a
    torch.func transform it is made afresh: a tensor made there must not outlive it."""
    if (torch.compiler.is_compiling() or torch._guards.detect_fake_mode() is not None
            or _python_dispatch._get_current_dispatch_mode() is not None
            or torch._C._functorch.get_interpreter_stack()):
        return torch.tensor(values, dtype=dtype, device=device)
    return _constant(values, dtype, torch.device(device))


@lru_cache(maxsize=4096)
def _constant(values: tuple, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    return torch.tensor(values, dtype=dtype, device=device)


def scalar_or_tensor(x, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """x (a number or a tensor) as a tensor of dtype on device; a number by a fill."""
    if isinstance(x, numbers.Real) and not isinstance(x, torch.Tensor):
        return torch.full((), float(x), dtype=dtype, device=device)
    return torch.as_tensor(x, dtype=dtype, device=device)
