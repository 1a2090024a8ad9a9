"""torch.compile of the plant step: one op per step in the graph (torch_grid/step_op.py), whatever the
root and the integrator, and a compiled rollout's values and gradients equal the eager ones."""
from __future__ import annotations

import pytest
import torch

from oracles import rel_err
from torch_grid.integrators import INTEGRATORS


def _state(view, nv, batch, seed):
    g = torch.Generator().manual_seed(seed)
    q = view.random_configuration(batch, generator=g)
    return q, torch.randn(batch, nv, dtype=torch.float64, generator=g), torch.randn(batch, nv, dtype=torch.float64,
                                                                                   generator=g)


@pytest.mark.parametrize("root", ["fixed", "planar", "free"])
def test_a_traced_step_is_a_few_ops(step_roots, root):
    """torch._dynamo.explain of one step: at most 25 graph nodes (the step op and the argument handling,
    where the composition is a couple of hundred) and no graph break, for every integrator, both
    conventions, with external forces."""
    robot = step_roots[root]
    for convention in ("pin", "mujoco"):
        view = getattr(robot, convention)
        q, qd, tau = _state(view, robot.nv, 4, 0)
        f_ext = torch.randn(4, robot.nbodies, 6, dtype=torch.float64)
        for integrator in INTEGRATORS:
            torch._dynamo.reset()
            explained = torch._dynamo.explain(lambda *x: view.step(*x, 0.01, integrator, f_ext))(q, qd, tau)
            assert explained.graph_break_count == 0 and explained.op_count <= 25, (integrator, explained.op_count)


@pytest.mark.parametrize("root,integrator,step", [("free", "semi_implicit_euler", 0.01), ("planar", "rk4", 0.001)])
def test_compiled_rollout_is_the_eager_one(step_roots, root, integrator, step):
    """A 5-step rollout of a linear policy with external forces, compiled with fullgraph=True: the cost
    and its gradients (policy weights, initial state, forces, a tensor dt) equal the eager ones, and a
    second batch size reuses the compiled step (dynamic shapes)."""
    robot = step_roots[root]
    view = robot.mujoco
    policy = torch.nn.Linear(robot.nq + robot.nv, robot.nv).double()
    with torch.no_grad():  # a gentle feedback: the rollout stays finite on the stiff springs
        policy.weight.mul_(0.1)

    def rollout(q, qd, f_ext, dt):
        cost = 0
        for _ in range(5):
            q, qd = view.step(q, qd, policy(torch.cat([q, qd], dim=-1)), dt, integrator, f_ext)
            cost = cost + (qd ** 2).sum() + (q ** 2).sum()
        return cost

    compiled = torch.compile(rollout, fullgraph=True, dynamic=True)
    for batch in (6, 3):
        q, qd, _ = _state(view, robot.nv, batch, batch)
        f_ext = 0.1 * torch.randn(batch, robot.nbodies, 6, dtype=torch.float64)
        results = []
        for fn in (rollout, compiled):
            dt = torch.tensor(step, dtype=torch.float64, requires_grad=True)  # RK4 is stable on the springs below 2 ms
            inputs = [x.clone().requires_grad_() for x in (q, qd, f_ext)] + [dt]
            policy.zero_grad()
            cost = fn(*inputs)
            cost.backward()
            results.append([cost.detach()] + [x.grad for x in inputs] + [p.grad.clone() for p in policy.parameters()])
        assert all(torch.isfinite(x).all() for x in results[0])
        for ours, ref in zip(results[1], results[0]):
            assert rel_err(ours, ref) <= 1e-10
