"""torch.func transforms over the functions: grad, vjp, jacrev (and jacrev of jacrev), vmap with a
batching rule (one batched call, no per-sample fallback), vmap of grad, functional_call; forward mode
(jvp, jacfwd, hessian, forward_ad) of the value ops."""
from __future__ import annotations


import pytest
import torch
from torch.autograd import forward_ad

from oracles import rel_err
from torch_grid.ops import levels


@pytest.fixture(scope="module")
def balls(pinocchio_balls):
    return pinocchio_balls[0]


def _robot(name, robots, balls):
    return balls if name == "balls" else robots[name]


def _state(robot, convention, batch, seed):
    g = torch.Generator().manual_seed(seed)
    q = getattr(robot, convention).random_configuration(batch, generator=g)
    qd, x = (torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    return q, qd, x


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["iiwa14", "balls"])
def test_grad_vjp_jacrev_equal_autograd(robots, balls, name, convention):
    robot = _robot(name, robots, balls)
    view = getattr(robot, convention)
    q, qd, tau = (x[0] for x in _state(robot, convention, 1, seed=1))

    def loss(q, qd, tau):
        return view.forward_dynamics(q, qd, tau).square().sum() + view.energy(q, qd)[2]

    leaves = [x.clone().requires_grad_(True) for x in (q, qd, tau)]
    ref = torch.autograd.grad(loss(*leaves), leaves)
    got = torch.func.grad(loss, argnums=(0, 1, 2))(q, qd, tau)
    for a, b in zip(got, ref):
        assert rel_err(a, b) <= 1e-12
    out, pullback = torch.func.vjp(lambda q: view.inverse_dynamics(q, qd, tau), q)
    assert rel_err(out, view.inverse_dynamics(q, qd, tau)) <= 1e-15
    w = torch.randn_like(qd)
    leaf = q.clone().requires_grad_(True)
    (ref_q,) = torch.autograd.grad(view.inverse_dynamics(leaf, qd, tau), leaf, w)
    assert rel_err(pullback(w)[0], ref_q) <= 1e-12
    # the Jacobian of M q-dependence by reverse mode, and of qd by the analytic gradient
    J = torch.func.jacrev(lambda qd: view.inverse_dynamics(q, qd, tau))(qd)
    assert rel_err(J, view.inverse_dynamics_derivatives(q, qd, tau)[1]) <= 1e-12


def test_hessian_by_reverse_over_reverse(robots):
    """jacrev(jacrev(f)): the backward's own ops transformed again, against autograd's double backward."""
    robot = robots["go2"]
    q, qd, tau = (x[0] for x in _state(robot, "pin", 1, seed=2))

    def loss(qd):
        return robot.forward_dynamics(q, qd, tau).square().sum()

    H = torch.func.jacrev(torch.func.jacrev(loss))(qd)
    assert rel_err(H, torch.autograd.functional.hessian(loss, qd)) <= 1e-10


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["go2", "balls"])
def test_vmap_is_the_batched_call(robots, balls, name, convention):
    robot = _robot(name, robots, balls)
    view = getattr(robot, convention)
    q, qd, x = _state(robot, convention, 5, seed=3)
    fallback = torch._C._functorch._is_vmap_fallback_enabled()
    torch._C._functorch._set_vmap_fallback_enabled(False)  # an op without a batching rule raises
    try:
        tau = torch.func.vmap(view.inverse_dynamics)(q, qd, x)
        M = torch.func.vmap(view.crba)(q)
        jac = torch.func.vmap(lambda q: view.frame_jacobian(q, robot.nframes - 1))(q)
        shared = torch.func.vmap(view.inverse_dynamics, in_dims=(0, None, None))(q, qd[0], x[0])
        moved = torch.func.vmap(view.inverse_dynamics, in_dims=(1, 1, 1))(q.mT, qd.mT, x.mT)
        # the second-order tensors (in the MuJoCo convention composed in torch from Pinocchio's ops)
        second = torch.func.vmap(view.inverse_dynamics_second_derivatives)(q, qd, x)
        hess = torch.func.vmap(lambda q: view.frame_kinematic_hessian(q, robot.nframes - 1))(q)
        pose = torch.func.vmap(lambda q: view.end_effector_pose(q, [robot.nframes - 1]))(q)  # a list argument
        # per-sample gradients: vmap of grad
        grads = torch.func.vmap(torch.func.grad(lambda q, qd, x: view.forward_dynamics(q, qd, x).square().sum()))(
            q, qd, x)
    finally:
        torch._C._functorch._set_vmap_fallback_enabled(fallback)
    assert all(rel_err(a, b) <= 1e-14 for a, b in zip(second, view.inverse_dynamics_second_derivatives(q, qd, x)))
    assert rel_err(hess, view.frame_kinematic_hessian(q, robot.nframes - 1)) <= 1e-14
    assert torch.equal(pose, view.end_effector_pose(q, [robot.nframes - 1]))
    assert torch.equal(tau, view.inverse_dynamics(q, qd, x)) and torch.equal(moved, tau)
    assert torch.equal(M, view.crba(q)) and torch.equal(jac, view.frame_jacobian(q, robot.nframes - 1))
    assert torch.equal(shared, view.inverse_dynamics(q, qd[0], x[0]))
    leaf = q.clone().requires_grad_(True)
    (ref,) = torch.autograd.grad(view.forward_dynamics(leaf, qd, x).square().sum(), leaf)
    assert rel_err(grads, ref) <= 1e-12


