"""The plant step and its Jacobians (torch_grid/step/integrators.py): against MuJoCo's mj_step (Euler and
RK4), the same schemes written with Pinocchio's aba and integrate, Crocoddyl's semi-implicit Euler
derivatives written with Pinocchio, and central differences; autograd through step to second order."""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import torch
from torch.autograd import forward_ad

from oracles import rel_err
from torch_grid.step.integrators import INTEGRATORS, RK_FUSED, TABLEAUS

MJ_INTEGRATORS = {"semi_implicit_euler": mujoco.mjtIntegrator.mjINT_EULER, "rk4": mujoco.mjtIntegrator.mjINT_RK4}


def _state(view, robot, batch, seed):
    g = torch.Generator().manual_seed(seed)
    q = view.random_configuration(batch, generator=g)
    qd, tau = (torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    return q, qd, tau


@pytest.mark.parametrize("integrator", list(MJ_INTEGRATORS))
@pytest.mark.parametrize("name", ["iiwa14", "go2", "trees"])
def test_mujoco_convention_is_mj_step(robots, mj_sims, name, integrator):
    """mj_step with qfrc_applied = tau (contacts, limits off; damping, where the model has it, explicit
    in both), float64 <= 1e-9, at dt = 0.01 and 0.05: MuJoCo 4's RK4 carries each stage's velocity to
    the chart at q by dexp^-1 (Munthe-Kaas), which a plain sum of stage velocities misses by 1e-6 on a
    free body."""
    robot, sim = robots[name], mj_sims[name]
    m, d = sim.m, sim.d  # the session's harness: mj_forward, which the others call, ignores what is set here
    m.opt.integrator = MJ_INTEGRATORS[integrator]
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    q, qd, tau = _state(robot.mujoco, robot, 3, 1)
    for dt in (0.01, 0.05):
        m.opt.timestep = dt
        q_next, qd_next = robot.mujoco.step(q, qd, tau, dt, integrator)
        for k in range(3):
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q[k].numpy(), qd[k].numpy(), tau[k].numpy()
            mujoco.mj_step(m, d)
            assert np.abs(q_next[k].numpy() - d.qpos).max() <= 1e-9
            assert np.abs(qd_next[k].numpy() - d.qvel).max() <= 1e-9 * max(1.0, np.abs(d.qvel).max())


@pytest.mark.parametrize("turn", [2.0, 3.0, 4.0, 6.0, 9.0])
def test_rk4_is_mj_step_where_a_stage_turns_past_pi(robots, turn):
    """A free and a ball joint turning by `turn` rad per step: rk4's later stages pass pi (and 2 pi, 3 pi),
    where MuJoCo carries their velocity by the turn taken the short way round, as the MuJoCo convention's
    kernel and its torch composition (autograd's) do; the Jacobians there against central differences of
    step, and the two paths' equal."""
    from mjcf_models import SPINNERS

    robot = robots["spinners"]
    m = mujoco.MjModel.from_xml_string(SPINNERS)
    m.opt.integrator, dt = mujoco.mjtIntegrator.mjINT_RK4, 0.02
    m.opt.timestep = dt
    d = mujoco.MjData(m)
    view, nv = robot.mujoco, robot.nv
    q, qd, tau = _state(view, robot, 3, 6)
    for rotation in (slice(3, 6), slice(6, 9)):  # the free joint's, the ball's
        qd[:, rotation] *= turn / dt / qd[:, rotation].norm(dim=-1, keepdim=True)
    q_next, qd_next = view.step(q, qd, tau, dt, "rk4")
    composed = view.step(q, qd.clone().requires_grad_(True), tau, dt, "rk4")
    for k in range(3):
        d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q[k].numpy(), qd[k].numpy(), tau[k].numpy()
        mujoco.mj_step(m, d)
        assert view.difference(torch.from_numpy(d.qpos.copy()), q_next[k]).abs().max() <= 1e-10, k
        assert rel_err(qd_next[k], torch.from_numpy(d.qvel.copy())) <= 1e-10, k
    assert rel_err(composed[0].detach(), q_next) <= 1e-12 and rel_err(composed[1].detach(), qd_next) <= 1e-12
    A, B = view.step_derivatives(q, qd, tau, dt, "rk4")
    A_c, B_c = view.step_derivatives(q, qd.clone().requires_grad_(True), tau, dt, "rk4")
    assert rel_err(A_c.detach(), A) <= 1e-10 and rel_err(B_c.detach(), B) <= 1e-10
    h, columns = 1e-6, []
    for c in range(3 * nv):
        e = torch.zeros(3 * nv, dtype=torch.float64)
        e[c] = h
        plus, minus = (view.step(view.integrate(q, s * e[:nv]), qd + s * e[nv:2 * nv], tau + s * e[2 * nv:], dt, "rk4")
                       for s in (1.0, -1.0))
        columns.append(torch.cat([view.difference(minus[0], plus[0]), plus[1] - minus[1]], dim=-1) / (2 * h))
    assert rel_err(torch.cat([A, B], dim=-1), torch.stack(columns, dim=-1)) <= 1e-5
    # the step Hessian through the same turns: against forward over reverse through step itself
    def deviation(z, q, qd, tau, y_q, y_v):
        out_q, out_v = view.step(view.integrate(q, z[:nv]), qd + z[nv:2 * nv], tau + z[2 * nv:], dt, "rk4")
        return torch.cat([view.difference(y_q, out_q), out_v - y_v])

    ref = torch.func.vmap(torch.func.jacfwd(torch.func.jacrev(deviation)), in_dims=(None, 0, 0, 0, 0, 0))(
        torch.zeros(3 * nv, dtype=torch.float64), q, qd, tau, q_next, qd_next)
    assert rel_err(view.step_second_derivatives(q, qd, tau, dt, "rk4"), ref) <= 1e-9


def _actuated_go2():
    """go2 in MuJoCo (as the mj_sims harness builds it) with a motor of gear 1 on each hinge, so that
    mjd_transitionFD's B is d/dtau of the hinges' torques."""
    import oracles
    from pathlib import Path

    spec = mujoco.MjSpec.from_string(oracles._urdf_for_mujoco(Path(oracles.urdf_path_for("go2")).read_text()))
    spec.worldbody.first_body().add_freejoint()
    for joint in spec.joints:
        if joint.type == mujoco.mjtJoint.mjJNT_HINGE:
            motor = spec.add_actuator()
            motor.trntype, motor.target, motor.gear[0] = mujoco.mjtTrn.mjTRN_JOINT, joint.name, 1.0
    m = spec.compile()
    m.opt.gravity[:] = (0.0, 0.0, -9.81)
    m.opt.disableflags |= (int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT) | int(mujoco.mjtDisableBit.mjDSBL_DAMPER)
                           | int(mujoco.mjtDisableBit.mjDSBL_SPRING) | int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP))
    return m


