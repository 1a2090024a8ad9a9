"""MJCF read through MuJoCo's compiler, against MuJoCo itself (its convention, float64, <= 1e-9).

The model exercises what MuJoCo's compiled model brings and a URDF does not: a planar root of
slide, slide, hinge; a body with two hinges about different anchors; bodies welded to their parent
(inertia from geoms, a site on one); angles in degrees and euler orientations; several trees, one
of them on a free joint; the model's own gravity.
"""
from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest
import torch

import torch_grid
from torch_grid.model.parse import source_to_model

from mjcf_models import ZOO as MODEL

JOINTS = ["root", "yaw", "pitch", "slide_x", "slide_z", "tilt", "knee", "swing"]
TOL = 1e-9


@pytest.fixture(scope="module")
def zoo(robots):
    return robots["zoo"], rigid_only(mujoco.MjModel.from_xml_string(MODEL))


def rigid_only(m):
    """m with contacts and joint limits disabled: the rigid-body dynamics torch_grid computes."""
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    return m


def at_state(m, d, qpos, qvel, qacc, step):
    """d at (qpos, qvel, qacc) after MuJoCo's `step` (mj_forward replaces qacc, mj_inverse reads it),
    the state as tensors, and MuJoCo's M."""
    d.qpos[:], d.qvel[:], d.qacc[:] = qpos, qvel, qacc
    step(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    return [torch.from_numpy(x.copy()) for x in (qpos, qvel, qacc)], M


def states(m, n, seed):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        qpos = rng.uniform(-1.5, 1.5, m.nq)
        qpos[3:7] /= np.linalg.norm(qpos[3:7])
        yield qpos, rng.normal(size=m.nv), rng.normal(size=m.nv)


def rel(a, b):
    return np.abs(np.asarray(a) - np.asarray(b)).max() / max(np.abs(np.asarray(b)).max(), 1e-12)


def test_layout_is_mujocos(zoo):
    robot, m = zoo
    assert robot.joint_names == JOINTS
    assert (robot.nq, robot.nv) == (m.nq, m.nv) == (7 + 7, 6 + 7)
    assert robot.floating_base
    assert [j.type for j in robot.model.joints] == ["free", "revolute", "revolute", "prismatic", "prismatic",
                                                    "revolute", "revolute", "revolute"]
    pitch = robot.model.joints[2]
    assert (pitch.lower, pitch.upper) == pytest.approx((-np.pi / 3, np.pi / 3))  # degrees, converted
    bodies = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(m.nbody)]
    assert robot.frame_names == bodies + ["tip"]
    assert robot.model.gravity == (0.5, -1.0, -7.0)


def test_dynamics_match_mujoco(zoo):
    robot, m = zoo
    d = mujoco.MjData(m)
    view = robot.mujoco
    for qpos, qvel, qacc in states(m, 4, seed=1):
        (q, v, a), M = at_state(m, d, qpos, qvel, qacc, mujoco.mj_forward)
        assert rel(view.crba(q), M) <= TOL
        assert rel(view.nonlinear_effects(q, v), d.qfrc_bias) <= TOL
        tau = M @ qacc + d.qfrc_bias
        assert rel(view.inverse_dynamics(q, v, a), tau) <= TOL
        d.qacc[:] = qacc  # mj_forward replaced it by its own
        mujoco.mj_inverse(m, d)
        assert rel(view.inverse_dynamics(q, v, a), d.qfrc_inverse) <= TOL
        d.qfrc_applied[:] = tau
        mujoco.mj_forward(m, d)
        assert rel(view.forward_dynamics(q, v, torch.from_numpy(tau)), d.qacc) <= 1e-8
        assert rel(view.forward_dynamics(q, v, torch.from_numpy(tau)), qacc) <= 1e-8


def test_frames_match_mujoco(zoo):
    robot, m = zoo
    d = mujoco.MjData(m)
    for qpos, _, _ in states(m, 3, seed=2):
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        pos, rot = robot.mujoco.forward_kinematics(torch.from_numpy(qpos.copy()))
        want_pos = np.concatenate([d.xpos, d.site_xpos])
        want_rot = np.concatenate([d.xmat, d.site_xmat]).reshape(-1, 3, 3)
        assert rel(pos, want_pos) <= TOL
        assert rel(rot, want_rot) <= TOL


