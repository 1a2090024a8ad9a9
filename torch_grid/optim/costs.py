"""Costs and barriers for trajectory optimisation: each returns (value (...,), gradient, Gauss-Newton
Hessian), in torch over the robot's ops, so autograd differentiates them too.

State costs are functions of x = (q, qd): their gradient (..., 2 nv) and Hessian (..., 2 nv, 2 nv) are
along the tangent [dq; dqd] (q moved by integrate), as Crocoddyl's Lx, Lxx; control costs take tau:
(..., nv), (..., nv, nv). A residual r with Jacobian J and weights w (per sample, so a batch may hold
different goals) costs sum(w r^2) / 2, gradient J^T (w r), Gauss-Newton Hessian J^T diag(w) J.
"""
from __future__ import annotations

import numbers

import torch

from ..ops.arguments import check_tensor
from ..space.lie import block_diagonal, dexp_inverse_block, left_jacobian_inverse, log3


class CostFunctions:
    """The costs of a robot's views (mixed into robot._Functions). Each state cost returns (value (...,),
    gradient (..., 2 nv), Gauss-Newton Hessian (..., 2 nv, 2 nv)) along the tangent [dq; dqd]; control_cost
    returns (value (...,), gradient (..., nv), Hessian (..., nv, nv))."""

    def state_cost(self, q, qd, q_ref, qd_ref, weights) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """r = [difference(q_ref, q); qd - qd_ref], weights (..., 2 nv). Returns (value (...,), gradient
        (..., 2 nv), Gauss-Newton Hessian (..., 2 nv, 2 nv)), as every state cost."""
        nv = self.nv
        w, q_ref, qd_ref = _arguments("state_cost", self, q, qd, ("weights", weights, (2 * nv,)),
                                      ("q_ref", q_ref, (self.nq,)), ("qd_ref", qd_ref, (nv,)))
        r_q, r_v = self.difference(q_ref, q), qd - qd_ref
        j_q = self.d_difference(q_ref, q)[1]
        # J = [[j_q, 0], [0, I]]: its blocks apart (the dense 2 nv product costs 8x the q block's)
        batch = torch.broadcast_shapes(r_q.shape[:-1], r_v.shape[:-1], w.shape[:-1])
        value_q, grad_q, hess_q = _weighted(r_q, j_q, w[..., :nv])
        value_v, grad_v, hess_v = _diagonal(r_v, w[..., nv:])
        return (value_q + value_v, torch.cat([grad_q.expand(*batch, nv), grad_v.expand(*batch, nv)], dim=-1),
                block_diagonal(hess_q.expand(*batch, nv, nv), hess_v.expand(*batch, nv, nv)))

    def control_cost(self, tau, tau_ref, weights) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """r = tau - tau_ref, weights (..., nv). Returns (value (...,), gradient (..., nv), Hessian (..., nv, nv))."""
        # the robot's nv (a bare CostFunctions, without a robot: tau's own size)
        nv = getattr(self, "nv", tau.shape[-1] if isinstance(tau, torch.Tensor) and tau.dim() else 0)
        check_tensor("control_cost", "tau", tau, (nv,), tau)
        tau_ref = _checked("control_cost", "tau_ref", tau_ref, (nv,), tau)
        weights = _checked_weights("control_cost", weights, nv, tau)
        _broadcast("control_cost", [("tau", tau, 1), ("tau_ref", tau_ref, 1), ("weights", weights, 1)])
        return _diagonal(tau - tau_ref, weights)

    def frame_translation_cost(self, q, qd, frame, target, weights) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """r = the frame's world position - target (..., 3), weights (..., 3)."""
        target, weights = _arguments("frame_translation_cost", self, q, qd, ("target", target, (3,)),
                                     ("weights", weights, (3,)))
        index = self._robot.frame_index(frame, "frame_translation_cost: frame")
        position = self.forward_kinematics(q)[0][..., index, :]
        jacobian = self.frame_jacobian(q, index, "local_world_aligned")[..., :3, :]
        return _weighted(position - target, _state_rows(jacobian, qd), weights)

    def frame_placement_cost(self, q, qd, frame, target, weights) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """r = log6(target^-1 oMf) [linear; angular] (Crocoddyl's ResidualModelFramePlacement), target a
        (..., 4, 4) placement, weights (..., 6); J = Jlog6(target^-1 oMf) J_frame(LOCAL)."""
        target, weights = _arguments("frame_placement_cost", self, q, qd, ("target", target, (4, 4)),
                                     ("weights", weights, (6,)))
        index = self._robot.frame_index(frame, "frame_placement_cost: frame")
        positions, rotations = self.forward_kinematics(q)
        R, p = rotations[..., index, :, :], positions[..., index, :]
        R_ref, p_ref = target[..., :3, :3], target[..., :3, 3]
        R_rel = R_ref.mT @ R
        w = log3(_quaternion_of(R_rel))
        p_rel = R_ref.mT @ (p - p_ref).unsqueeze(-1)
        r = torch.cat([(left_jacobian_inverse(w) @ p_rel).squeeze(-1), w], dim=-1)
        jacobian = dexp_inverse_block("free", r, 0) @ self.frame_jacobian(q, index, "local")
        return _weighted(r, _state_rows(jacobian, qd), weights)

    def com_cost(self, q, qd, target, weights, params=None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """r = center of mass - target (..., 3), weights (..., 3); params as in inverse_dynamics."""
        target, weights = _arguments("com_cost", self, q, qd, ("target", target, (3,)), ("weights", weights, (3,)),
                                     *_params(self, params))[:2]
        return _weighted(self.com(q, params) - target, _state_rows(self.jacobian_com(q, params), qd), weights)

    def momentum_cost(self, q, qd, target, weights, params=None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """r = centroidal momentum h(q, qd) [linear; angular] - target (..., 6), weights (..., 6): both its q
        block (dccrba) and its qd block (A); params as in inverse_dynamics."""
        target, weights = _arguments("momentum_cost", self, q, qd, ("target", target, (6,)),
                                     ("weights", weights, (6,)), *_params(self, params))[:2]
        A, h = self.ccrba(q, qd, params)
        return _weighted(h - target, torch.cat([self.dccrba(q, qd, params), A], dim=-1), weights)


def quadratic_barrier(x: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor, weights: torch.Tensor):
    """Crocoddyl's quadratic barrier: sum(w (min(x - lower, 0)^2 + max(x - upper, 0)^2)) / 2, zero inside
    [lower, upper]; (value (...,), gradient (..., n), Hessian (..., n, n), diagonal). A NaN in x or a bound
    is NaN in all three (its entry of the Hessian too, which is w or 0 elsewhere)."""
    _checked_bounds("quadratic_barrier", x, lower, upper, weights)
    r = torch.clamp(x - lower, max=0) + torch.clamp(x - upper, min=0)
    outside = torch.where(torch.isnan(r), r, ((x < lower) | (x > upper)).to(x.dtype))
    value = 0.5 * (weights * r * r).sum(-1)
    return value, weights * r, torch.diag_embed(weights * outside)


def log_barrier(x: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor, weights: torch.Tensor):
    """The logarithmic barrier of joint position, velocity or torque limits (as GRiD's):
    -sum(w (log(x - lower) + log(upper - x))), lower < upper; infinite outside (lower, upper), with an
    infinite gradient and Hessian there rather than a NaN: the gradient is -inf at or below lower and +inf
    at or above upper, its limits from inside; NaN where x or a bound is NaN, on neither side. (value (...,),
    gradient (..., n), Hessian (..., n, n), diagonal, exact)."""
    _checked_bounds("log_barrier", x, lower, upper, weights)
    a, b = x - lower, upper - x
    inside = (a > 0) & (b > 0)
    a_s, b_s = torch.where(inside, a, torch.ones_like(a)), torch.where(inside, b, torch.ones_like(b))
    inf = torch.where(torch.isnan(a) | torch.isnan(b), torch.nan, torch.full_like(x, float("inf")))
    value = torch.where(inside, -weights * (torch.log(a_s) + torch.log(b_s)), inf).sum(-1)
    grad = torch.where(inside, weights * (1 / b_s - 1 / a_s), torch.where(a > 0, inf, -inf))
    hess = torch.where(inside, weights * (1 / (a_s * a_s) + 1 / (b_s * b_s)), inf)
    return value, grad, torch.diag_embed(hess)


def _weighted(r: torch.Tensor, J: torch.Tensor, w: torch.Tensor):
    wr = w * r
    # each output on the batch shape of all three, the gradient's (J^T w r reads them all): a target's reaches r
    # alone, a velocity's J alone
    grad = (J.mT @ wr.unsqueeze(-1)).squeeze(-1)
    hess = J.mT @ (w.unsqueeze(-1) * J)
    return (0.5 * (wr * r).sum(-1)).expand(grad.shape[:-1]), grad, hess.expand(*grad.shape[:-1], *hess.shape[-2:])


def _diagonal(r: torch.Tensor, w: torch.Tensor):
    """_weighted with J = I."""
    wr = w * r
    return 0.5 * (wr * r).sum(-1), wr, torch.diag_embed(w.expand_as(wr))


def _state_rows(jacobian: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
    """A residual's Jacobian along q, (..., m, nv), as one along [dq; dqd] (zero qd block)."""
    batch = torch.broadcast_shapes(jacobian.shape[:-2], qd.shape[:-1])
    jacobian = jacobian.expand(*batch, *jacobian.shape[-2:])
    return torch.cat([jacobian, torch.zeros_like(jacobian)], dim=-1)


def _arguments(cost: str, view, q, qd, *named) -> list[torch.Tensor]:
    """The tensors of named (name, tensor, trailing shape), refused by name unless of that shape and q's dtype and
    device, after q (..., nq) and qd (..., nv) (the frame, com and momentum costs read qd's batch alone), and
    where the batch shapes of them all do not broadcast."""
    check_tensor(cost, "q", q, (view.nq,), q)
    check_tensor(cost, "qd", qd, (view.nv,), q)
    tensors = [_checked(cost, name, x, shape, q) for name, x, shape in named]
    _broadcast(cost, [("q", q, 1), ("qd", qd, 1)] + [(name, x, len(shape)) for (name, _, shape), x in zip(named, tensors)])
    return tensors


def _params(view, params) -> list:
    """A cost's params as one of _arguments' named tensors (none when absent)."""
    return [] if params is None else [("params", params, (view.model.nbodies, 10))]


def _broadcast(cost: str, named) -> None:
    """Refuses (name, tensor, number of trailing dimensions) whose batch shapes do not broadcast, naming each
    (torch's own error, or an inner function's, named none of them)."""
    shapes = [(name, tuple(x.shape[:x.dim() - k])) for name, x, k in named]
    batched = [shape for _, shape in shapes if shape]
    if any(shape != batched[0] for shape in batched[1:]):  # one batch shape beside unbatched ones broadcasts
        try:
            torch.broadcast_shapes(*(shape for _, shape in shapes))
        except RuntimeError:
            raise ValueError(f"{cost}: the batch shapes do not broadcast: "
                             + ", ".join(f"{name} {shape}" for name, shape in shapes)) from None


def _checked_weights(cost: str, weights, n: int, like: torch.Tensor) -> torch.Tensor:
    return _checked(cost, "weights", weights, (n,), like)


def _checked(cost: str, name: str, tensor, shape: tuple[int, ...], like: torch.Tensor) -> torch.Tensor:
    """`tensor` itself, refused unless it is a tensor whose trailing dimensions are `shape`, of like's dtype
    and device."""
    if not isinstance(tensor, torch.Tensor) or tuple(tensor.shape[max(0, tensor.dim() - len(shape)):]) != shape:
        got = tuple(tensor.shape) if isinstance(tensor, torch.Tensor) else type(tensor).__name__
        want = ", ".join(["..."] + [str(n) for n in shape])
        raise ValueError(f"{cost}: {name} must be a tensor of shape ({want}), got {got}")
    return _like(cost, name, tensor, like)


def _like(cost: str, name: str, tensor: torch.Tensor, like: torch.Tensor, whose: str = "the state's") -> torch.Tensor:
    """Refuses a tensor of another dtype or device than like's (torch would promote it, or fail deep inside)."""
    if isinstance(like, torch.Tensor) and (tensor.dtype != like.dtype or tensor.device != like.device):
        raise TypeError(f"{cost}: {name} is {tensor.dtype} on {tensor.device}, expected {whose} {like.dtype} on "
                        f"{like.device}")
    return tensor


def _checked_bounds(barrier: str, x: torch.Tensor, lower, upper, weights) -> None:
    """Refuses an x that is not a float tensor (..., n), bounds or weights that are neither numbers nor tensors
    broadcasting with x, or tensors of another dtype or device than x's, naming the argument."""
    if not isinstance(x, torch.Tensor) or not x.is_floating_point() or x.dim() == 0:
        got = f"{x.dtype} of shape {tuple(x.shape)}" if isinstance(x, torch.Tensor) else type(x).__name__
        raise TypeError(f"{barrier}: x must be a float tensor of shape (..., n), got {got}")
    for name, t in (("lower", lower), ("upper", upper), ("weights", weights)):
        if not isinstance(t, (torch.Tensor, numbers.Real)) or isinstance(t, bool):
            raise TypeError(f"{barrier}: {name} must be a number or a tensor, got {type(t).__name__}")
        shape = tuple(t.shape) if isinstance(t, torch.Tensor) else ()
        try:
            torch.broadcast_shapes(x.shape, shape)
        except RuntimeError:
            raise ValueError(f"{barrier}: {name} of shape {shape} does not broadcast with x's shape "
                             f"{tuple(x.shape)}") from None
        if isinstance(t, torch.Tensor):
            _like(barrier, name, t, x, "x's")


def _quaternion_of(R: torch.Tensor) -> torch.Tensor:
    """The unit quaternion (xyzw) of rotation matrices (..., 3, 3), by the largest of w, x, y, z (each
    branch's square root kept positive, so that gradients through the others stay finite)."""
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    trace = m00 + m11 + m22
    s = [torch.sqrt(torch.clamp(t, min=1e-12)) * 2 for t in
         (1 + trace, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22)]
    d21, d02, d10 = R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]
    a01, a02, a12 = R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1]
    cases = [
        torch.stack([d21 / s[0], d02 / s[0], d10 / s[0], s[0] / 4], dim=-1),
        torch.stack([s[1] / 4, a01 / s[1], a02 / s[1], d21 / s[1]], dim=-1),
        torch.stack([a01 / s[2], s[2] / 4, a12 / s[2], d02 / s[2]], dim=-1),
        torch.stack([a02 / s[3], a12 / s[3], s[3] / 4, d10 / s[3]], dim=-1),
    ]
    pick = torch.stack([trace, m00, m11, m22], dim=-1).argmax(-1, keepdim=True).unsqueeze(-1)
    return torch.gather(torch.stack(cases, dim=-2), -2, pick.expand(*pick.shape[:-2], 1, 4)).squeeze(-2)
