"""The step of models with joint damping and springs: MuJoCo's mj_step under its own flags (the Euler
integrator's damping implicit unless eulerdamp is disabled), mjd_transitionFD, the kernels against the
torch composition that autograd differentiates, the step Hessian against differences of its Jacobians,
and mpc.pytorch's dynamics."""
from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest
import torch

import torch_grid
from mjcf_models import DAMPED_FLOATING, DAMPED_PLANAR
from oracles import rel_err
from test_step import _mj_step_differences
from torch_grid.step.integrators import INTEGRATORS
from torch_grid.optim.mpc_adapter import MPCDynamics

MODELS = {"planar": DAMPED_PLANAR, "floating": DAMPED_FLOATING}
MJ_INTEGRATORS = {"semi_implicit_euler": mujoco.mjtIntegrator.mjINT_EULER, "rk4": mujoco.mjtIntegrator.mjINT_RK4}


@pytest.fixture(scope="module")
def damped(robots):
    """name -> (robot with MuJoCo's default eulerdamp, robot with it off, the MjModel text)."""
    out = {}
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "the MJCF model has")
        for name, text in MODELS.items():
            out[name] = (robots[f"damped_{name}"], torch_grid.load(text, eulerdamp=False), text)
    return out


def _mj(text: str, integrator: str, dt: float, eulerdamp: bool):
    """MuJoCo's model under its default flags but contacts (none of the rigid-body dynamics)."""
    m = mujoco.MjModel.from_xml_string(text)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    if not eulerdamp:
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    m.opt.integrator, m.opt.timestep = MJ_INTEGRATORS[integrator], dt
    return m, mujoco.MjData(m)


def _state(view, nv, batch, seed):
    g = torch.Generator().manual_seed(seed)
    q = view.random_configuration(batch, generator=g)
    qd, tau = (3 * torch.randn(batch, nv, dtype=torch.float64, generator=g) for _ in range(2))
    return q, qd, tau


def test_eulerdamp_follows_the_mjcf_flag():
    """The load option defaults to the MJCF's flag; eulerdamp=False or the flag disabled change the
    step, and the option is refused when not a bool."""
    off = DAMPED_PLANAR.replace('<option gravity="0 0 -9.81"/>', '<option gravity="0 0 -9.81"><flag eulerdamp="disable"/></option>')
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "the MJCF model has")
        assert torch_grid.load(DAMPED_PLANAR)._implicit_damping
        assert not torch_grid.load(off)._implicit_damping
        assert torch_grid.load(off, eulerdamp=True)._implicit_damping
        assert not torch_grid.load(DAMPED_PLANAR, passive_forces=False)._implicit_damping
        with pytest.raises(TypeError, match="eulerdamp must be None, True or False, got 'yes'"):
            torch_grid.load(DAMPED_PLANAR, eulerdamp="yes")


@pytest.mark.parametrize("integrator", list(MJ_INTEGRATORS))
@pytest.mark.parametrize("eulerdamp", [True, False])
@pytest.mark.parametrize("name", list(MODELS))
def test_step_is_mj_step(damped, name, eulerdamp, integrator):
    """step in MuJoCo's convention against mj_step with qfrc_applied = tau, MuJoCo's flags (eulerdamp on
    or off) matching the load option; the damping is stiff enough (dt D / M up to 1) that an explicit
    step would differ by far more than the tolerance. RK4, explicit, at the smaller steps it is stable at
    (at dt = 0.05 the ball joint's velocity grows to 1e3 rad/s in one step)."""
    robot = damped[name][0 if eulerdamp else 1]
    text = damped[name][2]
    q, qd, tau = _state(robot.mujoco, robot.nv, 3, 1)
    for dt in (0.01, 0.05) if integrator == "semi_implicit_euler" else (0.005, 0.01):
        m, d = _mj(text, integrator, dt, eulerdamp)
        q_next, qd_next = robot.mujoco.step(q, qd, tau, dt, integrator)
        for k in range(3):
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q[k].numpy(), qd[k].numpy(), tau[k].numpy()
            mujoco.mj_step(m, d)
            assert np.abs(q_next[k].numpy() - d.qpos).max() <= 1e-9 * max(1.0, np.abs(d.qpos).max())
            assert np.abs(qd_next[k].numpy() - d.qvel).max() <= 1e-9 * max(1.0, np.abs(d.qvel).max())


