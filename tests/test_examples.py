"""The examples run (shortened) and do what they print: iLQR lowers the cost on iiwa14 and go2, the
policy's loss falls through back-propagation over the dynamics, the compiled rollout equals eager, system
identification recovers a payload, computed-torque control tracks its trajectory, every example takes
--device, and the package's demo agrees with its oracles."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch

import torch_grid

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
sys.path.insert(0, str(EXAMPLES))

import computed_torque  # noqa: E402
import ilqr  # noqa: E402
import policy_rollout  # noqa: E402
import system_identification  # noqa: E402


def test_horizon_is_the_per_knot_calls(robots):
    """One horizon call over (B, T) equals step, step_derivatives and the costs at each knot."""
    robot = robots["go2"]
    view, nv = robot.mujoco, robot.nv
    g = torch.Generator().manual_seed(0)
    q = view.random_configuration(2, 3, generator=g)
    qd, tau = (torch.randn(2, 3, nv, dtype=torch.float64, generator=g) for _ in range(2))
    costs = [("state_cost", {"q_ref": view.neutral_configuration(), "qd_ref": torch.zeros(nv, dtype=torch.float64),
                             "weights": torch.ones(2 * nv, dtype=torch.float64)}),
             ("control_cost", {"tau_ref": torch.zeros(nv, dtype=torch.float64), "weights": torch.ones(nv, dtype=torch.float64)})]
    out = view.horizon(q, qd, tau, 0.02, "rk4", costs)
    q_next, qd_next = view.step(q, qd, tau, 0.02, "rk4")
    assert torch.allclose(out["q_next"], q_next, rtol=1e-14, atol=1e-14)
    assert torch.allclose(out["qd_next"], qd_next, rtol=1e-14, atol=1e-14)
    for t in range(3):
        A, B = view.step_derivatives(q[:, t], qd[:, t], tau[:, t], 0.02, "rk4")
        assert torch.allclose(out["A"][:, t], A, rtol=1e-12, atol=1e-12) and torch.allclose(out["B"][:, t], B, rtol=1e-12, atol=1e-12)
        state = view.state_cost(q[:, t], qd[:, t], **costs[0][1])
        control = view.control_cost(tau[:, t], **costs[1][1])
        assert torch.allclose(out["cost"][:, t], state[0] + control[0], rtol=1e-12)
        assert torch.allclose(out["lx"][:, t], state[1], rtol=1e-12) and torch.allclose(out["luu"][:, t], control[2])
    assert out["lxu"].shape == (2, 3, 2 * nv, nv) and not out["lxu"].any()
    with pytest.raises(ValueError, match="horizon: costs must name one of"):
        view.horizon(q, qd, tau, 0.02, costs=[("torque_cost", {})])
    # one (name, kwargs) pair where a list of them is expected raised Python's "too many values to unpack"
    with pytest.raises(TypeError, match=r"horizon: costs must be a sequence of \(name, keyword arguments\) pairs.*"
                                        r"got an entry 'control_cost'"):
        view.horizon(q, qd, tau, 0.02, costs=costs[1])
    # one knot without a batch dimension: the same numbers up to the order of a product's terms (torch's
    # matrix-vector and batched products may sum in different orders: 6e-17 apart on lx on one CPU)
    single = view.horizon(q[0, 0], qd[0, 0], tau[0, 0], 0.02, "rk4", costs)
    for k in out:
        assert single[k].shape == out[k][0, 0].shape and torch.allclose(single[k], out[k][0, 0], rtol=1e-14, atol=1e-15), k


def test_horizon_outputs_share_the_batch_of_the_cost_references(robots):
    """One trajectory against a batch of state references: every output of the horizon call has the references'
    batch (A and B the trajectory's at each sample), as the per-sample calls would."""
    robot = robots["go2"]
    view, nv = robot.pin, robot.nv
    g = torch.Generator().manual_seed(1)
    q = view.random_configuration(3, generator=g)
    qd, tau = (torch.randn(3, nv, dtype=torch.float64, generator=g) for _ in range(2))
    refs = view.random_configuration(4, 1, generator=g)  # (4, 1, nq) against the knots (3,)
    costs = [("state_cost", {"q_ref": refs, "qd_ref": torch.zeros(nv, dtype=torch.float64),
                             "weights": torch.ones(2 * nv, dtype=torch.float64)})]
    out = view.horizon(q, qd, tau, 0.02, "semi_implicit_euler", costs)
    assert {k: tuple(x.shape[:2]) for k, x in out.items()} == {k: (4, 3) for k in out}, {k: x.shape for k, x in out.items()}
    for b in range(4):
        one = view.horizon(q, qd, tau, 0.02, "semi_implicit_euler", [("state_cost", {**costs[0][1], "q_ref": refs[b]})])
        for k in one:
            assert torch.equal(out[k][b], one[k]), k


@pytest.mark.parametrize("problem", ["reach", "balance"])
def test_ilqr_example_lowers_the_cost(problem):
    """The cost falls; every iteration reports the step sizes accepted, and the last line the outcome."""
    lines = []
    costs = getattr(ilqr, problem)(batch=4, T=30, iterations=4, log=lines.append)
    assert all(b <= a for a, b in zip(costs, costs[1:])) and costs[-1] < 0.5 * costs[0]
    iterations = [line for line in lines if line.startswith("iteration")]
    assert len(iterations) == len(costs) and all("step (samples): " in line for line in iterations[1:])
    if problem == "balance":  # close to its linearization: converged within the four iterations
        assert len(costs) < 5 and lines[-1].startswith("converged after")
    else:
        assert lines[-1].startswith(("converged after", "stopped at the iteration limit (4)"))


def test_ilqr_example_reports_a_stalled_line_search(monkeypatch):
    """A trial cost that never falls (here made so): the line search fails for every sample and iLQR stops."""
    total_cost, calls = ilqr.total_cost, []

    def rising(*args, **kwargs):
        calls.append(None)
        return total_cost(*args, **kwargs) + 1e9 * (len(calls) > 1)  # every trial above the first rollout's cost

    monkeypatch.setattr(ilqr, "total_cost", rising)
    lines = []
    costs = ilqr.reach(batch=2, T=5, iterations=3, log=lines.append)
    assert len(costs) == 2 and costs[1] == costs[0]
    assert lines[-2].endswith("step (samples): line search failed (2)")
    assert lines[-1] == ("stalled after 1 iteration: the line search found no decrease for 2 of 2 samples "
                         "(step sizes 1, 0.5, 0.25, 0.1); 0 converged")


def test_ilqr_riccati_pass_flags_a_quu_that_is_not_positive_definite(monkeypatch):
    """The pass marks the samples whose Quu has no Cholesky factor (without waiting on the device), and iLQR
    stops there with an error that says how many."""
    B, T, nv = 3, 4, 2
    luu = torch.eye(nv, dtype=torch.float64).repeat(B, T, 1, 1)
    luu[1, 2] = -luu[1, 2]  # sample 1, knot 2: negative definite
    zeros = lambda *shape: torch.zeros(B, T, *shape, dtype=torch.float64)  # noqa: E731
    h = {"A": zeros(2 * nv, 2 * nv), "B": zeros(2 * nv, nv), "lx": zeros(2 * nv) + 1, "lu": zeros(nv) + 1,
         "lxx": zeros(2 * nv, 2 * nv), "luu": luu, "lxu": zeros(2 * nv, nv)}
    K, k, failed = ilqr.backward_pass(h, torch.zeros(B, 2 * nv, dtype=torch.float64),
                                      torch.zeros(B, 2 * nv, 2 * nv, dtype=torch.float64), 1e-6)
    assert failed.tolist() == [False, True, False]
    torch.testing.assert_close(k[0][0], -torch.ones(nv, dtype=torch.float64) / (1 + 1e-6))  # Quu = (1 + reg) I

    backward_pass = ilqr.backward_pass
    monkeypatch.setattr(ilqr, "backward_pass", lambda *args: (*backward_pass(*args)[:2], torch.tensor([False, True])))
    with pytest.raises(torch.linalg.LinAlgError, match="iteration 1: Quu is not positive definite for 1 of 2 samples"):
        ilqr.reach(batch=2, T=5, iterations=2, log=lambda *_: None)


def test_policy_example_learns_and_compiles():
    values = policy_rollout.main(batch=16, updates=6, log=lambda *_: None)
    losses, (eager, compiled) = values[:-2], values[-2:]
    assert losses[-1] < losses[0]
    assert abs(compiled - eager) <= 1e-10 * abs(eager)


def test_system_identification_recovers_the_payload():
    """Least squares on the regressor and gradient descent through forward dynamics find the 2.5 kg payload
    from noisy torques; the consistent fit of the last link lowers its loss; randomised plants spread."""
    result = system_identification.main(samples=128, steps=150, log=lambda *_: None)
    assert abs(result["least_squares"] - 2.5) < 0.005
    assert abs(result["gradient_descent"] - 2.5) < 0.03
    losses = result["last_link_losses"]
    assert losses[-1] < 0.02 * losses[0]
    spread = result["rollout_errors"]
    assert torch.isfinite(spread).all() and spread.max() > 2 * spread.min()


def test_computed_torque_tracks_the_trajectory():
    """The tracking error falls from the random start's to well below it within half a second."""
    errors = computed_torque.main(batch=8, steps=500, log=lambda *_: None)
    assert len(errors) == 3 and errors[-1] < 1e-3 * errors[0], errors


@pytest.mark.parametrize("example", sorted(p.stem for p in EXAMPLES.glob("*.py")))
def test_every_example_takes_a_device(example):
    """The docs say each example takes --device cuda: each one's command line has the option."""
    help_text = subprocess.run([sys.executable, str(EXAMPLES / f"{example}.py"), "--help"], capture_output=True,
                               text=True, check=True, timeout=120).stdout
    assert "--device" in help_text, help_text


def test_demo_runs_and_matches_the_oracles(capsys):
    """`python -m torch_grid.demo`, the README's first command, on a small batch: every bundled robot's
    functions run, and its sample check against Pinocchio or MuJoCo agrees."""
    import re

    from torch_grid import demo

    demo.main(["--batch", "4", "--device", "cpu"])
    errors = re.findall(r"max relative error (\S+)", capsys.readouterr().out)
    assert len(errors) == len(torch_grid.BUNDLED) and all(float(e) <= 1e-10 for e in errors), errors
