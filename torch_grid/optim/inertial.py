"""Physically consistent inertial parameters, for identification and learning.

A body's ten parameters pi = [m, h = m c, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz] (Pinocchio's order, I
the rotational inertia about the joint frame origin) describe a real mass distribution exactly when
its pseudo-inertia

    J = [[Sigma, h], [h^T, m]],   Sigma = tr(I) / 2 * 1 - I   (the second moment of the mass)

is positive semidefinite (Wensing, Kim and Slotine, "Linear matrix inequalities for physically
consistent inertial parameter identification", RA-L 2017): a non-negative mass, a positive inertia
about the centre of mass, and its triangle inequalities. The log-Cholesky parametrisation (Rucker and
Wensing, "Smooth parameterization of rigid-body inertia", RA-L 2022) maps any theta in R^10 to such a
J = U U^T, U = e^alpha [[e^d1, s12, s13, t1], [0, e^d2, s23, t2], [0, 0, e^d3, t3], [0, 0, 0, 1]], and
back: gradient steps on theta keep every mass positive and every inertia realisable.
"""
from __future__ import annotations

from typing import Sequence

import torch


def pseudo_inertia(params: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4): each body's pseudo-inertia J from its parameters (..., 10)."""
    _checked("pseudo_inertia", "params", params, (10,))
    m, h = params[..., 0], params[..., 1:4]
    xx, xy, yy, xz, yz, zz = params[..., 4:].unbind(-1)
    inertia = torch.stack([torch.stack([xx, xy, xz], -1), torch.stack([xy, yy, yz], -1),
                           torch.stack([xz, yz, zz], -1)], -2)
    trace = (xx + yy + zz)[..., None, None]
    sigma = 0.5 * trace * torch.eye(3, dtype=params.dtype, device=params.device) - inertia
    top = torch.cat([sigma, h.unsqueeze(-1)], -1)
    bottom = torch.cat([h, m.unsqueeze(-1)], -1).unsqueeze(-2)
    return torch.cat([top, bottom], -2)


def parameters_from_pseudo_inertia(J: torch.Tensor) -> torch.Tensor:
    """(..., 10): the parameters of the pseudo-inertias J (..., 4, 4); I = tr(Sigma) 1 - Sigma."""
    _checked("parameters_from_pseudo_inertia", "J", J, (4, 4))
    sigma = J[..., :3, :3]
    trace = sigma.diagonal(dim1=-2, dim2=-1).sum(-1, keepdim=True)
    inertia = trace.unsqueeze(-1) * torch.eye(3, dtype=J.dtype, device=J.device) - sigma
    upper = inertia[..., [0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]]
    return torch.cat([J[..., 3, 3:4], J[..., :3, 3], upper], -1)


def log_cholesky_to_parameters(theta: torch.Tensor) -> torch.Tensor:
    """(..., 10) physically consistent parameters from theta (..., 10) = [alpha, d1, d2, d3, s12, s23, s13,
    t1, t2, t3], any real values (differentiable)."""
    _checked("log_cholesky_to_parameters", "theta", theta, (10,))
    alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3 = theta.unbind(-1)
    zero, one = torch.zeros_like(alpha), torch.ones_like(alpha)
    U = torch.stack([torch.stack([d1.exp(), s12, s13, t1], -1), torch.stack([zero, d2.exp(), s23, t2], -1),
                     torch.stack([zero, zero, d3.exp(), t3], -1), torch.stack([zero, zero, zero, one], -1)], -2)
    U = alpha.exp()[..., None, None] * U
    return parameters_from_pseudo_inertia(U @ U.mT)


