"""The derivative functions against their oracles (autograd is in test_autograd.py).

pin: vs Pinocchio's derivative algorithms (computeRNEADerivatives, computeABADerivatives, ...),
or central differences along pinocchio.integrate where it has none (float64, <= 1e-8 / 1e-6).
mjx: vs central finite differences of real MuJoCo (mj_inverse, mj_forward, mj_jacBody, ...), qpos
moved by mj_integratePos, qvel/qacc/qfrc directly (float64, <= 1e-6).
"""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import torch

from oracles import pin_forces, rel_err, to_pin_q

ROBOTS = ["iiwa14", "go2", "g1", "tiago"]
FLOATING = ["go2", "g1", "trees"]  # "trees": two free roots, a ball, an MJCF (MuJoCo oracle only)


def _states(robot, batch=3, seed=0, convention="pin"):
    g = torch.Generator().manual_seed(seed)
    view = getattr(robot, convention)
    q = view.random_configuration(batch, generator=g)
    qd, x = (torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    f = 5 * torch.randn(batch, robot.nbodies, 6, dtype=torch.float64, generator=g)
    return q, qd, x, f


@pytest.mark.parametrize("name", ROBOTS)
def test_inverse_dynamics_derivatives_vs_pinocchio(robots, pin_models, name):
    robot, pm = robots[name], pin_models[name]
    pd = pm.createData()
    q, qd, qdd, f = _states(robot)
    dq, dqd = robot.inverse_dynamics_derivatives(q, qd, qdd, f)
    for b in range(q.shape[0]):
        ref = pin.computeRNEADerivatives(pm, pd, to_pin_q(robot, q[b]), qd[b].numpy(), qdd[b].numpy(), pin_forces(pm, f[b]))
        assert rel_err(dq[b], ref[0]) <= 1e-8 and rel_err(dqd[b], ref[1]) <= 1e-8


@pytest.mark.parametrize("name", ROBOTS)
def test_forward_dynamics_derivatives_vs_pinocchio(robots, pin_models, name):
    robot, pm = robots[name], pin_models[name]
    pd = pm.createData()
    q, qd, tau, f = _states(robot, seed=1)
    outs = robot.forward_dynamics_derivatives(q, qd, tau, f)
    for b in range(q.shape[0]):
        pin.computeABADerivatives(pm, pd, to_pin_q(robot, q[b]), qd[b].numpy(), tau[b].numpy(), pin_forces(pm, f[b]))
        minv = np.triu(pd.Minv) + np.triu(pd.Minv, 1).T
        for ours, ref in zip(outs, (pd.ddq_dq, pd.ddq_dv, minv)):
            assert rel_err(ours[b], ref) <= 1e-8


@pytest.mark.parametrize("name", ["iiwa14", "go2", "tiago"])
def test_body_velocities_vs_pinocchio(robots, pin_models, name):
    robot, pm = robots[name], pin_models[name]
    pd = pm.createData()
    q, qd, _, _ = _states(robot, seed=2)
    ours = robot.body_velocities(q, qd)
    for b in range(q.shape[0]):
        pin.forwardKinematics(pm, pd, to_pin_q(robot, q[b]), qd[b].numpy())
        assert rel_err(ours[b], np.stack([pd.v[i].vector for i in range(1, pm.njoints)])) <= 1e-12


def _central(fn, x, k, eps, perturb):
    return (fn(perturb(x, k, eps)) - fn(perturb(x, k, -eps))) / (2 * eps)


def _move_qpos(m):
    def perturb(qpos, k, eps):
        out, dq = qpos.copy(), np.zeros(m.nv)
        dq[k] = eps
        mujoco.mj_integratePos(m, out, dq, 1.0)
        return out

    return perturb


def _move(x, k, eps):
    out = x.copy()
    out[k] += eps
    return out


@pytest.mark.parametrize("name", FLOATING)
def test_mujoco_inverse_dynamics_derivatives_vs_finite_differences(robots, mj_sims, name):
    robot, sim = robots[name], mj_sims[name]
    q, qd, qdd, _ = (x[0].numpy() for x in _states(robot, batch=1, seed=3, convention="mujoco"))
    dq, dqd = (x.numpy() for x in robot.mujoco.inverse_dynamics_derivatives(*(torch.from_numpy(x) for x in (q, qd, qdd))))
    eps = 1e-6
    fd_q = np.stack([_central(lambda p: sim.qfrc_inverse(p, qd, qdd), q, k, eps, _move_qpos(sim.m)) for k in range(robot.nv)], 1)
    fd_v = np.stack([_central(lambda v: sim.qfrc_inverse(q, v, qdd), qd, k, eps, _move) for k in range(robot.nv)], 1)
    assert rel_err(dq, fd_q) <= 1e-6 and rel_err(dqd, fd_v) <= 1e-6


@pytest.mark.parametrize("name", FLOATING)
def test_mujoco_forward_dynamics_derivatives_vs_finite_differences(robots, mj_sims, name):
    robot, sim = robots[name], mj_sims[name]
    q, qd, u, _ = (x[0].numpy() for x in _states(robot, batch=1, seed=4, convention="mujoco"))
    outs = [x.numpy() for x in robot.mujoco.forward_dynamics_derivatives(*(torch.from_numpy(x) for x in (q, qd, u)))]
    eps = 1e-6
    fd_q = np.stack([_central(lambda p: sim.qacc(p, qd, u), q, k, eps, _move_qpos(sim.m)) for k in range(robot.nv)], 1)
    fd_v = np.stack([_central(lambda v: sim.qacc(q, v, u), qd, k, eps, _move) for k in range(robot.nv)], 1)
    fd_u = np.stack([_central(lambda t: sim.qacc(q, qd, t), u, k, eps, _move) for k in range(robot.nv)], 1)
    for ours, ref in zip(outs, (fd_q, fd_v, fd_u)):
        assert rel_err(ours, ref) <= 1e-6


@pytest.mark.parametrize("name", ["iiwa14", "go2"])
def test_end_effector_pose_derivatives_vs_pinocchio_retraction(robots, pin_models, name):
    """Central differences of the pose along Pinocchio's own integrate (its tangent)."""
    robot, pm = robots[name], pin_models[name]
    q, _, _, _ = _states(robot, batch=1, seed=10)
    frames = [robot.nframes - 1, 3]
    ours = robot.end_effector_pose_derivatives(q, frames)[0].numpy()
    q_pin = to_pin_q(robot, q[0])
    pose = lambda qp: robot.end_effector_pose(_from_pin_q(robot, qp), frames).numpy()  # noqa: E731
    eps = 1e-6
    fd = np.stack([(pose(pin.integrate(pm, q_pin, eps * e)) - pose(pin.integrate(pm, q_pin, -eps * e))) / (2 * eps)
                   for e in np.eye(robot.nv)], axis=-1)
    assert rel_err(ours, fd) <= 1e-6


def _from_pin_q(robot, q_pin):
    """Pinocchio's q -> torch_grid's (a continuous joint's (cos, sin) -> angle)."""
    out, k = [], 0
    for joint in robot.model.joints:
        if joint.type == "continuous":
            out.append(np.arctan2(q_pin[k + 1], q_pin[k]))
            k += 2
        else:
            out.extend(q_pin[k:k + joint.nq])
            k += joint.nq
    return torch.tensor(np.array(out, dtype=float))


# --------------------------------------------------------------------------------------------
# inertial-parameter regressors
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ROBOTS)
def test_regressors_vs_pinocchio(robots, pin_models, name):
    robot, pm = robots[name], pin_models[name]
    pd = pm.createData()
    q, qd, qdd, _ = _states(robot, seed=11)
    pi = robot.inertial_parameters()
    assert rel_err(pi, np.concatenate([pm.inertias[i].toDynamicParameters() for i in range(1, pm.njoints)])) <= 1e-14
    Y, Yk, Yp = robot.inverse_dynamics_regressor(q, qd, qdd), robot.kinetic_energy_regressor(q, qd), \
        robot.potential_energy_regressor(q)
    for b in range(q.shape[0]):
        qp = to_pin_q(robot, q[b])
        assert rel_err(Y[b], pin.computeJointTorqueRegressor(pm, pd, qp, qd[b].numpy(), qdd[b].numpy())) <= 1e-8
        assert rel_err(Yk[b], pin.computeKineticEnergyRegressor(pm, pd, qp, qd[b].numpy())) <= 1e-8
        assert rel_err(Yp[b], pin.computePotentialEnergyRegressor(pm, pd, qp)) <= 1e-8
    energy = robot.energy(q, qd)
    assert rel_err(Yk @ pi, energy[..., 0]) <= 1e-12 and rel_err(Yp @ pi, energy[..., 1]) <= 1e-12


