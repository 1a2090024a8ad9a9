"""Argument checks of a robot's functions: each error names the argument, what was expected and what
was received. The robot's functions (robot.py) call these; this module imports none of them."""
from __future__ import annotations

import numbers

import torch

from .levels import dual
from .table import OPS

REFERENCES = {"world": 0, "local": 1, "local_world_aligned": 2}


def check_tensor(op: str, name: str, x, trailing: tuple[int, ...], q) -> None:
    """Refuse `x` unless it is a float32 or float64 tensor of shape (..., *trailing) with q's dtype and device."""
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{op}: {name} must be a torch.Tensor, got {type(x).__name__}")
    if x.dtype not in (torch.float32, torch.float64):
        raise TypeError(f"{op}: {name} must be float32 or float64, got {x.dtype}")
    if x is not q and x.dtype != q.dtype:
        raise TypeError(f"{op}: {name} has dtype {x.dtype} but q has {q.dtype}; all tensors must share one dtype")
    if x is not q and x.device != q.device:
        raise ValueError(f"{op}: {name} is on {x.device} but q is on {q.device}; all tensors must share one device")
    if x.dim() < len(trailing) or tuple(x.shape[x.dim() - len(trailing):]) != trailing:
        want = ", ".join(["..."] + [str(t) for t in trailing])
        raise ValueError(f"{op}: {name} must have shape ({want}), got {tuple(x.shape)}")


def check_arguments(op: str, arguments) -> tuple[int, ...]:
    """Refuse the (name, tensor or None, trailing shape) arguments of a function composed in torch, q first, as
    `checked` refuses an op's; returns the broadcast of their leading batch shapes."""
    given = [(name, x, tuple(trailing)) for name, x, trailing in arguments if x is not None]
    return _batch_shape(op, given, arguments[0][1])[1]


def checked(op: str, tensor_args, args) -> list:
    """The arguments checked (each error names the argument, what was expected and what was received),
    with every tensor expanded to the broadcast of their leading batch shapes."""
    spec = OPS[op].args
    names = [a.name for a in spec]
    for k, _ in tensor_args:
        if args[k] is None and not spec[k].optional:
            raise TypeError(f"{op}: {names[k]} must be a torch.Tensor, got None")
    given = [(k, tuple(trailing)) for k, trailing in tensor_args if args[k] is not None]
    shapes, batch = _batch_shape(op, [(names[k], args[k], trailing) for k, trailing in given], args[0])
    args = list(args)
    for (k, trailing), shape in zip(given, shapes):
        if shape != batch:
            args[k] = args[k].expand(*batch, *trailing)
    return args


def _batch_shape(op: str, given, q) -> tuple[list[tuple[int, ...]], tuple[int, ...]]:
    """Each (name, tensor, trailing shape) checked by check_tensor against q; their leading batch shapes and
    the broadcast of them, refused where they do not broadcast."""
    for name, x, trailing in given:
        check_tensor(op, name, x, trailing, q)
    shapes = [tuple(x.shape[: x.dim() - len(trailing)]) for _, x, trailing in given]
    # torch's broadcasting rule on the batch shapes (torch.broadcast_shapes costs tens of µs)
    batch = [1] * max(len(s) for s in shapes)
    for shape in shapes:
        for axis, size in enumerate(shape, len(batch) - len(shape)):
            if size != batch[axis] and size != 1 and batch[axis] != 1:
                listed = ", ".join(f"{name} {s}" for (name, _, _), s in zip(given, shapes))
                raise ValueError(f"{op}: the leading batch shapes do not broadcast: {listed}")
            batch[axis] = size if size != 1 else batch[axis]
    return shapes, tuple(batch)


def check_batch_shape(op: str, batch_shape: tuple) -> tuple[int, ...]:
    """A sampler's `*batch_shape`: non-negative integers (dtype and device are keyword arguments)."""
    for size in batch_shape:
        if isinstance(size, bool) or not isinstance(size, numbers.Integral) or size < 0:
            raise TypeError(f"{op}: batch_shape must be non-negative integers (dtype=, device= are keyword "
                            f"arguments), got {size!r} in {batch_shape!r}")
    return tuple(int(size) for size in batch_shape)


def forward_mode(args, stack=None) -> bool:
    """Whether forward-mode AD sees the call: a torch.func jvp transform (in `stack`, torch.func's
    interpreter stack, read when not given), or a forward_ad dual argument (never while torch.compile
    traces, which runs the kernels)."""
    if torch.compiler.is_compiling():
        return False
    if stack is None:
        stack = torch._C._functorch.get_interpreter_stack()
    return (bool(stack) and any(i.key() == torch._C._functorch.TransformType.Jvp for i in stack)) or dual(args)


def reference_code(op: str, reference) -> int:
    """The code of a frame Jacobian's reference frame, given by name (REFERENCES) to `op`."""
    ref = REFERENCES.get(reference.lower()) if isinstance(reference, str) else None
    if ref is None:
        raise ValueError(f"{op}: reference must be one of {sorted(REFERENCES)}, got {reference!r}")
    return ref


def check_dt(op: str, dt, q: torch.Tensor, *others: torch.Tensor) -> None:
    """dt must be a real number, or a tensor of q's dtype and device whose shape broadcasts with the batch
    shape of q and the others."""
    if isinstance(dt, torch.Tensor):
        if dt.dtype != q.dtype or dt.device != q.device:
            raise TypeError(f"{op}: dt must have q's dtype and device ({q.dtype}, {q.device}), got {dt.dtype}, "
                            f"{dt.device}")
        try:
            torch.broadcast_shapes(dt.shape, *(x.shape[:-1] for x in (q, *others) if isinstance(x, torch.Tensor)))
        except RuntimeError:
            raise ValueError(f"{op}: dt must be a number or a tensor whose shape broadcasts with the batch shape "
                             f"(a step per sample: the batch shape itself), got shape {tuple(dt.shape)} with q "
                             f"{tuple(q.shape)}") from None
    elif not isinstance(dt, numbers.Real) or isinstance(dt, bool):
        raise TypeError(f"{op}: dt must be a number or a tensor, got {type(dt).__name__}")