def test_functional_call_and_forward_mode(robots):
    robot = robots["iiwa14"]
    q, qd, x = _state(robot, "pin", 2, seed=4)

    class Plant(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.gain = torch.nn.Parameter(torch.ones(robot.nv, dtype=torch.float64))

        def forward(self, q, qd):
            return robot.forward_dynamics(q, qd, -self.gain * qd)

    plant = Plant()
    params = {"gain": 2 * torch.ones(robot.nv, dtype=torch.float64)}
    g = torch.func.grad(lambda p: torch.func.functional_call(plant, p, (q, qd)).sum())(params)["gain"]
    gain = params["gain"].clone().requires_grad_(True)
    (ref,) = torch.autograd.grad(robot.forward_dynamics(q, qd, -gain * qd).sum(), gain)
    assert rel_err(g, ref) <= 1e-12


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["iiwa14", "balls"])
def test_forward_mode(robots, balls, name, convention):
    """jvp, jacfwd, hessian (jacfwd of jacrev) and torch.autograd.forward_ad of the value ops against
    reverse mode, at quaternions of norm 1.2."""
    robot = _robot(name, robots, balls)
    view = getattr(robot, convention)
    q, qd, x = (t[0] for t in _state(robot, convention, 1, seed=5))
    q = 1.2 * q
    f = torch.randn(robot.nbodies, 6, dtype=torch.float64)
    functions = {
        "inverse_dynamics": lambda q, qd, x: view.inverse_dynamics(q, qd, x, f),
        "forward_dynamics": lambda q, qd, x: view.forward_dynamics(q, qd, x, f),
        "crba": lambda q, qd, x: view.crba(q), "minv": lambda q, qd, x: view.minv(q),
        "generalized_gravity": lambda q, qd, x: view.generalized_gravity(q),
        "nonlinear_effects": lambda q, qd, x: view.nonlinear_effects(q, qd),
        "energy": lambda q, qd, x: view.energy(q, qd), "com": lambda q, qd, x: view.com(q),
        "forward_kinematics": lambda q, qd, x: view.forward_kinematics(q)[1],
        "end_effector_pose": lambda q, qd, x: view.end_effector_pose(q, [robot.nframes - 1]),
    }
    tangents = tuple(torch.randn_like(t) for t in (q, qd, x))
    for label, fn in functions.items():
        out, jv = torch.func.jvp(fn, (q, qd, x), tangents)
        assert torch.equal(out, fn(q, qd, x)), label
        J = torch.func.jacrev(fn, argnums=(0, 1, 2))(q, qd, x)
        ref = sum((Jk.reshape(out.numel(), -1) @ t.reshape(-1)).reshape(out.shape) for Jk, t in zip(J, tangents))
        assert rel_err(jv, ref) <= 1e-10, label
        assert rel_err(torch.func.jacfwd(fn)(q, qd, x), J[0]) <= 1e-10, label
        with forward_ad.dual_level():
            dual = fn(*(forward_ad.make_dual(p, t) for p, t in zip((q, qd, x), tangents)))
            assert rel_err(forward_ad.unpack_dual(dual).tangent, ref) <= 1e-10, label

    def loss(qd):
        return view.forward_dynamics(q, qd, x).square().sum()

    assert rel_err(torch.func.hessian(loss)(qd), torch.autograd.functional.hessian(loss, qd)) <= 1e-10


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["go2", "balls"])
def test_forward_mode_of_the_kernel_jvps(robots, balls, name, convention):
    """Ops whose outputs are derivatives, differentiated in forward mode by their own kernel on dual
    numbers: jvp against central differences along the tangent and forward_ad, jacfwd against jacrev,
    batched, at quaternions of norm 1.2."""
    robot = _robot(name, robots, balls)
    view = getattr(robot, convention)
    q, qd, _ = _state(robot, convention, 2, seed=10)
    q = 1.2 * q
    frame = robot.nframes - 1
    functions = {
        "jacobian_com": lambda q, qd: view.jacobian_com(q),
        "potential_energy_regressor": lambda q, qd: view.potential_energy_regressor(q),
        "ccrba": lambda q, qd: torch.cat([view.ccrba(q, qd)[0], view.ccrba(q, qd)[1].unsqueeze(-1)], -1),
        "frame_jacobian_dot": lambda q, qd: torch.stack([view.frame_jacobian_dot(q, qd, frame, ref)
                                                         for ref in ("local", "world", "local_world_aligned")]),
        "cmm_time_variation": lambda q, qd: view.cmm_time_variation(q, qd),
        "dccrba": lambda q, qd: view.dccrba(q, qd),
        "coriolis_matrix": lambda q, qd: view.coriolis_matrix(q, qd),
        "kinetic_energy_regressor": lambda q, qd: view.kinetic_energy_regressor(q, qd),
        "body_velocities": lambda q, qd: view.body_velocities(q, qd),
        # qdd = flip(qd): its tangent moves qdd too
        "inverse_dynamics_regressor": lambda q, qd: view.inverse_dynamics_regressor(q, qd, qd.flip(-1)),
    }
    g = torch.Generator().manual_seed(11)
    tangents = tuple(torch.randn(x.shape, dtype=x.dtype, generator=g) for x in (q, qd))
    eps = 1e-6
    for label, fn in functions.items():
        out, jv = torch.func.jvp(fn, (q, qd), tangents)
        assert torch.equal(out, fn(q, qd)), label
        fd = (fn(q + eps * tangents[0], qd + eps * tangents[1]) - fn(q - eps * tangents[0], qd - eps * tangents[1])) / (2 * eps)
        assert rel_err(jv, fd) <= 1e-6, label
        with forward_ad.dual_level():
            dual = fn(*(forward_ad.make_dual(p, t) for p, t in zip((q, qd), tangents)))
            assert rel_err(forward_ad.unpack_dual(dual).tangent, jv) <= 1e-12, label
        J = torch.func.jacrev(fn, argnums=(0, 1))(q[0], qd[0])
        for k, Jf in enumerate(torch.func.jacfwd(fn, argnums=(0, 1))(q[0], qd[0])):
            assert rel_err(Jf, J[k]) <= 1e-10, label
    H = torch.func.hessian(lambda q: view.com(q).square().sum())(q[0])
    assert rel_err(H, torch.func.jacrev(torch.func.jacrev(lambda q: view.com(q).square().sum()))(q[0])) <= 1e-10


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["go2", "balls"])
def test_forward_mode_of_the_composed_functions(robots, balls, name, convention):
    """In forward mode the external-force gradients, osc_inertia and forward_dynamics_parameter_derivatives
    are composed of ops that have one (body_velocities, minv, frame_jacobian, inverse_dynamics_regressor,
    forward_dynamics): the same values as their kernels, and tangents against central differences,
    forward_ad and jacrev, at quaternions of norm 1.2."""
    robot = _robot(name, robots, balls)
    view = getattr(robot, convention)
    q, qd, tau = _state(robot, convention, 2, seed=13)
    q = 1.2 * q
    frame = robot.nframes - 1
    functions = {
        "inverse_dynamics_external_force_derivatives": view.inverse_dynamics_external_force_derivatives,
        "forward_dynamics_external_force_derivatives": view.forward_dynamics_external_force_derivatives,
        "osc_inertia": lambda q: torch.stack([view.osc_inertia(q, frame, ref) for ref in ("local", "local_world_aligned")]),
        "forward_dynamics_parameter_derivatives": lambda q: view.forward_dynamics_parameter_derivatives(
            q, *((qd, tau) if q.dim() > 1 else (qd[0], tau[0]))),
    }
    t = torch.randn(q.shape, dtype=q.dtype, generator=torch.Generator().manual_seed(14))
    eps = 1e-6
    for label, fn in functions.items():
        with forward_ad.dual_level():
            value, tangent = forward_ad.unpack_dual(fn(forward_ad.make_dual(q, t)))
        assert rel_err(value, fn(q)) <= 1e-12, label
        assert rel_err(tangent, (fn(q + eps * t) - fn(q - eps * t)) / (2 * eps)) <= 1e-6, label
        assert rel_err(torch.func.jvp(fn, (q,), (t,))[1], tangent) <= 1e-12, label
        assert rel_err(torch.func.jacfwd(fn)(q[0]), torch.func.jacrev(fn)(q[0])) <= 1e-10, label
    # forward_dynamics_parameter_derivatives along qd and tau as well
    fn = lambda qd, tau: view.forward_dynamics_parameter_derivatives(q[0], qd, tau)  # noqa: E731
    for Jf, Jr in zip(torch.func.jacfwd(fn, argnums=(0, 1))(qd[0], tau[0]), torch.func.jacrev(fn, argnums=(0, 1))(qd[0], tau[0])):
        assert rel_err(Jf, Jr) <= 1e-10


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_per_sample_hessians_by_vmap(robots, convention):
    """vmap of hessian (forward over reverse) and of jacfwd equal a loop over the samples: through
    end_effector_pose's rpy rows, torch.linalg.solve had returned garbage for every sample but the first."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, tau = _state(robot, convention, 3, seed=12)
    q = 1.2 * q
    one, two = [robot.nframes - 1], [1, robot.nframes - 1]  # (the garbage came with one frame)
    transforms = {
        "end_effector_pose": torch.func.hessian(lambda q, qd, tau: view.end_effector_pose(q, one).square().sum()),
        "end_effector_pose_derivatives": torch.func.jacfwd(lambda q, qd, tau: view.end_effector_pose_derivatives(q, one)),
        "end_effector_pose_derivatives, two frames": torch.func.jacfwd(
            lambda q, qd, tau: view.end_effector_pose_derivatives(q, two)),
        "forward_dynamics": torch.func.hessian(lambda q, qd, tau: view.forward_dynamics(q, qd, tau).square().sum(),
                                               argnums=(0, 1, 2)),
        "com": torch.func.hessian(lambda q, qd, tau: view.com(q).square().sum()),
    }
    for label, fn in transforms.items():
        batched = torch.func.vmap(fn)(q, qd, tau)
        loop = [fn(*(x[i] for x in (q, qd, tau))) for i in range(3)]
        for got, ref in zip(torch.utils._pytree.tree_leaves(batched),
                            [torch.stack(parts) for parts in zip(*map(torch.utils._pytree.tree_leaves, loop))]):
            assert rel_err(got, ref) <= 1e-12, label


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["go2", "balls"])
def test_hessians_in_q_of_the_value_functions(robots, balls, name, convention):
    """The Hessian in q of a weighted sum of each value function, unbatched, at quaternions of norm 1.2:
    torch.func.hessian (forward over reverse) and jacrev of jacrev (whose cotangents carry a batch q
    does not) against autograd's double backward and central differences of the gradient."""
    robot = _robot(name, robots, balls)
    view = getattr(robot, convention)
    q, qd, x = (t[0] for t in _state(robot, convention, 1, seed=8))
    q = 1.2 * q
    functions = {
        "inverse_dynamics": lambda q: view.inverse_dynamics(q, qd, x),
        "forward_dynamics": lambda q: view.forward_dynamics(q, qd, x),
        "crba": lambda q: view.crba(q), "minv": lambda q: view.minv(q),
        "generalized_gravity": lambda q: view.generalized_gravity(q),
        "nonlinear_effects": lambda q: view.nonlinear_effects(q, qd),
        "energy": lambda q: view.energy(q, qd), "com": lambda q: view.com(q),
        "forward_kinematics": lambda q: torch.cat([t.reshape(-1) for t in view.forward_kinematics(q)]),
        "end_effector_pose": lambda q: view.end_effector_pose(q, [1, robot.nframes - 1]),
    }
    g = torch.Generator().manual_seed(9)
    for label, fn in functions.items():
        w = torch.randn(fn(q).shape, dtype=torch.float64, generator=g)

        def loss(q):
            return (w * fn(q)).sum()

        ref = torch.autograd.functional.hessian(loss, q)
        assert rel_err(torch.func.hessian(loss)(q), ref) <= 1e-10, label
        assert rel_err(torch.func.jacrev(torch.func.jacrev(loss))(q), ref) <= 1e-10, label
        eps, grad = 1e-6, torch.func.grad(loss)
        fd = torch.stack([(grad(q + eps * e) - grad(q - eps * e)) / (2 * eps) for e in torch.eye(q.numel(), dtype=q.dtype)])
        assert rel_err(ref, fd) <= 1e-6, label