@pytest.mark.parametrize("name", FLOATING)
def test_mujoco_regressors(robots, mj_sims, name):
    """In MuJoCo's convention Y pi is MuJoCo's inverse dynamics; the energy regressors are invariant."""
    robot, sim = robots[name], mj_sims[name]
    q, qd, qdd, _ = _states(robot, batch=2, seed=12, convention="mujoco")
    pi = robot.inertial_parameters()
    Y = robot.mujoco.inverse_dynamics_regressor(q, qd, qdd)
    for b in range(2):
        assert rel_err(Y[b] @ pi, sim.qfrc_inverse(q[b].numpy(), qd[b].numpy(), qdd[b].numpy())) <= 1e-9
        kinetic, potential = sim.energy(q[b].numpy(), qd[b].numpy())[:2]
        assert abs(float(robot.mujoco.kinetic_energy_regressor(q[b], qd[b]) @ pi) - kinetic) <= 1e-9 * max(1, abs(kinetic))
        assert abs(float(robot.mujoco.potential_energy_regressor(q[b]) @ pi) - potential) <= 1e-9 * max(1, abs(potential))


def test_forward_dynamics_parameter_derivatives_vs_finite_differences(robots):
    """Central differences of qdd in every parameter of one body, the parameters passed as an input
    (params=, itself held to rebuilt and Pinocchio-edited models in tests/test_parameters.py)."""
    robot = robots["go2"]
    body = robot.nbodies - 1
    pi = robot.inertial_parameters().view(robot.nbodies, 10)
    # a step relative to the size of each group (mass, first moment, inertia): qdd is rational in them
    size = pi[body].abs()
    scale = torch.cat([size[:1], size[1:4].max().expand(3), size[4:].max().expand(6)])
    for convention in ("pin", "mujoco"):
        view = getattr(robot, convention)
        q, qd, tau, _ = _states(robot, batch=1, seed=13, convention=convention)
        ours = view.forward_dynamics_parameter_derivatives(q, qd, tau)[0]
        for k in range(10):
            eps = 1e-4 * float(scale[k])
            step = torch.zeros_like(pi)
            step[body, k] = eps
            fd = (view.forward_dynamics(q, qd, tau, params=pi + step)[0]
                  - view.forward_dynamics(q, qd, tau, params=pi - step)[0]) / (2 * eps)
            assert rel_err(ours[:, 10 * body + k], fd) <= 1e-6, (convention, k)


