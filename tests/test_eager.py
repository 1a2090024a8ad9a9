"""Eager reverse mode through the ops' own autograd.Functions (torch_grid/ops/eager.py) against the ops'
registered autograd (what torch.compile traces): the same formulas, so the same gradients, first order and
double backward (create_graph), both conventions, a fixed base and a free joint, broadcast batches; a
TorchDispatchMode still sees every kernel call; the argument errors keep their wording; an op without a
derivative still refuses to be differentiated."""
from __future__ import annotations

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

ROBOTS = ["iiwa14", "go2"]


def _calls(view):
    """(name, function of the robot, the same through the registered op, the inputs' shapes but q's)."""
    ops, c = view._robot._ops, view._convention
    frame = view._robot.nframes - 1
    return [
        ("inverse_dynamics", view.inverse_dynamics, lambda q, qd, x: ops.inverse_dynamics(q, qd, x, None, None, c)),
        ("forward_dynamics", view.forward_dynamics, lambda q, qd, x: ops.forward_dynamics(q, qd, x, None, None, c)),
        ("crba", lambda q, qd, x: view.crba(q), lambda q, qd, x: ops.crba(q, None, c)),
        ("frame_jacobian", lambda q, qd, x: view.frame_jacobian(q, frame, "world"),
         lambda q, qd, x: ops.frame_jacobian(q, frame, 0, c)),
        ("energy", lambda q, qd, x: view.energy(q, qd), lambda q, qd, x: ops.energy(q, qd, None, c)),
    ]


def _inputs(robot, view, g):
    q = view.random_configuration(2, 3, generator=g)
    qd = torch.randn(3, robot.nv, dtype=torch.float64, generator=g)  # broadcast against q's (2, 3)
    x = torch.randn(2, 1, robot.nv, dtype=torch.float64, generator=g)
    return [t.requires_grad_() for t in (q, qd, x)]


def _grads(fn, inputs, weights, create_graph):
    outs = fn(*inputs)
    outs = outs if isinstance(outs, tuple) else (outs,)
    loss = sum((o * w).sum() for o, w in zip(outs, weights))
    return torch.autograd.grad(loss, inputs, create_graph=create_graph, allow_unused=True)


def _close(a, b):
    if a is None or b is None:
        assert a is None and b is None
        return
    torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ROBOTS)
def test_eager_gradients_are_the_registered_autograds(robots, name):
    robot = robots[name]
    g = torch.Generator().manual_seed(11)
    for view in (robot.pin, robot.mujoco):
        inputs = _inputs(robot, view, g)
        for op, eager, registered in _calls(view):
            outs = eager(*inputs)
            outs = outs if isinstance(outs, tuple) else (outs,)
            assert all(o.grad_fn is not None and o.grad_fn.name().startswith(f"{op}_eager") for o in outs), op
            weights = [torch.randn(o.shape, dtype=torch.float64, generator=g) for o in outs]
            for a, b in zip(_grads(eager, inputs, weights, False), _grads(registered, inputs, weights, False)):
                _close(a, b)
            # double backward: the gradients' own gradients along a direction, through both paths
            first = [_grads(f, inputs, weights, True) for f in (eager, registered)]
            direction = [torch.randn(t.shape, dtype=torch.float64, generator=g) for t in inputs]
            if op in ("crba", "frame_jacobian"):  # ² functions: their backward has no derivative of its own
                continue
            second = [torch.autograd.grad(sum((d * t).sum() for d, t in zip(direction, f) if t is not None), inputs,
                                          allow_unused=True) for f in first]
            for a, b in zip(*second):
                _close(a, b)


class _Spy(TorchDispatchMode):
    def __init__(self):
        super().__init__()
        self.names: list[str] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.names.append(func.name().split("::")[-1])
        return func(*args, **(kwargs or {}))


def test_a_dispatch_mode_sees_the_kernels_forward_and_backward(robots):
    robot = robots["go2"]
    q, qd, x = _inputs(robot, robot.pin, torch.Generator().manual_seed(12))
    with _Spy() as spy:
        tau = robot.inverse_dynamics(q, qd, x)
        torch.autograd.grad(tau.sum(), (q, qd, x))
    assert {"inverse_dynamics", "inverse_dynamics_vjp_full", "tangent_to_ambient"} <= set(spy.names), spy.names


def test_argument_errors_are_worded_under_grad(robots):
    robot = robots["iiwa14"]
    q, qd, x = _inputs(robot, robot.pin, torch.Generator().manual_seed(13))
    with pytest.raises(ValueError, match=r"inverse_dynamics: qd must have shape \(\.\.\., 7\), got \(3, 6\)"):
        robot.inverse_dynamics(q, qd[:, :6], x)
    with pytest.raises(ValueError, match="leading batch shapes do not broadcast"):
        robot.inverse_dynamics(q, torch.zeros(4, 7, dtype=torch.float64, requires_grad=True), x)


def test_an_op_without_a_derivative_refuses_a_backward(robots):
    robot = robots["iiwa14"]
    q, qd, x = _inputs(robot, robot.pin, torch.Generator().manual_seed(14))
    dA, _ = robot.inverse_dynamics_derivatives(q, qd, x)
    gq, = torch.autograd.grad(dA.sum(), q, create_graph=True)
    with pytest.raises(NotImplementedError, match="no derivative"):
        torch.autograd.grad(gq.sum(), q)


@pytest.mark.parametrize("name", ["go2", "damped_planar"])
def test_inverse_dynamics_plain_backward_is_the_differentiable_one(robots, name):
    """A plain backward of inverse_dynamics takes qdd's gradient from its vector-Jacobian product's pass on a
    robot without rotor armature (go2), and from M with it (damped_planar: that pass's M is the bodies' alone);
    a differentiable backward (create_graph) builds M: the gradients agree, both conventions."""
    robot = robots[name]
    g = torch.Generator().manual_seed(15)
    for view in (robot.pin, robot.mujoco):
        inputs = _inputs(robot, view, g)
        tau = view.inverse_dynamics(*inputs)
        w = torch.randn(tau.shape, dtype=torch.float64, generator=g)
        with _Spy() as spy:
            plain = torch.autograd.grad((tau * w).sum(), inputs, retain_graph=True)
        assert ("inverse_dynamics_vjp_full" in spy.names) == (name == "go2"), spy.names
        differentiable = torch.autograd.grad((tau * w).sum(), inputs, create_graph=True)
        for a, b in zip(plain, differentiable):
            _close(a, b.detach())
