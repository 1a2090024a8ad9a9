"""Validation of robot models at parse level: every refusal names the joint, link or frame and the
offending value, and the edge cases that are physically sound still load. Nothing here compiles."""
from __future__ import annotations

import json
import math

import numpy as np
import pinocchio as pin
import pytest

import torch_grid
from torch_grid.model.description import Frame, Joint, RobotModel, check_triangle_inequality
from torch_grid.model.parse import ROBOTS_DIR, source_to_model

URDF = """<robot name="arm">
  <link name="base"/>
  <link name="upper">{upper}</link>
  <link name="forearm">{forearm}</link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="elbow" type="{kind}"><parent link="upper"/><child link="forearm"/><origin xyz="{origin}"/>
    <axis xyz="{axis}"/><limit lower="{lower}" upper="1" effort="1" velocity="1"/></joint>
</robot>"""


def inertial(mass="1", com="0 0 0.2", ixx="0.01", iyy="0.01", izz="0.005", ixy="0", ixz="0", iyz="0") -> str:
    return (f'<inertial><origin xyz="{com}"/><mass value="{mass}"/><inertia ixx="{ixx}" ixy="{ixy}" '
            f'ixz="{ixz}" iyy="{iyy}" iyz="{iyz}" izz="{izz}"/></inertial>')


def urdf(forearm: str | None = None, upper: str | None = None, kind="revolute", origin="0 0 0.4", axis="0 1 0",
         lower="-1") -> str:
    """A two-joint arm; the arguments replace one part of it."""
    return URDF.format(forearm=inertial() if forearm is None else forearm, upper=inertial() if upper is None else upper,
                       kind=kind, origin=origin, axis=axis, lower=lower)


ARM_MJCF = """<mujoco model="arm"><worldbody>
  <body name="upper" pos="{pos}">
    <joint name="shoulder" type="hinge" axis="{axis}"/>
    <inertial pos="0 0 0.1" mass="{mass}" diaginertia="{diag}"/>
  </body>
</worldbody></mujoco>"""


def mjcf(pos="0 0 0.1", axis="0 1 0", mass="1.5", diag="0.01 0.012 0.005") -> str:
    return ARM_MJCF.format(pos=pos, axis=axis, mass=mass, diag=diag)


IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def joint(name: str, parent: int, **changes) -> Joint:
    fields = dict(name=name, type="revolute", parent=parent, axis=(0.0, 1.0, 0.0), rotation=IDENTITY,
                  translation=(0.0, 0.0, 0.4), mass=1.0, com=(0.0, 0.0, 0.2),
                  inertia=(0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.005), lower=-1.0, upper=1.0)
    return Joint(**{**fields, **changes})


def model(elbow: dict | None = None, frame: dict | None = None, gravity=(0.0, 0.0, -9.81)) -> RobotModel:
    """A hand-built two-joint arm with a tool frame; `elbow` and `frame` replace fields of those parts."""
    joints = (joint("shoulder", -1), joint("elbow", 0, **(elbow or {})))
    tool = Frame(**{**dict(name="tool", parent=1, rotation=IDENTITY, translation=(0.0, 0.0, 0.4)), **(frame or {})})
    return RobotModel("arm", joints, (tool,), gravity)


def refused(build, *words: str) -> str:
    """Assert that build() raises ValueError whose message holds every word; return the message."""
    with pytest.raises(ValueError) as info:
        build()
    message = str(info.value)
    for w in words:
        assert w in message, f"{w!r} not in {message!r}"
    return message


# -- URDF values Pinocchio's reader (urdfdom) would silently zero --------------------------------
def test_nan_mass_in_urdf_is_refused():
    text = urdf(forearm=inertial(mass="nan"))
    # The root cause: urdfdom cannot read "nan", logs an error, and leaves the link's inertial at 0.
    assert pin.buildModelFromXML(text).inertias[2].mass == 0.0
    refused(lambda: source_to_model(text, False), "link 'forearm'", "<mass value>", "'nan'", "finite")