# --------------------------------------------------------------------------------------------
# Jacobian time variation
# --------------------------------------------------------------------------------------------
def _limb_frames(robot):
    """Frames on the last body and on a middle one: they move with several joints."""
    last = next(i for i in reversed(range(robot.nframes)) if robot.model.frames[i].parent == robot.nbodies - 1)
    middle = next(i for i, f in enumerate(robot.model.frames) if f.parent == robot.nbodies // 2)
    return [last, middle]


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("reference, pin_reference", [("world", pin.WORLD), ("local", pin.LOCAL),
                                                      ("local_world_aligned", pin.LOCAL_WORLD_ALIGNED)])
def test_frame_jacobian_dot_vs_pinocchio(robots, pin_models, name, reference, pin_reference):
    robot, pm = robots[name], pin_models[name]
    pd = pm.createData()
    q, qd, _, _ = _states(robot, batch=2, seed=14)
    for frame in _limb_frames(robot):
        ours = robot.frame_jacobian_dot(q, qd, frame, reference)
        for b in range(2):
            pin.computeJointJacobiansTimeVariation(pm, pd, to_pin_q(robot, q[b]), qd[b].numpy())
            pin.updateFramePlacements(pm, pd)
            assert rel_err(ours[b], pin.getFrameJacobianTimeVariation(pm, pd, frame, pin_reference)) <= 1e-8


@pytest.mark.parametrize("name", FLOATING)
def test_mujoco_frame_jacobian_dot_vs_finite_differences(robots, mj_sims, name):
    """d/dt of mj_jacBody along qpos(t) = mj_integratePos(qpos, qvel, t), qvel fixed in MuJoCo's frame."""
    robot, sim = robots[name], mj_sims[name]
    q, qd, _, _ = (x[0].numpy() for x in _states(robot, batch=1, seed=15, convention="mujoco"))
    for frame in _limb_frames(robot):
        body = robot.model.frames[frame].name if robot.model.frames[frame].kind == "body" else None
        if body is None:
            body = next(f.name for f in robot.model.frames if f.kind == "body" and f.parent == robot.model.frames[frame].parent)
        index = robot.frame_index(body)
        ours = robot.mujoco.frame_jacobian_dot(torch.from_numpy(q), torch.from_numpy(qd), index).numpy()
        dt = 1e-6

        def jac(t):
            moved = q.copy()
            mujoco.mj_integratePos(sim.m, moved, qd, t)
            return sim.jac_body(moved, body)

        assert rel_err(ours, (jac(dt) - jac(-dt)) / (2 * dt)) <= 1e-6


# --------------------------------------------------------------------------------------------
# Coriolis matrix
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ROBOTS)
def test_coriolis_matrix_vs_pinocchio(robots, pin_models, name):
    robot, pm = robots[name], pin_models[name]
    pd = pm.createData()
    q, qd, _, _ = _states(robot, seed=16)
    C = robot.coriolis_matrix(q, qd)
    for b in range(q.shape[0]):
        assert rel_err(C[b], pin.computeCoriolisMatrix(pm, pd, to_pin_q(robot, q[b]), qd[b].numpy())) <= 1e-8
    # dM/dt - 2 C is skew-symmetric; dM/dt by central differences along Pinocchio's integrate.
    qp, v = to_pin_q(robot, q[0]), qd[0].numpy()
    crba = lambda x: robot.crba(torch.from_numpy(_from_pin_q(robot, x).numpy()))  # noqa: E731
    dt = 1e-6
    Mdot = (crba(pin.integrate(pm, qp, dt * v)) - crba(pin.integrate(pm, qp, -dt * v))) / (2 * dt)
    N = Mdot - 2 * C[0]
    assert (N + N.T).abs().max() <= 1e-6 * Mdot.abs().max()


