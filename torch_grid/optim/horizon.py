"""Horizon calls: every knot of a batch of trajectories in one call, what an LQR/DDP backward pass reads.

States and controls carry a knot axis T among their leading dimensions, (..., T, nq), (..., T, nv); the
step, its derivatives and the costs are batched over it (no Python loop over T).
"""
from __future__ import annotations

import reprlib
from typing import Sequence

import torch

STATE_COSTS = ("state_cost", "frame_translation_cost", "frame_placement_cost", "com_cost", "momentum_cost")
CONTROL_COSTS = ("control_cost",)


class HorizonFunctions:
    """The horizon call of a robot's views (mixed into robot._Functions)."""

    def horizon(self, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, dt, integrator: str = "semi_implicit_euler",
                costs: Sequence[tuple[str, dict]] = (), step_hessian: bool = False,
                f_ext: torch.Tensor | None = None, params: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Per knot: the next state, the step's Jacobians A, B (and, with step_hessian, its Hessian) and the
        sum of the listed costs with its derivatives.

        q (..., T, nq), qd and tau (..., T, nv); dt a number or a (..., T) tensor. costs: (name, keyword
        arguments) of the state costs (STATE_COSTS, taking (q, qd, **kwargs)) and control costs
        (CONTROL_COSTS, taking (tau, **kwargs)); their references and weights broadcast against (..., T).
        Returns a dict with the keys q_next, qd_next, A (..., T, 2nv, 2nv), B (..., T, 2nv, nv),
        [H (..., T, 2nv, 3nv, 3nv)], cost (..., T), lx (..., T, 2nv), lu (..., T, nv), lxx (..., T, 2nv, 2nv),
        luu (..., T, nv, nv) and lxu (..., T, 2nv, nv) (zero: no listed cost couples state and control), all on
        the batch of the states and the costs' arguments together. params: the inertial
        parameters (..., nbodies, 10), broadcast against (..., T) as the states, as in inverse_dynamics.
        """
        if params is not None:
            return self._with(params, "horizon").horizon(q, qd, tau, dt, integrator, costs, step_hessian, f_ext)
        q_next, qd_next, A, B = self._step_and_derivatives(q, qd, tau, dt, integrator, f_ext, "horizon")
        out = {"q_next": q_next, "qd_next": qd_next, "A": A, "B": B}
        if step_hessian:
            out["H"] = self.step_second_derivatives(q, qd, tau, dt, integrator, f_ext)
        nv, batch = qd.shape[-1], A.shape[:-2]
        zeros = {"cost": (), "lx": (2 * nv,), "lu": (nv,), "lxx": (2 * nv, 2 * nv), "luu": (nv, nv), "lxu": (2 * nv, nv)}
        terms = {k: torch.zeros((*batch, *shape), dtype=qd.dtype, device=qd.device) for k, shape in zeros.items()}
        for entry in costs:
            if not (isinstance(entry, (tuple, list)) and len(entry) == 2 and isinstance(entry[1], dict)):
                raise TypeError("horizon: costs must be a sequence of (name, keyword arguments) pairs, such as "
                                f"[('control_cost', dict(tau_ref=..., weights=...))], got an entry {reprlib.repr(entry)}")
            name, kwargs = entry
            if name in STATE_COSTS:
                value, grad, hess = getattr(self, name)(q, qd, **kwargs)
                keys = ("cost", "lx", "lxx")
            elif name in CONTROL_COSTS:
                value, grad, hess = getattr(self, name)(tau, **kwargs)
                keys = ("cost", "lu", "luu")
            else:
                raise ValueError(f"horizon: costs must name one of {STATE_COSTS + CONTROL_COSTS}, got {name!r}")
            for key, x in zip(keys, (value, grad, hess)):
                terms[key] = terms[key] + x
        # every output on one batch shape: a cost's references or weights may carry a batch beyond the states'
        trailing = {"q_next": 1, "qd_next": 1, "A": 2, "B": 2, "H": 3, **{k: len(shape) for k, shape in zeros.items()}}
        result = {**out, **terms}
        shape = torch.broadcast_shapes(*(x.shape[:x.dim() - trailing[k]] for k, x in result.items()))
        return {k: x.expand((*shape, *x.shape[x.dim() - trailing[k]:])) for k, x in result.items()}
