"""Ball (spherical) joints, and free joints at the roots of several trees. A ball joint has nq 4 (a
quaternion, xyzw in the pin convention, wxyz in MuJoCo's) and nv 3 (the local angular velocity).

- An MJCF model against MuJoCo itself (its convention, float64, <= 1e-9): a ball under a free body,
  a body with a hinge then a ball about another anchor, a planar root (slide, slide, hinge) carrying a
  ball, a tree hanging from a ball under the world; damping and armature on a ball. Derivatives
  against central differences of mj_inverse / mj_forward along mj_integratePos.
- A fixed-base model whose only quaternions are balls: its MuJoCo twin reorders them.
- Several trees with a free joint at two of the roots (tests/mjcf_models.py; its derivatives and
  gradcheck run in test_derivatives.py and test_autograd.py).
- A pinocchio.Model with spherical joints against Pinocchio (its convention): the dynamics, its
  derivatives (computeRNEADerivatives, computeABADerivatives), Jacobians and centroidal quantities.
- gradcheck of the autograd paths in both conventions, quaternions in ambient coordinates.
"""
from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import torch

import torch_grid
from oracles import PinOracle, rel_err
from test_mjcf import rigid_only

BALLS = """
<mujoco model="balls">
  <option gravity="0.3 -0.2 -9"/>
  <default><joint damping="0.05"/></default>
  <worldbody>
    <body name="torso" pos="0 0 1" euler="5 10 15">
      <freejoint name="root"/>
      <geom type="box" size="0.2 0.1 0.05" density="700"/>
      <body name="shoulder" pos="0.25 0 0" euler="0 0 30">
        <joint name="shoulder_ball" type="ball" pos="0.02 0.01 0" armature="0.01" damping="0.2"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0.05" size="0.03"/>
        <body name="forearm" pos="0.3 0 0.05">
          <joint name="elbow" type="hinge" axis="0 1 0" pos="0.01 0 0"/>
          <joint name="wrist_ball" type="ball" pos="0.2 0 0"/>
          <geom type="capsule" fromto="0 0 0 0.25 0.02 0" size="0.025"/>
          <site name="hand" pos="0.25 0.02 0" euler="0 45 0"/>
        </body>
      </body>
    </body>
    <body name="planar" pos="-1 0 0.5">
      <joint name="px" type="slide" axis="1 0 0"/>
      <joint name="pz" type="slide" axis="0 0 1"/>
      <joint name="pitch" type="hinge" axis="0 1 0" pos="0 0 0.1"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.4" size="0.05"/>
      <body name="hip" pos="0 0 -0.05">
        <joint name="hip_ball" type="ball" pos="0 0.01 0.02"/>
        <inertial pos="0 0.01 -0.2" mass="0.8" diaginertia="0.01 0.012 0.004" quat="0.8 0.6 0 0"/>
      </body>
    </body>
    <body name="hanging" pos="1 1 1">
      <joint name="hang_ball" type="ball" pos="0 0 0.1"/>
      <geom type="cylinder" fromto="0 0 0 0 0.1 -0.5" size="0.02"/>
    </body>
  </worldbody>
</mujoco>
"""
# No free joint: the MuJoCo twin differs from the Pinocchio kernel by the balls' quaternion order only.
FIXED_BALLS = """
<mujoco model="fixed_balls">
  <worldbody>
    <body name="upper" pos="0 0 1">
      <joint name="top" type="ball" pos="0 0 0.05" armature="0.02"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 -0.4" size="0.03"/>
      <body name="lower" pos="0.1 0 -0.4">
        <joint name="knee" type="hinge" axis="1 0 0"/>
        <joint name="ankle" type="ball" pos="0 0.02 -0.1"/>
        <geom type="box" size="0.05 0.1 0.2" pos="0 0 -0.2"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
TOL = 1e-9


@pytest.fixture(scope="module")
def balls(tmp_path_factory):
    with pytest.warns(UserWarning, match="contacts"):
        robot = torch_grid.load(BALLS, cache_dir=tmp_path_factory.mktemp("cache"))
    return robot, rigid_only(mujoco.MjModel.from_xml_string(BALLS))


@pytest.fixture(scope="module")
def trees(robots, mj_sims):
    """Two free roots, a hinge tree between them, a ball under the second (conftest, tests/mjcf_models.py)."""
    return robots["trees"], mj_sims["trees"].m


@pytest.fixture(scope="module")
def fixed_balls(tmp_path_factory):
    with pytest.warns(UserWarning, match="contacts"):
        robot = torch_grid.load(FIXED_BALLS, cache_dir=tmp_path_factory.mktemp("cache"))
    return robot, rigid_only(mujoco.MjModel.from_xml_string(FIXED_BALLS))


def random_qpos(m, rng) -> np.ndarray:
    """A qpos with random joints and random unit quaternions (MuJoCo's wxyz)."""
    qpos = rng.uniform(-1.5, 1.5, m.nq)
    for j in range(m.njnt):
        if m.jnt_type[j] in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL):
            a = m.jnt_qposadr[j] + (3 if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE else 0)
            qpos[a:a + 4] = rng.normal(size=4)
            qpos[a:a + 4] /= np.linalg.norm(qpos[a:a + 4])
    return qpos