@pytest.mark.parametrize("name", FLOATING)
def test_mujoco_coriolis_matrix_gives_bias_force_and_skew_rate(robots, mj_sims, name):
    robot, sim = robots[name], mj_sims[name]
    q, qd, _, _ = _states(robot, batch=2, seed=17, convention="mujoco")
    bias = robot.mujoco.coriolis_matrix(q, qd) @ qd.unsqueeze(-1)
    bias = bias.squeeze(-1) + robot.mujoco.generalized_gravity(q)
    for b in range(2):
        assert rel_err(bias[b], sim.qfrc_bias(q[b].numpy(), qd[b].numpy())) <= 1e-9
    # dM/dt - 2 C is skew-symmetric, dM/dt by central differences of mj_fullM along mj_integratePos
    qpos, v, h = q[0].numpy(), qd[0].numpy(), 1e-6
    moved = [qpos.copy(), qpos.copy()]
    for x, step in zip(moved, (h, -h)):
        mujoco.mj_integratePos(sim.m, x, v, step)
    Mdot = (sim.full_m(moved[0]) - sim.full_m(moved[1])) / (2 * h)
    N = Mdot - 2 * robot.mujoco.coriolis_matrix(q[0], qd[0]).numpy()
    assert np.abs(N + N.T).max() <= 1e-6 * np.abs(Mdot).max()


# --------------------------------------------------------------------------------------------
# external forces, operational-space inertia
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ROBOTS)
def test_external_force_gradients_vs_pinocchio(robots, pin_models, name):
    """ID and FD are affine in f_ext: the Jacobians must reproduce Pinocchio's differences."""
    robot, pm = robots[name], pin_models[name]
    pd = pm.createData()
    q, qd, x, f = _states(robot, batch=2, seed=18)
    dtau, dqdd = robot.inverse_dynamics_external_force_derivatives(q), robot.forward_dynamics_external_force_derivatives(q)
    for b in range(2):
        qp, v, a = to_pin_q(robot, q[b]), qd[b].numpy(), x[b].numpy()
        ref_tau = pin.rnea(pm, pd, qp, v, a, pin_forces(pm, f[b])) - pin.rnea(pm, pd, qp, v, a)
        ref_qdd = pin.aba(pm, pd, qp, v, a, pin_forces(pm, f[b])) - pin.aba(pm, pd, qp, v, a)
        assert rel_err(dtau[b].reshape(robot.nv, -1) @ f[b].reshape(-1), ref_tau) <= 1e-9
        assert rel_err(dqdd[b].reshape(robot.nv, -1) @ f[b].reshape(-1), ref_qdd) <= 1e-9


