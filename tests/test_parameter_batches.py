"""Inertial parameters with a batch of their own, through the paths that flatten or split the samples'
batch: the composed step derivatives (in pieces of CHUNK samples), horizon, the Runge-Kutta step
Hessian and MuJoCo's second-order inverse dynamics. Each sample computes with its own parameters (a
loop over samples is the oracle), and shapes that do not broadcast are refused on every path; and
what check=True refuses."""
from __future__ import annotations

import pytest
import torch

from test_parameters import other_parameters, own_parameters
from torch_grid import conventions as C
from torch_grid.step.integrators import CHUNK

TOL = dict(rtol=1e-12, atol=1e-12)


def _states(robot, batch, seed):
    g = torch.Generator().manual_seed(seed)
    q = robot.random_configuration(*batch, generator=g)
    qd, tau = (torch.randn(*batch, robot.nv, generator=g, dtype=torch.float64) for _ in range(2))
    return q, qd, tau


def _parameter_sets(robot, n):
    """n physically consistent parameter sets, each a different scaling of the robot's own bodies."""
    scale = 1 + 0.5 * torch.rand(n, robot.nbodies, 1, generator=torch.Generator().manual_seed(n), dtype=torch.float64)
    return own_parameters(robot) * scale


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_composed_step_derivatives_give_each_piece_its_parameters(robots, integrator):
    """Parameters that require grad take the composed path, which splits a batch above CHUNK samples into
    pieces: each sample's derivatives are the fused kernel's with its own parameters, and the gradient
    reaches every set."""
    robot = robots["iiwa14"]
    n = CHUNK + 44
    q, qd, tau = _states(robot, (n,), 1)
    pis = _parameter_sets(robot, n)
    fused = robot.step_derivatives(q, qd, tau, 0.01, integrator, params=pis)
    leaf = pis.clone().requires_grad_(True)
    composed = robot.step_derivatives(q, qd, tau, 0.01, integrator, params=leaf)
    for f, c in zip(fused, composed):
        assert torch.allclose(f, c.detach(), **TOL)
    sum(c.sum() for c in composed).backward()
    assert leaf.grad.shape == pis.shape and bool((leaf.grad.abs().sum((-2, -1)) > 0).all())
    # a parameter batch that does not broadcast against the states' is refused on both paths
    for params in (pis[:CHUNK], leaf[:CHUNK]):
        with pytest.raises(ValueError, match="broadcast"):
            robot.step_derivatives(q, qd, tau, 0.01, integrator, params=params)


def test_horizon_with_per_sample_parameters_that_require_grad(robots):
    """horizon's documented per-sample layout, params (S, 1, nbodies, 10) against states (S, T, ·), over
    more knots than one piece: the same as without grad, where the fused kernels run."""
    robot = robots["iiwa14"]
    samples, knots = 100, 3
    q, qd, tau = _states(robot, (samples, knots), 2)
    pis = _parameter_sets(robot, samples).unsqueeze(1)
    plain = robot.horizon(q, qd, tau, 0.01, params=pis)
    traced = robot.horizon(q, qd, tau, 0.01, params=pis.clone().requires_grad_(True))
    for key in ("q_next", "qd_next", "A", "B"):
        assert torch.allclose(plain[key], traced[key].detach(), **TOL), key


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_runge_kutta_step_hessian_with_batched_parameters(robots, convention):
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, tau = _states(robot, (2, 3), 3)
    if convention == "mujoco":
        q = C.q_pin_to_mujoco(q)
    pis = torch.stack([other_parameters(robot, seed=s) for s in range(3)])
    # states (2, 3) against parameters (3, ...): one set per column
    H = view.step_second_derivatives(q, qd, tau, 0.01, "rk4", params=pis)
    assert H.shape == (2, 3, 2 * robot.nv, 3 * robot.nv, 3 * robot.nv)
    for i in range(2):
        for k in range(3):
            single = view.step_second_derivatives(q[i, k], qd[i, k], tau[i, k], 0.01, "rk4", params=pis[k])
            assert torch.allclose(H[i, k], single, **TOL), (i, k)
    # one state against a batch of parameters
    H = view.step_second_derivatives(q[0, 0], qd[0, 0], tau[0, 0], 0.01, "rk4", params=pis)
    assert H.shape[0] == 3
    assert torch.allclose(H[2], view.step_second_derivatives(q[0, 0], qd[0, 0], tau[0, 0], 0.01, "rk4", params=pis[2]),
                          **TOL)
    with pytest.raises(ValueError, match="broadcast"):
        view.step_second_derivatives(q, qd, tau, 0.01, "rk4", params=torch.cat([pis, pis]))


def test_runge_kutta_step_hessian_in_pieces_gives_each_piece_its_parameters(robots, monkeypatch):
    """A batch above one piece of the Runge-Kutta step Hessian (here pieces of two samples, as a humanoid's
    are at the default size) with one parameter set per sample: each piece computes with its samples' sets."""
    import torch_grid.step.rk_hessian as rk_hessian

    robot = robots["go2"]
    nv = robot.nv
    q, qd, tau = _states(robot, (3,), 5)
    pis = torch.stack([other_parameters(robot, seed=s) for s in range(3)])
    monkeypatch.setattr(rk_hessian, "PIECE_BYTES", 2 * 8 * nv * (3 * nv) ** 2)
    H = robot.step_second_derivatives(q, qd, tau, 0.01, "midpoint", params=pis)
    for k in range(3):
        single = robot.step_second_derivatives(q[k], qd[k], tau[k], 0.01, "midpoint", params=pis[k])
        assert torch.allclose(H[k], single, **TOL), k