def mujoco_states(m, n, seed):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield random_qpos(m, rng), rng.normal(size=m.nv), rng.normal(size=m.nv)


def t(x: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.array(x, dtype=float))


def test_layout(balls):
    robot, m = balls
    assert [j.type for j in robot.model.joints] == ["free", "ball", "revolute", "ball", "prismatic", "prismatic",
                                                    "revolute", "ball", "ball"]
    assert (robot.nq, robot.nv) == (m.nq, m.nv) == (7 + 4 + 1 + 4 + 3 + 4 + 4, 6 + 3 + 1 + 3 + 3 + 3 + 3)
    q_mujoco, q_pin = robot.mujoco.neutral_configuration(), robot.pin.neutral_configuration()
    balls_q = [qi for j, qi in zip(robot.model.joints, robot.model.q_index) if j.type == "ball"]
    for qi in balls_q:  # identities, wxyz as in MuJoCo's qpos0
        assert np.array_equal(q_mujoco[qi:qi + 4].numpy(), m.qpos0[qi:qi + 4])
    assert np.array_equal(q_mujoco[3:7].numpy(), [1, 0, 0, 0])
    assert torch.equal(torch_grid.conventions.q_pin_to_mujoco(q_pin, True, balls_q), q_mujoco)
    q = robot.mujoco.random_configuration(5, generator=torch.Generator().manual_seed(0))
    for qi in balls_q:
        assert torch.allclose(q[:, qi:qi + 4].norm(dim=-1), torch.ones(5, dtype=q.dtype))
    assert torch.equal(torch_grid.conventions.q_mujoco_to_pin(torch_grid.conventions.q_pin_to_mujoco(q, True, balls_q),
                                                           True, balls_q), q)
    shoulder = robot.model.joints[1]
    assert (shoulder.armature, shoulder.damping) == (0.01, 0.2)