def test_mjmodel_source_is_the_same_robot(zoo, tmp_path):
    robot, m = zoo
    from_object = source_to_model(mujoco.MjModel.from_xml_string(MODEL), None)
    assert from_object == robot.model
    assert from_object.name == "zoo"


def test_offsets_mujoco_ignores_are_ignored():
    """Where MuJoCo's compiler marks an inertial frame or a site as its body's frame (body_sameframe,
    site_sameframe: within about 1e-6, or the MjModel edited after compiling), mj_kinematics takes the
    body's frame and ignores the stored offset; so does the reading."""
    edited = mujoco.MjModel.from_xml_string(MODEL)
    flyer, pendulum = (mujoco.mj_name2id(edited, mujoco.mjtObj.mjOBJ_BODY, b) for b in ("flyer", "pendulum"))
    assert (edited.body_sameframe[flyer], edited.body_sameframe[pendulum]) == (1, 3)  # the body's frame; its axes
    tilted = np.array([0.9, 0.1, 0.3, 0.2]) / np.linalg.norm([0.9, 0.1, 0.3, 0.2])
    edited.body_ipos[flyer], edited.body_iquat[flyer], edited.body_iquat[pendulum] = [0.1, 0.05, 0.0], tilted, tilted
    original = mujoco.MjModel.from_xml_string(MODEL)
    for m in (edited, original):
        rigid_only(m)
    qpos, qvel, qacc = next(states(original, 1, seed=11))
    _, M_edited = at_state(edited, mujoco.MjData(edited), qpos, qvel, qacc, mujoco.mj_inverse)
    _, M = at_state(original, mujoco.MjData(original), qpos, qvel, qacc, mujoco.mj_inverse)
    assert rel(M_edited, M) <= 1e-15  # MuJoCo ignores the edits
    assert source_to_model(edited, None) == source_to_model(MODEL, None)
    # offsets below the compiler's tolerance: MuJoCo simulates the body's frame
    near = MODEL.replace('pos="0 0.01 -0.2" mass="0.8" diaginertia="0.01 0.012 0.004" quat="0.8 0.6 0 0"',
                         'pos="3e-7 0 0" mass="0.8" diaginertia="0.01 0.012 0.004"').replace(
        '<site name="tip" pos="0.05 0.01 0" euler="0 90 0"/>', '<site name="tip" pos="2e-7 0 0" euler="0 0.00001 0"/>')
    m = mujoco.MjModel.from_xml_string(near)
    assert m.body_sameframe[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "leg")] == m.site_sameframe[0] == 1
    exact = near.replace('pos="3e-7 0 0"', 'pos="0 0 0"').replace('pos="2e-7 0 0" euler="0 0.00001 0"', 'pos="0 0 0"')
    assert source_to_model(near, None) == source_to_model(exact, None)


def test_pin_convention_is_the_same_dynamics(zoo):
    """pin and MuJoCo views of one MJCF model differ only by the conventions' transforms."""
    robot, m = zoo
    g = torch.Generator().manual_seed(3)
    q = robot.random_configuration(2, generator=g)
    qm = torch_grid.conventions.q_pin_to_mujoco(q, True)
    M_pin = robot.crba(q)
    M_mujoco = robot.mujoco.crba(qm)
    assert rel(torch_grid.conventions.congruence_pin_to_mujoco(q, M_pin, True), M_mujoco) <= TOL


def with_joint(attributes: str) -> str:
    return MODEL.replace('<joint name="swing" type="hinge" axis="1 0 0"/>',
                         f'<joint name="swing" type="hinge" axis="1 0 0" {attributes}/>')


