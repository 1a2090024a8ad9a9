"""Inertial parameters as inputs (`params=`, `with_parameters`): the robot's own parameters give the
compiled path; others equal Pinocchio with an edited model (model.inertias) and MuJoCo with edited
body_mass / body_ipos / body_iquat / body_inertia; gradients with respect to them by gradcheck and
gradgradcheck, torch.func and per-sample parameters against a loop; the physical-consistency helpers."""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import torch

import oracles
from oracles import PinOracle, rel_err, to_pin_q
from torch_grid import conventions as C
from torch_grid.optim.inertial import (
    check_physical,
    log_cholesky_to_parameters,
    parameters_to_log_cholesky,
    pseudo_inertia,
)

# name -> (call(view, q, qd, x, params), arity over (q, qd, x)) for every function that takes params
PARAMETER_FUNCTIONS = {
    "inverse_dynamics": lambda v, q, qd, x, p: v.inverse_dynamics(q, qd, x, params=p),
    "forward_dynamics": lambda v, q, qd, x, p: v.forward_dynamics(q, qd, x, params=p),
    "crba": lambda v, q, qd, x, p: v.crba(q, params=p),
    "minv": lambda v, q, qd, x, p: v.minv(q, params=p),
    "generalized_gravity": lambda v, q, qd, x, p: v.generalized_gravity(q, params=p),
    "nonlinear_effects": lambda v, q, qd, x, p: v.nonlinear_effects(q, qd, params=p),
    "energy": lambda v, q, qd, x, p: v.energy(q, qd, params=p),
    "com": lambda v, q, qd, x, p: v.com(q, params=p),
    "jacobian_com": lambda v, q, qd, x, p: v.jacobian_com(q, params=p),
    "ccrba": lambda v, q, qd, x, p: v.ccrba(q, qd, params=p),
    "cmm_time_variation": lambda v, q, qd, x, p: v.cmm_time_variation(q, qd, params=p),
    "dccrba": lambda v, q, qd, x, p: v.dccrba(q, qd, params=p),
    "coriolis_matrix": lambda v, q, qd, x, p: v.coriolis_matrix(q, qd, params=p),
    "inverse_dynamics_derivatives": lambda v, q, qd, x, p: v.inverse_dynamics_derivatives(q, qd, x, params=p),
    "forward_dynamics_derivatives": lambda v, q, qd, x, p: v.forward_dynamics_derivatives(q, qd, x, params=p),
    "forward_dynamics_external_force_derivatives":
        lambda v, q, qd, x, p: v.forward_dynamics_external_force_derivatives(q, params=p),
    "forward_dynamics_parameter_derivatives":
        lambda v, q, qd, x, p: v.forward_dynamics_parameter_derivatives(q, qd, x, params=p),
    "osc_inertia": lambda v, q, qd, x, p: v.osc_inertia(q, v.frame_names[-1], params=p),
    "centroidal_map_derivatives": lambda v, q, qd, x, p: v.centroidal_map_derivatives(q, params=p),
}
# their second derivatives, which have no backward of their own
SECOND_ORDER = {
    "inverse_dynamics_second_derivatives": lambda v, q, qd, x, p: v.inverse_dynamics_second_derivatives(q, qd, x, params=p),
    "forward_dynamics_second_derivatives": lambda v, q, qd, x, p: v.forward_dynamics_second_derivatives(q, qd, x, params=p),
}


DERIVATIVES = ("coriolis_matrix", "inverse_dynamics_derivatives", "forward_dynamics_derivatives",
               "forward_dynamics_external_force_derivatives", "forward_dynamics_parameter_derivatives", "osc_inertia",
               "centroidal_map_derivatives", "cmm_time_variation", "dccrba", "jacobian_com", "crba", "minv")


def _states(robot, batch, seed):
    g = torch.Generator().manual_seed(seed)
    q = robot.random_configuration(*batch, generator=g)
    qd, x = (torch.randn(*batch, robot.nv, generator=g, dtype=torch.float64) for _ in range(2))
    return q, qd, x


def own_parameters(robot) -> torch.Tensor:
    return robot.inertial_parameters().view(robot.nbodies, 10)