@pytest.mark.parametrize("convention", [0, 1])
def test_ambient_direction_is_the_tangent_matrix_product(balls, convention):
    """tangent.ambient_direction (a tangent vector pushed to q's coordinates) against the product with the
    explicit nv x nq matrix of tangent_directions, at non-unit quaternions, with u's batch broadcast."""
    from torch_grid.space.tangent import ambient_direction, tangent_directions

    robot, _ = balls
    view = robot.mujoco if convention else robot.pin
    q = 1.3 * view.random_configuration(4, generator=torch.Generator().manual_seed(5))
    u = torch.randn(2, 4, robot.nv, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    ref = (u.unsqueeze(-2) @ tangent_directions(robot.model, q, convention)).squeeze(-2)
    assert torch.allclose(ambient_direction(robot.model, q, u, convention), ref, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("convention", [0, 1])
def test_tangent_direction_is_tangent_to_ambient_transposed(balls, convention):
    """tangent.tangent_direction (a direction of q's coordinates carried to the tangent space, what forward mode
    feeds the derivative kernels) against the explicit transpose of tangent_to_ambient, column by column, at
    quaternions of norms 1.7 and 0.4 and a zero one (the identity), t's batch broadcast; a NaN quaternion gives
    NaN in its own joint's entries and leaves the others as they were."""
    from torch_grid.space.tangent import layout, tangent_direction, tangent_to_ambient

    robot, _ = balls
    model = robot.model
    view = robot.mujoco if convention else robot.pin
    free, ball = layout(model).quaternions[:2]
    q = view.random_configuration(3, generator=torch.Generator().manual_seed(7))
    q[0, free.quat:free.quat + 4] *= 1.7
    q[1, ball.quat:ball.quat + 4] *= 0.4
    q[2, ball.quat:ball.quat + 4] = 0
    t = torch.randn(2, 3, robot.nq, dtype=torch.float64, generator=torch.Generator().manual_seed(8))
    eye = torch.eye(robot.nv, dtype=torch.float64)
    columns = torch.stack([tangent_to_ambient(model, q, eye[k].expand(3, -1), convention) for k in range(robot.nv)], -2)
    ref = (columns @ t.unsqueeze(-1)).squeeze(-1)
    got = tangent_direction(model, q, t, convention)
    assert got.shape == (2, 3, robot.nv)
    assert torch.allclose(got, ref, rtol=1e-14, atol=1e-14)
    spoiled = q.clone()
    spoiled[1, ball.quat] = float("nan")
    got_nan = tangent_direction(model, spoiled, t, convention)
    own = torch.zeros(robot.nv, dtype=torch.bool)
    own[ball.angular:ball.angular + 3] = True
    assert got_nan[:, 1, own].isnan().all()
    assert torch.equal(got_nan[:, 1, ~own], got[:, 1, ~own]) and torch.equal(got_nan[:, [0, 2]], got[:, [0, 2]])


def test_free_joints_at_every_root(trees):
    robot, m = trees
    assert [j.type for j in robot.model.joints] == ["free", "revolute", "revolute", "free", "ball", "prismatic"]
    assert [j.parent for j in robot.model.joints] == [-1, 0, -1, -1, 3, 4]
    assert robot.joint_names == [m.joint(j).name for j in range(m.njnt)] and (robot.nq, robot.nv) == (m.nq, m.nv)
    q = robot.mujoco.neutral_configuration()
    assert q[3:7].tolist() == [1, 0, 0, 0] and q[12:16].tolist() == [1, 0, 0, 0] and q[16:20].tolist() == [1, 0, 0, 0]
    joints = list(robot.model.joints)
    joints[4] = dataclasses.replace(joints[4], type="free")  # MuJoCo itself refuses it below a moving body
    with pytest.raises(ValueError, match="'tail_ball'.*free joint is only supported at the root of a tree"):
        dataclasses.replace(robot.model, joints=tuple(joints))


@pytest.mark.parametrize("fixture", ["balls", "fixed_balls", "trees"])
def test_dynamics_match_mujoco(fixture, request):
    robot, m = request.getfixturevalue(fixture)
    d, view = mujoco.MjData(m), robot.mujoco
    for qpos, qvel, qacc in mujoco_states(m, 3, seed=1):
        d.qpos[:], d.qvel[:], d.qacc[:] = qpos, qvel, qacc
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        q, v, a = t(qpos), t(qvel), t(qacc)
        assert rel_err(view.crba(q), M) <= TOL
        assert rel_err(view.minv(q), np.linalg.inv(M)) <= 1e-8
        assert rel_err(view.nonlinear_effects(q, v), d.qfrc_bias) <= TOL
        assert rel_err(view.passive_forces(q, v), d.qfrc_passive) <= TOL
        pos, rot = view.forward_kinematics(q)
        assert rel_err(pos, np.concatenate([d.xpos, d.site_xpos])) <= TOL
        assert rel_err(rot, np.concatenate([d.xmat, d.site_xmat]).reshape(-1, 3, 3)) <= TOL
        d.qacc[:] = qacc
        mujoco.mj_inverse(m, d)
        tau = d.qfrc_inverse.copy()
        assert rel_err(view.inverse_dynamics(q, v, a), tau) <= TOL
        d.qfrc_applied[:] = tau
        mujoco.mj_forward(m, d)
        d.qfrc_applied[:] = 0
        assert rel_err(view.forward_dynamics(q, v, t(tau)), d.qacc) <= 1e-8
        assert rel_err(view.forward_dynamics(q, v, t(tau)), qacc) <= 1e-8


def test_site_jacobian_matches_mujoco(balls):
    robot, m = balls
    d = mujoco.MjData(m)
    for qpos, _, _ in mujoco_states(m, 2, seed=3):
        d.qpos[:] = qpos
        mujoco.mj_forward(m, d)
        jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jacp, jacr, m.site("hand").id)
        J = robot.mujoco.frame_jacobian(t(qpos), "hand")
        assert rel_err(J, np.concatenate([jacp, jacr])) <= TOL


def _central(fn, x, k, eps, move):
    def at(s):
        return fn(move(x, k, s * eps))
    return (at(1) - at(-1)) / (2 * eps)


def _move_qpos(m):
    def move(qpos, k, e):
        out, dq = qpos.copy(), np.zeros(m.nv)
        dq[k] = e
        mujoco.mj_integratePos(m, out, dq, 1.0)
        return out
    return move


def _move(x, k, e):
    out = x.copy()
    out[k] += e
    return out


@pytest.mark.parametrize("fixture", ["balls", "fixed_balls"])
def test_derivatives_match_mujoco_differences(fixture, request):
    """Tangent derivatives along mj_integratePos (a ball turns by its local rotation) and qvel."""
    robot, m = request.getfixturevalue(fixture)
    d = mujoco.MjData(m)

    def qfrc_inverse(qpos, qvel, qacc):
        d.qpos[:], d.qvel[:], d.qacc[:] = qpos, qvel, qacc
        mujoco.mj_inverse(m, d)
        return d.qfrc_inverse.copy()

    def qacc_of(qpos, qvel, qfrc):
        d.qpos[:], d.qvel[:], d.qfrc_applied[:] = qpos, qvel, qfrc
        mujoco.mj_forward(m, d)
        return d.qacc.copy()

    eps, nv = 1e-6, m.nv
    for qpos, qvel, qacc in mujoco_states(m, 2, seed=4):
        dq, dv = robot.mujoco.inverse_dynamics_derivatives(t(qpos), t(qvel), t(qacc))
        fd_q = np.stack([_central(lambda p: qfrc_inverse(p, qvel, qacc), qpos, k, eps, _move_qpos(m)) for k in range(nv)], 1)
        fd_v = np.stack([_central(lambda v: qfrc_inverse(qpos, v, qacc), qvel, k, eps, _move) for k in range(nv)], 1)
        assert rel_err(dq, fd_q) <= 1e-6 and rel_err(dv, fd_v) <= 1e-6
        u = qfrc_inverse(qpos, qvel, qacc)
        gq, gv, gu = robot.mujoco.forward_dynamics_derivatives(t(qpos), t(qvel), t(u))
        fd_q = np.stack([_central(lambda p: qacc_of(p, qvel, u), qpos, k, eps, _move_qpos(m)) for k in range(nv)], 1)
        fd_v = np.stack([_central(lambda v: qacc_of(qpos, v, u), qvel, k, eps, _move) for k in range(nv)], 1)
        fd_u = np.stack([_central(lambda f: qacc_of(qpos, qvel, f), u, k, eps, _move) for k in range(nv)], 1)
        assert rel_err(gq, fd_q) <= 1e-6 and rel_err(gv, fd_v) <= 1e-6 and rel_err(gu, fd_u) <= 1e-6


# --------------------------------------------------------------------------------------------
# Pinocchio's spherical joints
# --------------------------------------------------------------------------------------------
def test_pinocchio_spherical_joints(pinocchio_balls):
    robot, model = pinocchio_balls
    assert [j.type for j in robot.model.joints] == ["free", "ball", "revolute", "ball", "ball"]
    assert (robot.nq, robot.nv) == (model.nq, model.nv)
    oracle, data = PinOracle(model), model.createData()
    g = torch.Generator().manual_seed(5)
    tool = robot.frame_index("tool")
    for _ in range(3):
        q = robot.pin.random_configuration(generator=g)
        v, a = torch.randn(model.nv, generator=g, dtype=q.dtype), torch.randn(model.nv, generator=g, dtype=q.dtype)
        qn, vn, an = q.numpy(), v.numpy(), a.numpy()
        view = robot.pin
        tau = oracle.rnea(qn, vn, an)
        assert rel_err(view.inverse_dynamics(q, v, a), tau) <= TOL
        assert rel_err(view.forward_dynamics(q, v, t(tau)), an) <= 1e-8
        assert rel_err(view.crba(q), oracle.crba(qn)) <= TOL
        assert rel_err(view.minv(q), oracle.minv(qn)) <= 1e-8
        assert rel_err(view.energy(q, v), oracle.energy(qn, vn)) <= TOL
        assert rel_err(view.com(q), oracle.com(qn)) <= TOL
        assert rel_err(view.jacobian_com(q), oracle.jacobian_com(qn)) <= TOL
        A, h = view.ccrba(q, v)
        A_ref, h_ref = oracle.ccrba(qn, vn)
        assert rel_err(A, A_ref) <= TOL and rel_err(h, h_ref) <= TOL
        for reference in ("local_world_aligned", "local", "world"):
            assert rel_err(view.frame_jacobian(q, "tool", reference), oracle.frame_jacobian(qn, tool, reference)) <= TOL
        dq, dv = view.inverse_dynamics_derivatives(q, v, a)
        ref_q, ref_v, _ = pin.computeRNEADerivatives(model, data, qn, vn, an)
        assert rel_err(dq, ref_q) <= TOL and rel_err(dv, ref_v) <= TOL
        gq, gv, gu = view.forward_dynamics_derivatives(q, v, t(tau))
        pin.computeABADerivatives(model, data, qn, vn, tau)
        assert rel_err(gq, data.ddq_dq) <= 1e-8 and rel_err(gv, data.ddq_dv) <= 1e-8
        assert rel_err(gu, oracle.minv(qn)) <= 1e-8


def test_float32_matches_float64(balls):
    robot, _ = balls
    q = robot.mujoco.random_configuration(4, generator=torch.Generator().manual_seed(6))
    v = torch.randn(4, robot.nv, dtype=q.dtype, generator=torch.Generator().manual_seed(7))
    for fn in (robot.mujoco.inverse_dynamics, robot.mujoco.forward_dynamics):
        want = fn(q, v, v)
        assert rel_err(fn(q.float(), v.float(), v.float()), want) <= 1e-4


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_gradcheck(balls, convention):
    """Autograd through quaternions in ambient coordinates (their normalisation included), the planar
    root and the ball chains: first-order ops, and the backward of the inverse-dynamics gradient."""
    robot, _ = balls
    view = getattr(robot, convention)
    g = torch.Generator().manual_seed(8)
    q = view.random_configuration(2, generator=g) * 1.1  # off the unit sphere
    q.requires_grad_(True)
    v, a = (torch.randn(2, robot.nv, dtype=q.dtype, generator=g).requires_grad_(True) for _ in range(2))
    assert torch.autograd.gradcheck(view.inverse_dynamics, (q, v, a))
    assert torch.autograd.gradcheck(view.forward_dynamics, (q, v, a))
    assert torch.autograd.gradcheck(lambda x: view.end_effector_pose(x, ["hand", "hip"]), (q,))
    assert torch.autograd.gradcheck(view.crba, (q,))
    assert torch.autograd.gradcheck(lambda x, y: view.energy(x, y), (q, v))
    assert torch.autograd.gradcheck(lambda x, y, z: view.inverse_dynamics_derivatives(x, y, z)[0], (q, v, a))


@pytest.mark.parametrize("fixture", ["balls", "trees"])
def test_mujoco_twins_equal_the_torch_transforms(fixture, request):
    """The fused MuJoCo-convention kernels against conventions.py applied to the Pinocchio-convention
    ones, for every free joint and ball joint."""
    robot, _ = request.getfixturevalue(fixture)
    C = torch_grid.conventions
    free, balls = C.free_joints(robot.model), C.ball_joints(robot.model)
    g = torch.Generator().manual_seed(9)
    q = robot.pin.random_configuration(3, generator=g)
    v, a = (torch.randn(3, robot.nv, dtype=q.dtype, generator=g) for _ in range(2))
    qm = C.q_pin_to_mujoco(q, balls=balls, free=free)
    assert torch.equal(C.q_mujoco_to_pin(qm, balls=balls, free=free), q)
    vm, am = C.v_pin_to_mujoco(q, v, free=free), C.a_pin_to_mujoco(q, v, a, free=free)
    assert rel_err(C.v_mujoco_to_pin(q, vm, free=free), v) <= 1e-15 and rel_err(C.a_mujoco_to_pin(q, v, am, free=free), a) <= 1e-14
    pin_view, mjx = robot.pin, robot.mujoco
    assert rel_err(mjx.crba(qm), C.congruence_pin_to_mujoco(q, pin_view.crba(q), free=free)) <= TOL
    assert rel_err(mjx.minv(qm), C.congruence_pin_to_mujoco(q, pin_view.minv(q), free=free)) <= TOL
    tau = pin_view.inverse_dynamics(q, v, a)
    assert rel_err(mjx.inverse_dynamics(qm, vm, am), C.covector_pin_to_mujoco(q, tau, free=free)) <= TOL
    assert rel_err(mjx.forward_dynamics(qm, vm, C.covector_pin_to_mujoco(q, tau, free=free)), am) <= 1e-8
    last = robot.nframes - 1
    J = pin_view.frame_jacobian(q, last)
    assert rel_err(mjx.frame_jacobian(qm, last), C.columns_pin_to_mujoco(q, J, free=free)) <= TOL
    assert rel_err(mjx.jacobian_com(qm), C.columns_pin_to_mujoco(q, pin_view.jacobian_com(q), free=free)) <= TOL


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_zero_ball_quaternion_reads_as_identity(balls, convention):
    """A ball quaternion of zero norm is the identity rotation, as a free joint's (and MuJoCo's
    mj_normalizeQuat); its gradient is the one at the identity."""
    robot, _ = balls
    view = getattr(robot, convention)
    q = view.random_configuration(generator=torch.Generator().manual_seed(10))
    ident = q.clone()
    zero = q.clone()
    for qi in torch_grid.conventions.ball_joints(robot.model):
        ident[qi:qi + 4] = torch.tensor([1.0, 0, 0, 0] if convention == "mujoco" else [0, 0, 0, 1.0], dtype=q.dtype)
        zero[qi:qi + 4] = 0
    assert torch.equal(view.crba(zero), view.crba(ident))
    v = torch.randn(robot.nv, dtype=q.dtype, generator=torch.Generator().manual_seed(11))
    for x in (zero, ident):
        x.requires_grad_(True)
        view.inverse_dynamics(x, v, v).square().sum().backward()
    assert torch.isfinite(zero.grad).all() and torch.allclose(zero.grad, ident.grad, rtol=1e-12, atol=1e-12)


def test_conventions_of_a_robot_match_mujoco(trees):
    """conventions.of(robot): a Pinocchio-convention state and force carried into MuJoCo's by the robot's own
    layout (two free roots, a ball joint) gives mj_forward's qacc, M and a Jacobian in MuJoCo's convention;
    the other way round gives the state back; the free functions given the same lists agree."""
    robot, m = trees
    C, cv = torch_grid.conventions, torch_grid.conventions.of(robot)
    assert cv.free == C.free_joints(robot.model) and cv.balls == C.ball_joints(robot.model) and cv.free[1] != (0, 0)
    g = torch.Generator().manual_seed(4)
    q = robot.pin.random_configuration(2, generator=g)
    v, tau = (torch.randn(2, robot.nv, dtype=q.dtype, generator=g) for _ in range(2))
    qdd = robot.pin.forward_dynamics(q, v, tau)
    qm, vm, taum, am = cv.q_pin_to_mujoco(q), cv.v_pin_to_mujoco(q, v), cv.covector_pin_to_mujoco(q, tau), \
        cv.a_pin_to_mujoco(q, v, qdd)
    assert torch.equal(qm, C.q_pin_to_mujoco(q, balls=cv.balls, free=cv.free))
    d = mujoco.MjData(m)
    for s in range(2):
        d.qpos[:], d.qvel[:], d.qfrc_applied[:] = qm[s].numpy(), vm[s].numpy(), taum[s].numpy()
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        assert rel_err(am[s], d.qacc) <= 1e-8
        assert rel_err(cv.congruence_pin_to_mujoco(q[s], robot.pin.crba(q[s])), M) <= TOL
        jac, site = np.zeros((6, m.nv)), m.site(m.nsite - 1).name
        mujoco.mj_jacSite(m, d, jac[:3], jac[3:], m.site(site).id)
        J = robot.pin.frame_jacobian(q[s], site)
        assert rel_err(cv.columns_pin_to_mujoco(q[s], J), jac) <= TOL
    assert torch.equal(cv.q_mujoco_to_pin(qm), q)
    assert rel_err(cv.v_mujoco_to_pin(q, vm), v) <= 1e-15 and rel_err(cv.covector_mujoco_to_pin(q, taum), tau) <= 1e-15
    assert rel_err(cv.a_mujoco_to_pin(q, v, am), qdd) <= 1e-14
    assert torch.equal(C.of(robot.mujoco).q_pin_to_mujoco(q), qm) and torch.equal(C.of(robot.model).q_pin_to_mujoco(q), qm)


def test_conventions_of_a_robot_broadcast_a_batch_of_configurations(trees):
    """A batch of configurations against one velocity, force, acceleration, mass matrix or Jacobian (the batch
    of q_pin beyond the other argument's had raised torch's concatenation error): each sample is the
    one-configuration call's."""
    robot, _ = trees
    cv = torch_grid.conventions.of(robot)
    g = torch.Generator().manual_seed(6)
    q = robot.pin.random_configuration(3, generator=g)
    v, a = (torch.randn(robot.nv, dtype=q.dtype, generator=g) for _ in range(2))
    M, J = robot.pin.crba(q[0]), torch.randn(6, robot.nv, dtype=q.dtype, generator=g)
    calls = {"v_pin_to_mujoco": lambda q: cv.v_pin_to_mujoco(q, v), "v_mujoco_to_pin": lambda q: cv.v_mujoco_to_pin(q, v),
             "covector_pin_to_mujoco": lambda q: cv.covector_pin_to_mujoco(q, v),
             "a_pin_to_mujoco": lambda q: cv.a_pin_to_mujoco(q, v, a), "a_mujoco_to_pin": lambda q: cv.a_mujoco_to_pin(q, v, a),
             "congruence_pin_to_mujoco": lambda q: cv.congruence_pin_to_mujoco(q, M),
             "columns_pin_to_mujoco": lambda q: cv.columns_pin_to_mujoco(q, J)}
    for name, call in calls.items():
        batched = call(q)
        assert batched.shape[0] == 3, name
        for s in range(3):
            assert rel_err(batched[s], call(q[s])) <= 1e-14, name


def test_conventions_of_a_robot_check_their_arguments(trees):
    robot, _ = trees
    cv = torch_grid.conventions.of(robot)
    q = robot.pin.neutral_configuration()
    with pytest.raises(ValueError, match=rf"of\('{robot.name}'\).q_pin_to_mujoco: q must have nq = {robot.nq} entries.*"
                                         rf"got shape \({robot.nv},\)"):
        cv.q_pin_to_mujoco(q[:robot.nv])
    with pytest.raises(ValueError, match=rf"v_pin_to_mujoco: v must have nv = {robot.nv} entries"):
        cv.v_pin_to_mujoco(q, q)
    with pytest.raises(ValueError, match=r"congruence_pin_to_mujoco: M must be \(\.\.\., nv, nv\)"):
        cv.congruence_pin_to_mujoco(q, torch.zeros(3, robot.nv, dtype=q.dtype))
    with pytest.raises(ValueError, match=r"columns_pin_to_mujoco: J must be \(\.\.\., rows, nv\)"):
        cv.columns_pin_to_mujoco(q, torch.zeros(robot.nv, dtype=q.dtype))
    # an argument of another dtype than q_pin's failed inside torch or was promoted (a float64 acceleration
    # from a float32 velocity), an integer one too
    v = torch.zeros(robot.nv, dtype=q.dtype)
    with pytest.raises(TypeError, match=r"a_pin_to_mujoco: v_pin is torch.float32 on cpu, expected q_pin's torch.float64"):
        cv.a_pin_to_mujoco(q, v.float(), v)
    with pytest.raises(TypeError, match=r"v_mujoco_to_pin: v is torch.float64 on cpu, expected q_pin's torch.float32"):
        cv.v_mujoco_to_pin(q.float(), v)
    with pytest.raises(TypeError, match=r"columns_pin_to_mujoco: J must be a float tensor, got torch.int64"):
        cv.columns_pin_to_mujoco(q, torch.zeros(6, robot.nv, dtype=torch.long))
    with pytest.raises(TypeError, match=r"q_mujoco_to_pin: q must be a float tensor, got torch.int64"):
        cv.q_mujoco_to_pin(q.long())
    for other in ("trees", pin.buildSampleModelManipulator()):  # a pinocchio.Model has joints, not a RobotModel's
        with pytest.raises(TypeError, match=f"expected a Robot, a RobotView or a RobotModel, got {type(other).__name__}"):
            torch_grid.conventions.of(other)


def test_conventions_of_a_robot_with_mimic_joints_take_its_reduced_layout(trees):
    """With a mimic joint before the second free root and the ball joint, their places in the reduced q and
    v (what a mimic robot's functions take) are those of the coupling."""
    from torch_grid.model.description import Mimic
    from torch_grid.ops.mimic import Coupling

    robot, _ = trees
    names = [j.name for j in robot.model.joints]
    model = dataclasses.replace(robot.model, mimics=(Mimic(names[2], names[1], 0.5, 0.1),))
    coupling, cv = Coupling(model), torch_grid.conventions.of(model)
    assert (cv.nq, cv.nv) == (coupling.nq, coupling.nv) == (robot.nq - 1, robot.nv - 1)
    kept = coupling.reduce_q(torch.arange(model.nq, dtype=torch.float64)).tolist()  # the full q index of each
    reduced = {name: (kept.index(model.q_index[k]), coupling.v_src[model.v_index[k]]) for k, name in enumerate(names)
               if name != names[2]}
    assert cv.free == [reduced[j.name] for j in model.joints if j.type == "free"]
    assert cv.balls == [reduced[j.name][0] for j in model.joints if j.type == "ball"]
