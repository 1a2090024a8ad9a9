"""The step functions over the grid a user meets: every integrator x fixed, planar and free roots x
unbatched, batched and broadcast inputs x with and without grad x both conventions, for step,
step_derivatives, step_second_derivatives and horizon, each sample equal to the same call on that
sample alone (the kernel path, nothing requiring grad)."""
from __future__ import annotations

import pytest
import torch

from oracles import rel_err
from torch_grid.step.integrators import INTEGRATORS

# the leading batch shapes of (q, qd, tau)
SHAPES = {"unbatched": ((), (), ()), "batched": ((3,), (3,), (3,)), "broadcast": ((3,), (1,), ())}


def _inputs(view, nv, shapes, seed):
    g = torch.Generator().manual_seed(seed)
    q = view.random_configuration(*shapes[0], generator=g)
    qd, tau = (torch.randn(*shape, nv, dtype=torch.float64, generator=g) for shape in shapes[1:])
    return q, qd, tau


def _sample(x, batch, k):
    """Sample k of x broadcast to the batch shape (x itself when unbatched)."""
    return x.expand(*batch, x.shape[-1])[k] if batch else x


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("shape", list(SHAPES))
@pytest.mark.parametrize("root", ["fixed", "planar", "free"])
def test_step_grid(step_roots, root, shape, convention):
    robot = step_roots[root]
    view = getattr(robot, convention)
    q, qd, tau = _inputs(view, robot.nv, SHAPES[shape], 17)
    batch = torch.broadcast_shapes(q.shape[:-1], qd.shape[:-1], tau.shape[:-1])
    samples = range(batch.numel()) if batch else [None]
    dt = 0.01
    for integrator in INTEGRATORS:
        refs = []
        for k in samples:
            one = [_sample(x, batch, k) for x in (q, qd, tau)]
            refs.append((*view.step(*one, dt, integrator), *view.step_derivatives(*one, dt, integrator),
                         view.step_second_derivatives(*one, dt, integrator)))
        for grad in (False, True):
            args = [q, qd, tau.clone().requires_grad_(grad)]
            out = (*view.step(*args, dt, integrator), *view.step_derivatives(*args, dt, integrator))
            horizon = view.horizon(*(x.unsqueeze(-2) for x in args), dt, integrator)
            out_h = tuple(horizon[key].squeeze(-3 if key in ("A", "B") else -2) for key in ("q_next", "qd_next", "A", "B"))
            if grad:
                with pytest.raises(NotImplementedError, match="step_second_derivatives has no derivative"):
                    view.step_second_derivatives(*args, dt, integrator)
                (out[1].sum() + out[2].sum()).backward()  # the composition has a backward
                assert torch.isfinite(args[2].grad).all()
            else:
                out = out + (view.step_second_derivatives(*args, dt, integrator),)
            for k, ref in zip(samples, refs):
                for ours, theirs in ((out, ref), (out_h, ref[:4])):
                    for x, r in zip(ours, theirs):
                        assert x.shape == batch + r.shape, (integrator, grad)
                        assert rel_err(x[k] if batch else x, r) <= 1e-11, (integrator, grad)
