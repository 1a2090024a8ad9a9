"""Costs and barriers (torch_grid/optim/costs.py): gradients against central differences along the tangent
spaces, the Gauss-Newton Hessian against the exact one where the residual vanishes, the placement
residual against Pinocchio's log6, autograd through the values, the barriers' pieces."""
from __future__ import annotations

import pinocchio as pin
import pytest
import torch

import torch_grid
from oracles import rel_err
from torch_grid.space.lie import _rotation


def _cases(view, robot, q, qd, at_zero: bool):
    """name -> f(q, qd) for every state cost, at random targets or (at_zero) at the state's own values."""
    g = torch.Generator().manual_seed(1)
    n, nv, frame = q.shape[0], robot.nv, robot.nframes - 1
    positions, rotations = view.forward_kinematics(q)
    placement = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
    if at_zero:
        q_ref, qd_ref, position, com, momentum = q, qd, positions[:, frame], view.com(q), view.ccrba(q, qd)[1]
        placement[:, :3, :3], placement[:, :3, 3] = rotations[:, frame], positions[:, frame]
    else:
        q_ref, qd_ref = view.random_configuration(n, generator=g), torch.randn(n, nv, dtype=torch.float64, generator=g)
        position, com, momentum = (torch.randn(n, k, dtype=torch.float64, generator=g) for k in (3, 3, 6))
        placement[:, :3, :3] = _rotation(2 * torch.randn(n, 3, dtype=torch.float64, generator=g))
        placement[:, :3, 3] = torch.randn(n, 3, dtype=torch.float64, generator=g)

    def w(k):
        return 0.5 + torch.rand(n, k, dtype=torch.float64, generator=torch.Generator().manual_seed(k))

    return {
        "state_cost": lambda q, qd: view.state_cost(q, qd, q_ref, qd_ref, w(2 * nv)),
        "frame_translation_cost": lambda q, qd: view.frame_translation_cost(q, qd, frame, position, w(3)),
        "frame_placement_cost": lambda q, qd: view.frame_placement_cost(q, qd, frame, placement, w(6)),
        "com_cost": lambda q, qd: view.com_cost(q, qd, com, w(3)),
        "momentum_cost": lambda q, qd: view.momentum_cost(q, qd, momentum, w(6)),
    }


def _tangent_differences(view, q, qd, fn, h=1e-6):
    """Central differences of fn(q, qd) along [dq; dqd] (q moved by integrate): (..., *out, 2 nv)."""
    nv, cols = qd.shape[-1], []
    for k in range(2 * nv):
        z = torch.zeros(q.shape[0], 2 * nv, dtype=torch.float64)
        z[:, k] = h
        plus, minus = fn(view.integrate(q, z[:, :nv]), qd + z[:, nv:]), fn(view.integrate(q, -z[:, :nv]), qd - z[:, nv:])
        cols.append((plus - minus) / (2 * h))
    return torch.stack(cols, dim=-1)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_gradients_and_hessians(robots, convention):
    robot = robots["go2"]
    view = getattr(robot, convention)
    g = torch.Generator().manual_seed(0)
    q, qd = view.random_configuration(3, generator=g), torch.randn(3, robot.nv, dtype=torch.float64, generator=g)
    for name, fn in _cases(view, robot, q, qd, at_zero=False).items():
        value, grad, hess = fn(q, qd)
        assert value.shape == (3,) and hess.shape == (3, 2 * robot.nv, 2 * robot.nv)
        assert rel_err(grad, _tangent_differences(view, q, qd, lambda a, b: fn(a, b)[0])) <= 1e-7, name
        assert rel_err(hess.mT, hess) <= 1e-14, name
    # where the residual vanishes, the Gauss-Newton Hessian is the Hessian
    for name, fn in _cases(view, robot, q, qd, at_zero=True).items():
        value, grad, hess = fn(q, qd)
        assert value.abs().max() <= 1e-20 and grad.abs().max() <= 1e-10, name
        assert rel_err(hess, _tangent_differences(view, q, qd, lambda a, b: fn(a, b)[1], h=1e-5)) <= 1e-6, name