def other_parameters(robot, seed=0, scale=0.2) -> torch.Tensor:
    """Physically consistent parameters near the robot's own: a step in log-Cholesky coordinates."""
    g = torch.Generator().manual_seed(seed)
    theta = parameters_to_log_cholesky(own_parameters(robot))
    return log_cholesky_to_parameters(theta + scale * torch.randn(theta.shape, generator=g, dtype=torch.float64))


def _outputs(x):
    return x if isinstance(x, tuple) else (x,)


def _mujoco_state(q_pin, qd, x):
    """The same sample in MuJoCo's layout: q's quaternion reordered; qd, qdd and tau as they are (random)."""
    return C.q_pin_to_mujoco(q_pin) if q_pin.shape[-1] >= 7 else q_pin, qd, x


# -- the robot's own parameters are the compiled path ------------------------------------------------------
@pytest.mark.parametrize("name", ["iiwa14", "go2"])
@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_own_parameters_equal_the_compiled_path(robots, name, convention):
    robot = robots[name]
    view = getattr(robot, convention)
    q, qd, x = _states(robot, (3,), 1)
    if convention == "mujoco" and robot.floating_base:
        q = C.q_pin_to_mujoco(q)
    pi = own_parameters(robot)
    for function, call in {**PARAMETER_FUNCTIONS, **SECOND_ORDER}.items():
        for a, b in zip(_outputs(call(view, q, qd, x, None)), _outputs(call(view, q, qd, x, pi))):
            assert (a - b).abs().max() <= 1e-13 * (1 + a.abs().max()), function
    # and the fused step derivatives, on the view
    own = view.with_parameters(pi)
    for integrator in ("semi_implicit_euler", "rk4"):
        for a, b in zip(view.step_derivatives(q, qd, x, 0.01, integrator), own.step_derivatives(q, qd, x, 0.01, integrator)):
            assert (a - b).abs().max() <= 1e-13 * (1 + a.abs().max()), integrator


# -- other parameters: Pinocchio and MuJoCo with edited models -------------------------------------------
def _pin_edited(pin_model, pi):
    model = pin_model.copy()
    for i, row in enumerate(pi.numpy()):
        model.inertias[i + 1] = pin.Inertia.FromDynamicParameters(row)
    return model


@pytest.mark.parametrize("name", ["iiwa14", "go2"])
def test_other_parameters_equal_pinocchio_with_an_edited_model(robots, pin_models, name):
    robot = robots[name]
    pi = other_parameters(robot)
    P = PinOracle(_pin_edited(pin_models[name], pi))
    q, qd, x = _states(robot, (2,), 2)
    view = robot.pin
    for k in range(2):
        qp, v, a = to_pin_q(robot, q[k]), qd[k].numpy(), x[k].numpy()
        pairs = [(view.inverse_dynamics(q[k], qd[k], x[k], params=pi), P.rnea(qp, v, a)),
                 (view.forward_dynamics(q[k], qd[k], x[k], params=pi), P.aba(qp, v, a)),
                 (view.crba(q[k], params=pi), P.crba(qp)), (view.minv(q[k], params=pi), P.minv(qp)),
                 (view.generalized_gravity(q[k], params=pi), P.gravity(qp)),
                 (view.nonlinear_effects(q[k], qd[k], params=pi), P.nle(qp, v)),
                 (view.energy(q[k], qd[k], params=pi), P.energy(qp, v)), (view.com(q[k], params=pi), P.com(qp)),
                 (view.jacobian_com(q[k], params=pi), P.jacobian_com(qp))]
        A, h = view.ccrba(q[k], qd[k], params=pi)
        pairs += list(zip((A, h), P.ccrba(qp, v)))
        pm, pd = P.model, P.data
        pin.computeRNEADerivatives(pm, pd, qp, v, a)
        pairs += list(zip(view.inverse_dynamics_derivatives(q[k], qd[k], x[k], params=pi), (pd.dtau_dq.copy(), pd.dtau_dv.copy())))
        pin.computeABADerivatives(pm, pd, qp, v, a)
        pairs += list(zip(view.forward_dynamics_derivatives(q[k], qd[k], x[k], params=pi)[:2], (pd.ddq_dq.copy(), pd.ddq_dv.copy())))
        pairs.append((view.coriolis_matrix(q[k], qd[k], params=pi), pin.computeCoriolisMatrix(pm, pd, qp, v).copy()))
        for ours, ref in pairs:
            assert rel_err(ours, ref) <= 1e-11
        # the edit is not a no-op: the robot's own parameters give another mass matrix
        assert rel_err(view.crba(q[k]), P.crba(qp)) > 1e-3