@pytest.mark.parametrize("integrator", list(MJ_INTEGRATORS))
@pytest.mark.parametrize("eulerdamp", [True, False])
@pytest.mark.parametrize("name", list(MODELS))
def test_step_derivatives_are_mjd_transitionFD(damped, name, eulerdamp, integrator):
    """A and B (the motors' columns) against MuJoCo's mjd_transitionFD (centred differences of mj_step;
    for RK4, which it refuses, the same differences written here, at a larger step: on the stiff springs
    MuJoCo's RK4 rounds to 1e-11, which steps of 1e-7 amplify to 1e-4), on the kernel path and on the path
    autograd records."""
    robot = damped[name][0 if eulerdamp else 1]
    m, d = _mj(damped[name][2], integrator, 0.01, eulerdamp)
    motors = [m.jnt_dofadr[m.actuator_trnid[a, 0]] for a in range(m.nu)]
    q, qd, tau = _state(robot.mujoco, robot.nv, 2, 3)
    kernel = robot.mujoco.step_derivatives(q, qd, tau, 0.01, integrator)
    traced = robot.mujoco.step_derivatives(q.clone().requires_grad_(), qd, tau, 0.01, integrator)
    for k in range(2):
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q[k].numpy(), qd[k].numpy(), tau[k].numpy()
        if integrator == "rk4":
            fd_a, fd_b = _mj_step_differences(m, d, q[k].numpy(), qd[k].numpy(), d.qfrc_applied.copy(),
                                              d.ctrl.copy(), 1e-5)
        else:
            fd_a, fd_b = np.zeros((2 * m.nv, 2 * m.nv)), np.zeros((2 * m.nv, m.nu))
            mujoco.mjd_transitionFD(m, d, 1e-7, True, fd_a, fd_b, None, None)
        tol = 1e-6 if integrator == "semi_implicit_euler" else 1e-5
        for A, B in (kernel, traced):
            assert rel_err(A[k], fd_a) <= tol
            assert rel_err(B[k][:, motors], fd_b) <= tol


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", list(MODELS))
def test_kernels_are_the_composition(damped, name, convention):
    """Every integrator, with the damping implicit and explicit: the kernels' (q', qd', A, B), which run when
    nothing differentiates them (step_derivatives, horizon), equal the torch composition autograd
    records, and horizon's with a step Hessian too."""
    for robot in damped[name][:2]:
        view = getattr(robot, convention)
        q, qd, tau = _state(view, robot.nv, 3, 5)
        for integrator in INTEGRATORS:
            kernel = view._step_and_derivatives(q, qd, tau, 0.02, integrator, None)
            traced = view._step_and_derivatives(q, qd.clone().requires_grad_(), tau, 0.02, integrator, None)
            for ours, ref in zip(kernel, traced):
                assert rel_err(ours, ref) <= 1e-12, integrator
            for ours, ref in zip(kernel[:2], view.step(q, qd, tau, 0.02, integrator)):
                assert rel_err(ours, ref) <= 1e-12
            out = view.horizon(q.unsqueeze(-2), qd.unsqueeze(-2), tau.unsqueeze(-2), 0.02, integrator,
                               step_hessian=True)
            assert rel_err(out["A"].squeeze(-3), traced[2]) <= 1e-12
            assert rel_err(out["B"].squeeze(-3), traced[3]) <= 1e-12


