"""No silently wrong result: forward-mode AD refuses with the op's name; a free-flyer quaternion of
zero norm (below MuJoCo's mjMINVAL) reads as the identity (mj_normalizeQuat) in every function and
gradient, in both conventions, and one with a NaN or infinite entry is NaN wherever it matters."""
from __future__ import annotations

import pytest
import torch

from functions import FUNCTIONS
from test_autograd import _states


def _flat(out) -> torch.Tensor:
    return torch.cat([x.flatten(1) for x in (out if isinstance(out, tuple) else (out,))], 1)


def _base_quaternions(robot, convention: str, value: float) -> tuple[torch.Tensor, ...]:
    """(q, q at the identity quaternion, q with the quaternion (value, 0, 0, 0) in xyzw order)."""
    q, qd, x, f = _states(robot, 3, 4, convention)
    w = 3 if convention == "mujoco" else 6
    identity = q.clone()
    identity[..., 3:7] = 0.0
    identity[..., w] = 1.0
    degenerate = q.clone()
    degenerate[..., 3:7] = 0.0
    degenerate[..., 4] = value
    return q, identity, degenerate, qd, x, f


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("tiny", [0.0, 1e-16])
def test_zero_quaternion_reads_as_identity(robots, convention, tiny):
    robot = robots["go2"]
    view = getattr(robot, convention)
    _, identity, degenerate, qd, x, f = _base_quaternions(robot, convention, tiny)
    for name, (call, arity) in FUNCTIONS.items():
        got = _flat(call(view, robot, *(degenerate, qd, x, f)[:arity]))
        ref = _flat(call(view, robot, *(identity, qd, x, f)[:arity]))
        assert torch.isfinite(got).all(), f"{name}: non-finite output for a quaternion of norm {tiny}"
        assert torch.allclose(got, ref, rtol=1e-12, atol=1e-12), f"{name}: differs from the identity quaternion"


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_nonfinite_quaternion_is_nan_in_every_function(robots, convention, bad):
    """Every entry that the base orientation changes is non-finite (a diverged state is never read as a
    rotation); one that it leaves alone (Pinocchio's local velocities, M's zeros) keeps its value."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, identity, degenerate, qd, x, f = _base_quaternions(robot, convention, bad)
    for name, (call, arity) in FUNCTIONS.items():
        got = _flat(call(view, robot, *(degenerate, qd, x, f)[:arity]))
        ref = _flat(call(view, robot, *(identity, qd, x, f)[:arity]))
        turned = _flat(call(view, robot, *(q, qd, x, f)[:arity]))
        finite, moved = torch.isfinite(got), ~torch.isclose(ref, turned, rtol=1e-12, atol=1e-12)
        assert not (finite & moved).any(), f"{name}: a finite entry for a quaternion with {bad}"
        assert torch.allclose(got[finite], ref[finite], rtol=1e-12, atol=1e-12), name


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_zero_configuration_has_finite_gradients(robots, convention):
    robot = robots["go2"]
    view = getattr(robot, convention)
    q = torch.zeros(2, robot.nq, dtype=torch.float64, requires_grad=True)
    qd = torch.randn(2, robot.nv, dtype=torch.float64)
    tau = torch.randn(2, robot.nv, dtype=torch.float64)
    foot = next(i for i, f in enumerate(robot.model.frames) if f.parent == robot.nbodies - 1)  # moved by a leg
    for out in (view.forward_dynamics(q, qd, tau), view.crba(q), view.com(q), view.frame_jacobian(q, foot)):
        (grad,) = torch.autograd.grad(out.square().sum(), q)
        assert torch.isfinite(grad).all()
        assert grad[..., 7:].abs().sum() > 0  # the joints still get their gradient


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_second_order_tensors_refuse_forward_mode(robots, convention):
    """inverse_dynamics_second_derivatives and frame_kinematic_hessian have no forward mode (a third derivative):
    refused by name in both conventions, the MuJoCo one (composed in torch from Pinocchio's tensors on a
    floating base) included, rather than returning the tangent of the composition alone."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, qdd, _ = _states(robot, 2, 5, convention)
    with pytest.raises(NotImplementedError, match="inverse_dynamics_second_derivatives has no forward-mode derivative"):
        torch.func.jvp(lambda x: view.inverse_dynamics_second_derivatives(q, x, qdd), (qd,), (torch.ones_like(qd),))
    with pytest.raises(NotImplementedError, match="frame_kinematic_hessian has no forward-mode derivative"):
        torch.func.jvp(lambda x: view.frame_kinematic_hessian(x, robot.nframes - 1), (q,), (torch.ones_like(q),))


def test_osc_inertia_of_a_frame_with_fewer_than_six_dofs_is_refused(robots):
    robot = robots["iiwa14"]
    low = next(i for i, f in enumerate(robot.model.frames) if 0 <= f.parent <= 2)  # moved by at most 3 joints
    with pytest.raises(ValueError, match=rf"frame '{robot.frame_names[low]}' is moved by \d dofs"):
        robot.osc_inertia(robot.random_configuration(2), low)
    assert torch.isfinite(robot.osc_inertia(robot.random_configuration(2), robot.nframes - 1)).all()