def test_mujoco_inverse_dynamics_second_derivatives_with_batched_parameters(robots):
    """MuJoCo's second-order inverse dynamics of a robot with a free joint (reframed from Pinocchio's):
    the parameters' batch is part of the result's."""
    robot = robots["go2"]
    q, qd, qdd = _states(robot, (3,), 4)
    q = C.q_pin_to_mujoco(q)
    pis = torch.stack([other_parameters(robot, seed=s) for s in range(2)]).unsqueeze(1)  # (2, 1, nbodies, 10)
    out = robot.mujoco.inverse_dynamics_second_derivatives(q, qd, qdd, params=pis)
    for j in range(2):
        for k in range(3):
            single = robot.mujoco.inverse_dynamics_second_derivatives(q[k], qd[k], qdd[k], params=pis[j, 0])
            for b, s in zip(out, single):
                assert b.shape[:2] == (2, 3)
                assert torch.allclose(b[j, k], s, **TOL), (j, k)


def test_check_refuses_what_no_body_can_be(robots):
    robot = robots["iiwa14"]
    pi = own_parameters(robot).clone()
    names = robot.body_names
    bad = pi.clone()
    bad[4, 6] = float("nan")
    with pytest.raises(ValueError, match=f"body 4 \\({names[4]!r}\\) has a parameter that is not finite"):
        robot.with_parameters(bad, check=True)
    bad = pi.clone()
    bad[2, :4] = 0.0  # no mass, no first moment, but a rotational inertia
    with pytest.raises(ValueError, match=f"body 2 \\({names[2]!r}\\) has no mass but a first moment or a rotational inertia"):
        robot.with_parameters(bad, check=True)
    # the last body massless: its joint moves nothing, M has a zero column
    bad = pi.clone()
    bad[-1] = 0.0
    with pytest.raises(ValueError, match=f"joint {names[-1]!r} \\(body {robot.nbodies - 1}\\) moves no mass"):
        robot.with_parameters(bad, check=True)
    # a massless body with a heavy child is fine: the joint moves the child
    ok = pi.clone()
    ok[-2] = 0.0
    robot.with_parameters(torch.stack([pi, ok]), check=True)


def test_functions_composed_in_torch_check_their_parameters(robots):
    """centroidal_map_derivatives and MuJoCo's second-order inverse dynamics of a robot with a free joint are
    composed in torch: their params (and f_ext) are refused as an op's are, naming the function and the
    argument, where a 1-d tensor had raised an IndexError and a batch that does not broadcast torch's own error."""
    robot = robots["go2"]
    q, qd, qdd = _states(robot, (4,), 5)
    q = C.q_pin_to_mujoco(q)
    pi = own_parameters(robot)
    calls = {"centroidal_map_derivatives": lambda p, f=None: robot.mujoco.centroidal_map_derivatives(q, params=p),
             "inverse_dynamics_second_derivatives":
                 lambda p, f=None: robot.mujoco.inverse_dynamics_second_derivatives(q, qd, qdd, f, params=p)}
    for name, call in calls.items():
        with pytest.raises(ValueError, match=rf"{name}: params must have shape \(\.\.\., 13, 10\), got \(130,\)"):
            call(pi.flatten())
        with pytest.raises(TypeError, match=f"{name}: params must be a torch.Tensor, got list"):
            call(pi.tolist())
        with pytest.raises(ValueError, match=rf"{name}: the leading batch shapes do not broadcast: q \(4,\), .*params \(3,\)"):
            call(pi.expand(3, *pi.shape))
    with pytest.raises(ValueError, match=r"inverse_dynamics_second_derivatives: f_ext must have shape \(\.\.\., 13, 6\)"):
        calls["inverse_dynamics_second_derivatives"](pi, torch.zeros(4, 12, 6, dtype=torch.float64))


def test_steps_name_themselves_in_a_params_error(robots):
    """step, its derivatives and the horizon take params through a view of them: a wrong shape's error names the
    function called, not with_parameters."""
    robot = robots["go2"]
    q, qd, tau = _states(robot, (2,), 7)
    bad = own_parameters(robot).flatten()
    calls = {"step": lambda: robot.step(q, qd, tau, 0.01, "rk4", params=bad),
             "step_derivatives": lambda: robot.step_derivatives(q, qd, tau, 0.01, "rk4", params=bad),
             "step_second_derivatives": lambda: robot.step_second_derivatives(q, qd, tau, 0.01, "euler", params=bad),
             "horizon": lambda: robot.horizon(q, qd, tau, 0.01, "euler", params=bad)}
    for name, call in calls.items():
        with pytest.raises(ValueError, match=rf"^{name}: params must be a tensor of shape \(\.\.\., 13, 10\), got \(130,\)"):
            call()


@pytest.mark.parametrize("integrator", ["euler", "rk4"])
def test_one_state_many_parameter_sets_that_require_grad(robots, integrator):
    """One state under a batch of parameter sets that require grad (the composed step): q' has the batch of
    the parameters, as the fused kernel's, and each is the step with its own set (explicit Euler's q' had
    kept the state's batch shape, (1, nq) for (3, nq))."""
    robot = robots["go2"]
    q, qd, tau = _states(robot, (1,), 6)
    pis = _parameter_sets(robot, 3)
    for call in (lambda p: robot.step(q, qd, tau, 0.01, integrator, params=p),
                 lambda p: (robot.horizon(q, qd, tau, 0.01, integrator, params=p)["q_next"],)):
        fused = call(pis)
        composed = call(pis.clone().requires_grad_(True))
        for f, c in zip(fused, composed):
            assert c.shape == f.shape == (3, f.shape[-1])
            assert torch.allclose(f, c.detach(), **TOL)
