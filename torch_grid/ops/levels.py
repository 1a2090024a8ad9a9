"""Which differentiation sees a call: an active torch.func transform, a forward-mode dual level, or one that
torch.compile traces. The ops, their backwards and the Robot methods choose between a kernel and a torch
composition by these."""
from __future__ import annotations

import inspect
import sys

import torch
from torch._C._functorch import TransformType
from torch._functorch import eager_transforms
from torch._functorch.pyfunctorch import coerce_cinterpreter
from torch.autograd import forward_ad


def transforming() -> bool:
    """Whether a torch.func transform is active (then ops go through FuncOps)."""
    return isinstance(torch._C._functorch.peek_interpreter_stack(), torch._C._functorch.CInterpreter)


def traced_transform() -> bool:
    """While torch.compile traces: whether the ops are to go through FuncOps, that is, a torch.func transform
    other than vmap is innermost, or a forward-mode dual level is open (the compiler does not see a dual
    argument's tangent, so the level, not the argument, decides)."""
    return top_transform() not in (None, TransformType.Vmap) or forward_ad._current_level >= 0


def top_transform() -> TransformType | None:
    """The innermost active torch.func transform (Vmap, Grad, Jvp, ...), or None; in the functorch calls
    that torch.compile traces (the interpreter stack itself it cannot)."""
    return coerce_cinterpreter(torch._C._functorch.peek_interpreter_stack()).key() if transforming() else None


def kernels_kept_off(model, convention: int, q) -> bool:
    """Whether the kernels that fuse a composition (the step's, integrate's and difference's, and the maps inside
    backwards) are kept off a call: on CUDA in MuJoCo's convention of a robot with quaternion joints. There an H100
    gave the step kernels NaN (the Runge-Kutta schemes on a floating base, every scheme but Euler with ball joints:
    bench/RESULTS.md), where the CPU build and the composition of the other ops were right; the composition runs
    instead until a GPU run shows the kernels right."""
    return isinstance(q, torch.Tensor) and q.is_cuda and bool(convention) and model.conventions_differ


def differentiated(tensors) -> bool:
    """Inside a backward: whether something differentiates it in turn (create_graph's grad mode, a torch.func
    transform, a forward-mode dual tensor), so that it must be made of ops with derivatives of their own."""
    return torch.is_grad_enabled() or transforming() or dual(tensors)


def dual(args) -> bool:
    """Whether an argument carries a torch.autograd.forward_ad tangent."""
    return forward_ad._current_level >= 0 and any(
        isinstance(x, torch.Tensor) and forward_ad.unpack_dual(x).tangent is not None for x in args)


# torch 2.11's compiler miscompiles the backward of a torch.func.vjp (and jacrev's, made of one) whose function
# breaks the graph, as the ops do under a transform: the gradients come back zero (torch 2.12 has it right).
_VJP_MISCOMPILED = tuple(int(x) for x in torch.__version__.split("+")[0].split(".")[:2]) < (2, 12)


def miscompiled_vjp(stack) -> bool:
    """Whether this eager call (interpreter stack `stack`) runs inside a torch.compile'd call, under a torch.func.vjp
    or jacrev that is the only transform, on a torch that miscompiles that vjp's backward (2.11). Nested in another
    transform (hessian, jacrev of jacrev, vmap of jacrev), and under grad, the compiled results are right."""
    if not _VJP_MISCOMPILED or len(stack) != 1 or stack[0].key() != TransformType.Grad:
        return False
    if torch._C._dynamo.eval_frame.get_eval_frame_callback() is None:
        return False
    vjp = inspect.unwrap(eager_transforms._vjp_with_argnums).__code__  # what vjp and jacrev call the function from
    frame = sys._getframe(1)
    while frame is not None and frame.f_code is not vjp:
        frame = frame.f_back
    return frame is not None