def test_armature_and_energy_match_mujoco(tmp_path):
    text = MODEL
    for joint, value in (("yaw", 0.03), ("slide_x", 0.2), ("knee", 0.05), ("swing", 0.1)):
        text = text.replace(f'name="{joint}"', f'name="{joint}" armature="{value}"')
    m = rigid_only(mujoco.MjModel.from_xml_string(text))
    m.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_ENERGY)
    robot = torch_grid.load(text, cache_dir=tmp_path, convention="mujoco")
    assert [j.armature for j in robot.model.joints] == [0.0, 0.03, 0.0, 0.2, 0.0, 0.0, 0.05, 0.1]
    d = mujoco.MjData(m)
    for qpos, qvel, qacc in states(m, 3, seed=4):
        (q, v, a), M = at_state(m, d, qpos, qvel, qacc, mujoco.mj_forward)
        assert rel(robot.crba(q), M) <= TOL
        assert rel(robot.minv(q), np.linalg.inv(M)) <= 1e-8
        assert rel(robot.forward_dynamics(q, v, torch.zeros(m.nv, dtype=torch.float64)), d.qacc) <= 1e-8
        energy = robot.energy(q, v).numpy()
        assert rel(energy[:2], d.energy[::-1]) <= TOL  # MuJoCo's is [potential, kinetic]
        d.qacc[:] = qacc
        mujoco.mj_inverse(m, d)
        assert rel(robot.inverse_dynamics(q, v, a), d.qfrc_inverse) <= TOL
    with pytest.raises(ValueError, match="'root': armature on a free joint"):
        source_to_model(MODEL.replace('<freejoint name="root"/>', '<joint name="root" type="free" armature="1"/>'),
                        None)


PASSIVE = {"yaw": 'damping="0.3" stiffness="2" springref="10" ref="15"', "slide_z": 'damping="1.5" ref="0.1"',
           "knee": 'stiffness="4" springref="-20" armature="0.02"', "swing": 'damping="0.2"'}


@pytest.fixture(scope="module")
def springy(tmp_path_factory):
    """The model with joint damping, stiffness, spring references and refs (MuJoCo moves a joint by
    qpos - ref), as MuJoCo and as two robots."""
    text = MODEL
    for joint, attributes in PASSIVE.items():
        text = text.replace(f'name="{joint}"', f'name="{joint}" {attributes}')
    m = rigid_only(mujoco.MjModel.from_xml_string(text))
    cache = tmp_path_factory.mktemp("cache")
    with_passive = torch_grid.load(text, cache_dir=cache, convention="mujoco")
    without = torch_grid.load(text, cache_dir=cache, convention="mujoco", passive_forces=False)
    return m, with_passive, without


def test_passive_forces_match_mujoco(springy):
    m, robot, rigid = springy
    d = mujoco.MjData(m)
    for qpos, qvel, qacc in states(m, 3, seed=5):
        (q, v, a), M = at_state(m, d, qpos, qvel, qacc, mujoco.mj_forward)
        pos, rot = robot.forward_kinematics(q)
        assert rel(pos, np.concatenate([d.xpos, d.site_xpos])) <= TOL
        assert rel(rot, np.concatenate([d.xmat, d.site_xmat]).reshape(-1, 3, 3)) <= TOL
        assert rel(robot.crba(q), M) <= TOL
        assert rel(robot.passive_forces(q, v), d.qfrc_passive) <= TOL
        assert np.abs(d.qfrc_passive).max() > 0.1
        tau = torch.from_numpy(np.random.default_rng(0).normal(size=m.nv))
        d.qfrc_applied[:] = tau.numpy()
        mujoco.mj_forward(m, d)
        assert rel(robot.forward_dynamics(q, v, tau), d.qacc) <= 1e-8
        d.qacc[:] = qacc
        mujoco.mj_inverse(m, d)
        assert rel(robot.inverse_dynamics(q, v, a), d.qfrc_inverse) <= TOL
        # Without them: the rigid-body dynamics alone, whose difference is the passive force.
        assert rel(rigid.inverse_dynamics(q, v, a) - robot.inverse_dynamics(q, v, a), d.qfrc_passive) <= TOL


