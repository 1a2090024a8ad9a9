"""No silently wrong result: forward-mode AD refuses with the op's name, and a free-flyer quaternion
of zero or non-finite norm reads as the identity (MuJoCo's mj_normalizeQuat) in every function and
gradient, in both conventions."""
from __future__ import annotations

import pytest
import torch
from torch.autograd import forward_ad

from functions import FUNCTIONS
from test_autograd import _states


def _flat(out) -> torch.Tensor:
    return torch.cat([x.flatten(1) for x in (out if isinstance(out, tuple) else (out,))], 1)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("bad", [0.0, float("nan"), float("inf")])
def test_degenerate_quaternion_reads_as_identity(robots, convention, bad):
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, x, f = _states(robot, 3, 4, convention)
    w = 3 if convention == "mujoco" else 6
    identity = q.clone()
    identity[..., 3:7] = 0.0
    identity[..., w] = 1.0
    degenerate = q.clone()
    degenerate[..., 3:7] = 0.0
    degenerate[..., 4] = bad  # 0: the zero quaternion; nan / inf: a non-finite norm
    for name, (call, arity) in FUNCTIONS.items():
        got = _flat(call(view, robot, *(degenerate, qd, x, f)[:arity]))
        ref = _flat(call(view, robot, *(identity, qd, x, f)[:arity]))
        assert torch.isfinite(got).all(), f"{name}: non-finite output for a quaternion with {bad}"
        assert torch.allclose(got, ref, rtol=1e-12, atol=1e-12), f"{name}: differs from the identity quaternion"


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
    """inverse_dynamics_second_order and frame_kinematic_hessian have no forward mode (a third derivative):
    refused by name in both conventions, the MuJoCo one (composed in torch from Pinocchio's tensors on a
    floating base) included, rather than returning the tangent of the composition alone."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, qdd, _ = _states(robot, 2, 5, convention)
    with pytest.raises(NotImplementedError, match="inverse_dynamics_second_order has no forward-mode derivative"):
        torch.func.jvp(lambda x: view.inverse_dynamics_second_order(q, x, qdd), (qd,), (torch.ones_like(qd),))
    with pytest.raises(NotImplementedError, match="frame_kinematic_hessian has no forward-mode derivative"):
        torch.func.jvp(lambda x: view.frame_kinematic_hessian(x, robot.nframes - 1), (q,), (torch.ones_like(q),))


def test_osc_inertia_of_a_frame_with_fewer_than_six_dofs_is_refused(robots):
    robot = robots["iiwa14"]
    low = next(i for i, f in enumerate(robot.model.frames) if 0 <= f.parent <= 2)  # moved by at most 3 joints
    with pytest.raises(ValueError, match=rf"frame '{robot.frame_names[low]}' is moved by \d dofs"):
        robot.osc_inertia(robot.random_configuration(2), low)
    assert torch.isfinite(robot.osc_inertia(robot.random_configuration(2), robot.nframes - 1)).all()
