"""Forward dynamics' second derivatives in closed form, from inverse dynamics' and the first derivatives.

At qdd(x) solving ID(q, qd, qdd) + K qdd - p(q, qd) = tau (K = 0 for forward dynamics, dt D for MuJoCo's
Euler step with the damping implicit; p the passive forces, linear), differentiating twice with
Z = d qdd / dx and W = (M + K)^-1:
    d2qdd/dx_j dx_k = -W (d2tau/dx_j dx_k + dM/dx_j Z_k + dM/dx_k Z_j)     (dM/dx only along q)
    d2qdd/dtau_j dq_k = d/dq_k W[:, j] = -(W dM/dq_k W)[:, j]
from inverse_dynamics_second_derivatives at that qdd, in either convention.
"""
from __future__ import annotations

import torch

from .levels import transforming


def cholesky_or_nan(A: torch.Tensor) -> torch.Tensor:
    """The Cholesky factor (..., n, n) of symmetric A, NaN for a sample where A is not positive definite (a
    NaN in its inputs, non-physical inertial parameters) rather than an error for the whole batch: a solve
    with it is NaN for that sample alone."""
    L, info = torch.linalg.cholesky_ex(A)
    return torch.where((info == 0).unsqueeze(-1).unsqueeze(-1), L, torch.nan)


def second_order(second: tuple[torch.Tensor, ...], z_q: torch.Tensor, z_qd: torch.Tensor,
                 inverse: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """(d2qdd_dq2, d2qdd_dqd2, d2qdd_dqdqd, d2qdd_dtaudq), each (..., nv, nv, nv), from `second` (the four
    inverse_dynamics_second_derivatives tensors at qdd), Z = (z_q, z_qd) and W = `inverse` (..., nv, nv)."""
    traced = torch.compiler.is_compiling() or transforming()
    if traced or (torch.is_grad_enabled() and any(t.requires_grad for t in second)):
        return _closed_form(*second, z_q, z_qd, inverse)
    # Chunks of samples, written over the inverse-dynamics tensors (kept blocks, already mapped):
    # whole-batch temporaries of nv^3 per sample would each be mapped and zeroed afresh. The results are
    # returned from `flat`, which is `second` itself where the batch flattens to a view, else its copy.
    nv = inverse.shape[-1]
    flat = [t.reshape(-1, nv, nv, nv) for t in second]
    z_q, z_qd, inverse = (t.expand(*second[0].shape[:-3], nv, nv).reshape(-1, nv, nv) for t in (z_q, z_qd, inverse))
    step = max(1, (1 << 20) // (8 * nv ** 3))
    for s in range(0, flat[0].shape[0], step):
        rows = slice(s, s + step)
        results = _closed_form(*(t[rows] for t in flat), z_q[rows], z_qd[rows], inverse[rows])
        for t, r in zip(flat, results):
            t[rows] = r
    return tuple(f.view(t.shape) for f, t in zip(flat, second))


def _closed_form(d2q, d2qd, dqdqd, dM, z_q, z_qd, inverse):
    """The closed form: one large matrix product per sample for each O(nv^4) term."""
    nv, neg_inverse = inverse.shape[-1], -inverse
    dMt = dM.transpose(-1, -2).contiguous()  # [i, j, m] = dM[i, m, j]

    def right(x, z):  # sum_m x[i, j, m] z[m, k]
        return (x.flatten(-3, -2) @ z).unflatten(-2, (nv, nv))

    def solve(x):  # -W along the first axis
        return (neg_inverse @ x.flatten(-2)).unflatten(-1, (nv, nv))

    along_j = right(dMt, z_q)  # sum_m dM[i, m, j] Z[m, k]
    d2qdd_dq2 = d2q + along_j + along_j.transpose(-1, -2)
    d2qdd_dqdqd = dqdqd + right(dMt, z_qd)
    # [i, j, k] = sum_b (-W dM)[i, b, k] W[b, j], W symmetric
    d2qdd_dtaudq = right(solve(dM).transpose(-1, -2), inverse).transpose(-1, -2)
    return solve(d2qdd_dq2), solve(d2qd), solve(d2qdd_dqdqd), d2qdd_dtaudq
