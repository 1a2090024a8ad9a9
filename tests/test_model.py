"""Robot sources and the model description: bundled robots, saved models, pinocchio.Model, MJCF,
and refusal of what the kernels do not support."""
from __future__ import annotations

import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pinocchio as pin
import pytest
import torch

import torch_grid
from torch_grid.model.description import Mimic, RobotModel
from torch_grid.model.parse import ROBOTS_DIR, source_to_model

ARM_MJCF = """
<mujoco model="arm">
  <worldbody>
    <body name="base" pos="0 0 0.1">
      {free}
      <inertial pos="0 0 0" mass="2" diaginertia="0.02 0.03 0.04"/>
      <body name="upper" pos="0 0 0.2" quat="0.9238795 0 0.3826834 0">
        <joint name="shoulder" type="hinge" axis="0 1 0"/>
        <inertial pos="0.05 0 0.1" mass="1.5" diaginertia="0.01 0.012 0.005"/>
        <body name="slider" pos="0 0 0.3">
          <joint name="extend" type="slide" axis="0.6 0 0.8"/>
          <inertial pos="0 0.02 0.05" mass="0.7" diaginertia="0.003 0.002 0.004"/>
          <body name="wrist" pos="0.1 0 0">
            <joint name="twist" type="hinge" axis="1 1 0"/>
            <inertial pos="0 0 0.03" mass="0.3" diaginertia="0.001 0.001 0.0005"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.mark.parametrize("name", sorted(torch_grid.BUNDLED))
def test_bundled_model_equals_fresh_parse(name):
    bundled = RobotModel.load(ROBOTS_DIR / f"{name}.json")
    description = next(p for p in (ROBOTS_DIR / f"{name}.urdf", ROBOTS_DIR / f"{name}.xml") if p.exists())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an MJCF's contacts and limits
        fresh = source_to_model(str(description), torch_grid.BUNDLED[name])
    assert bundled.joints == fresh.joints and bundled.frames == fresh.frames
    assert bundled.name == name


def test_bundled_sizes():
    iiwa = RobotModel.load(ROBOTS_DIR / "iiwa14.json")
    go2 = RobotModel.load(ROBOTS_DIR / "go2.json")
    assert (iiwa.floating_base, iiwa.nq, iiwa.nv) == (False, 7, 7)
    assert (go2.floating_base, go2.nq, go2.nv, go2.nbodies) == (True, 19, 18, 13)


def test_hash_is_content_hash():
    model = RobotModel.load(ROBOTS_DIR / "iiwa14.json")
    assert RobotModel.from_dict(model.to_dict()).hash == model.hash
    joints = list(model.joints)
    joints[2] = type(joints[2])(**{**joints[2].__dict__, "mass": joints[2].mass + 1e-9})
    assert RobotModel(model.name, tuple(joints), model.frames).hash != model.hash


def test_a_saved_model_loads_whatever_its_file_name_and_a_broken_one_is_named(robots, tmp_path):
    """A model saved to a file without the .json suffix loads as one; a file that is not JSON, or JSON that is not a
    saved model, is refused naming the file."""
    robot = robots["go2"]
    path = tmp_path / "go2_model"
    robot.save(path)
    assert source_to_model(str(path), None) == robot.model
    for text, words in (("not json", "is not a saved robot model"), ("[1, 2]", "is JSON but not a saved robot model")):
        broken = tmp_path / "broken.json"
        broken.write_text(text)
        with pytest.raises(ValueError, match=words) as info:
            source_to_model(str(broken), None)
        assert str(broken) in str(info.value)


def test_save_and_load_without_pinocchio(robots, tmp_path):
    robot = robots["go2"]
    path = tmp_path / "go2_saved.json"
    robot.save(path)
    script = textwrap.dedent(f"""
        import sys
        sys.modules["pinocchio"] = None  # any import of Pinocchio now fails
        import torch, torch_grid
        for source in ({str(path)!r}, "go2", "iiwa14"):
            robot = torch_grid.load(source)
            q = robot.random_configuration(3, generator=torch.Generator().manual_seed(0))
            print(source, robot.nq, float(robot.crba(q).sum()))
        try:
            torch_grid.load({str(ROBOTS_DIR / 'iiwa14.urdf')!r})
        except ImportError as e:
            print("urdf needs pinocchio:", e)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    lines = out.stdout.splitlines()
    q = robot.random_configuration(3, generator=torch.Generator().manual_seed(0))
    assert lines[0].split()[1] == str(robot.nq)
    assert float(lines[0].split()[2]) == pytest.approx(float(robot.crba(q).sum()), rel=1e-14)
    assert "urdf needs pinocchio: Pinocchio is needed" in lines[-1]