@pytest.mark.parametrize("name", FLOATING)
def test_mujoco_external_force_gradients(robots, name):
    robot = robots[name]
    q, qd, x, f = _states(robot, batch=2, seed=19, convention="mujoco")
    view = robot.mujoco
    tau = view.inverse_dynamics(q, qd, x, f) - view.inverse_dynamics(q, qd, x)
    qdd = view.forward_dynamics(q, qd, x, f) - view.forward_dynamics(q, qd, x)
    flat = f.reshape(2, -1, 1)
    assert rel_err((view.inverse_dynamics_external_force_derivatives(q).reshape(2, robot.nv, -1) @ flat)[..., 0], tau) <= 1e-12
    assert rel_err((view.forward_dynamics_external_force_derivatives(q).reshape(2, robot.nv, -1) @ flat)[..., 0], qdd) <= 1e-12


@pytest.mark.parametrize("name", ["iiwa14", "go2", "g1"])
@pytest.mark.parametrize("reference, pin_reference", [("local", pin.LOCAL), ("local_world_aligned", pin.LOCAL_WORLD_ALIGNED)])
def test_osc_inertia_vs_pinocchio(robots, pin_models, name, reference, pin_reference):
    robot, pm = robots[name], pin_models[name]
    pd = pm.createData()
    q, _, _, _ = _states(robot, batch=2, seed=20)
    frame = _limb_frames(robot)[0]
    ours = robot.osc_inertia(q, frame, reference)
    for b in range(2):
        qp = to_pin_q(robot, q[b])
        minv = pin.computeMinverse(pm, pd, qp)
        minv = np.triu(minv) + np.triu(minv, 1).T
        J = pin.computeFrameJacobian(pm, pd, qp, frame, pin_reference)
        assert rel_err(ours[b], np.linalg.inv(J @ minv @ J.T)) <= 1e-8
    if robot.floating_base:  # invariant under the convention
        mjx = robot.mujoco.osc_inertia(torch.cat([q[:, :3], q[:, [6, 3, 4, 5]], q[:, 7:]], -1), frame, reference)
        assert rel_err(mjx, ours) <= 1e-12


# --------------------------------------------------------------------------------------------
# centroidal derivatives
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ROBOTS)
def test_centroidal_derivatives_vs_pinocchio(robots, pin_models, name):
    robot, pm = robots[name], pin_models[name]
    pd = pm.createData()
    q, qd, qdd, _ = _states(robot, batch=2, seed=21)
    dAg, dh = robot.cmm_time_variation(q, qd), robot.dccrba(q, qd)
    for b in range(2):
        qp = to_pin_q(robot, q[b])
        pin.computeCentroidalMapTimeVariation(pm, pd, qp, qd[b].numpy())
        assert rel_err(dAg[b], pd.dAg) <= 1e-8
        ref = pin.computeCentroidalDynamicsDerivatives(pm, pd, qp, qd[b].numpy(), qdd[b].numpy())
        assert rel_err(dh[b], ref[0]) <= 1e-8


def _mujoco_momentum(sim, qpos, qvel):
    """Centroidal momentum [linear; angular about the com] from MuJoCo's subtree quantities."""
    sim._set(qpos, qvel)
    mujoco.mj_forward(sim.m, sim.d)
    mujoco.mj_subtreeVel(sim.m, sim.d)
    mass = sim.m.body_subtreemass[sim.root]
    return np.concatenate([mass * sim.d.subtree_linvel[sim.root], sim.d.subtree_angmom[sim.root]])


@pytest.mark.parametrize("name", FLOATING)
def test_mujoco_centroidal_derivatives_vs_finite_differences(robots, mj_sims, name):
    robot, sim = robots[name], mj_sims[name]
    q, qd, _, _ = (x[0].numpy() for x in _states(robot, batch=1, seed=22, convention="mujoco"))
    view = robot.mujoco
    A, h = (x.numpy() for x in view.ccrba(torch.from_numpy(q), torch.from_numpy(qd)))
    assert rel_err(h, _mujoco_momentum(sim, q, qd)) <= 1e-9
    dh = view.dccrba(torch.from_numpy(q), torch.from_numpy(qd)).numpy()
    eps = 1e-6
    fd = np.stack([_central(lambda p: _mujoco_momentum(sim, p, qd), q, k, eps, _move_qpos(sim.m))
                   for k in range(robot.nv)], 1)
    assert rel_err(dh, fd) <= 1e-6
    # h_dot = A qacc + dAg qvel; with qacc = 0, along qpos(t) = mj_integratePos(qpos, qvel, t).
    dAg = view.cmm_time_variation(torch.from_numpy(q), torch.from_numpy(qd)).numpy()

    def momentum_at(t):
        moved = q.copy()
        mujoco.mj_integratePos(sim.m, moved, qd, t)
        return _mujoco_momentum(sim, moved, qd)

    assert rel_err(dAg @ qd, (momentum_at(eps) - momentum_at(-eps)) / (2 * eps)) <= 1e-6