def _mujoco_edited(robot, pi):
    """go2's MuJoCo model with each jointed body's inertia set from pi (in its frame, the joint frame) and
    the bodies welded to it (merged into pi, as in the robot's own parameters) made massless."""
    sim = oracles.mujoco_from_urdf(oracles.urdf_path_for("go2"), True, robot.joint_names)
    m = sim.m
    body_of = {int(m.jnt_bodyid[j]): j for j in range(m.njnt)}
    for b in range(1, m.nbody):
        if b not in body_of:
            m.body_mass[b], m.body_inertia[b] = 0.0, 0.0
            continue
        row = pi[body_of[b]].numpy()
        mass, c = row[0], row[1:4] / row[0]
        xx, xy, yy, xz, yz, zz = row[4:]
        Io = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        Ic = Io - mass * (c @ c * np.eye(3) - np.outer(c, c))
        w, R = np.linalg.eigh(Ic)
        if np.linalg.det(R) < 0:
            R[:, 0] = -R[:, 0]
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, R.reshape(-1))
        m.body_mass[b], m.body_ipos[b], m.body_iquat[b], m.body_inertia[b] = mass, c, quat, w
    mujoco.mj_setConst(m, sim.d)  # the subtree masses the centre of mass reads
    return sim


def test_other_parameters_equal_mujoco_with_an_edited_model(robots):
    robot = robots["go2"]
    pi = other_parameters(robot, seed=3)
    sim = _mujoco_edited(robot, pi)
    q_pin, qd, x = _states(robot, (2,), 4)
    q = C.q_pin_to_mujoco(q_pin)
    view = robot.mujoco
    for k in range(2):
        qm, v, a = q[k].numpy(), qd[k].numpy(), x[k].numpy()
        assert rel_err(view.crba(q[k], params=pi), sim.full_m(qm)) <= 1e-11
        assert rel_err(view.inverse_dynamics(q[k], qd[k], x[k], params=pi), sim.qfrc_inverse(qm, v, a)) <= 1e-11
        assert rel_err(view.forward_dynamics(q[k], qd[k], x[k], params=pi), sim.qacc(qm, v, a)) <= 1e-10
        assert rel_err(view.nonlinear_effects(q[k], qd[k], params=pi), sim.qfrc_bias(qm, v)) <= 1e-11
        assert rel_err(view.energy(q[k], qd[k], params=pi), sim.energy(qm, v)) <= 1e-11
        assert rel_err(view.com(q[k], params=pi), sim.subtree_com(qm)) <= 1e-11
        assert rel_err(view.jacobian_com(q[k], params=pi), sim.jac_subtree_com(qm)) <= 1e-11
        assert rel_err(view.crba(q[k]), sim.full_m(qm)) > 1e-3


