"""Second derivatives through autograd: the backward of every value op is itself differentiable
(create_graph=True), torch.autograd.gradgradcheck with respect to every input, both conventions,
a fixed arm and a floating model with ball joints at non-unit quaternions; a Hessian of a scalar
loss through forward_dynamics against central differences of its analytic gradient."""
from __future__ import annotations

import pytest
import torch
from torch.autograd import gradgradcheck

from oracles import rel_err

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
def balls(pinocchio_balls):
    return pinocchio_balls[0]


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


@pytest.mark.parametrize("name", ["iiwa14", "go2", "balls"])
def test_mass_product_gradient(robots, balls, name):
    """mass_product_vjp, the O(n) tangent gradient of lam . M(q) a in the backwards of inertia_solve and
    energy, against crba_vjp (an O(n d) kernel of its own) with the weight lam a^T; its backward and
    forward-mode rules (inverse-dynamics products) against central differences, at quaternions of norm 1.3."""
    robot = balls if name == "balls" else robots[name]
    g = torch.Generator().manual_seed(5)
    q = robot.random_configuration(3, generator=g)
    a, lam = (torch.randn(3, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    ours = robot._ops.mass_product_vjp(q, a, lam, None, 0)
    assert rel_err(ours, robot._ops.crba_vjp(q, lam.unsqueeze(-1) * a.unsqueeze(-2), None, 0)) <= 1e-12
    inputs = [t[:1].clone().requires_grad_(True) for t in (1.3 * q, a, lam)]
    for call in (robot._ops.mass_product_vjp, lambda *x: robot._func.call("mass_product_vjp", *x)):
        assert torch.autograd.gradcheck(lambda *x: call(*x, None, 0), inputs, eps=1e-6, atol=1e-6, rtol=1e-5,
                                        check_forward_ad=call is not robot._ops.mass_product_vjp)


def test_derivative_outputs_refuse_a_second_backward(robots):
    """Ops whose outputs are already derivatives (J, the dynamics gradients) differentiate once; a
    backward of their backward is a clear error, not a missing term."""
    robot = robots["iiwa14"]
    q, qd, x, _ = _inputs(robot, "pin", seed=9)
    for out in (robot.frame_jacobian(q, robot.nframes - 1), robot.inverse_dynamics_derivatives(q, qd, x)[0]):
        (g,) = torch.autograd.grad(out.square().sum(), q, create_graph=True)
        with pytest.raises(NotImplementedError, match="cannot be differentiated once more"):
            torch.autograd.grad(g.sum(), q)