def _mj_step_differences(m, d, qpos, qvel, qfrc, ctrl, eps):
    """Centred differences of mj_step in the tangent spaces, as mjd_transitionFD (which refuses RK4)."""
    def step(dx, du):
        d.qpos[:], d.qvel[:], d.qfrc_applied[:], d.ctrl[:] = qpos, qvel + dx[m.nv:], qfrc, ctrl + du
        mujoco.mj_integratePos(m, d.qpos, dx[:m.nv], 1.0)
        mujoco.mj_step(m, d)
        return d.qpos.copy(), d.qvel.copy()

    base_q, base_v = step(np.zeros(2 * m.nv), np.zeros(m.nu))
    cols = []
    for k in range(2 * m.nv + m.nu):
        outs = []
        for sign in (1, -1):
            z = np.zeros(2 * m.nv + m.nu)
            z[k] = sign * eps
            q1, v1 = step(z[:2 * m.nv], z[2 * m.nv:])
            dq = np.zeros(m.nv)
            mujoco.mj_differentiatePos(m, dq, 1.0, base_q, q1)
            outs.append(np.concatenate([dq, v1 - base_v]))
        cols.append((outs[0] - outs[1]) / (2 * eps))
    jac = np.stack(cols, axis=-1)
    return jac[:, :2 * m.nv], jac[:, 2 * m.nv:]


@pytest.mark.parametrize("integrator", list(MJ_INTEGRATORS))
def test_mujoco_convention_derivatives_are_mujocos(robots, integrator):
    """A, B against MuJoCo's mjd_transitionFD (centred differences of mj_step; for RK4, which it refuses,
    the same differences written here) on a floating quadruped: the base's generalized force through
    qfrc_applied, the hinges' through motors."""
    robot, m = robots["go2"], _actuated_go2()
    d, dt, nv = mujoco.MjData(m), 0.01, robot.nv
    m.opt.integrator, m.opt.timestep = MJ_INTEGRATORS[integrator], dt
    q, qd, tau = _state(robot.mujoco, robot, 2, 7)
    A, B = robot.mujoco.step_derivatives(q, qd, tau, dt, integrator)
    for k in range(2):
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = q[k].numpy(), qd[k].numpy()
        d.qfrc_applied[:6], d.ctrl[:] = tau[k, :6].numpy(), tau[k, 6:].numpy()
        if integrator == "rk4":
            fd_a, fd_b = _mj_step_differences(m, d, q[k].numpy(), qd[k].numpy(), d.qfrc_applied.copy(),
                                              d.ctrl.copy(), 1e-7)
        else:
            fd_a, fd_b = np.zeros((2 * nv, 2 * nv)), np.zeros((2 * nv, m.nu))
            mujoco.mjd_transitionFD(m, d, 1e-7, True, fd_a, fd_b, None, None)
        assert np.abs(A[k].numpy() - fd_a).max() <= 1e-6 * max(1.0, np.abs(fd_a).max())
        assert np.abs(B[k, :, 6:].numpy() - fd_b).max() <= 1e-6 * max(1.0, np.abs(fd_b).max())