def parameters_to_log_cholesky(params: torch.Tensor) -> torch.Tensor:
    """theta (..., 10) with log_cholesky_to_parameters(theta) = params, for parameters (..., 10) whose
    pseudo-inertia is positive definite (a positive mass, an inertia strictly within its triangle
    inequalities); raises ValueError otherwise."""
    _checked("parameters_to_log_cholesky", "params", params, (10,))
    J = pseudo_inertia(params)
    flip = torch.arange(3, -1, -1, device=params.device)
    L, info = torch.linalg.cholesky_ex(J[..., flip, :][..., :, flip])  # J = U U^T, U upper: flipped Cholesky
    if bool((info != 0).any()):
        raise ValueError("parameters_to_log_cholesky: a pseudo-inertia is not positive definite (a massless body, "
                         "or an inertia on its triangle inequality's boundary); check_physical names it")
    U = L[..., flip, :][..., :, flip]
    scale = U[..., 3, 3]
    V = U / scale[..., None, None]
    return torch.stack([scale.log(), V[..., 0, 0].log(), V[..., 1, 1].log(), V[..., 2, 2].log(), V[..., 0, 1],
                        V[..., 1, 2], V[..., 0, 2], V[..., 0, 3], V[..., 1, 3], V[..., 2, 3]], -1)


def _checked(function: str, name: str, x, trailing: tuple[int, ...]) -> None:
    """Refuses x unless a float tensor (..., *trailing), naming it (an integer one gave float32 results, a wrong
    size an unpacking error)."""
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{function}: {name} must be a torch.Tensor, got {type(x).__name__}")
    if not x.is_floating_point():
        raise TypeError(f"{function}: {name} must be a float tensor, got {x.dtype}")
    if tuple(x.shape[max(0, x.dim() - len(trailing)):]) != trailing:
        want = ", ".join(["..."] + [str(n) for n in trailing])
        raise ValueError(f"{function}: {name} must have shape ({want}), got {tuple(x.shape)}")


def check_physical(params: torch.Tensor, names: Sequence[str], tolerance: float = 1e-10,
                   parents: Sequence[int] | None = None, op: str = "with_parameters") -> None:
    """Raise ValueError naming the first body whose parameters (..., nbodies, 10) are not physically
    consistent: a parameter that is not finite, a negative mass, a massless body with a first moment or
    an inertia, or a pseudo-inertia with an eigenvalue below -tolerance times its largest entry (the
    inertia about the centre of mass not positive, or a triangle inequality broken). names: the bodies'
    (their joints') names. With `parents` (each body's parent index, -1 for the world), also a joint
    whose bodies, its own and all below it, have no mass: the joint-space inertia matrix is then
    singular at every configuration. op: the function whose argument params is, named in the error."""
    p = params.detach().to(torch.float64)
    finite = torch.isfinite(p).all(-1).reshape(-1, p.shape[-2]).all(0)  # per body, over the batch
    for body, name in enumerate(names):
        if not bool(finite[body]):
            raise ValueError(f"{op}: params: body {body} ({name!r}) has a parameter that is not finite (nan or inf)")
    J = pseudo_inertia(p)
    eigenvalues = torch.linalg.eigvalsh(J)
    scale = J.abs().amax((-2, -1)).clamp_min(torch.finfo(torch.float64).tiny)
    for body, name in enumerate(names):
        mass = p[..., body, 0]
        if bool((mass < 0).any()):
            raise ValueError(f"{op}: params: body {body} ({name!r}) has a negative mass, {float(mass.min()):.6g}")
        if bool(((mass == 0) & (p[..., body, 1:] != 0).any(-1)).any()):
            raise ValueError(f"{op}: params: body {body} ({name!r}) has no mass but a first moment or a rotational "
                             "inertia, which only mass can have")
        ratios = eigenvalues[..., body, 0] / scale[..., body]
        worst = ratios.min() if ratios.numel() else 0.0  # an empty batch has nothing to refuse
        if float(worst) < -tolerance:
            raise ValueError(f"{op}: params: body {body} ({name!r}) is not physically consistent: its pseudo-inertia "
                             f"has a negative eigenvalue ({float(worst):.3g} of its largest entry), so its "
                             "inertia about the centre of mass is not positive or breaks a triangle inequality")
    if parents is not None:
        moved = p[..., 0].clone()  # mass each joint moves: its body's and its descendants'
        for body in reversed(range(len(names))):
            if parents[body] >= 0:
                moved[..., parents[body]] += moved[..., body]
        for body, name in enumerate(names):
            if bool((moved[..., body] == 0).any()):
                raise ValueError(f"{op}: params: joint {name!r} (body {body}) moves no mass (its body and those below "
                                 "it are massless), so the joint-space inertia matrix is singular")
