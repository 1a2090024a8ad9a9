"""torch_grid.optim.mpc_adapter.MPCDynamics with mpc.pytorch (GradMethods.ANALYTIC): its R, S are the
Jacobians of its forward in x's own coordinates (against autograd, with non-unit quaternions), they
have a backward, and mpc.pytorch's solve and its gradients with them equal those with AUTO_DIFF."""
from __future__ import annotations

import pytest
import torch
from mpc import mpc

from oracles import rel_err
from torch_grid.optim.mpc_adapter import MPCDynamics


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["iiwa14", "go2"])
def test_grad_input_is_the_jacobian(robots, name, convention):
    robot = robots[name]
    view = getattr(robot, convention)
    dyn = MPCDynamics(view, 0.02, "rk4")
    g = torch.Generator().manual_seed(0)
    q = 1.1 * view.random_configuration(2, generator=g)
    x = torch.cat([q, torch.randn(2, robot.nv, dtype=torch.float64, generator=g)], dim=-1)
    u = torch.randn(2, robot.nv, dtype=torch.float64, generator=g)
    R, S = dyn.grad_input(x, u)
    jx, ju = torch.autograd.functional.jacobian(dyn, (x, u))
    assert rel_err(R, torch.stack([jx[k, :, k] for k in range(2)])) <= 1e-12
    assert rel_err(S, torch.stack([ju[k, :, k] for k in range(2)])) <= 1e-12


def test_grad_input_has_a_backward(robots):
    robot = robots["iiwa14"]
    dyn = MPCDynamics(robot.pin, 0.05)
    g = torch.Generator().manual_seed(1)
    x = torch.cat([robot.random_configuration(1, generator=g), torch.randn(1, robot.nv, dtype=torch.float64, generator=g)],
                  dim=-1).requires_grad_(True)
    u = torch.randn(1, robot.nv, dtype=torch.float64, generator=g).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x, u: dyn.grad_input(x, u), (x, u))


def test_a_state_of_another_size_is_refused_naming_x(robots):
    # one entry short was reported as step's qd (..., 7), an argument the caller never passed
    robot = robots["iiwa14"]
    dyn = MPCDynamics(robot.pin, 0.05)
    x, u = torch.zeros(2, robot.nq + robot.nv - 1, dtype=torch.float64), torch.zeros(2, robot.nv, dtype=torch.float64)
    for method in ("forward", "grad_input"):
        with pytest.raises(ValueError, match=rf"MPCDynamics.{method}: x must have shape \(\.\.\., nq \+ nv = 14\), got \(2, 13\)"):
            getattr(dyn, method)(x, u)


def test_mpc_pytorch_solve_and_gradients_match_autodiff(robots):
    """A joint-space goal for two iiwa14 arms over 10 knots: the solution and d(final q)/d(goal) with
    ANALYTIC (our R, S and their backward) against AUTO_DIFF (autograd through forward)."""
    robot = robots["iiwa14"]
    view, nv = robot.pin, robot.nv
    n, batch, T = 2 * nv, 2, 10
    g = torch.Generator().manual_seed(2)
    q0 = view.random_configuration(batch, generator=g)
    x0 = torch.cat([q0, torch.zeros(batch, nv, dtype=torch.float64)], dim=-1)
    C = torch.diag(torch.cat([torch.ones(nv), 0.01 * torch.ones(nv), 1e-3 * torch.ones(nv)])).double()
    C = C.expand(T, batch, n + nv, n + nv)
    results = []
    for method in (mpc.GradMethods.ANALYTIC, mpc.GradMethods.AUTO_DIFF):
        goal = (q0 + 0.3).requires_grad_(True)
        target = torch.cat([goal, torch.zeros(batch, nv, dtype=torch.float64), view.generalized_gravity(q0)], dim=-1)
        c = -(C[0] @ target.unsqueeze(-1)).squeeze(-1).expand(T, batch, n + nv)
        solver = mpc.MPC(n, nv, T, lqr_iter=30, grad_method=method, exit_unconverged=False, detach_unconverged=False,
                         verbose=-1, eps=1e-8)
        x, u, _ = solver(x0, mpc.QuadCost(C, c), MPCDynamics(view, 0.05))
        x[-1, :, :nv].sum().backward()
        results.append((x.detach(), goal.grad))
    (x_a, g_a), (x_b, g_b) = results
    assert (x_a[-1, :, :nv] - q0 - 0.3).abs().max() < 0.3  # moved toward the goal
    assert rel_err(x_a, x_b) <= 1e-8 and rel_err(g_a, g_b) <= 1e-6