def _pinocchio_step(model, q, v, tau, dt, integrator):
    """The schemes of integrators.py written with Pinocchio: aba, integrate, and dIntegrate's ARG1
    (dexp) inverted for the Runge-Kutta stages."""
    data = model.createData()

    def acc(q, v):
        return pin.aba(model, data, q, v, tau)

    a0 = acc(q, v)
    if integrator == "semi_implicit_euler":
        v_next = v + dt * a0
        return pin.integrate(model, q, v_next * dt), v_next
    rows, weights = TABLEAUS[integrator]
    carried, accs = [v], [a0]
    for row in rows:
        theta = sum(c * w for c, w in zip(row, carried))
        vi = v + dt * sum(c * a for c, a in zip(row, accs))
        accs.append(acc(pin.integrate(model, q, theta * dt), vi))
        carried.append(np.linalg.solve(pin.dIntegrate(model, q, theta * dt, pin.ARG1), vi))
    theta = sum(c * w for c, w in zip(weights, carried))
    return pin.integrate(model, q, theta * dt), v + dt * sum(c * a for c, a in zip(weights, accs))


@pytest.mark.parametrize("name", ["iiwa14", "go2"])
def test_pin_convention_is_the_pinocchio_scheme(robots, pin_models, name):
    robot, model = robots[name], pin_models[name]
    q, qd, tau = _state(robot.pin, robot, 2, 2)
    for integrator in INTEGRATORS:
        q_next, qd_next = robot.pin.step(q, qd, tau, 0.03, integrator)
        for k in range(2):
            ref_q, ref_v = _pinocchio_step(model, q[k].numpy(), qd[k].numpy(), tau[k].numpy(), 0.03, integrator)
            assert np.abs(q_next[k].numpy() - ref_q).max() <= 1e-10, integrator
            assert rel_err(qd_next[k], torch.from_numpy(ref_v)) <= 1e-10, integrator


def test_semi_implicit_euler_derivatives_are_crocoddyls(robots, pin_models):
    """Crocoddyl's IntegratedActionModelEuler (semi-implicit: dx = [v dt + a dt^2; a dt], x' = x (+) dx),
    its Fx, Fu written with Pinocchio's computeABADerivatives and dIntegrate, on a floating base."""
    robot, model = robots["go2"], pin_models["go2"]
    data, nv, dt = model.createData(), model.nv, 0.02
    q, qd, tau = _state(robot.pin, robot, 2, 3)
    A, B = robot.pin.step_derivatives(q, qd, tau, dt, "semi_implicit_euler")
    for k in range(2):
        qk, vk, uk = q[k].numpy(), qd[k].numpy(), tau[k].numpy()
        pin.computeABADerivatives(model, data, qk, vk, uk)
        da_dx = np.hstack([data.ddq_dq, data.ddq_dv])
        minv = np.triu(data.Minv) + np.triu(data.Minv, 1).T
        a = pin.aba(model, data, qk, vk, uk)
        dq = vk * dt + a * dt * dt
        j0, j1 = pin.dIntegrate(model, qk, dq, pin.ARG0), pin.dIntegrate(model, qk, dq, pin.ARG1)
        ddx_dx = np.vstack([da_dx * dt * dt, da_dx * dt])
        ddx_dx[:nv, nv:] += dt * np.eye(nv)
        fx = np.vstack([j1 @ ddx_dx[:nv] + np.hstack([j0, np.zeros((nv, nv))]), ddx_dx[nv:] + np.hstack([np.zeros((nv, nv)), np.eye(nv)])])
        fu = np.vstack([j1 @ minv * dt * dt, minv * dt])
        assert rel_err(A[k], torch.from_numpy(fx)) <= 1e-10 and rel_err(B[k], torch.from_numpy(fu)) <= 1e-10