def test_a_batch_of_targets_or_velocities_gives_every_output_its_batch(robots):
    """One state against a batch of targets (which reach the residual alone), and a batch of velocities
    against one configuration (which reach only the Jacobian's zero q̇ block): each output has the batch
    shape, its samples the one-sample calls' values (the Hessian was one matrix, the value one number)."""
    robot = robots["go2"]
    view, nv, frame = robot.pin, robot.nv, robot.nframes - 1
    g = torch.Generator().manual_seed(2)
    q, qd = view.random_configuration(generator=g), torch.randn(4, nv, dtype=torch.float64, generator=g)
    targets = {k: torch.randn(4, k, dtype=torch.float64, generator=g) for k in (3, 6)}
    placement = torch.eye(4, dtype=torch.float64).repeat(4, 1, 1)
    placement[:, :3, 3] = targets[3]
    ones = {k: torch.ones(k, dtype=torch.float64) for k in (3, 6)}
    costs = {
        "frame_translation_cost": lambda qd, b: view.frame_translation_cost(q, qd, frame, targets[3][b], ones[3]),
        "frame_placement_cost": lambda qd, b: view.frame_placement_cost(q, qd, frame, placement[b], ones[6]),
        "com_cost": lambda qd, b: view.com_cost(q, qd, targets[3][b], ones[3]),
        "momentum_cost": lambda qd, b: view.momentum_cost(q, qd, targets[6][b], ones[6]),
    }
    for name, cost in costs.items():
        for outputs, one in ((cost(qd[0], slice(None)), lambda b: cost(qd[0], b)),  # the targets batched
                             (cost(qd, 0), lambda b: cost(qd[b], 0))):  # the velocities batched
            assert [x.shape for x in outputs] == [(4,), (4, 2 * nv), (4, 2 * nv, 2 * nv)], name
            for b in range(4):
                assert all(rel_err(x[b], y) <= 1e-14 for x, y in zip(outputs, one(b))), (name, b)