@pytest.mark.parametrize(
    "forearm, words",
    [
        (inertial(mass="inf"), ["<mass value>", "'inf'"]),
        (inertial(mass="1.5 "), ["<mass value>", "'1.5 '"]),  # urdfdom refuses the trailing space
        (inertial(ixx="NaN"), ["<inertia ixx>", "'NaN'"]),
        (inertial(izz="1e400"), ["<inertia izz>", "'1e400'"]),
        (inertial(com="nan 0 0.2"), ["<origin xyz>", "'nan 0 0.2'"]),
        ('<inertial><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>',
         ["must hold one <mass> element, got none"]),
        ('<inertial><mass/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>',
         ["<mass value>", "no such attribute"]),
        ('<inertial><mass value="1"/></inertial>', ["must hold one <inertia> element, got none"]),
    ],
)
def test_unreadable_urdf_inertial_is_refused(forearm, words):
    refused(lambda: source_to_model(urdf(forearm=forearm), False), "link 'forearm'", *words)


@pytest.mark.parametrize("text", ["2", " 2", "2 ", "+2.5e0", ".5", "2.", "1_0", "0x2", "2e", "\u0663", "-inf", "2e400"])
def test_urdf_number_check_agrees_with_pinocchio(text):
    """A mass is accepted exactly when Pinocchio reads it as the number it spells."""
    source = urdf(forearm=inertial(mass=text))
    try:
        spelled = float(text)
    except ValueError:
        spelled = None
    read = pin.buildModelFromXML(source).inertias[2].mass
    pinocchio_reads_it = spelled is not None and math.isfinite(spelled) and read == spelled
    try:
        source_to_model(source, False)
        accepted = True
    except ValueError as e:
        assert "link 'forearm'" in str(e)
        accepted = False
    assert accepted == pinocchio_reads_it


def test_negative_mass_in_urdf_is_refused():
    refused(lambda: source_to_model(urdf(forearm=inertial(mass="-1")), False),
            "link 'forearm'", "<mass value>", ">= 0", "-1")


@pytest.mark.parametrize(
    "changes, words",
    [
        (dict(origin="nan 0 0.4"), ["<origin xyz>", "'nan 0 0.4'"]),
        (dict(axis="0 nan 1"), ["<axis xyz>", "'0 nan 1'"]),
        (dict(lower="nan"), ["<limit lower>", "'nan'"]),
    ],
)
def test_non_finite_urdf_joint_value_names_the_joint(changes, words):
    # Pinocchio refuses these too, but without saying where.
    refused(lambda: source_to_model(urdf(**changes), False), "joint 'elbow'", *words)


# -- the model itself ---------------------------------------------------------------------------
def test_zero_axis_is_refused():
    words = ["joint 'elbow'", "axis must be a unit vector", "(0.0, 0.0, 0.0)"]
    refused(lambda: source_to_model(urdf(axis="0 0 0"), False), *words)  # was a bare ZeroDivisionError
    refused(lambda: model(elbow=dict(axis=(0.0, 0.0, 0.0))), *words)


def test_non_unit_axis_is_refused():
    refused(lambda: model(elbow=dict(axis=(0.7071, 0.0, 0.7071))), "joint 'elbow'", "unit vector", "0.7071")


@pytest.mark.parametrize("kind", ["PrismaticUnaligned", "RevoluteUnaligned"])
def test_non_unit_axis_from_pinocchio_model_is_refused(kind):
    """Pinocchio moves an unaligned joint by its axis as given, not normalised: such a model is refused
    (it used to be normalised, a prismatic joint then moving half as far as Pinocchio's)."""
    pm = pin.Model()
    jid = pm.addJoint(0, getattr(pin, f"JointModel{kind}")(np.array([0.0, 0.0, 2.0])), pin.SE3.Identity(), "slide")
    pm.appendBodyToJoint(jid, pin.Inertia.FromSphere(1.0, 0.1), pin.SE3.Identity())
    if kind == "PrismaticUnaligned":
        pd = pm.createData()
        pin.forwardKinematics(pm, pd, np.array([0.5]))
        assert pd.oMi[jid].translation.tolist() == [0.0, 0.0, 1.0]
    refused(lambda: source_to_model(pm, None), "joint 'slide'", "unit vector", "(0.0, 0.0, 2.0)", "norm 2")