def test_passive_derivatives_match_mujoco_differences(springy):
    """Against central differences of mj_inverse and mj_forward along mj_integratePos, qvel fixed."""
    m, robot, _ = springy
    d = mujoco.MjData(m)
    eps = 1e-6
    qpos, qvel, qacc = next(states(m, 1, seed=6))
    tau = np.random.default_rng(1).normal(size=m.nv)

    def mj(pos, vel):
        d.qpos[:], d.qvel[:], d.qfrc_applied[:] = pos, vel, tau
        mujoco.mj_forward(m, d)
        qdd = d.qacc.copy()
        d.qacc[:] = qacc
        mujoco.mj_inverse(m, d)
        return d.qfrc_inverse.copy(), qdd

    columns = {"q": [], "qd": []}
    for k in range(m.nv):
        dv = np.zeros(m.nv)
        dv[k] = eps
        plus, minus = qpos.copy(), qpos.copy()
        mujoco.mj_integratePos(m, plus, dv, 1.0)
        mujoco.mj_integratePos(m, minus, -dv, 1.0)
        columns["q"].append([(x - y) / (2 * eps) for x, y in zip(mj(plus, qvel), mj(minus, qvel))])
        columns["qd"].append([(x - y) / (2 * eps) for x, y in zip(mj(qpos, qvel + dv), mj(qpos, qvel - dv))])
    fd = {k: [np.stack([c[i] for c in cols], axis=-1) for i in range(2)] for k, cols in columns.items()}
    q, v, a = (torch.from_numpy(x.copy()) for x in (qpos, qvel, qacc))
    dtau_dq, dtau_dqd = robot.inverse_dynamics_derivatives(q, v, a)
    dqdd_dq, dqdd_dqd, _ = robot.forward_dynamics_derivatives(q, v, torch.from_numpy(tau))
    assert rel(dtau_dq, fd["q"][0]) <= 1e-6 and rel(dtau_dqd, fd["qd"][0]) <= 1e-6
    assert rel(dqdd_dq, fd["q"][1]) <= 1e-6 and rel(dqdd_dqd, fd["qd"][1]) <= 1e-6


def test_passive_forces_in_autograd(springy):
    _, robot, _ = springy
    g = torch.Generator().manual_seed(7)
    q = robot.random_configuration(2, generator=g)
    v = torch.randn(2, robot.nv, dtype=torch.float64, generator=g, requires_grad=True)
    tau = torch.randn(2, robot.nv, dtype=torch.float64, generator=g)
    qdd = robot.forward_dynamics(q, v, tau)
    (grad,) = torch.autograd.grad(qdd.sum(), v)
    _, dqdd_dqd, _ = robot.forward_dynamics_derivatives(q, v.detach(), tau)
    assert rel(grad, dqdd_dqd.sum(dim=-2)) <= 1e-12
    inputs = [x.detach().clone().requires_grad_(True) for x in (q, v, tau)]
    for fn in (robot.passive_forces, robot.forward_dynamics, robot.inverse_dynamics, robot.inverse_dynamics_derivatives,
               robot.forward_dynamics_derivatives):
        arity = 2 if fn == robot.passive_forces else 3
        assert torch.autograd.gradcheck(fn, inputs[:arity], eps=1e-6, atol=1e-6, rtol=1e-5, fast_mode=True)