def test_bundled_humanoid_kernels_are_the_composition():
    """The bundled MJCF humanoid (damped and sprung hinges, a free root): kernel and composition agree."""
    robot = torch_grid.load("humanoid")
    for view in (robot.pin, robot.mujoco):
        q, qd, tau = _state(view, robot.nv, 2, 9)
        for integrator in ("euler", "semi_implicit_euler", "rk4"):
            kernel = view.step_derivatives(q, qd, tau, 0.01, integrator)
            traced = view.step_derivatives(q, qd, tau.clone().requires_grad_(), 0.01, integrator)
            for ours, ref in zip(kernel, traced):
                assert rel_err(ours, ref) <= 1e-11, integrator


def _tangent_shift(view, q, qd, tau, z):
    nv = qd.shape[-1]
    return view.integrate(q, z[..., :nv], 1.0), qd + z[..., nv:2 * nv], tau + z[..., 2 * nv:]


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("integrator", ["euler", "semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("name", list(MODELS))
def test_step_hessian_is_the_derivative_of_the_jacobians(damped, name, integrator, convention):
    """step_second_derivatives (the damping implicit in semi_implicit_euler): u^T H w against central
    differences along u of the velocity rows of [A B] w, symmetrised in (u, w): moving q along the tangent
    turns A's input chart, which adds A's product with the Lie bracket of u and w, antisymmetric."""
    robot = damped[name][0]
    view = getattr(robot, convention)
    q, qd, tau = _state(view, robot.nv, 2, 11)
    nv, dt, eps = robot.nv, 0.01, 1e-6
    H = view.step_second_derivatives(q, qd, tau, dt, integrator)
    g = torch.Generator().manual_seed(2)
    u, w = (torch.randn(2, 3 * nv, dtype=torch.float64, generator=g) for _ in range(2))

    def along(a, b):
        diffs = []
        for sign in (1, -1):
            A, B = view.step_derivatives(*_tangent_shift(view, q, qd, tau, sign * eps * a), dt, integrator)
            diffs.append((torch.cat([A, B], dim=-1) @ b.unsqueeze(-1)).squeeze(-1))
        return (diffs[0] - diffs[1]) / (2 * eps)

    fd = (along(u, w) + along(w, u)) / 2
    ours = torch.einsum("...rab,...a,...b->...r", H, u, w)
    assert rel_err(ours[..., nv:], fd[..., nv:]) <= 1e-6


@pytest.mark.parametrize("name", list(MODELS))
def test_mpc_grad_input_is_autograd(damped, name):
    """MPCDynamics.grad_input (step_derivatives' kernel mapped to q's coordinates) against the Jacobian
    autograd takes of forward."""
    robot = damped[name][0]
    dyn = MPCDynamics(robot.mujoco, 0.01)
    q, qd, tau = _state(robot.mujoco, robot.nv, 2, 13)
    x = torch.cat([q, qd], dim=-1)
    R, S = dyn.grad_input(x, tau)
    for k in range(2):
        jx, ju = torch.autograd.functional.jacobian(lambda a, b: dyn(a, b), (x[k], tau[k]))
        if name == "planar":  # plain coordinates: the Jacobians themselves
            assert rel_err(R[k], jx) <= 1e-12
        else:  # q's coordinates on the unit sphere: the same along its tangent
            assert rel_err(R[k][:, robot.nq:], jx[:, robot.nq:]) <= 1e-12
        assert rel_err(S[k], ju) <= 1e-12


@pytest.mark.parametrize("name", list(MODELS))
def test_energy_holds_the_springs_as_mj_energy_pos(damped, name):
    """energy's potential holds the joint springs' (mj_energyPos: gravity and sum k (q - springref)^2 / 2) in MuJoCo's
    convention and Pinocchio's, and kinetic + potential is the mechanical; a robot loaded without the passive forces
    has gravity's alone (MuJoCo with its springs turned off). Differentiable: its gradient in q is minus the springs'
    and gravity's generalized forces, that is generalized_gravity - passive_forces at qd = 0."""
    robot, text = damped[name][0], damped[name][2]
    m, d = _mj(text, "semi_implicit_euler", 0.01, True)
    q, qd, _ = _state(robot.mujoco, robot.nv, 3, 5)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "the MJCF model has")
        rigid = torch_grid.load(text, passive_forces=False)
    assert robot.includes_passive_forces and not rigid.includes_passive_forces
    assert "passive forces" in repr(robot) and "passive" not in repr(rigid)
    for view, springs in ((robot.mujoco, True), (rigid.mujoco, False)):
        m.opt.disableflags = int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | (0 if springs else int(mujoco.mjtDisableBit.mjDSBL_SPRING))
        energy = view.energy(q, qd)
        for k in range(3):
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:] = q[k].numpy(), qd[k].numpy()
            mujoco.mj_forward(m, d)
            mujoco.mj_energyPos(m, d)
            mujoco.mj_energyVel(m, d)
            reference = np.array([d.energy[1], d.energy[0], d.energy[0] + d.energy[1]])
            assert np.abs(energy[k].numpy() - reference).max() <= 1e-12 * max(1.0, np.abs(reference).max())
    pin_q = robot.pin.random_configuration(2, generator=torch.Generator().manual_seed(6))
    springs = robot.pin.energy(pin_q, torch.zeros(2, robot.nv, dtype=torch.float64))[:, 1] - rigid.pin.energy(
        pin_q, torch.zeros(2, robot.nv, dtype=torch.float64))[:, 1]
    torch.testing.assert_close(springs, robot._passive.spring_energy(pin_q), rtol=0, atol=1e-12)
    assert (springs > 0).all()
    leaf = q.clone().requires_grad_()
    (grad,) = torch.autograd.grad(robot.mujoco.energy(leaf, torch.zeros_like(qd))[:, 1].sum(), leaf)
    zero = torch.zeros_like(qd)
    expected = robot.mujoco.generalized_gravity(q) - robot.mujoco.passive_forces(q, zero)
    dofs = [m.jnt_dofadr[j] for j in range(m.njnt) if m.jnt_type[j] in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)]
    qpos = [m.jnt_qposadr[j] for j in range(m.njnt) if m.jnt_type[j] in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)]
    torch.testing.assert_close(grad[:, qpos], expected[:, dofs], rtol=0, atol=1e-10)