def test_angular_gravity_from_pinocchio_model_is_refused():
    """Pinocchio's gravity is a spatial motion; an angular part would change its dynamics, and a
    RobotModel's gravity is linear, so it is refused rather than dropped."""
    pm = pin.buildModelFromXML(urdf())
    pm.gravity = pin.Motion(np.array([0.0, 0.0, -9.81]), np.array([0.0, 0.5, 0.0]))
    refused(lambda: source_to_model(pm, None), "model.gravity", "angular part", "(0.0, 0.5, 0.0)")


@pytest.mark.parametrize("mass", [-1.0, math.nan, math.inf])
def test_bad_mass_is_refused(mass):
    refused(lambda: model(elbow=dict(mass=mass)), "joint 'elbow'", "mass", repr(mass))


def test_negative_mass_from_pinocchio_model_names_joint_and_link():
    pm = pin.buildModelFromXML(urdf())
    pm.inertias[2] = pin.Inertia(-1.0, np.zeros(3), np.eye(3) * 0.01)
    refused(lambda: source_to_model(pm, None), "joint 'elbow' (link 'forearm')", "mass must be >= 0", "-1.0")


@pytest.mark.parametrize(
    "parts, words",
    [
        (dict(elbow=dict(translation=(math.nan, 0.0, 0.4))), ["joint 'elbow'", "translation", "nan"]),
        (dict(elbow=dict(rotation=(math.nan,) + IDENTITY[1:])), ["joint 'elbow'", "rotation", "nan"]),
        (dict(elbow=dict(com=(0.0, math.inf, 0.2))), ["joint 'elbow'", "com", "inf"]),
        (dict(elbow=dict(inertia=(0.01, 0.0, 0.0, 0.0, math.nan, 0.0, 0.0, 0.0, 0.005))),
         ["joint 'elbow'", "inertia", "nan"]),
        (dict(elbow=dict(axis=(0.0, math.nan, 1.0))), ["joint 'elbow'", "axis", "nan"]),
        (dict(elbow=dict(lower=math.nan)), ["joint 'elbow'", "lower limit", "nan"]),
        (dict(frame=dict(translation=(0.0, math.inf, 0.0))), ["frame 'tool'", "translation", "inf"]),
        (dict(gravity=(0.0, 0.0, math.nan)), ["gravity", "nan"]),
    ],
)
def test_non_finite_value_is_refused(parts, words):
    refused(lambda: model(**parts), *words)


def test_nan_limit_from_pinocchio_model_is_refused():
    pm = pin.buildModelFromXML(urdf())
    pm.lowerPositionLimit[1] = math.nan  # used to become -inf, an unbounded joint
    refused(lambda: source_to_model(pm, None), "joint 'elbow'", "lower limit", "nan")


def test_nan_in_saved_model_is_refused(tmp_path):
    d = model().to_dict()
    d["joints"][1]["mass"] = math.nan
    path = tmp_path / "arm.json"
    path.write_text(json.dumps(d))  # written as NaN, which json reads back
    refused(lambda: RobotModel.load(path), "joint 'elbow'", "mass", "nan")


@pytest.mark.parametrize(
    "parts, words",
    [
        (dict(elbow=dict(rotation=tuple(2 * x for x in IDENTITY))), ["joint 'elbow'", "rotation matrix", "2.0"]),
        (dict(frame=dict(rotation=(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0))),  # a mirror
         ["frame 'tool'", "rotation matrix", "determinant -1"]),
    ],
)
def test_non_rotation_matrix_is_refused(parts, words):
    refused(lambda: model(**parts), *words)


def test_asymmetric_inertia_is_refused():
    inertia = (0.01, 0.002, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.005)
    refused(lambda: model(elbow=dict(inertia=inertia)), "joint 'elbow'", "symmetric", "Ixy=0.002", "Iyx=0.0")