def test_couplings_are_refused():
    ball = MODEL.replace('type="hinge" axis="1 0 0"', 'type="ball" stiffness="2"')
    with pytest.raises(ValueError, match="'swing': stiffness on a ball joint"):
        source_to_model(ball, None)
    coupled = MODEL.replace("</worldbody>", "</worldbody><equality><joint name='tie' joint1='knee' joint2='swing'/>"
                            "</equality>")
    with pytest.raises(ValueError, match="equality constraint 'tie'"):
        source_to_model(coupled, None)
    tendon = MODEL.replace("</worldbody>", "</worldbody><tendon><fixed name='tie' stiffness='3'><joint joint='knee' "
                           "coef='1'/><joint joint='swing' coef='1'/></fixed></tendon>")
    with pytest.raises(ValueError, match="tendon 'tie' has stiffness"):
        source_to_model(tendon, None)
    free_damping = MODEL.replace('<freejoint name="root"/>', '<joint name="root" type="free" damping="1"/>')
    with pytest.raises(ValueError, match="'root': damping on a free joint"):
        source_to_model(free_damping, None)
    heavy = MODEL.replace('<body name="pendulum" pos="1 1 1">', '<body name="pendulum" pos="1 1 1" gravcomp="1">')
    with pytest.raises(ValueError, match="'pendulum' has gravcomp"):
        source_to_model(heavy, None)
    yielding = MODEL.replace('<joint name="swing" type="hinge" axis="1 0 0"/>',
                             '<joint name="swing" type="hinge" axis="1 0 0" stiffness="2" springyield="0.3"/>')
    with pytest.raises(ValueError, match="'swing' has springyield .*plasticity"):
        source_to_model(yielding, None)
    for extra in ('armature="0.2"', 'damping="0.1"'):
        # MuJoCo adds them to the joint (times gear^2) whether or not the motor is driven: refused
        driven = MODEL.replace("</worldbody>", f"</worldbody><actuator><motor name='drive' joint='knee' gear='3' {extra}/>"
                               "</actuator>")
        m = mujoco.MjModel.from_xml_string(driven)
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
        plain = mujoco.MjModel.from_xml_string(MODEL)
        d, d_plain = mujoco.MjData(m), mujoco.MjData(plain)
        d.qvel[:] = d_plain.qvel[:] = d.qacc[:] = d_plain.qacc[:] = 1.0
        mujoco.mj_inverse(m, d), mujoco.mj_inverse(plain, d_plain)
        assert np.abs(d.qfrc_inverse - d_plain.qfrc_inverse).max() > 0.1, extra  # M (+ 1.8) or the passive force
        with pytest.raises(ValueError, match=f"actuator 'drive' has {extra.split('=')[0]} .*times gear"):
            source_to_model(driven, None)
    rope = MODEL.replace("</worldbody>", '<flexcomp name="rope" type="grid" count="3 1 1" spacing="0.1 0.1 0.1" dim="1" '
                         'radius="0.01" mass="0.3"><edge stiffness="5"/></flexcomp></worldbody>')
    with pytest.raises(ValueError, match="flex 'rope' .*deformable"):
        source_to_model(rope, None)
    two_free = MODEL.replace('<joint name="swing" type="hinge" axis="1 0 0"/>', '<freejoint name="loose"/>')
    assert [j.type for j in source_to_model(two_free, None).joints][-1] == "free"  # a root: supported


def test_unmodelled_features_are_listed_once():
    text = with_joint('range="-1 1" limited="true"').replace(
        "</worldbody>", "</worldbody><actuator><motor joint='knee'/><motor joint='swing'/></actuator>")
    with pytest.warns(UserWarning) as record:
        source_to_model(text, None)
    assert len(record) == 1
    message = str(record[0].message)
    for w in ("2 actuators", "contacts", "joint limits (pitch, swing)", "without them"):
        assert w in message
    # contacts of an explicit pair between geoms that collide with nothing else, and sleeping
    quiet = MODEL.replace("<geom ", '<geom contype="0" conaffinity="0" ').replace(
        '<option gravity="0.5 -1 -7"/>', '<option gravity="0.5 -1 -7"><flag sleep="enable"/></option>').replace(
        'type="box"', 'name="box" type="box"').replace('type="cylinder"', 'name="rod" type="cylinder"')
    paired = quiet.replace("</worldbody>", "</worldbody><contact><pair geom1='box' geom2='rod'/></contact>")
    with pytest.warns(UserWarning) as record:
        source_to_model(paired, None)
    message = str(record[0].message)
    assert len(record) == 1 and "contacts (1 explicit pairs)" in message and "sleep" in message, message
    pid = MODEL.replace("<mujoco model=\"zoo\">", '<mujoco model="zoo"><extension><plugin plugin="mujoco.pid"><instance '
                        'name="pid"><config key="kp" value="4"/></instance></plugin></extension>').replace(
        "</worldbody>", "</worldbody><actuator><plugin joint='knee' plugin='mujoco.pid' instance='pid'/></actuator>")
    with pytest.warns(UserWarning, match=r"1 plugins \(the forces they apply\)"):
        source_to_model(pid, None)