def test_step_with_other_parameters_is_mujocos_rk4(robots):
    """One RK4 step in MuJoCo's convention with edited parameters against mj_step with the edited model, and
    its derivatives (the fused kernel with the parameters) against centred differences of the step."""
    robot = robots["go2"]
    pi = other_parameters(robot, seed=5)
    sim = _mujoco_edited(robot, pi)
    m, d, dt = sim.m, sim.d, 0.005
    m.opt.integrator, m.opt.timestep = mujoco.mjtIntegrator.mjINT_RK4, dt
    q_pin, qd, tau = _states(robot, (), 6)
    q = C.q_pin_to_mujoco(q_pin)
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q.numpy(), qd.numpy(), tau.numpy()
    mujoco.mj_step(m, d)
    q_next, qd_next = robot.mujoco.step(q, qd, tau, dt, "rk4", params=pi)
    assert rel_err(q_next, d.qpos) <= 1e-10 and rel_err(qd_next, d.qvel) <= 1e-10
    A, B = robot.mujoco.step_derivatives(q, qd, tau, dt, "rk4", params=pi)
    eps, cols = 1e-6, []
    for k in range(2 * robot.nv):
        z = torch.zeros(2 * robot.nv, dtype=torch.float64)
        ends = []
        for sign in (1.0, -1.0):
            z[k] = sign * eps
            qn, vn = robot.mujoco.step(robot.mujoco.integrate(q, z[:robot.nv]), qd + z[robot.nv:], tau, dt, "rk4",
                                       params=pi)
            ends.append(torch.cat([robot.mujoco.difference(q_next, qn), vn - qd_next]))
        cols.append((ends[0] - ends[1]) / (2 * eps))
    assert rel_err(A, torch.stack(cols, -1)) <= 1e-6
    # the horizon call and the centre-of-mass cost with the parameters are the per-knot calls with them
    target, weights = torch.zeros(3, dtype=torch.float64), torch.ones(3, dtype=torch.float64)
    out = robot.mujoco.horizon(q[None], qd[None], tau[None], dt, "rk4",  # one knot
                               [("com_cost", {"target": target, "weights": weights})], params=pi)
    assert torch.equal(out["A"][0], A) and torch.equal(out["B"][0], B)
    assert torch.equal(out["cost"][0], robot.mujoco.com_cost(q, qd, target, weights, params=pi)[0])


# -- per-sample parameters -----------------------------------------------------------------------------
def test_per_sample_parameters_equal_a_loop(robots):
    robot = robots["go2"]
    q, qd, x = _states(robot, (3,), 5)
    pis = torch.stack([other_parameters(robot, seed=s) for s in range(3)])
    for function, call in PARAMETER_FUNCTIONS.items():
        batched = _outputs(call(robot.mujoco, C.q_pin_to_mujoco(q), qd, x, pis))
        for k in range(3):
            single = _outputs(call(robot.mujoco, C.q_pin_to_mujoco(q[k]), qd[k], x[k], pis[k]))
            for b, s in zip(batched, single):
                assert torch.allclose(b[k], s, rtol=1e-13, atol=1e-13), function
    # one set of parameters broadcast over a batch of states, and a batch of parameters over one state
    a = robot.crba(q, params=pis[0])
    assert torch.allclose(a, torch.stack([robot.crba(q[k], params=pis[0]) for k in range(3)]), rtol=1e-13, atol=1e-13)
    b = robot.crba(q[0], params=pis)
    assert b.shape == (3, robot.nv, robot.nv)
    assert torch.allclose(b[1], robot.crba(q[0], params=pis[1]), rtol=1e-13, atol=1e-13)


# -- gradients -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,convention", [("iiwa14", "pin"), ("go2", "pin"), ("go2", "mujoco")])
def test_gradients_with_respect_to_parameters_and_state(robots, name, convention):
    """gradcheck with respect to params and every state input, all at once, in float64."""
    robot = robots[name]
    view = getattr(robot, convention)
    q, qd, x = _states(robot, (2,), 6)
    if convention == "mujoco":
        q = C.q_pin_to_mujoco(q)
    pi = other_parameters(robot, seed=7)
    for function, call in PARAMETER_FUNCTIONS.items():
        inputs = tuple(t.clone().requires_grad_(True) for t in (q, qd, x, pi))
        fast = function in DERIVATIVES  # random projections of the Jacobian: its outputs are matrices
        assert torch.autograd.gradcheck(lambda *a: call(view, *a), inputs, eps=1e-6, atol=1e-6, rtol=1e-5,
                                        fast_mode=fast), function


def test_a_rollout_differentiates_with_respect_to_parameters(robots):
    """gradcheck of three RK4 steps with respect to per-sample parameters (the loss of a rollout trains them)."""
    robot = robots["iiwa14"]
    q, qd, tau = _states(robot, (2,), 16)
    pis = torch.stack([other_parameters(robot, seed=s) for s in (17, 18)]).requires_grad_(True)

    def rollout(p):
        x, v = q, qd
        for _ in range(3):
            x, v = robot.step(x, v, tau, 0.01, "rk4", params=p)
        return torch.cat([x, v], -1)

    assert torch.autograd.gradcheck(rollout, (pis,), eps=1e-6, atol=1e-6, rtol=1e-5, fast_mode=True)