SWITCHED = DAMPED_PLANAR.replace('<option gravity="0 0 -9.81"/>', '<option gravity="0 0 -9.81"><flag {}/></option>')


@pytest.mark.parametrize("flags", ['spring="disable"', 'damper="disable"', 'spring="disable" damper="disable"'])
def test_the_passive_switches_are_mujocos(flags):
    """MuJoCo's switches of the joints' springs and dampers (<flag spring="disable"/>, damper="disable") hold in the
    model read: its passive forces are qfrc_passive under them (the model alone, no kernels built)."""
    from torch_grid.model.mjcf import from_mujoco
    from torch_grid.step.passive import PassiveForces

    m = mujoco.MjModel.from_xml_string(SWITCHED.format(flags))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    d = mujoco.MjData(m)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "the MJCF model has")
        model = from_mujoco(m)
    g = np.random.default_rng(2)
    d.qpos[:], d.qvel[:] = g.normal(size=m.nq), g.normal(size=m.nv)
    mujoco.mj_forward(m, d)
    ours = PassiveForces(model)(torch.as_tensor(d.qpos.copy()), torch.as_tensor(d.qvel.copy()))
    assert np.abs(ours.numpy() - d.qfrc_passive).max() <= 1e-12
    assert ("spring" in flags) == (not any(j.stiffness for j in model.joints))
    assert ("damper" in flags) == (not any(j.damping for j in model.joints))