def test_pinocchio_model_source(robots):
    model = pin.buildModelFromUrdf(str(ROBOTS_DIR / "go2.urdf"), pin.JointModelFreeFlyer())
    robot = torch_grid.load(model)
    assert robot.model.joints == robots["go2"].model.joints
    assert robot.frame_names == [f.name for f in model.frames]
    with pytest.raises(ValueError, match="floating_base=False"):
        torch_grid.load(model, floating_base=False)


def _mjcf_case(tmp_path, floating: bool):
    path = tmp_path / "arm.xml"  # named as the model in the text (the name is part of the cache key)
    path.write_text(ARM_MJCF.format(free='<freejoint name="root"/>' if floating else ""))
    return path


@pytest.mark.parametrize("floating", [False, True])
def test_mjcf_source_matches_pinocchio_and_mujoco(tmp_path, floating):
    import mujoco

    path = _mjcf_case(tmp_path, floating)
    robot = torch_grid.load(str(path))
    assert robot.floating_base == floating
    assert [j.type for j in robot.model.joints] == (["free"] if floating else []) + ["revolute", "prismatic", "revolute"]
    pm = pin.buildModelFromMJCF(str(path))
    pd = pm.createData()
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    g = torch.Generator().manual_seed(5)
    for _ in range(3):
        q = robot.random_configuration(generator=g)
        qd = torch.randn(robot.nv, dtype=torch.float64, generator=g)
        qdd = torch.randn(robot.nv, dtype=torch.float64, generator=g)
        ref = pin.rnea(pm, pd, q.numpy(), qd.numpy(), qdd.numpy())
        assert np.abs(robot.inverse_dynamics(q, qd, qdd).numpy() - ref).max() <= 1e-9 * np.abs(ref).max()
        # MuJoCo itself, in its own convention.
        qpos = torch_grid.conventions.q_pin_to_mujoco(q, floating)
        d.qpos[:], d.qvel[:] = qpos.numpy(), qd.numpy()
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        ours = robot.mujoco.crba(qpos).numpy()
        assert np.abs(ours - M).max() <= 1e-9 * np.abs(M).max()


def test_mjcf_string_source():
    text = ARM_MJCF.format(free="")
    robot = torch_grid.load(text)
    assert robot.nv == 3 and not robot.floating_base


def test_continuous_joint_has_one_coordinate(robots):
    robot = robots["tiago"]
    kinds = [j.type for j in robot.model.joints]
    assert "continuous" in kinds and "prismatic" in kinds
    pm = pin.buildModelFromUrdf(source_to_tiago())
    assert robot.nq == pm.nq - kinds.count("continuous") and robot.nv == pm.nv


def source_to_tiago():
    from conftest import ROBOT_SPECS

    return ROBOT_SPECS["tiago"][0]


URDF_TEMPLATE = """<robot name="bad">
  <link name="a"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="b"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="c"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="j2" type="{kind}"><parent link="b"/><child link="c"/><axis xyz="0 1 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>{extra}</joint>
</robot>"""


@pytest.mark.parametrize(
    "kind, extra, words",
    [
        ("planar", "", ["'j2'", "planar"]),
        ("floating", "", ["'j2'", "floating"]),
    ],
)
def test_unsupported_urdf_joints_are_refused(kind, extra, words):
    with pytest.raises(ValueError) as info:
        torch_grid.load(URDF_TEMPLATE.format(kind=kind, extra=extra))
    for w in words:
        assert w in str(info.value)


def test_mimic_joints_are_independent_by_default():
    mimic = URDF_TEMPLATE.format(kind="revolute", extra='<mimic joint="j1" multiplier="2" offset="0.1"/>')
    with pytest.warns(UserWarning, match="mimic joints 'j2' \\(mimics 'j1'\\) are independent"):
        model = source_to_model(mimic, None)
    pm = pin.buildModelFromXML(mimic)
    assert [j.name for j in model.joints] == list(pm.names[1:]) and model.nv == pm.nv == 2
    coupled = source_to_model(mimic, None, mimic=True)
    assert coupled.mimics == (Mimic(joint="j2", master="j1", multiplier=2.0, offset=0.1),)
    assert coupled.kernel_model == model  # the same kernels
    plain = URDF_TEMPLATE.format(kind="revolute", extra="")
    assert source_to_model(plain, None, mimic=True) == source_to_model(plain, None)