def test_float32_parameters_are_float64_rounded(robots):
    """float32 calls with float32 parameters run the float64 kernels on the widened inputs (test_api)."""
    robot = robots["go2"]
    q, qd, x = _states(robot, (5,), 19)
    pi = other_parameters(robot, seed=20).float()
    for function, call in PARAMETER_FUNCTIONS.items():
        single = _outputs(call(robot.pin, q.float(), qd.float(), x.float(), pi))
        double = _outputs(call(robot.pin, q.float().double(), qd.float().double(), x.float().double(), pi.double()))
        for s, d in zip(single, double):
            assert s.dtype == torch.float32 and torch.equal(s, d.float()), function


@pytest.mark.parametrize("function", ["inverse_dynamics", "forward_dynamics", "crba", "minv", "generalized_gravity",
                                      "nonlinear_effects", "energy"])
def test_second_derivatives_with_respect_to_parameters(robots, function):
    robot = robots["iiwa14"]
    q, qd, x = _states(robot, (1,), 8)
    pi = other_parameters(robot, seed=9)
    call = PARAMETER_FUNCTIONS[function]
    inputs = tuple(t.clone().requires_grad_(True) for t in (q, qd, x, pi))
    assert torch.autograd.gradgradcheck(lambda *a: call(robot.pin, *a), inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_torch_func_with_respect_to_parameters(robots, convention):
    """torch.func along the parameters: jvp (forward mode) and vjp (reverse) agree, <u, J t> = <J^T u, t>, for
    random u and t (the reverse mode is held to central differences by gradcheck above); jacrev and jacfwd
    give autograd's Jacobian on the dynamics; vmap over per-sample parameters is the loop."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, x = _states(robot, (), 10)
    if convention == "mujoco":
        q = C.q_pin_to_mujoco(q)
    pi = other_parameters(robot, seed=11)
    g = torch.Generator().manual_seed(12)
    t = torch.randn(pi.shape, dtype=torch.float64, generator=g)
    pis = torch.stack([pi, other_parameters(robot, seed=12)])
    for function, call in PARAMETER_FUNCTIONS.items():
        f = lambda p: torch.cat([o.flatten() for o in _outputs(call(view, q, qd, x, p))])  # noqa: E731
        value, forward = torch.func.jvp(f, (pi,), (t,))
        u = torch.randn(value.shape, dtype=torch.float64, generator=g)
        reverse = torch.func.vjp(f, pi)[1](u)[0]
        assert torch.allclose((u * forward).sum(), (reverse * t).sum(), rtol=1e-10, atol=1e-10), function
        assert torch.allclose(torch.func.vmap(f)(pis), torch.stack([f(p) for p in pis]), rtol=1e-13, atol=1e-13)
    for function in ("inverse_dynamics", "forward_dynamics"):
        f = lambda p: PARAMETER_FUNCTIONS[function](view, q, qd, x, p)  # noqa: E731
        reference = torch.autograd.functional.jacobian(f, pi)
        assert torch.allclose(torch.func.jacrev(f)(pi), reference, rtol=1e-10, atol=1e-10), function
        assert torch.allclose(torch.func.jacfwd(f)(pi), reference, rtol=1e-10, atol=1e-10), function


# -- the view ------------------------------------------------------------------------------------------
def test_with_parameters_view(robots):
    robot = robots["go2"]
    q, qd, x = _states(robot, (2,), 14)
    pi = other_parameters(robot, seed=15)
    view = robot.mujoco.with_parameters(pi)
    assert view.convention == "mujoco" and "given inertial parameters" in repr(view)
    qm = C.q_pin_to_mujoco(q)
    assert torch.equal(view.forward_dynamics(qm, qd, x), robot.mujoco.forward_dynamics(qm, qd, x, params=pi))
    assert torch.equal(view.com(qm), robot.mujoco.com(qm, params=pi))
    assert torch.equal(view.inertial_parameters(), pi.flatten(-2))
    # in the parameters' own dtype unless asked otherwise (a float32 set came back as a float64 copy)
    assert robot.with_parameters(pi.float()).inertial_parameters().dtype == torch.float32
    assert robot.with_parameters(pi.float()).inertial_parameters(torch.float64).dtype == torch.float64
    assert robot.inertial_parameters().dtype == torch.float64
    # an integer dtype truncated the parameters (masses of 0 kg)
    for source in (robot, view):
        with pytest.raises(TypeError, match="inertial_parameters: dtype must be torch.float32 or torch.float64, got torch.int64"):
            source.inertial_parameters(torch.int64)
    # composed functions compute with the view's parameters too
    q_next, qd_next = view.step(qm, qd, x, 0.01)  # the step kernel, with the parameters
    assert rel_err(qd_next, qd + 0.01 * view.forward_dynamics(qm, qd, x)) <= 1e-15
    assert not torch.allclose(qd_next, robot.mujoco.step(qm, qd, x, 0.01)[1], rtol=1e-6, atol=1e-6)
    assert not torch.allclose(view.step(qm, qd, x, 0.01, integrator="rk4")[1],
                              robot.mujoco.step(qm, qd, x, 0.01, integrator="rk4")[1], rtol=1e-6, atol=1e-6)
    compiled = torch.compile(lambda q, qd, tau: view.step(q, qd, tau, 0.01, integrator="rk4"), fullgraph=False)
    assert torch.allclose(compiled(qm, qd, x)[1], view.step(qm, qd, x, 0.01, integrator="rk4")[1], rtol=1e-12, atol=1e-12)
    # a kernel without parameters refuses rather than compute with the robot's own
    # the fused step kernels with the parameters equal the torch composition (taken when differentiated)
    for integrator in ("semi_implicit_euler", "rk4"):
        fused = view.step(qm, qd, x, 0.01, integrator) + view.step_derivatives(qm, qd, x, 0.01, integrator)
        q_grad = qm.clone().requires_grad_(True)
        composed = view.step(q_grad, qd, x, 0.01, integrator) + view.step_derivatives(q_grad, qd, x, 0.01, integrator)
        for a, b in zip(fused, composed):
            assert rel_err(a, b.detach()) <= 1e-11, integrator
    # kinematics do not depend on the parameters
    assert torch.equal(view.frame_jacobian(qm, view.frame_names[-1]), robot.mujoco.frame_jacobian(qm, view.frame_names[-1]))
    with pytest.raises(ValueError, match=r"params must be a tensor of shape \(\.\.\., 13, 10\)"):
        robot.with_parameters(pi[:3])
    with pytest.raises(ValueError, match="params: the leading batch shapes do not broadcast|params"):
        robot.crba(q, params=torch.stack([pi] * 3))


def test_check_names_the_body(robots):
    robot = robots["iiwa14"]
    pi = own_parameters(robot).clone()
    robot.with_parameters(pi, check=True)
    # an empty batch has nothing to refuse (it failed in a min() of nothing); an integer set is refused by its
    # dtype (check=True read its truncated masses and blamed a joint that moves no mass)
    robot.with_parameters(pi.expand(0, *pi.shape), check=True)
    with pytest.raises(TypeError, match="with_parameters: params must be float32 or float64, got torch.int64"):
        robot.with_parameters(pi.long(), check=True)
    bad = pi.clone()
    bad[3, 0] = -1.0
    with pytest.raises(ValueError, match=f"body 3 \\({robot.joint_names[3]!r}\\) has a negative mass"):
        robot.with_parameters(bad, check=True)
    bad = pi.clone()
    bad[2, 4] = 50.0  # I_xx far above I_yy + I_zz: a broken triangle inequality
    with pytest.raises(ValueError, match=f"body 2 \\({robot.joint_names[2]!r}\\) is not physically consistent"):
        robot.with_parameters(bad, check=True)


# -- the log-Cholesky parametrisation ------------------------------------------------------------------
def test_log_cholesky_round_trip_and_consistency():
    theta = torch.randn(50, 10, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    params = log_cholesky_to_parameters(theta)
    assert (params[:, 0] > 0).all()
    assert (torch.linalg.eigvalsh(pseudo_inertia(params)) > 0).all()
    assert torch.allclose(parameters_to_log_cholesky(params), theta, rtol=1e-10, atol=1e-10)
    check_physical(params.unsqueeze(0), [f"b{k}" for k in range(50)])
    # the rotational inertia about the centre of mass is positive and meets the triangle inequalities
    m, c = params[:, 0], params[:, 1:4] / params[:, :1]
    xx, xy, yy, xz, yz, zz = params[:, 4:].unbind(-1)
    Io = torch.stack([torch.stack([xx, xy, xz], -1), torch.stack([xy, yy, yz], -1), torch.stack([xz, yz, zz], -1)], -2)
    Ic = Io - m[:, None, None] * ((c * c).sum(-1)[:, None, None] * torch.eye(3, dtype=torch.float64)
                                  - c.unsqueeze(-1) * c.unsqueeze(-2))
    w = torch.linalg.eigvalsh(Ic)
    assert (w > 0).all() and (w[:, 0] + w[:, 1] >= w[:, 2] - 1e-12).all()
    assert torch.autograd.gradcheck(log_cholesky_to_parameters, (theta[:3].clone().requires_grad_(True),))


def test_log_cholesky_helpers_refuse_integer_tensors_and_wrong_sizes_naming_them():
    # an integer tensor gave float32 results (its values truncated first), a wrong size an unpacking error
    params = log_cholesky_to_parameters(torch.zeros(2, 10, dtype=torch.float64))
    cases = [
        (TypeError, r"pseudo_inertia: params must be a float tensor, got torch.int64", lambda: pseudo_inertia(params.long())),
        (ValueError, r"pseudo_inertia: params must have shape \(\.\.\., 10\), got \(2, 9\)",
         lambda: pseudo_inertia(params[:, :9])),
        (TypeError, r"log_cholesky_to_parameters: theta must be a float tensor, got torch.int64",
         lambda: log_cholesky_to_parameters(torch.zeros(2, 10, dtype=torch.long))),
        (ValueError, r"log_cholesky_to_parameters: theta must have shape \(\.\.\., 10\), got \(2, 11\)",
         lambda: log_cholesky_to_parameters(torch.zeros(2, 11, dtype=torch.float64))),
        (ValueError, r"parameters_to_log_cholesky: params must have shape \(\.\.\., 10\), got \(10, 1\)",
         lambda: parameters_to_log_cholesky(params[0].unsqueeze(-1))),
        (TypeError, r"parameters_to_log_cholesky: params must be a torch.Tensor, got list",
         lambda: parameters_to_log_cholesky(params.tolist())),
    ]
    for error, message, call in cases:
        with pytest.raises(error, match=message):
            call()
    assert pseudo_inertia(params.float()).dtype == torch.float32 and pseudo_inertia(params[:0]).shape == (0, 4, 4)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_parameter_derivatives_with_external_forces(robots, convention):
    """d qdd / d params where external forces act (they move qdd, where Y is evaluated): against central
    differences of forward_dynamics along the parameters, and equal to the kernel's where f_ext is zero."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, tau = _states(robot, (2,), 21)
    if convention == "mujoco":
        q = C.q_pin_to_mujoco(q)
    f_ext = torch.randn(2, robot.nbodies, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(22))
    pi = other_parameters(robot, seed=23)
    ours = view.forward_dynamics_parameter_derivatives(q, qd, tau, f_ext, pi)
    direction = torch.randn(pi.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(24))
    h = 1e-6
    ref = (view.forward_dynamics(q, qd, tau, f_ext, pi + h * direction)
           - view.forward_dynamics(q, qd, tau, f_ext, pi - h * direction)) / (2 * h)
    assert rel_err(ours @ direction.reshape(-1), ref) <= 1e-7
    zero = torch.zeros_like(f_ext)
    assert rel_err(view.forward_dynamics_parameter_derivatives(q, qd, tau, zero, pi),
                   view.forward_dynamics_parameter_derivatives(q, qd, tau, params=pi)) <= 1e-12
