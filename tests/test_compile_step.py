"""torch.compile of the plant step: one op per step in the graph (torch_grid/step/compiled.py), whatever the
root and the integrator, and a compiled rollout's values and gradients equal the eager ones."""
from __future__ import annotations

import pytest
import torch

from oracles import rel_err
from torch_grid.step.integrators import INTEGRATORS


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


@pytest.mark.parametrize("root,integrator", [("free", "rk4"), ("planar", "semi_implicit_euler")])
def test_compiled_step_under_torch_func_is_the_eager_one(step_roots, root, integrator):
    """Compiled, the step under vmap (the op's vmap rule: vmapped and shared inputs, and a backward through
    it), torch.func.grad, jacrev, jvp and forward-mode dual tensors (the composition: the op has no rule for
    those) equals the eager step, where a step op without those rules returned a wrong tangent."""
    from torch.autograd import forward_ad

    robot = step_roots[root]
    view = robot.mujoco
    q, qd, tau = _state(view, robot.nv, 3, 7)
    f_ext = 0.1 * torch.randn(robot.nbodies, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(8))
    t = torch.randn_like(tau)

    def step(q, qd, tau):
        return view.step(q, qd, tau, 0.005, integrator, f_ext)

    def dual(q, qd, tau):
        with forward_ad.dual_level():
            out = step(q, qd, forward_ad.make_dual(tau, t))
            return [forward_ad.unpack_dual(x) for x in out]

    def vmap_backward(q, qd, tau):
        shared = tau[0].detach().requires_grad_()
        out = torch.func.vmap(step, in_dims=(None, 0, None))(q[0], qd, shared)
        return torch.autograd.grad((out[0].sin().sum() + out[1].sin().sum()), shared)

    transforms = {
        "vmap": lambda q, qd, tau: torch.func.vmap(step)(q, qd, tau),
        "vmap shared": lambda q, qd, tau: torch.func.vmap(step, in_dims=(None, 0, None))(q[0], qd, tau[0]),
        "vmap backward": vmap_backward,
        "grad": lambda q, qd, tau: torch.func.grad(lambda x: step(q, qd, x)[1].sin().sum())(tau),
        "jacrev": lambda q, qd, tau: torch.func.jacrev(lambda x, y: step(x, qd, y), argnums=(0, 1))(q, tau),
        "jvp": lambda q, qd, tau: torch.func.jvp(lambda x: step(q, qd, x), (tau,), (t,)),
        "dual": dual,
    }
    for name, fn in transforms.items():
        torch._dynamo.reset()
        eager = torch.utils._pytree.tree_leaves(fn(q, qd, tau.clone()))
        compiled = torch.utils._pytree.tree_leaves(torch.compile(fn)(q, qd, tau.clone()))
        assert len(compiled) == len(eager)
        for ours, ref in zip(compiled, eager):
            assert rel_err(ours, ref) <= 1e-12, name


def test_compiled_runge_kutta_jacobians_under_grad_are_the_eager_ones(step_roots):
    """step_derivatives of a Runge-Kutta scheme on a free root, its inputs requiring grad (the composition,
    whose carried velocities' Jacobians torch.func takes in reverse mode while compiling, forward mode
    otherwise): compiled with fullgraph=True, the values and the gradient equal eager's."""
    robot = step_roots["free"]
    view = robot.mujoco
    q, qd, tau = _state(view, robot.nv, 3, 4)
    tau.requires_grad_(True)

    def loss(q, qd, tau):
        A, B = view.step_derivatives(q, qd, tau, 0.01, "rk4")
        return A.square().sum() + B.sum()

    eager = loss(q, qd, tau)
    (grad,) = torch.autograd.grad(eager, tau)
    torch._dynamo.reset()
    compiled = torch.compile(loss, fullgraph=True, backend="aot_eager")(q, qd, tau)
    (compiled_grad,) = torch.autograd.grad(compiled, tau)
    assert rel_err(compiled.detach(), eager.detach()) <= 1e-12 and rel_err(compiled_grad, grad) <= 1e-11