def test_panda_with_mimic_fingers_matches_pinocchio(tmp_path):
    """A published robot with a mimic joint (the Panda's second finger) loads as Pinocchio's default
    model does and computes its dynamics."""
    from oracles import erd_dir

    path = erd_dir() / "panda_description" / "urdf" / "panda.urdf"
    with pytest.warns(UserWarning, match="panda_finger_joint2"):
        robot = torch_grid.load(str(path), cache_dir=tmp_path)
    pm = pin.buildModelFromUrdf(str(path))
    pd = pm.createData()
    g = torch.Generator().manual_seed(9)
    q = robot.random_configuration(generator=g)
    qd, qdd = (torch.randn(robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    ref = pin.rnea(pm, pd, q.numpy(), qd.numpy(), qdd.numpy())
    assert np.abs(robot.inverse_dynamics(q, qd, qdd).numpy() - ref).max() <= 1e-9 * np.abs(ref).max()
    M = pin.crba(pm, pd, q.numpy())
    M = np.triu(M) + np.triu(M, 1).T
    assert np.abs(robot.crba(q).numpy() - M).max() <= 1e-9 * np.abs(M).max()
    # mimic=True: Pinocchio's mimic model, from the same kernels
    coupled = torch_grid.load(str(path), mimic=True, cache_dir=tmp_path)
    pm = pin.buildModelFromUrdf(str(path), True)
    pd = pm.createData()
    assert coupled.nv == pm.nv == robot.nv - 1
    q = coupled.random_configuration(generator=g)
    qd, qdd = (torch.randn(coupled.nv, dtype=torch.float64, generator=g) for _ in range(2))
    ref = pin.rnea(pm, pd, q.numpy(), qd.numpy(), qdd.numpy())
    assert np.abs(coupled.inverse_dynamics(q, qd, qdd).numpy() - ref).max() <= 1e-9 * np.abs(ref).max()


def test_urdf_axes_off_the_coordinate_axes_move_as_in_pinocchio():
    """Revolute, continuous and prismatic joints about axes off the coordinate axes (Pinocchio's unaligned
    joints; a continuous one used to fail to load): each moves its body as Pinocchio's does."""
    inertia = '<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>'
    limit = '<limit lower="-1" upper="1" effort="1" velocity="1"/>'
    links = "".join(f'<link name="{n}">{inertia}</link>' for n in "abcd")
    chain = [("revolute", "0 1 1", limit), ("continuous", "1 2 2", ""), ("prismatic", "3 0 -4", limit)]
    joints = "".join(f'<joint name="j{k}" type="{kind}"><parent link="{"abcd"[k]}"/><child link="{"abcd"[k + 1]}"/>'
                     f'<origin xyz="0.1 0.2 0.3" rpy="0.3 -0.2 0.1"/><axis xyz="{axis}"/>{lim}</joint>'
                     for k, (kind, axis, lim) in enumerate(chain))
    text = f'<robot name="axes">{links}{joints}</robot>'
    model = source_to_model(text, False)
    assert [j.type for j in model.joints] == [kind for kind, _, _ in chain]
    pm = pin.buildModelFromXML(text)
    pd = pm.createData()
    x = np.array([0.7, -2.5, 0.4])
    pin.forwardKinematics(pm, pd, np.array([x[0], np.cos(x[1]), np.sin(x[1]), x[2]]))
    for jid, (j, xj) in enumerate(zip(model.joints, x), start=1):
        axis = np.array(j.axis)
        motion = pin.SE3(np.eye(3), xj * axis) if j.type == "prismatic" else pin.SE3(pin.exp3(xj * axis), np.zeros(3))
        ours = pin.SE3(np.array(j.rotation).reshape(3, 3), np.array(j.translation)) * motion
        assert np.abs(ours.homogeneous - pd.liMi[jid].homogeneous).max() <= 1e-15, j.name


def test_kinematic_loop_is_refused():
    loop = URDF_TEMPLATE.format(kind="revolute", extra="").replace(
        "</robot>", '<joint name="j3" type="revolute"><parent link="a"/><child link="c"/><axis xyz="1 0 0"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>')
    with pytest.raises(ValueError, match="'c' is the child of several joints"):
        torch_grid.load(loop)


def test_closed_chain_no_root_reaches_is_refused():
    """Links a and b each the child of one joint, but of each other: no root reaches them, and Pinocchio's
    URDF reader built the robot without them (nor their child d), silently."""
    joint = ('<joint name="{}" type="revolute"><parent link="{}"/><child link="{}"/><axis xyz="0 0 1"/>'
             '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>')
    text = URDF_TEMPLATE.format(kind="revolute", extra="").replace("</robot>", "".join(
        [f'<link name="{n}"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/>'
         "</inertial></link>" for n in ("x", "y", "z")]
        + [joint.format(*names) for names in (("k1", "x", "y"), ("k2", "y", "x"), ("k3", "y", "z"))]) + "</robot>")
    assert list(pin.buildModelFromXML(text).names) == ["universe", "j1", "j2"]  # k1, k2, k3 dropped
    with pytest.raises(ValueError, match=r"joints 'k\d', 'k\d' form a closed chain of links \(. <- . <- .\) that no root"):
        torch_grid.load(text)
    alone = URDF_TEMPLATE.format(kind="revolute", extra="").replace("</robot>", joint.format("k", "x", "x") + "</robot>")
    with pytest.raises(ValueError, match=r"joints 'k' form a closed chain of links \(x <- x\)"):
        torch_grid.load(alone.replace("</robot>", '<link name="x"/></robot>'))


@pytest.mark.parametrize("change, words", [
    (('<limit lower="-1" upper="1" effort="1" velocity="1"/>{extra}</joint>\n</robot>', "{extra}</joint>\n</robot>"),
     "joint 'j2': a revolute joint needs a <limit>"),
    (('effort="1" velocity="1"/>{extra}', 'velocity="1"/>{extra}'), "joint 'j2': <limit> has no effort"),
    (('<child link="c"/>', '<child link="d"/>'), "joint 'j2': its child link 'd' is not a <link> of the URDF"),
    (('name="j2" type="{kind}"', 'name="j1" type="{kind}"'), "joint 'j1' is declared more than once"),
    (("\n</robot>", '<link name="d"/></robot>'), "one root link (the child of no joint), got 2: 'a', 'd'"),
])
def test_urdf_pinocchio_refuses_names_the_reason(change, words):
    """urdfdom, Pinocchio's URDF reader, prints why it refuses a URDF on the C++ stderr only (unseen in a
    notebook); the error says it."""
    text = URDF_TEMPLATE.replace(*change).format(kind="revolute", extra="")
    with pytest.raises(ValueError, match="URDF"):
        pin.buildModelFromXML(text)
    with pytest.raises(ValueError) as info:
        torch_grid.load(text)
    assert "Pinocchio could not parse the URDF" in str(info.value) and words in str(info.value)


def test_unsupported_mjcf_joint_feature_is_refused(tmp_path):
    path = tmp_path / "ball.xml"
    path.write_text(ARM_MJCF.format(free="").replace('type="slide" axis="0.6 0 0.8"', 'type="ball" stiffness="3"'))
    with pytest.raises(ValueError, match="'extend': stiffness on a ball joint is not supported"):
        torch_grid.load(str(path))


@pytest.mark.parametrize(
    "source, exc, words",
    [
        ("/no/such/robot.urdf", ValueError, ["source", "/no/such/robot.urdf"]),
        ("not_a_robot", ValueError, ["not_a_robot", "iiwa14"]),
        ("<robot name='x'><link name='a'></robot>", ValueError, ["source", "XML"]),
        ("<robot name='x'><joint name='j' type='revolute'/></robot>", ValueError, ["source"]),
        ("<sdf version='1.6'/>", ValueError, ["<sdf>"]),
        (3.5, TypeError, ["source", "float"]),
    ],
)
def test_bad_sources_raise(source, exc, words):
    with pytest.raises(exc) as info:
        torch_grid.load(source)
    for w in words:
        assert w in str(info.value), f"{w!r} not in {info.value}"


def test_bad_load_options_raise():
    with pytest.raises(ValueError, match="convention"):
        torch_grid.load("iiwa14", convention="drake")
    with pytest.raises(TypeError, match="floating_base"):
        torch_grid.load("iiwa14", floating_base="yes")
    with pytest.raises(TypeError, match="enable_mujoco_kernels"):
        torch_grid.load("iiwa14", enable_mujoco_kernels=1)


def test_frame_index_reads_names_and_indices_and_names_the_argument():
    """The model layer finds frames for every function that takes one: a name, an index (numpy's too), and
    errors that name the caller's argument, suggest near names and give the valid range."""
    model = RobotModel.load(ROBOTS_DIR / "go2.json")
    index = [f.name for f in model.frames].index("FL_foot")
    assert model.frame_index("FL_foot") == index
    assert model.frame_index(np.int64(index)) == index and model.frame_index(index) == index
    with pytest.raises(ValueError, match=r"frame_jacobian: frame: 'go2' has no frame named 'FL_fot'; did you mean 'FL_foot'"):
        model.frame_index("FL_fot", "frame_jacobian: frame")
    with pytest.raises(ValueError, match=rf"frame index {len(model.frames)} is out of range \[0, {len(model.frames)}\)"):
        model.frame_index(len(model.frames))
    with pytest.raises(ValueError, match=r"frame index -1 is out of range"):
        model.frame_index(-1)
    for wrong in (True, 1.0, None):
        with pytest.raises(TypeError, match=f"frames must be a frame name or index, got {type(wrong).__name__}"):
            model.frame_index(wrong, "frames")
    assert RobotModel.from_dict(model.to_dict()).frame_index("FL_foot") == index  # the lookup is not saved, rebuilt