def test_constraints_mujoco_turns_off_are_neither_refused_nor_listed():
    """<flag constraint="disable"/> turns off MuJoCo's whole constraint solver (contacts, limits, friction
    loss, equality constraints), equality="disable" the equality constraints: the model is then the
    rigid-body dynamics."""
    untied = with_joint('range="-1 1" limited="true" frictionloss="0.3"')
    tied = untied.replace("</worldbody>", "</worldbody><equality><joint name='tie' joint1='knee' joint2='swing'/>"
                          "</equality>")
    each = 'equality="disable" contact="disable" limit="disable" frictionloss="disable"'
    for flags in ('constraint="disable"', each):
        off, plain, free = (text.replace('<option gravity="0.5 -1 -7"/>', f'<option gravity="0.5 -1 -7"><flag {flags}/>'
                                         '</option>') for text in (tied, MODEL, untied))
        m, m_plain = mujoco.MjModel.from_xml_string(off), mujoco.MjModel.from_xml_string(plain)
        d, d_plain = mujoco.MjData(m), mujoco.MjData(m_plain)
        qpos, qvel, _ = next(states(m, 1, seed=12))
        qpos[-1] = 2.0  # past swing's limit
        for model, data in ((m, d), (m_plain, d_plain)):
            data.qpos[:], data.qvel[:] = qpos, qvel
            mujoco.mj_forward(model, data)
        assert rel(d.qacc, d_plain.qacc) <= 1e-15
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert source_to_model(off, None) == source_to_model(free, None)  # the same limits
    with pytest.raises(ValueError, match="equality constraint 'tie'"):
        source_to_model(tied.replace('<option gravity="0.5 -1 -7"/>',
                                     '<option gravity="0.5 -1 -7"><flag contact="disable"/></option>'), None)


def test_floating_base_must_agree():
    with pytest.raises(ValueError, match="floating_base=False"):
        source_to_model(MODEL, False)
    fixed = MODEL.replace('<freejoint name="root"/>', "")
    assert not source_to_model(fixed, None).floating_base
    with pytest.raises(ValueError, match="floating_base=True"):
        source_to_model(fixed, True)


def test_bundled_humanoid_matches_mujoco():
    """The bundled MJCF robot (multi-hinge bodies, armature, damping, springs), loaded by name from its
    JSON, against MuJoCo compiling its XML."""
    robot = torch_grid.load("humanoid", convention="mujoco")
    m = rigid_only(mujoco.MjModel.from_xml_path(str(torch_grid.model.parse.ROBOTS_DIR / "humanoid.xml")))
    assert robot.joint_names == [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)]
    d = mujoco.MjData(m)
    for qpos, qvel, qacc in states(m, 2, seed=8):
        (q, v, a), M = at_state(m, d, qpos, qvel, qacc, mujoco.mj_inverse)
        assert rel(robot.crba(q), M) <= TOL
        assert rel(robot.inverse_dynamics(q, v, a), d.qfrc_inverse) <= TOL
        assert rel(robot.forward_dynamics(q, v, torch.from_numpy(d.qfrc_inverse.copy())), qacc) <= 1e-8


def test_float32_and_gradcheck_on_the_planar_and_multi_joint_model(zoo):
    """float32 against MuJoCo's float64, and gradcheck of the main functions, on the model with a
    planar root, a two-hinge body and several trees."""
    robot, m = zoo
    d = mujoco.MjData(m)
    qpos, qvel, qacc = next(states(m, 1, seed=9))
    state, M = at_state(m, d, qpos, qvel, qacc, mujoco.mj_inverse)
    q, v, a = (x.float() for x in state)
    assert robot.mujoco.crba(q).dtype == torch.float32
    assert rel(robot.mujoco.crba(q), M) <= 1e-5
    assert rel(robot.mujoco.inverse_dynamics(q, v, a), d.qfrc_inverse) <= 1e-5
    g = torch.Generator().manual_seed(10)
    for view in (robot.pin, robot.mujoco):
        q = view.random_configuration(2, generator=g).requires_grad_(True)
        v, a = (torch.randn(2, robot.nv, dtype=torch.float64, generator=g, requires_grad=True) for _ in range(2))
        for fn, inputs in ((view.inverse_dynamics, (q, v, a)), (view.forward_dynamics, (q, v, a)), (view.crba, (q,)),
                           (view.inverse_dynamics_derivatives, (q, v, a))):
            assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-5, fast_mode=True)