@pytest.mark.parametrize("name", ["iiwa14", "go2", "g1"])
def test_centroidal_map_derivatives_vs_pinocchio(robots, pin_models, name):
    """d A / dq against central differences of pinocchio.ccrba's Ag along pinocchio.integrate."""
    robot, pm = robots[name], pin_models[name]
    data = pm.createData()
    q, _, _, _ = _states(robot, batch=1, seed=26)
    ours = robot.centroidal_map_derivatives(q)[0].numpy()
    q_pin = to_pin_q(robot, q[0])

    def A(qp):
        pin.ccrba(pm, data, qp, np.zeros(pm.nv))
        return data.Ag.copy()

    eps = 1e-6
    fd = np.stack([(A(pin.integrate(pm, q_pin, eps * e)) - A(pin.integrate(pm, q_pin, -eps * e))) / (2 * eps)
                   for e in np.eye(pm.nv)], axis=-1)
    assert ours.shape == (6, robot.nv, robot.nv)
    assert rel_err(ours, fd) <= 1e-6


@pytest.mark.parametrize("name", FLOATING)
def test_mujoco_centroidal_map_derivatives_vs_finite_differences(robots, mj_sims, name):
    """Column j of MuJoCo's A is its momentum at qvel = e_j: differences of that along mj_integratePos."""
    robot, sim = robots[name], mj_sims[name]
    q, _, _, _ = _states(robot, batch=1, seed=27, convention="mujoco")
    ours = robot.mujoco.centroidal_map_derivatives(q)[0].numpy()
    qpos, eps = q[0].numpy(), 1e-6
    fd = np.stack([np.stack([_central(lambda p: _mujoco_momentum(sim, p, unit), qpos, k, eps, _move_qpos(sim.m))
                             for k in range(robot.nv)], 1) for unit in np.eye(robot.nv)], 1)
    assert rel_err(ours, fd) <= 1e-6


@pytest.mark.parametrize("name", ["iiwa14", "go2", "g1"])
@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_vector_jacobian_products_match_the_matrices(robots, name, convention):
    """The O(n) products behind autograd equal the dense derivatives contracted with a vector."""
    robot = robots[name]
    view = getattr(robot, convention)
    q, qd, qdd, f = _states(robot, batch=3, seed=23, convention=convention)
    lam = torch.randn(3, robot.nv, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    dq, dqd = view.inverse_dynamics_derivatives(q, qd, qdd, f)
    g_q, g_qd = robot._ops.inverse_dynamics_vjp(q, qd, qdd, f, lam, None, view._convention)
    assert rel_err(g_q, (lam.unsqueeze(-2) @ dq).squeeze(-2)) <= 1e-12
    assert rel_err(g_qd, (lam.unsqueeze(-2) @ dqd).squeeze(-2)) <= 1e-12
    assert rel_err(robot._ops.inertia_solve(q, lam, None, view._convention), (view.minv(q) @ lam.unsqueeze(-1)).squeeze(-1)) <= 1e-12


@pytest.mark.parametrize("name", FLOATING)
def test_mujoco_end_effector_pose_derivatives_vs_finite_differences(robots, mj_sims, name):
    """Central differences of the pose along MuJoCo's own mj_integratePos."""
    robot, sim = robots[name], mj_sims[name]
    q, _, _, _ = _states(robot, batch=1, seed=25, convention="mujoco")
    frames = _limb_frames(robot)
    ours = robot.mujoco.end_effector_pose_derivatives(q, frames)[0].numpy()
    pose = lambda p: robot.mujoco.end_effector_pose(torch.from_numpy(p), frames).numpy()  # noqa: E731
    fd = np.stack([_central(pose, q[0].numpy(), k, 1e-6, _move_qpos(sim.m)) for k in range(robot.nv)], -1)
    assert rel_err(ours, fd) <= 1e-6