@pytest.mark.parametrize(
    "forearm, value",
    [
        (inertial(izz="-0.005"), "-0.005"),
        (inertial(ixx="0.01", iyy="0.01", ixy="0.02"), "-0.01"),  # the off-diagonal term alone breaks it
    ],
)
def test_inertia_not_positive_semi_definite_is_refused(forearm, value):
    refused(lambda: source_to_model(urdf(forearm=forearm), False),
            "joint 'elbow' (link 'forearm')", "positive semi-definite", value)


def test_inertia_breaking_triangle_inequality_warns_or_is_refused_when_strict():
    text = urdf(forearm=inertial(ixx="0.01", iyy="0.01", izz="0.03"))
    words = ["joint 'elbow' (link 'forearm')", "triangle inequality", "0.03 > 0.01 + 0.01"]
    parsed = source_to_model(text, False)  # positive definite: the model itself is accepted
    with pytest.warns(UserWarning) as record:
        check_triangle_inequality(parsed)
    assert len(record) == 1 and all(w in str(record[0].message) for w in words), [str(r.message) for r in record]
    refused(lambda: check_triangle_inequality(parsed, strict=True), *words)
    refused(lambda: torch_grid.load(text, strict_inertia=True), *words)  # refused before anything is built


def test_massless_leaf_joint_is_refused():
    words = ["joint 'elbow'", "no mass and no inertia", "joint-space inertia matrix is singular"]
    refused(lambda: source_to_model(urdf(forearm=""), False), *words)
    refused(lambda: model(elbow=dict(mass=0.0, inertia=(0.0,) * 9)), *words)


def test_massless_subtree_names_its_top_joint():
    message = refused(lambda: source_to_model(urdf(upper="", forearm=""), False), "joint 'shoulder'", "no mass")
    assert "elbow" not in message


def test_point_mass_on_revolute_axis_is_refused():
    point_on_axis = inertial(com="0 0.3 0", ixx="0", iyy="0", izz="0")  # the elbow turns about y
    refused(lambda: source_to_model(urdf(forearm=point_on_axis), False),
            "joint 'elbow'", "no inertia about its axis", "on the axis", "singular")


def test_prismatic_joint_moving_no_mass_is_refused():
    refused(lambda: source_to_model(urdf(kind="prismatic", forearm=inertial(mass="0")), False),
            "joint 'elbow'", "no mass", "singular")


def test_free_body_without_rotational_inertia_is_refused():
    free = joint("root", -1, type="free", axis=(0.0, 0.0, 0.0), inertia=(0.0,) * 9)
    refused(lambda: RobotModel("ball", (free,), ()), "joint 'root'", "positive definite rotational inertia",
            "singular")


# -- MJCF values refused before MuJoCo compiles them -------------------------------------------
@pytest.mark.parametrize(
    "changes, words",
    [
        (dict(mass="nan"), ["<inertial> in <body name='upper'>", "mass", "'nan'"]),
        (dict(pos="nan 0 0.1"), ["<body name='upper'>", "pos", "'nan 0 0.1'"]),
        (dict(diag="0.01 inf 0.005"), ["<inertial> in <body name='upper'>", "diaginertia", "inf"]),
        (dict(mass="-1"), ["<inertial> in <body name='upper'>", "mass must be >= 0", "'-1'"]),
        (dict(diag="-0.01 0.012 0.005"), ["<inertial> in <body name='upper'>", "diaginertia must be >= 0"]),
    ],
)
def test_mjcf_values_that_are_not_numbers_are_refused(changes, words):
    refused(lambda: source_to_model(mjcf(**changes), None), *words)


def test_zero_axis_in_mjcf_is_refused():
    refused(lambda: source_to_model(mjcf(axis="0 0 0"), None), "MuJoCo could not compile", "axis too small",
            "'shoulder'")


