"""Second derivatives through autograd: the backward of every value op is itself differentiable
(create_graph=True), torch.autograd.gradgradcheck with respect to every input, both conventions,
a fixed arm and a floating model with ball joints at non-unit quaternions; a Hessian of a scalar
loss through forward_dynamics against central differences of its analytic gradient."""
from __future__ import annotations

import pytest
import torch
from torch.autograd import gradgradcheck

import torch_grid
from oracles import rel_err
from test_quaternion_joints import pin_ball_model

FUNCTIONS = {
    "inverse_dynamics": lambda v, q, qd, x, f: v.inverse_dynamics(q, qd, x, f),
    "forward_dynamics": lambda v, q, qd, x, f: v.forward_dynamics(q, qd, x, f),
    "crba": lambda v, q, qd, x, f: v.crba(q),
    "minv": lambda v, q, qd, x, f: v.minv(q),
    "generalized_gravity": lambda v, q, qd, x, f: v.generalized_gravity(q),
    "nonlinear_effects": lambda v, q, qd, x, f: v.nonlinear_effects(q, qd),
    "energy": lambda v, q, qd, x, f: v.energy(q, qd),
    "com": lambda v, q, qd, x, f: v.com(q),
    "momentum": lambda v, q, qd, x, f: v.ccrba(q, qd)[1],  # ccrba's h (its A is a derivative)
    "forward_kinematics": lambda v, q, qd, x, f: v.forward_kinematics(q),
    "end_effector_pose": lambda v, q, qd, x, f: v.end_effector_pose(q, [v._robot.nframes - 1]),
}
ARITY = {"inverse_dynamics": 4, "forward_dynamics": 4, "nonlinear_effects": 2, "energy": 2, "momentum": 2}


@pytest.fixture(scope="module")
def balls(tmp_path_factory):
    return torch_grid.load(pin_ball_model(), cache_dir=tmp_path_factory.mktemp("cache"))


def _inputs(robot, convention, seed):
    g = torch.Generator().manual_seed(seed)
    q = 1.3 * getattr(robot, convention).random_configuration(1, generator=g)  # quaternions of norm 1.3
    qd, x = (torch.randn(1, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    f = torch.randn(1, robot.nbodies, 6, dtype=torch.float64, generator=g)
    return [t.requires_grad_(True) for t in (q, qd, x, f)]


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("function", list(FUNCTIONS))
@pytest.mark.parametrize("name", ["iiwa14", "balls"])
def test_gradgradcheck(robots, balls, name, function, convention):
    robot = balls if name == "balls" else robots[name]
    view = getattr(robot, convention)
    inputs = _inputs(robot, convention, seed=len(function))[:ARITY.get(function, 1)]
    call = FUNCTIONS[function]
    padded = inputs + [None] * (4 - len(inputs))
    with torch.no_grad():
        out = call(view, *padded)
        scales = [o.abs().max() for o in (out if isinstance(out, tuple) else (out,))]

    def scaled(*x):
        # outputs of order one, so that one absolute tolerance suits every op (M^-1 reaches 1e3)
        out = call(view, *x, *[None] * (4 - len(x)))
        return tuple(o / s for o, s in zip(out, scales)) if isinstance(out, tuple) else out / scales[0]

    assert gradgradcheck(scaled, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_hessian_of_a_loss_through_forward_dynamics(robots, convention):
    """torch.autograd.functional.hessian (double backward) of a scalar loss of q, qd and tau against
    central differences of its analytic gradient, on the floating go2."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    g = torch.Generator().manual_seed(3)
    q = view.random_configuration(generator=g)
    qd, tau = (torch.randn(robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    w = torch.randn(robot.nv, dtype=torch.float64, generator=g)
    nq, nv = robot.nq, robot.nv

    def loss(z):
        qdd = view.forward_dynamics(z[:nq], z[nq:nq + nv], z[nq + nv:])
        return (w * qdd).sum() + 0.5 * (qdd ** 2).sum()

    def gradient(z):
        z = z.detach().requires_grad_(True)
        return torch.autograd.grad(loss(z), z)[0]

    z = torch.cat([q, qd, tau])
    H = torch.autograd.functional.hessian(loss, z)
    h = 1e-6
    columns = [(gradient(z + h * e) - gradient(z - h * e)) / (2 * h) for e in torch.eye(z.numel(), dtype=z.dtype)]
    assert rel_err(H, torch.stack(columns, dim=-1)) <= 1e-6


@pytest.mark.parametrize("name", ["forward_dynamics", "energy"])
def test_mass_product_gradient_in_pieces(robots, monkeypatch, name):
    """Above autograd.WEIGHT_CHUNK samples (here 2) the mass-product gradient in inertia_solve's and
    energy's backward runs in pieces: the same Hessian-vector product as in one piece, on a (2, 3) batch
    whose q broadcasts over its first dimension, on the floating go2."""
    import torch_grid.autograd as autograd

    robot = robots["go2"]
    g = torch.Generator().manual_seed(4)
    q = robot.random_configuration(3, generator=g)
    qd, x, w = (torch.randn(2, 3, robot.nv, dtype=torch.float64, generator=g) for _ in range(3))

    def hvp():
        leaves = [t.detach().requires_grad_(True) for t in (q, qd, x)]
        out = FUNCTIONS[name](robot, *leaves, None)
        loss = (out * w[..., :out.shape[-1]]).sum()
        grads = torch.autograd.grad(loss, leaves, create_graph=True, allow_unused=True)
        product = sum((gr * v.sum()).sum() for gr, v in zip(grads, (q, qd, x)) if gr is not None)
        return torch.autograd.grad(product, leaves, allow_unused=True)

    whole = hvp()
    monkeypatch.setattr(autograd, "WEIGHT_CHUNK", 2)
    for a, b in zip(hvp(), whole):
        if a is not None:
            assert torch.allclose(a, b, rtol=1e-12, atol=1e-12)


def test_derivative_outputs_refuse_a_second_backward(robots):
    """Ops whose outputs are already derivatives (J, the dynamics gradients) differentiate once; a
    backward of their backward is a clear error, not a missing term."""
    robot = robots["iiwa14"]
    q, qd, x, _ = _inputs(robot, "pin", seed=9)
    for out in (robot.frame_jacobian(q, robot.nframes - 1), robot.inverse_dynamics_gradient(q, qd, x)[0]):
        (g,) = torch.autograd.grad(out.square().sum(), q, create_graph=True)
        with pytest.raises(NotImplementedError, match="cannot be differentiated once more"):
            torch.autograd.grad(g.sum(), q)
