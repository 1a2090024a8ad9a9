"""The step's entry points (step, step_derivatives, step_second_derivatives, horizon) refuse what they cannot take:
an unknown integrator, a malformed dt, f_ext or params, batches that do not broadcast, each error naming the
entry point and the argument, whichever path (kernel or composition) would run."""
from __future__ import annotations

import pytest
import torch


def _state(view, robot, batch, seed):
    g = torch.Generator().manual_seed(seed)
    q = view.random_configuration(batch, generator=g)
    qd, tau = (torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    return q, qd, tau


def test_unknown_integrator_is_refused(robots):
    robot = robots["iiwa14"]
    q, qd, tau = _state(robot.pin, robot, 1, 6)
    with pytest.raises(ValueError, match="integrator must be one of .* got 'rk5'"):
        robot.step(q, qd, tau, 0.01, "rk5")


@pytest.mark.parametrize("fn", ["step", "step_derivatives", "step_second_derivatives", "horizon"])
def test_malformed_dt_is_refused(robots, fn):
    """Each entry point names itself and dt, whatever dt is, before any kernel or torch op sees it."""
    robot = robots["iiwa14"]
    q, qd, tau = _state(robot.pin, robot, 3, 3)
    call = getattr(robot, fn)
    for dt, error, message in (("0.01", TypeError, "be a number or a tensor, got str"),
                               (None, TypeError, "got NoneType"), ([0.01], TypeError, "got list"),
                               (True, TypeError, "got bool"),
                               (torch.ones(2, dtype=torch.float64), ValueError, r"broadcasts with the batch shape .*, got shape \(2,\)"),
                               (torch.tensor(0.01), TypeError, "have q's dtype")):
        with pytest.raises(error, match=f"{fn}: dt must .*{message}"):
            call(q, qd, tau, dt, "rk4")


@pytest.mark.parametrize("fn", ["step", "step_derivatives", "step_second_derivatives", "horizon"])
def test_malformed_f_ext_and_params_are_refused_by_name(robots, fn):
    """f_ext and params, and a batch of them that does not broadcast, name the entry point, whichever path runs (a
    Runge-Kutta scheme's derivatives named their kernel, rk_step_derivatives, the composition under autograd
    forward_dynamics; a list f_ext raised an AttributeError in step_second_derivatives)."""
    robot = robots["go2"]
    q, qd, tau = (x.float() for x in _state(robot.pin, robot, 2, 5))
    call = getattr(robot, fn)
    f_ext = torch.zeros(2, robot.nbodies, 6)
    params = robot.inertial_parameters(dtype=torch.float32).reshape(robot.nbodies, 10)
    for kwargs, error, message in ((dict(f_ext=f_ext.double()), TypeError, "f_ext has dtype torch.float64 but q"),
                                   (dict(f_ext=f_ext.tolist()), TypeError, "f_ext must be a torch.Tensor, got list"),
                                   (dict(f_ext=f_ext[..., :5]), ValueError, r"f_ext must have shape \(\.\.\., 13, 6\)"),
                                   (dict(params=params.double()), TypeError, "params has dtype torch.float64 but q"),
                                   (dict(params=params.long()), TypeError, "params must be float32 or float64"),
                                   (dict(f_ext=f_ext[:1].expand(3, -1, -1)), ValueError,
                                    r"the batch shapes do not broadcast: q \(2,\), qd \(2,\), tau \(2,\), dt \(\), f_ext \(3,\)")):
        for grad in (False, True):
            if grad and fn == "step_second_derivatives":
                continue
            with pytest.raises(error, match=f"^{fn}: {message}"):
                call(q.clone().requires_grad_(grad), qd, tau, 0.01, "rk4", **kwargs)
