"""The kernels that carry gradients between q's coordinates and its tangent space inside backwards
(ops/lie_backward.py): tangent_to_ambient, which every op's backward ends with at a robot with quaternion
joints, and integrate's and difference's vector-Jacobian products. Each equals the torch composition it
replaces (space/tangent.py, space/lie.py), which a backward that is itself differentiated still runs:
on free, ball and one-dof joints, in both conventions, with broadcast batches, quaternions off the unit
sphere, zero (read as the identity) and NaN or infinite ones (NaN in their own sample alone), in float32."""
from __future__ import annotations

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from torch_grid.space.tangent import layout, tangent_to_ambient

ROBOTS = ["go2", "trees"]


def _configurations(view, generator: torch.Generator) -> torch.Tensor:
    """(2, 3, nq): norms 1.7 but for a zero quaternion at (0, 1), a NaN at (1, 0) and an infinity at (1, 2)."""
    q = view.random_configuration(2, 3, generator=generator)
    quats = [slice(j.quat, j.quat + 4) for j in layout(view._robot.model).quaternions]
    first, last = quats[0], quats[-1]
    for s in quats:
        q[..., s] *= 1.7
    q[0, 1, first] = 0
    q[1, 0, last.start + 1] = float("nan")
    q[1, 2, first.start] = float("inf")
    return q


class _Calls(TorchDispatchMode):
    """The names of the ops dispatched while active."""

    def __init__(self):
        super().__init__()
        self.names: list[str] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.names.append(func.name())
        return func(*args, **(kwargs or {}))


def _ran(kernel: str, fn) -> bool:
    """Whether calling fn ran the op `kernel`."""
    with _Calls() as calls:
        fn()
    return any(name.endswith(f"::{kernel}") for name in calls.names)


def _assert_same(kernel: torch.Tensor, composed: torch.Tensor, atol: float, spread: bool = False) -> None:
    """Equal to atol, NaN in the same entries (a spoiled quaternion's joint, and what reads it). spread: the
    composition's matrix products carry a NaN over its whole sample, where the kernel keeps it to the entries that
    read the spoiled joint: the kernel's NaN entries are among the composition's, in every spoiled sample."""
    if not spread:
        torch.testing.assert_close(kernel, composed, rtol=0, atol=atol, equal_nan=True)
        return
    nan, spoiled = torch.isnan(kernel), torch.isnan(composed)
    assert not (nan & ~spoiled).any()
    assert torch.equal(nan.flatten(2).any(-1), spoiled.flatten(2).any(-1))
    torch.testing.assert_close(kernel[~spoiled], composed[~spoiled], rtol=0, atol=atol)


@pytest.mark.parametrize("name", ROBOTS)
def test_tangent_to_ambient_kernel_is_the_composition(robots, name):
    robot = robots[name]
    g = torch.Generator().manual_seed(3)
    for view in (robot.pin, robot.mujoco):
        q = _configurations(view, g)
        grad = torch.randn(3, robot.nv, dtype=torch.float64, generator=g)  # broadcast against q's (2, 3)
        for dtype, atol in ((torch.float64, 1e-13), (torch.float32, 1e-5)):
            qx, gx = q.to(dtype), grad.to(dtype)
            kernel = robot._ops.tangent_to_ambient(qx, gx, view._convention)
            composed = tangent_to_ambient(robot.model, qx, gx, view._convention)
            assert kernel.dtype == dtype and kernel.shape == (2, 3, robot.nq)
            _assert_same(kernel, composed, atol)


@pytest.mark.parametrize("name", ROBOTS)
def test_backwards_through_the_kernel_are_the_composition(robots, name):
    """A plain backward maps the tangent gradient by the kernel, a differentiable one (create_graph) by the
    composition: the gradients of q agree for ops whose backwards end with the map."""
    robot = robots[name]
    g = torch.Generator().manual_seed(5)
    for view in (robot.pin, robot.mujoco):
        q = _configurations(view, g)
        qd, tau = (torch.randn(3, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
        frame = robot.nframes - 1
        for k, fn in enumerate((lambda q: view.inverse_dynamics(q, qd, tau), lambda q: view.forward_dynamics(q, qd, tau),
                                view.crba, view.generalized_gravity, lambda q: view.frame_jacobian(q, frame),
                                lambda q: view.forward_kinematics(q)[0])):
            x = q.clone().requires_grad_()
            out = fn(x)
            weight = torch.randn(out.shape, dtype=torch.float64, generator=g)
            if k == 0:  # (MuJoCo's frame_jacobian differentiates its kernel on dual numbers, in q's coordinates)
                assert _ran("tangent_to_ambient", lambda: torch.autograd.grad((out * weight).sum(), x, retain_graph=True))
            plain = torch.autograd.grad((out * weight).sum(), x, retain_graph=True)[0]
            differentiable = torch.autograd.grad((out * weight).sum(), x, create_graph=True)[0]
            _assert_same(plain, differentiable.detach(), 1e-12 * max(1.0, plain.nan_to_num().abs().max()))


@pytest.mark.parametrize("name", ROBOTS)
def test_integrate_and_difference_vjps_are_the_composition(robots, name):
    """integrate's and difference's backwards run one kernel each (integrate_vjp, difference_vjp), and give what
    their composition's backward gives (a create_graph backward), for every input, dt a column per sample."""
    robot = robots[name]
    g = torch.Generator().manual_seed(9)
    for view in (robot.pin, robot.mujoco):
        q, q1 = _configurations(view, g), view.random_configuration(2, 3, generator=g)
        v = torch.randn(2, 3, robot.nv, dtype=torch.float64, generator=g)
        dt = torch.rand(2, 3, dtype=torch.float64, generator=g) + 0.5
        for method, kernel, args in ((view.integrate, "integrate_vjp", (q, v, dt)),
                                     (view.difference, "difference_vjp", (q, q1))):
            inputs = [x.clone().requires_grad_() for x in args]
            out = method(*inputs)
            weight = torch.randn(out.shape, dtype=torch.float64, generator=g)
            assert _ran(kernel, lambda: torch.autograd.grad((out * weight).sum(), inputs, retain_graph=True))
            plain = torch.autograd.grad((out * weight).sum(), inputs, retain_graph=True)
            differentiable = torch.autograd.grad((out * weight).sum(), inputs, create_graph=True)
            for a, b in zip(plain, differentiable):
                a, b = (a, b.detach()) if a.dim() == 3 else (a.unsqueeze(-1), b.detach().unsqueeze(-1))  # dt's: (2, 3)
                _assert_same(a, b, 1e-12, spread=True)