@pytest.mark.parametrize("name, convention", [("go2", "pin"), ("balls", "pin"), ("iiwa14", "mujoco"), ("go2", "mujoco"),
                                              ("balls", "mujoco")])
def test_frame_jacobian_forward_mode(robots, balls, name, convention):
    """jvp and jacfwd of frame_jacobian (the kinematic Hessian along the tangent) against jacrev."""
    robot = _robot(name, robots, balls)
    view = getattr(robot, convention)
    q = 1.2 * _state(robot, convention, 1, seed=6)[0][0]
    t = torch.randn_like(q)
    for reference in ("world", "local", "local_world_aligned"):
        def fn(q):
            return view.frame_jacobian(q, robot.nframes - 1, reference)

        J = torch.func.jacrev(fn)(q)
        assert rel_err(torch.func.jvp(fn, (q,), (t,))[1], J @ t) <= 1e-10, reference
        assert rel_err(torch.func.jacfwd(fn)(q), J) <= 1e-10, reference


@pytest.mark.parametrize("name, convention", [("iiwa14", "pin"), ("balls", "pin"), ("go2", "pin"), ("balls", "mujoco"),
                                              ("go2", "mujoco")])
def test_dynamics_gradients_forward_mode(robots, balls, name, convention):
    """jvp and jacfwd of inverse_dynamics_derivatives and forward_dynamics_derivatives (the second-order
    kernel contracted with the tangents; MuJoCo's tensors with quaternions) against jacrev, with f_ext,
    at quaternions of norm 1.2."""
    robot = _robot(name, robots, balls)
    view = getattr(robot, convention)
    q, qd, x = (t[0] for t in _state(robot, convention, 1, seed=8))
    q = 1.2 * q
    f = torch.randn(robot.nbodies, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    tangents = tuple(torch.randn_like(t) for t in (q, qd, x, f))
    for fn in (view.inverse_dynamics_derivatives, view.forward_dynamics_derivatives):
        out, jv = torch.func.jvp(fn, (q, qd, x, f), tangents)
        J = torch.func.jacrev(fn, argnums=(0, 1, 2, 3))(q, qd, x, f)
        for o, d, Js in zip(out, jv, J):
            ref = sum((Jk.reshape(o.numel(), -1) @ t.reshape(-1)).reshape(o.shape) for Jk, t in zip(Js, tangents))
            assert rel_err(d, ref) <= 1e-9, fn.__name__
        fwd = torch.func.jacfwd(fn, argnums=1)(q, qd, x, f)
        assert all(rel_err(a, b[1]) <= 1e-9 for a, b in zip(fwd, J)), fn.__name__


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_transforms_under_torch_compile(robots, convention):
    """Compiled, torch.func's grad, jacrev, jvp and vmap over the dynamics equal the eager transforms (jvp
    returned a wrong tangent, grad and jacrev failed, where the ops ran without their torch.func rules
    inside a compiled transform). Forward-mode dual tensors are left out: a compiled graph drops the
    tangent of a dual tensor it receives (torch 2.13), whatever the function. On torch 2.11, whose compiler
    gets the backward of a lone vjp wrong, jacrev raises (test_compiled_vjp_refused_where_torch_miscompiles_it)."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, tau = _state(robot, convention, 3, 11)
    t = torch.randn(3, robot.nq, dtype=torch.float64, generator=torch.Generator().manual_seed(12))

    def fd(x):
        return view.forward_dynamics(x, qd, tau) + view.frame_jacobian(x, robot.nframes - 1).sum(-2)

    transforms = {"grad": torch.func.grad(lambda x: fd(x).sin().sum()), "jacrev": torch.func.jacrev(fd),
                  "jvp": lambda x: torch.func.jvp(fd, (x,), (t,))[1], "vmap": torch.func.vmap(fd)}
    for name, fn in transforms.items():
        torch._dynamo.reset()
        if name == "jacrev" and levels._VJP_MISCOMPILED:
            with pytest.raises(NotImplementedError, match="torch 2.12 computes it right"):
                torch.compile(fn)(q)
            continue
        ours, ref = torch.compile(fn)(q), fn(q)
        assert ours is not None and rel_err(ours, ref) <= 1e-12, name


def test_compiled_vjp_refused_where_torch_miscompiles_it(robots, monkeypatch):
    """torch 2.11 compiles the backward of a torch.func.vjp (jacrev's too) whose function breaks the graph into
    zero gradients; there a vjp or jacrev of the functions inside torch.compile raises, naming the function and
    the torch release that has it right, while grad, vmap of jacrev, jacrev of jacrev and hessian compile right
    and run, as does jacrev outside torch.compile. Here the torch at hand is taken for 2.11, so that this torch
    runs the check (on 2.11 itself test_transforms_under_torch_compile meets the refusal)."""
    monkeypatch.setattr(levels, "_VJP_MISCOMPILED", True)
    robot = robots["iiwa14"]
    q, qd, tau = (x[0] for x in _state(robot, "pin", 1, seed=13))
    w = torch.randn(robot.nv, dtype=torch.float64, generator=torch.Generator().manual_seed(14))

    def fd(x):
        return robot.forward_dynamics(q, qd, x)

    def loss(x):
        return fd(x).sin().sum()

    J = torch.autograd.functional.jacobian(fd, tau)
    refused = {"vjp": (lambda x: torch.func.vjp(fd, x)[1](w)[0], w @ J), "jacrev": (torch.func.jacrev(fd), J)}
    for name, (fn, expected) in refused.items():
        torch._dynamo.reset()
        with pytest.raises(NotImplementedError, match="forward_dynamics under torch.func.vjp or jacrev inside torch.compile"):
            torch.compile(fn)(tau)
        assert rel_err(fn(tau), expected) <= 1e-12, name
    run = {"grad": torch.func.grad(loss), "vmap of jacrev": torch.func.vmap(torch.func.jacrev(fd)),
           "jacrev of jacrev": torch.func.jacrev(torch.func.jacrev(loss)), "hessian": torch.func.hessian(loss)}
    for name, fn in run.items():
        torch._dynamo.reset()
        x = tau.expand(2, -1).clone() if name.startswith("vmap") else tau
        assert rel_err(torch.compile(fn)(x), fn(x)) <= 1e-12, name