def test_runge_kutta_derivatives_are_crocoddyls(robots, pin_models):
    """Crocoddyl's IntegratedActionModelRK (RK2 midpoint, RK3, RK4: k_i = [v_i; a_i] at
    x (+) dt sum_j a_ij k_j, x' = x (+) dt sum_i b_i k_i, Fx and Fu by the chain rule through the k_i),
    written with Pinocchio's aba and computeABADerivatives, on a fixed arm. On a floating base Crocoddyl
    adds stage velocities in their own charts (not Munthe-Kaas's dexp^-1, as MuJoCo 4): there the
    mj_step and central-difference tests hold instead."""
    robot, model = robots["iiwa14"], pin_models["iiwa14"]
    data, nv, dt = model.createData(), model.nv, 0.02
    q, qd, tau = _state(robot.pin, robot, 2, 14)
    for integrator in RK_FUSED:
        rows, weights = TABLEAUS[integrator]
        q_next, qd_next = robot.pin.step(q, qd, tau, dt, integrator)
        A, B = robot.pin.step_derivatives(q, qd, tau, dt, integrator)
        for k in range(2):
            x, u = np.concatenate([q[k].numpy(), qd[k].numpy()]), tau[k].numpy()
            ks, dks = [], []  # k_i and d k_i / d[x; u]
            for row in ((),) + rows:
                xi = x + dt * sum((c * kj for c, kj in zip(row, ks)), np.zeros(2 * nv))
                dxi = np.hstack([np.eye(2 * nv), np.zeros((2 * nv, nv))])
                dxi = dxi + dt * sum((c * dk for c, dk in zip(row, dks)), np.zeros_like(dxi))
                pin.computeABADerivatives(model, data, xi[:nv], xi[nv:], u)
                minv = np.triu(data.Minv) + np.triu(data.Minv, 1).T
                f_x = np.block([[np.zeros((nv, nv)), np.eye(nv), np.zeros((nv, nv))],
                                [data.ddq_dq, data.ddq_dv, minv]])
                ks.append(np.concatenate([xi[nv:], pin.aba(model, data, xi[:nv], xi[nv:], u)]))
                dks.append(f_x @ np.vstack([dxi, np.hstack([np.zeros((nv, 2 * nv)), np.eye(nv)])]))
            ref_x = x + dt * sum(w * kj for w, kj in zip(weights, ks))
            ref = np.hstack([np.eye(2 * nv), np.zeros((2 * nv, nv))]) + dt * sum(w * dk for w, dk in zip(weights, dks))
            assert rel_err(torch.cat([q_next[k], qd_next[k]]), torch.from_numpy(ref_x)) <= 1e-12, integrator
            assert rel_err(torch.cat([A[k], B[k]], dim=-1), torch.from_numpy(ref)) <= 1e-10, integrator


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["go2", "trees"])
def test_step_derivatives_match_central_differences(robots, name, convention):
    """A, B against central differences of step along [dq; dqd; dtau] (q moved by integrate, q' compared
    by difference), every integrator, a per-sample dt."""
    robot = robots[name]
    view = getattr(robot, convention)
    q, qd, tau = _state(view, robot, 2, 4)
    dt, nv, h = torch.tensor([0.02, 0.05], dtype=torch.float64), robot.nv, 1e-6
    for integrator in INTEGRATORS:
        A, B = view.step_derivatives(q, qd, tau, dt, integrator)
        base = view.step(q, qd, tau, dt, integrator)

        def moved(z):
            out = view.step(view.integrate(q, z[:, :nv]), qd + z[:, nv:2 * nv], tau + z[:, 2 * nv:], dt, integrator)
            return torch.cat([view.difference(base[0], out[0]), out[1] - base[1]], dim=-1)

        cols = []
        for k in range(3 * nv):
            z = torch.zeros(2, 3 * nv, dtype=torch.float64)
            z[:, k] = h
            cols.append((moved(z) - moved(-z)) / (2 * h))
        ref = torch.stack(cols, dim=-1)
        assert rel_err(torch.cat([A, B], dim=-1), ref) <= 1e-7, integrator


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["go2", "trees"])
def test_step_kernels_are_the_torch_composition(robots, name, convention):
    """The kernels of every scheme (what step, step_derivatives, horizon and MPCDynamics run when nothing
    differentiates them: step for the values of every scheme, step_derivatives for the Euler schemes'
    derivatives, rk_step_derivatives for Runge-Kutta's) against the same schemes composed in torch (what runs under autograd), on every joint type: turns of
    zero, 1e-6 rad, about one and beyond 2 pi in one step, a (2, 3) batch with a per-sample dt and
    external forces. The Runge-Kutta schemes are compared where a step turns by less than half a radian
    per rad/s of speed: beyond it their stages diverge (|A| reaches 1e40 at 400 rad/s) and two exact
    evaluations differ by their rounding, amplified."""
    robot = robots[name]
    view = getattr(robot, convention)
    g = torch.Generator().manual_seed(12)
    q = view.random_configuration(2, 3, generator=g)
    qd, tau = (torch.randn(2, 3, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    speed = torch.tensor([[0.0, 1e-4, 1.0], [20.0, 100.0, 400.0]], dtype=torch.float64)
    qd = qd * speed.unsqueeze(-1)
    dt = torch.tensor([0.01, 0.02, 0.04], dtype=torch.float64)
    f_ext = torch.randn(2, 3, robot.nbodies, 6, dtype=torch.float64, generator=g)
    # a zero quaternion reads as the identity in both (as MuJoCo's mj_normalizeQuat), not as NaN
    q[0, 0, 3:7] = 0  # the first free joint's quaternion
    stable = speed * dt <= 0.5
    for integrator in INTEGRATORS:
        fused = view._step_and_derivatives(q, qd, tau, dt, integrator, f_ext)
        fused += view.step(q, qd, tau, dt, integrator, f_ext)  # the values alone, from the step kernel
        composed = view.step(q, qd, tau.clone().requires_grad_(), dt, integrator, f_ext) + view.step_derivatives(
            q, qd, tau.clone().requires_grad_(), dt, integrator, f_ext)
        composed += composed[:2]
        compared = stable if integrator in RK_FUSED else torch.ones_like(stable)
        for a, b, what in zip(fused, composed, ("q'", "qd'", "A", "B", "step's q'", "step's qd'")):
            assert a.shape == b.shape and torch.isfinite(a[compared]).all()
            assert rel_err(a[compared], b.detach()[compared]) <= 1e-12, (integrator, what)
    conv, h = int(convention == "mujoco"), dt.unsqueeze(-1)
    with pytest.raises(RuntimeError, match="scheme must be 0 .euler. or 1 .semi-implicit euler., got 2"):
        robot._ops.step_derivatives(q, qd, tau, None, h, None, 2, 0, conv)
    with pytest.raises(RuntimeError, match=r"scheme must be 2 \(midpoint\), 3 \(rk3\) or 4 \(rk4\), got 1"):
        robot._ops.rk_step_derivatives(q, qd, tau, None, h, None, 1, 0, conv)
    with pytest.raises(RuntimeError, match=r"passive must be 0 \(none\), 1 \(explicit\) or 2 .*got 3"):
        robot._ops.step_derivatives(q, qd, tau, None, h, None, 1, 3, conv)
    with pytest.raises(RuntimeError, match=r"scheme must be 0 \(euler\), 1 \(semi-implicit euler\), 2 \(midpoint\), 3 "
                                           r"\(rk3\) or 4 \(rk4\), got 5"):
        robot._ops.step(q, qd, tau, None, h, None, 5, 0, conv)
    with pytest.raises(RuntimeError, match=r"passive must be 0 \(none\), 1 \(explicit\) or 2 .*got -1"):
        robot._ops.step(q, qd, tau, None, h, None, 1, -1, conv)
    for op, scheme, out, method in ((robot._ops.step_derivatives, 1, 2, "step_derivatives"),
                                    (robot._ops.rk_step_derivatives, 4, 2, "step_derivatives"), (robot._ops.step, 1, 0, "step")):
        outputs = op(q, qd, tau.clone().requires_grad_(), None, h, None, scheme, 0, conv)
        with pytest.raises(NotImplementedError, match=f"kernel has no derivative; differentiate Robot.{method}, which"):
            outputs[out].sum().backward()


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_step_kernels_under_torch_compile(robots, integrator):
    """step_derivatives compiled whole (fullgraph) takes the kernels too and gives the eager A, B."""
    robot = robots["go2"]
    q, qd, tau = _state(robot.mujoco, robot, 4, 13)
    compiled = torch.compile(lambda q, qd, tau: robot.mujoco.step_derivatives(q, qd, tau, 0.01, integrator),
                             fullgraph=True)
    for a, b in zip(compiled(q, qd, tau), robot.mujoco.step_derivatives(q, qd, tau, 0.01, integrator)):
        assert torch.equal(a, b)


@pytest.mark.parametrize("name, convention", [("iiwa14", "pin"), ("go2", "pin"), ("go2", "mujoco")])
def test_step_second_derivatives_match_differences_of_the_first(robots, name, convention):
    """The step Hessian [o, a, c] against central differences along z_c of the gradient of
    z -> [difference(q', q'(z)); qd'(z) - qd'], written with step_derivatives at x (+) z and the
    configuration space's Jacobians; symmetric in a, c. Every integrator, a fixed and a floating base."""
    robot = robots[name]
    view, nv = getattr(robot, convention), robot.nv
    q, qd, tau = _state(view, robot, 2, 8)
    dt, h = torch.tensor([0.02, 0.05], dtype=torch.float64), 1e-5
    for integrator in INTEGRATORS:
        H = view.step_second_derivatives(q, qd, tau, dt, integrator)
        y_q, _ = view.step(q, qd, tau, dt, integrator)

        def gradient(z):
            q_z = view.integrate(q, z[:, :nv])
            args = (q_z, qd + z[:, nv:2 * nv], tau + z[:, 2 * nv:], dt, integrator)
            J = torch.cat(view.step_derivatives(*args), dim=-1)
            J = torch.cat([view.d_difference(y_q, view.step(*args)[0])[1] @ J[:, :nv], J[:, nv:]], dim=-2)
            return torch.cat([J[..., :nv] @ view.d_integrate(q, z[:, :nv])[1], J[..., nv:]], dim=-1)

        cols = []
        for c in range(3 * nv):
            z = torch.zeros(2, 3 * nv, dtype=torch.float64)
            z[:, c] = h
            cols.append((gradient(z) - gradient(-z)) / (2 * h))
        assert rel_err(H, torch.stack(cols, dim=-1)) <= 1e-6, integrator
        assert rel_err(H.transpose(-1, -2), H) <= 1e-10, integrator


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_step_hessians_are_forward_over_reverse(robots, convention):
    """step_second_derivatives (the Euler schemes' closed form from forward_dynamics_second_derivatives; rk4's
    second-order chain rule through the stages) against forward over reverse through step
    itself, on every joint type (two free joints, a ball, a hinge, a slide), at rest, slow and fast (turns
    of about one rad per step), with a per-sample dt and external forces."""
    robot = robots["trees"]
    view, nv = getattr(robot, convention), robot.nv
    g = torch.Generator().manual_seed(14)
    q = view.random_configuration(3, generator=g)
    qd, tau = (torch.randn(3, nv, dtype=torch.float64, generator=g) for _ in range(2))
    qd = qd * torch.tensor([[0.0], [1.0], [30.0]], dtype=torch.float64)
    dt = torch.tensor([0.01, 0.03, 0.05], dtype=torch.float64)
    f_ext = torch.randn(3, robot.nbodies, 6, dtype=torch.float64, generator=g)
    z = torch.zeros(3 * nv, dtype=torch.float64)
    for integrator in ("euler", "semi_implicit_euler", "rk4"):
        ours = view.step_second_derivatives(q, qd, tau, dt, integrator, f_ext)
        y_q, y_v = view.step(q, qd, tau, dt, integrator, f_ext)

        def deviation(z, q, qd, tau, h, f, y_q, y_v):
            out_q, out_v = view.step(view.integrate(q, z[:nv]), qd + z[nv:2 * nv], tau + z[2 * nv:], h, integrator, f)
            return torch.cat([view.difference(y_q, out_q), out_v - y_v])

        ref = torch.func.vmap(torch.func.jacfwd(torch.func.jacrev(deviation)), in_dims=(None, 0, 0, 0, 0, 0, 0, 0))(
            z, q, qd, tau, dt, f_ext, y_q, y_v)
        assert ours.shape == ref.shape == (3, 2 * nv, 3 * nv, 3 * nv)
        # four stages of rounding, at 1.5 rad per step (rk4: 9e-11)
        assert rel_err(ours, ref) <= (1e-9 if integrator == "rk4" else 1e-11), integrator


def test_runge_kutta_hessian_in_pieces(robots, monkeypatch):
    """rk4's step Hessian over a batch in pieces (here of four samples and then two, sharing one set of
    buffers) equals the whole batch's, in its leading shape of two dimensions, with a per-sample dt; an
    empty batch gives an empty Hessian."""
    import torch_grid.step.rk_hessian as rk_hessian

    robot = robots["go2"]
    nv = robot.nv
    g = torch.Generator().manual_seed(21)
    q = robot.mujoco.random_configuration(2, 3, generator=g)
    qd, tau = (torch.randn(2, 3, nv, dtype=torch.float64, generator=g) for _ in range(2))
    dt = torch.rand(2, 3, dtype=torch.float64, generator=g) * 0.05
    whole = robot.mujoco.step_second_derivatives(q, qd, tau, dt, "rk4")
    monkeypatch.setattr(rk_hessian, "PIECE_BYTES", 4 * 8 * nv * (3 * nv) ** 2)
    pieces = robot.mujoco.step_second_derivatives(q, qd, tau, dt, "rk4")
    assert whole.shape == pieces.shape == (2, 3, 2 * nv, 3 * nv, 3 * nv)
    assert torch.allclose(whole, pieces, rtol=1e-13, atol=1e-13)
    assert rel_err(pieces[1, 2], robot.mujoco.step_second_derivatives(q[1, 2], qd[1, 2], tau[1, 2], dt[1, 2], "rk4")) <= 1e-13
    assert robot.mujoco.step_second_derivatives(q[:0], qd[:0], tau[:0], dt[:0], "rk4").shape == (0, 3, 2 * nv, 3 * nv,
                                                                                             3 * nv)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_euler_step_hessian_with_more_steps_than_states(robots, convention):
    """dt of a batch beyond the state's (one state at several steps, or states (3,) against dt (2, 1)): each
    sample of the Euler schemes' Hessian is its own dt's, the q-q block of the acceleration's included."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, tau = _state(view, robot, 3, 31)
    dt = torch.tensor([[0.01], [0.03]], dtype=torch.float64)
    for integrator in ("euler", "semi_implicit_euler"):
        H = view.step_second_derivatives(q[0], qd[0], tau[0], dt[:, 0], integrator)
        for j in range(2):
            single = view.step_second_derivatives(q[0], qd[0], tau[0], float(dt[j, 0]), integrator)
            assert rel_err(H[j], single) <= 1e-13, (integrator, j)
        H = view.step_second_derivatives(q, qd, tau, dt, integrator)
        assert H.shape == (2, 3, 2 * robot.nv, 3 * robot.nv, 3 * robot.nv)
        for j in range(2):
            for k in range(3):
                single = view.step_second_derivatives(q[k], qd[k], tau[k], float(dt[j, 0]), integrator)
                assert rel_err(H[j, k], single) <= 1e-13, (integrator, j, k)


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_step_hessian_refuses_a_derivative(robots, integrator):
    """step_second_derivatives has no backward (a third derivative) and does not run under vmap (it is
    batched already): asked for either, it says so."""
    robot = robots["go2"]
    q, qd, tau = _state(robot.pin, robot, 2, 4)
    with pytest.raises(NotImplementedError, match="step_second_derivatives has no derivative"):
        robot.pin.step_second_derivatives(q, qd.requires_grad_(), tau, 0.01, integrator)
    with pytest.raises(NotImplementedError, match="does not run under torch.func transforms"):
        torch.func.vmap(lambda *x: robot.pin.step_second_derivatives(*x, 0.01, integrator))(q, qd.detach(), tau)
    with torch.no_grad():
        assert robot.pin.step_second_derivatives(q, qd, tau, 0.01, integrator).shape[0] == 2


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_step_gradgradcheck(robots, convention, integrator):
    """Autograd through step to second order (a floating base, a non-unit quaternion)."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, tau = _state(view, robot, 1, 5)
    q = (q * 1.2).requires_grad_(True)
    qd, tau = qd.requires_grad_(True), tau.requires_grad_(True)

    def fn(q, qd, tau):
        return view.step(q, qd, tau, 0.05, integrator)

    assert torch.autograd.gradcheck(fn, (q, qd, tau))
    assert torch.autograd.gradgradcheck(fn, (q, qd, tau))


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_step_derivatives_under_vmap_and_forward_ad(robots, convention):
    """step_derivatives of every scheme (the torch composition under a transform) on a floating base: vmap
    with a float dt and a configuration or torque held fixed equals the batched call; forward-mode AD by
    torch.autograd.forward_ad equals torch.func.jvp (dexp^-1's derivative inside it is then taken in
    reverse mode, which that level may nest)."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, tau = _state(view, robot, 3, 23)
    t = torch.randn_like(qd)
    for integrator in INTEGRATORS:
        def f(q, qd, tau):
            return torch.cat(view.step_derivatives(q, qd, tau, 0.01, integrator), dim=-1)

        ref = f(q, qd, tau)
        assert rel_err(torch.func.vmap(f, in_dims=(0, 0, None))(q, qd, tau[0]), f(q, qd, tau[0])) <= 1e-14, integrator
        assert rel_err(torch.func.vmap(f, in_dims=(None, 0, 0))(q[0], qd, tau), f(q[0], qd, tau)) <= 1e-14, integrator
        assert rel_err(torch.func.vmap(f)(q, qd, tau), ref) <= 1e-14, integrator
        _, jvp = torch.func.jvp(lambda x: f(q, x, tau), (qd,), (t,))
        with forward_ad.dual_level():
            tangent = forward_ad.unpack_dual(f(q, forward_ad.make_dual(qd, t), tau)).tangent
        assert rel_err(tangent, jvp) <= 1e-12, integrator


def test_large_batches_go_in_pieces(robots, monkeypatch):
    """Under autograd (the torch composition) a batch above integrators.CHUNK samples is split (here at 2)
    and put back in its shape: the same A, B as one piece, with a per-sample dt and a leading batch of two
    dimensions."""
    import torch_grid.step.integrators as integrators

    robot = robots["go2"]
    g = torch.Generator().manual_seed(9)
    q = robot.mujoco.random_configuration(2, 3, generator=g)
    qd, tau = (torch.randn(2, 3, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    dt = torch.rand(3, dtype=torch.float64, generator=g) * 0.05
    tau.requires_grad_()
    whole = robot.mujoco.step_derivatives(q, qd, tau, dt, "rk4")
    monkeypatch.setattr(integrators, "CHUNK", 2)
    pieces = robot.mujoco.step_derivatives(q, qd, tau, dt, "rk4")
    assert all(x.requires_grad for x in pieces)
    for a, b in zip((x.detach() for x in whole), (x.detach() for x in pieces)):
        assert a.shape == b.shape == (2, 3, *a.shape[2:]) and torch.allclose(a, b, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_float32_follows_float64(robots, convention):
    """step, step_derivatives, step_second_derivatives and a cost in float32 against float64 (a floating
    base)."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, tau = _state(view, robot, 3, 10)
    for integrator in ("semi_implicit_euler", "rk4"):
        ours = view.step(q.float(), qd.float(), tau.float(), 0.01, integrator)
        ref = view.step(q, qd, tau, 0.01, integrator)
        assert all(a.dtype == torch.float32 for a in ours)
        assert all(torch.allclose(a.double(), b, rtol=1e-4, atol=1e-4) for a, b in zip(ours, ref)), integrator
        ours = view.step_derivatives(q.float(), qd.float(), tau.float(), 0.01, integrator)
        ref = view.step_derivatives(q, qd, tau, 0.01, integrator)
        assert all(rel_err(a, b) <= 1e-4 for a, b in zip(ours, ref)), integrator
        ours = view.step_second_derivatives(q.float(), qd.float(), tau.float(), 0.01, integrator)
        ref = view.step_second_derivatives(q, qd, tau, 0.01, integrator)
        assert ours.dtype == torch.float32 and rel_err(ours, ref) <= 1e-4, integrator
    weights = torch.ones(2 * robot.nv, dtype=torch.float64)
    ours = view.state_cost(q.float(), qd.float(), q[0].float(), qd[0].float(), weights.float())
    ref = view.state_cost(q, qd, q[0], qd[0], weights)
    assert all(rel_err(a, b) <= 1e-4 for a, b in zip(ours, ref))


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_float32_runge_kutta_jacobians_of_every_sample(robots, convention):
    """On the CPU a float32 batch runs the float64 kernel chunk by chunk: every sample's A and B equal
    float64's on the same rounded inputs (the Runge-Kutta workspace is zeroed in every chunk, whose layout
    moves with its size: the last sample of a short chunk was wrong by up to 100%)."""
    robot = robots["go2"]
    view = getattr(robot, convention)
    q, qd, tau = (x.float() for x in _state(view, robot, 21, 11))
    for integrator in ("midpoint", "rk3", "rk4"):
        for n in (7, 13, 21):
            ours = view.step_derivatives(q[:n], qd[:n], tau[:n], 0.01, integrator)
            ref = view.step_derivatives(q[:n].double(), qd[:n].double(), tau[:n].double(), 0.01, integrator)
            for a, b in zip(ours, ref):
                err = (a.double() - b).abs().flatten(1).amax(1) / b.abs().flatten(1).amax(1)
                assert err.max() <= 1e-6, (integrator, n, err.argmax().item(), err.max().item())


@pytest.mark.parametrize("name,convention", [("iiwa14", "pin"), ("go2", "pin"), ("go2", "mujoco")])
def test_composed_step_derivatives_of_every_scheme_equal_the_kernel(robots, name, convention):
    """Under autograd step_derivatives is composed in torch: every scheme's equals the kernel's (explicit
    Euler's raised: its q' rows, the same for every sample, were left unbatched). On CUDA in MuJoCo's
    convention the composition is what every call takes (integrators._fused_kept_off)."""
    robot = robots[name]
    view = getattr(robot, convention)
    q, qd, tau = _state(view, robot, 4, 12)
    for integrator in INTEGRATORS:
        ref = view.step_derivatives(q, qd, tau, 0.01, integrator)
        ours = view.step_derivatives(q.clone().requires_grad_(True), qd, tau, 0.01, integrator)
        assert all(rel_err(a.detach(), b) <= 1e-12 for a, b in zip(ours, ref)), integrator


class _OnCuda(torch.Tensor):
    """A CPU tensor that reads as a CUDA one, for the routing decision alone."""

    @property
    def is_cuda(self):
        return True


def test_fused_step_kernels_are_kept_off_cuda_where_a_gpu_showed_them_wrong(robots):
    from torch_grid.step.integrators import _fused_kept_off

    q = torch.zeros(2, robots["go2"].nq, dtype=torch.float64)
    cuda = torch.Tensor._make_subclass(_OnCuda, q)
    assert _fused_kept_off(robots["go2"].mujoco, cuda)
    assert not _fused_kept_off(robots["go2"].pin, cuda)
    assert not _fused_kept_off(robots["go2"].mujoco, q)
    assert not _fused_kept_off(robots["iiwa14"].mujoco, torch.Tensor._make_subclass(_OnCuda, torch.zeros(2, 7)))