# -- what must still load -----------------------------------------------------------------------
VALID = {
    "zero-mass intermediate link": lambda: source_to_model(urdf(upper=""), False),
    "point mass on a prismatic joint": lambda: source_to_model(
        urdf(kind="prismatic", forearm=inertial(com="0 0 0", ixx="0", iyy="0", izz="0")), False),
    "point mass off a revolute axis": lambda: source_to_model(
        urdf(forearm=inertial(ixx="0", iyy="0", izz="0")), False),
    "thin rod (triangle equality)": lambda: source_to_model(
        urdf(forearm=inertial(ixx="0.02", iyy="0.02", izz="0")), False),
    "flat plate, sum one ulp short": lambda: source_to_model(  # 0.1 + 0.7 < 0.8 in floating point
        urdf(forearm=inertial(ixx="0.1", iyy="0.7", izz="0.8")), False),
    "rounding-level negative moments": lambda: source_to_model(  # as exported in icub.urdf
        urdf(forearm=inertial(mass="0.526", com="0 0 0.03045", ixx="-5.42101e-20", iyy="-5.42101e-20", izz="0")),
        False),
    "massless link on a fixed joint": lambda: source_to_model(urdf().replace(
        "</robot>", '<link name="tip"/><joint name="tool" type="fixed"><parent link="forearm"/>'
                    '<child link="tip"/><origin xyz="0 0 0.3"/></joint></robot>'), False),
    "unbounded continuous joint": lambda: model(elbow=dict(type="continuous", lower=-math.inf, upper=math.inf)),
    "floating base": lambda: source_to_model(urdf(), True),
    "unit axis off the coordinate axes": lambda: source_to_model(urdf(axis="1 1 0"), False),
}


@pytest.mark.parametrize("case", sorted(VALID))
def test_valid_edge_cases_load(case):
    assert isinstance(VALID[case](), RobotModel)


@pytest.mark.parametrize("name", sorted(torch_grid.BUNDLED))
def test_bundled_robots_pass(name):
    RobotModel.load(ROBOTS_DIR / f"{name}.json")
    if (ROBOTS_DIR / f"{name}.urdf").exists():
        source_to_model(str(ROBOTS_DIR / f"{name}.urdf"), not torch_grid.BUNDLED[name])  # the other base too
    else:  # an MJCF: its free joint is part of the description
        with pytest.raises(ValueError, match="floating_base=False contradicts"):
            torch_grid.load(name, floating_base=False)


def test_conftest_robots_pass():
    from conftest import ROBOT_SPECS

    for source, floating in ROBOT_SPECS.values():
        source_to_model(source, floating)


# example-robot-data robots that validation refuses, with why: a URDF inertia that is not positive
# semi-definite, or a finger joint that moves no mass (M singular); MuJoCo refuses these as well.
# (romeo_small.urdf loads: its arm inertias only break the triangle inequality, a warning.)
REFUSED_PUBLISHED = {
    "romeo_description/urdf/romeo.urdf": "joint 'LFinger21': the links it moves have no mass and no inertia",
    "romeo_description/urdf/romeo_laas_small.urdf": "'LHipPitch_joint' (link 'LHipPitch_link'): inertia about "
                                                    "the centre of mass must be positive semi-definite",
}


def test_example_robot_data_passes_except_unphysical_inertias(erd_robots_dir):
    refusals = {}
    for path in sorted(erd_robots_dir.rglob("*.urdf")):
        try:
            source_to_model(str(path), False)
        except ValueError as e:
            if "not supported" not in str(e) and "Pinocchio could not parse" not in str(e):  # unsupported joint types, ur3
                refusals[str(path.relative_to(erd_robots_dir))] = str(e)
    assert set(refusals) == set(REFUSED_PUBLISHED), refusals
    for rel, words in REFUSED_PUBLISHED.items():
        assert words in refusals[rel]


def test_joints_out_of_depth_first_order_are_refused():
    # 'c' (child of 'b') then 'd' (child of the root), then 'e' back under 'b': b's subtree is split.
    parents = {"a": -1, "b": 0, "c": 1, "d": 0, "e": 1}
    joints = tuple(joint(name, parent) for name, parent in parents.items())
    refused(lambda: RobotModel("split", joints, ()), "'e'", "depth-first", "'d'")


def test_a_file_that_is_not_xml_is_refused_naming_it(tmp_path):
    path = tmp_path / "notes.urdf"
    path.write_text("# not a robot\n")
    with pytest.raises(ValueError, match=r"notes\.urdf is not well-formed XML"):
        torch_grid.load(path)