def test_nonlinear_passive_coefficients_are_refused_and_invdiscrete_is_named():
    """MuJoCo 4's higher damping and stiffness coefficients (damping="c0 c1") are refused, naming the joint; the
    invdiscrete flag (mj_inverse of a discrete step's acceleration) is named in the warning of what is not modelled."""
    from torch_grid.model.mjcf import from_mujoco

    for attribute, value in (('damping="0.4"', 'damping="0.4 0.8"'), ('stiffness="3"', 'stiffness="3 5"')):
        m = mujoco.MjModel.from_xml_string(DAMPED_PLANAR.replace(attribute, value, 1))
        if not hasattr(m, "dof_dampingpoly"):
            pytest.skip("this MuJoCo has no nonlinear passive coefficients")
        with pytest.raises(ValueError, match=r"joint 'root\w': \w+ has nonlinear coefficients .* give one coefficient"), \
                warnings.catch_warnings():
            warnings.filterwarnings("ignore", "the MJCF model has")
            from_mujoco(m)
    m = mujoco.MjModel.from_xml_string(SWITCHED.format('invdiscrete="enable"'))
    with pytest.warns(UserWarning, match="invdiscrete"):
        from_mujoco(m)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_a_nan_sample_stays_in_its_sample_through_the_damped_euler_composition(damped, convention):
    """MuJoCo's Euler step solves with M + dt D: under autograd (the torch composition) a sample whose matrix
    cannot be factored (a NaN in its state) is NaN alone, as in the kernel, instead of failing the batch."""
    robot = damped["floating"][0]
    view, nv = getattr(robot, convention), robot.nv
    g = torch.Generator().manual_seed(5)
    q = view.random_configuration(3, generator=g)
    q[1, -1] = float("nan")
    qd, tau = (torch.randn(3, nv, dtype=torch.float64, generator=g) for _ in range(2))
    kernel = view.step(q, qd, tau, 0.01) + view.step_derivatives(q, qd, tau, 0.01)
    tau_grad = tau.clone().requires_grad_(True)
    composed = view.step(q, qd, tau_grad, 0.01) + view.step_derivatives(q, qd, tau_grad, 0.01)
    hessian = view.step_second_derivatives(q, qd, tau, 0.01)
    for k, c in zip(kernel, composed):
        assert torch.isnan(c[1]).all() and torch.isnan(k[1]).all()
        assert rel_err(c[[0, 2]].detach(), k[[0, 2]]) <= 1e-12
    # the Hessian's entries along tau alone are zero whatever the state
    assert torch.isnan(hessian[1, :, :2 * nv, :2 * nv]).all() and torch.isfinite(hessian[[0, 2]]).all()
    (grad,) = torch.autograd.grad(composed[1][[0, 2]].sum(), tau_grad)
    assert torch.isfinite(grad[[0, 2]]).all()


def test_passive_forces_check_their_arguments(damped):
    """The passive forces, which no kernel checks, refuse what every function refuses, naming the function
    that reads them."""
    robot = damped["floating"][0]
    q, qd = robot.random_configuration(2), torch.zeros(2, robot.nv, dtype=torch.float64)
    cases = [
        (TypeError, r"passive_forces: q must be float32 or float64, got torch.int64", lambda: robot.passive_forces(q.long(), qd)),
        (TypeError, r"passive_forces: qd has dtype torch.float32 but q has torch.float64", lambda: robot.passive_forces(q, qd.float())),
        (ValueError, rf"passive_forces: qd must have shape \(\.\.\., {robot.nv}\), got \(2, 1\)", lambda: robot.passive_forces(q, qd[:, :1])),
        (ValueError, rf"passive_forces: q must have shape \(\.\.\., {robot.nq}\)", lambda: robot.passive_forces(q[:, 1:], qd)),
        (TypeError, r"forward_dynamics: tau must be float32 or float64, got torch.bool",
         lambda: robot.forward_dynamics(q, qd, qd.bool())),
        (TypeError, r"forward_dynamics_derivatives: tau must be float32 or float64, got torch.int64",
         lambda: robot.forward_dynamics_derivatives(q, qd, qd.long())),
        (TypeError, r"step: tau has dtype torch.float32 but q has torch.float64",
         lambda: robot.step(q, qd.requires_grad_(True), qd.float(), 0.01)),
        (TypeError, r"inverse_dynamics_second_derivatives: q must be float32 or float64",
         lambda: robot.mujoco.inverse_dynamics_second_derivatives(q.long(), qd, qd)),
    ]
    for exc, message, call in cases:
        with pytest.raises(exc, match=message):
            call()