def test_placement_residual_is_pinocchios_log6(robots, pin_models):
    """value = sum(w r^2) / 2 with r = pin.log6(target^-1 oMf) (Crocoddyl's placement residual)."""
    robot, model = robots["go2"], pin_models["go2"]
    data, frame = model.createData(), robot.nframes - 1
    g = torch.Generator().manual_seed(2)
    q, qd = robot.pin.random_configuration(2, generator=g), torch.zeros(2, robot.nv, dtype=torch.float64)
    target = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    target[:, :3, :3] = _rotation(torch.tensor([[0.3, -2.0, 1.0], [2.5, 1.5, 0.5]], dtype=torch.float64))
    target[:, :3, 3] = torch.randn(2, 3, dtype=torch.float64, generator=g)
    w = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0], dtype=torch.float64).expand(2, 6)
    value = robot.pin.frame_placement_cost(q, qd, frame, target, w)[0]
    name = robot.frame_names[frame]
    for k in range(2):
        pin.framesForwardKinematics(model, data, q[k].numpy())
        oMf = data.oMf[model.getFrameId(name)]
        r = pin.log6(pin.SE3(target[k].numpy()).actInv(oMf)).vector
        assert abs(value[k].item() - 0.5 * float((w[k].numpy() * r * r).sum())) <= 1e-10 * max(1.0, value[k].item())


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_autograd_through_the_values(robots, convention):
    """gradcheck and gradgradcheck of every state cost's value."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    g = torch.Generator().manual_seed(3)
    q = view.random_configuration(1, generator=g).requires_grad_(True)
    qd = torch.randn(1, robot.nv, dtype=torch.float64, generator=g).requires_grad_(True)
    for name, fn in _cases(view, robot, q.detach(), qd.detach(), at_zero=False).items():
        assert torch.autograd.gradcheck(lambda a, b: fn(a, b)[0], (q, qd)), name
        assert torch.autograd.gradgradcheck(lambda a, b: fn(a, b)[0], (q, qd)), name


def test_control_cost_and_barriers():
    g = torch.Generator().manual_seed(4)
    x, ref, w = (torch.randn(2, 5, dtype=torch.float64, generator=g) for _ in range(3))
    w = w.abs()
    robot_free = torch_grid.optim.costs.CostFunctions()
    value, grad, hess = robot_free.control_cost(x, ref, w)
    assert torch.allclose(value, 0.5 * (w * (x - ref) ** 2).sum(-1)) and torch.allclose(grad, w * (x - ref))
    assert torch.equal(hess, torch.diag_embed(w))
    lower, upper = -torch.ones(5, dtype=torch.float64), torch.ones(5, dtype=torch.float64)
    for barrier in (torch_grid.quadratic_barrier, torch_grid.log_barrier):
        inside = (0.9 * torch.tanh(x)).requires_grad_(True)
        value, grad, hess = barrier(inside, lower, upper, w)
        auto, = torch.autograd.grad(value.sum(), inside, create_graph=True)
        assert torch.allclose(grad, auto, rtol=1e-12, atol=1e-12), barrier
        second = torch.stack([torch.autograd.grad(auto[:, k].sum(), inside, retain_graph=True)[0] for k in range(5)], -1)
        assert torch.allclose(hess, second, rtol=1e-12, atol=1e-12), barrier
    outside = torch.tensor([[0.0, 2.0, 1.0, -3.0, -1.0]], dtype=torch.float64)
    value, grad, hess = torch_grid.log_barrier(outside, lower, upper, w[:1])
    # at or past a bound, the gradient is the limit from inside: -inf at the lower, +inf at the upper
    assert torch.isinf(value).all() and not torch.isnan(grad).any() and torch.isinf(hess[0, [1, 2, 3, 4], [1, 2, 3, 4]]).all()
    assert grad[0, 1] == grad[0, 2] == float("inf") and grad[0, 3] == grad[0, 4] == float("-inf")
    near = torch.tensor([[0.0, 1 - 1e-9, 0.0, -1 + 1e-9, 0.0]], dtype=torch.float64)
    assert (torch_grid.log_barrier(near, lower, upper, w[:1])[1][0, [1, 3]].sign() == grad[0, [1, 3]].sign()).all()
    outside = torch.tensor([[0.0, 2.0, 0.0, -3.0, 0.5]], dtype=torch.float64)
    value, grad, _ = torch_grid.quadratic_barrier(outside, lower, upper, w[:1])
    assert torch.allclose(value, 0.5 * (w[0, 1] * 1.0 + w[0, 3] * 4.0).unsqueeze(0))
    with pytest.raises(ValueError, match=r"control_cost: weights must be a tensor of shape \(\.\.\., 5\)"):
        robot_free.control_cost(x, ref, w[:, :3])


@pytest.mark.parametrize("argument", ["x", "lower", "upper"])
@pytest.mark.parametrize("barrier", [torch_grid.quadratic_barrier, torch_grid.log_barrier])
def test_barriers_are_nan_where_x_or_a_bound_is(barrier, argument):
    """A NaN in x or a bound is NaN in the barrier's value, gradient and Hessian entry of its sample (the
    quadratic barrier's Hessian was 0 there, as inside the bounds; the log barrier was +inf with a gradient
    of -inf, as below the lower bound), the other samples unchanged."""
    x = torch.tensor([[0.5, -2.0, 3.0], [0.2, 0.5, 0.9], [-1.5, 0.0, 2.5]], dtype=torch.float64)
    args = {"x": x, "lower": torch.full_like(x, -1.0), "upper": torch.full_like(x, 2.0), "weights": torch.full_like(x, 3.0)}
    clean = barrier(**args)
    args[argument] = args[argument].clone()
    args[argument][1, 1] = float("nan")
    value, grad, hess = barrier(**args)
    assert value[1].isnan() and grad[1, 1].isnan() and hess[1, 1, 1].isnan()
    for got, expected in zip((value, grad, hess), clean):
        assert torch.equal(got[[0, 2]], expected[[0, 2]])


def test_targets_and_bounds_of_another_shape_are_refused_naming_them(robots):
    robot = robots["go2"]
    view, nv, frame = robot.pin, robot.nv, robot.nframes - 1
    q, qd = view.random_configuration(2), torch.zeros(2, nv, dtype=torch.float64)
    ones = lambda *shape: torch.ones(*shape, dtype=torch.float64)  # noqa: E731
    cases = [
        (r"state_cost: q_ref must be a tensor of shape \(\.\.\., 19\), got \(18,\)",
         lambda: view.state_cost(q, qd, ones(18), qd, ones(2 * nv))),
        (r"state_cost: qd_ref must be a tensor of shape \(\.\.\., 18\), got \(2, 19\)",
         lambda: view.state_cost(q, qd, q, q, ones(2 * nv))),
        (r"control_cost: tau_ref must be a tensor of shape \(\.\.\., 18\), got \(19,\)",
         lambda: view.control_cost(qd, ones(19), ones(nv))),
        (r"frame_translation_cost: target must be a tensor of shape \(\.\.\., 3\), got \(4,\)",
         lambda: view.frame_translation_cost(q, qd, frame, ones(4), ones(3))),
        (r"frame_placement_cost: target must be a tensor of shape \(\.\.\., 4, 4\), got \(3, 3\)",
         lambda: view.frame_placement_cost(q, qd, frame, ones(3, 3), ones(6))),
        (r"com_cost: target must be a tensor of shape \(\.\.\., 3\), got list",
         lambda: view.com_cost(q, qd, [0.0, 0.0, 1.0], ones(3))),
        (r"momentum_cost: target must be a tensor of shape \(\.\.\., 6\), got \(3,\)",
         lambda: view.momentum_cost(q, qd, ones(3), ones(6))),
        (r"quadratic_barrier: upper of shape \(4,\) does not broadcast with x's shape \(2, 5\)",
         lambda: torch_grid.quadratic_barrier(ones(2, 5), -ones(5), ones(4), ones(5))),
        (r"log_barrier: weights of shape \(3, 5\) does not broadcast with x's shape \(2, 5\)",
         lambda: torch_grid.log_barrier(ones(2, 5), -ones(5), ones(5), ones(3, 5))),
    ]
    for message, call in cases:
        with pytest.raises(ValueError, match=message):
            call()
    # another dtype than the state's: refused by name (torch promoted some, failed inside others)
    q32, qd32 = q.float(), qd.float()
    dtypes = [
        (r"state_cost: weights is torch.float64 on cpu, expected the state's torch.float32",
         lambda: view.state_cost(q32, qd32, q32, qd32, ones(2 * nv))),
        (r"control_cost: tau_ref is torch.float64", lambda: view.control_cost(qd32, ones(nv), ones(nv).float())),
        (r"com_cost: target is torch.float64", lambda: view.com_cost(q32, qd32, ones(3), ones(3).float())),
        (r"quadratic_barrier: lower is torch.float64 on cpu, expected x's torch.float32",
         lambda: torch_grid.quadratic_barrier(ones(2, 5).float(), -ones(5), 1.0, ones(5).float())),
    ]
    for message, call in dtypes:
        with pytest.raises(TypeError, match=message):
            call()


def test_states_controls_and_x_of_another_size_or_dtype_are_refused_naming_them(robots):
    robot = robots["go2"]
    view, nv, frame = robot.pin, robot.nv, robot.nframes - 1
    q, qd = view.random_configuration(2), torch.zeros(2, nv, dtype=torch.float64)
    ones = lambda *shape: torch.ones(*shape, dtype=torch.float64)  # noqa: E731
    # the frame, com and momentum costs read qd's batch alone: a qd of another size or dtype was taken
    # silently (a gradient of q's dtype and 2 nv entries), state_cost's weights were blamed for it, an
    # integer tau gave a float32 value beside an integer gradient, an integer x a barrier of integers
    cases = [
        (ValueError, r"state_cost: qd must have shape \(\.\.\., 18\), got \(2, 17\)",
         lambda: view.state_cost(q, qd[:, 1:], q, qd[:, 1:], ones(2 * nv - 2))),
        (TypeError, r"state_cost: qd has dtype torch.float32 but q has torch.float64",
         lambda: view.state_cost(q, qd.float(), q, qd.float(), ones(2 * nv).float())),
        (ValueError, r"frame_translation_cost: qd must have shape \(\.\.\., 18\), got \(2, 17\)",
         lambda: view.frame_translation_cost(q, qd[:, 1:], frame, ones(3), ones(3))),
        (TypeError, r"frame_placement_cost: qd has dtype torch.float32 but q has torch.float64",
         lambda: view.frame_placement_cost(q, qd.float(), frame, torch.eye(4, dtype=torch.float64), ones(6))),
        (TypeError, r"com_cost: qd must be a torch.Tensor, got list",
         lambda: view.com_cost(q, qd.tolist(), ones(3), ones(3))),
        (TypeError, r"momentum_cost: q must be float32 or float64, got torch.int64",
         lambda: view.momentum_cost(q.long(), qd, ones(6), ones(6))),
        (ValueError, r"control_cost: tau must have shape \(\.\.\., 18\), got \(2, 17\)",
         lambda: view.control_cost(qd[:, 1:], ones(nv - 1), ones(nv - 1))),
        (TypeError, r"control_cost: tau must be float32 or float64, got torch.int64",
         lambda: view.control_cost(qd.long(), ones(nv).long(), ones(nv).long())),
        (TypeError, r"quadratic_barrier: x must be a float tensor of shape \(\.\.\., n\), got torch.int64",
         lambda: torch_grid.quadratic_barrier(torch.tensor([[0, 2]]), -1, 1, 1)),
        (TypeError, r"log_barrier: x must be a float tensor of shape \(\.\.\., n\), got list",
         lambda: torch_grid.log_barrier([0.0, 2.0], -1.0, 1.0, 1.0)),
        (TypeError, r"log_barrier: x must be a float tensor of shape \(\.\.\., n\), got torch.float64 of shape \(\)",
         lambda: torch_grid.log_barrier(ones(()), -1.0, 1.0, 1.0)),
        (TypeError, r"quadratic_barrier: lower must be a number or a tensor, got ndarray",
         lambda: torch_grid.quadratic_barrier(ones(2, 5), -ones(4).numpy(), 1.0, 1.0)),
    ]
    for error, message, call in cases:
        with pytest.raises(error, match=message):
            call()


def test_batches_that_do_not_broadcast_are_refused_naming_every_argument(robots):
    # torch's broadcasting errors named none of the arguments, or an inner function (difference, ccrba) did
    robot = robots["go2"]
    view, nv, frame = robot.pin, robot.nv, robot.nframes - 1
    q, qd = view.random_configuration(3), torch.zeros(3, nv, dtype=torch.float64)
    ones = lambda *shape: torch.ones(*shape, dtype=torch.float64)  # noqa: E731
    cases = [
        (r"state_cost: the batch shapes do not broadcast: q \(3,\), qd \(3,\), weights \(\), q_ref \(2,\), qd_ref \(3,\)",
         lambda: view.state_cost(q, qd, q[:2], qd, ones(2 * nv))),
        (r"frame_placement_cost: the batch shapes do not broadcast: q \(3,\), qd \(3,\), target \(2,\), weights \(\)",
         lambda: view.frame_placement_cost(q, qd, frame, torch.eye(4, dtype=torch.float64).expand(2, 4, 4), ones(6))),
        (r"com_cost: the batch shapes do not broadcast: .* weights \(2,\)", lambda: view.com_cost(q, qd, ones(3), ones(2, 3))),
        (r"momentum_cost: the batch shapes do not broadcast: q \(3,\), qd \(2,\)",
         lambda: view.momentum_cost(q, qd[:2], ones(6), ones(6))),
        (r"control_cost: the batch shapes do not broadcast: tau \(3,\), tau_ref \(2,\), weights \(\)",
         lambda: view.control_cost(qd, ones(2, nv), ones(nv))),
    ]
    for message, call in cases:
        with pytest.raises(ValueError, match=message):
            call()
