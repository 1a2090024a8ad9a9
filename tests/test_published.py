"""Published URDFs (example-robot-data) built and checked against Pinocchio: a representative set
in more depth (Baxter, 19 joints with mimic gripper joints read as independent joints; a 6-axis arm;
a floating quadruped; PR2, 30 joints with continuous and prismatic ones) built, then every URDF of
the package at parse level."""
from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
import torch

import torch_grid
from oracles import PinOracle, batch_apply, erd_dir, rel_err, to_pin_q
from torch_grid.model.parse import source_to_model
from test_validation import REFUSED_PUBLISHED

ROBOTS = {
    "baxter_description/urdf/baxter.urdf": False,
    "ur_description/urdf/ur5_robot.urdf": False,
    "solo_description/robots/solo12.urdf": True,
    "pr2_description/urdf/pr2.urdf": False,
}


@pytest.mark.parametrize("path, floating", sorted(ROBOTS.items()), ids=lambda x: str(x).split("/")[-1])
def test_published_robot_matches_pinocchio(path, floating):
    source = str(erd_dir() / path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Baxter's mimic gripper joints
        robot = torch_grid.load(source, floating_base=floating)
        pm = pin.buildModelFromUrdf(source, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(source)
    assert robot.joint_names == list(pm.names[1:])
    g = torch.Generator().manual_seed(11)
    q = robot.random_configuration(2, generator=g)
    qd, qdd = (torch.randn(2, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    oracle, qp = PinOracle(pm), to_pin_q(robot, q)
    tau = batch_apply(oracle.rnea, qp, qd.numpy(), qdd.numpy())
    assert rel_err(robot.inverse_dynamics(q, qd, qdd), tau) <= 1e-9
    assert rel_err(robot.crba(q), batch_apply(oracle.crba, qp)) <= 1e-9
    assert rel_err(robot.forward_dynamics(q, qd, torch.from_numpy(tau)), qdd) <= 1e-8


def _urdfs() -> list[str]:
    return [str(p.relative_to(erd_dir())) for p in sorted(erd_dir().rglob("*.urdf"))]


@pytest.mark.parametrize("path", _urdfs())
def test_every_example_robot_data_urdf(path):
    """Every URDF of example-robot-data parses into the tree Pinocchio reads, or is refused for a reason
    listed in test_validation.REFUSED_PUBLISHED or an unsupported feature the README documents. At parse
    level (the kernels of the representative set above are built and checked): a Pinocchio model rebuilt
    from the parsed description has the inverse dynamics and M of pinocchio.buildModelFromUrdf's. With
    mimic=True the couplings are the URDF's <mimic> tags and give Pinocchio's mimic model."""
    source = str(erd_dir() / path)
    floating = False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # mimic joints read as independent
            model = source_to_model(source, floating)
            if not model.joints:  # a lone body (a drone), which a build refuses: it moves on a free joint
                floating = True
                model = source_to_model(source, floating)
    except ValueError as e:
        documented = REFUSED_PUBLISHED.get(path)
        assert (documented and documented in str(e)) or "not supported" in str(e) or \
            "Pinocchio could not parse" in str(e), f"{path}: {e}"
        return
    pm = pin.buildModelFromUrdf(source, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(source)
    _check_against(model, pm)
    try:
        coupled = source_to_model(source, floating, mimic=True)
    except ValueError as e:  # a <mimic> naming no joint of the file: Pinocchio's mimic reader refuses it too
        assert "is not a joint of the model" in str(e), e
        with pytest.raises(ValueError):
            pin.buildModelFromUrdf(source, True)
        return
    tags = {j.get("name"): j.find("mimic") for j in ET.parse(source).getroot().iter("joint") if j.find("mimic") is not None}
    assert {m.joint: (m.master, m.multiplier, m.offset) for m in coupled.mimics} == {
        name: (t.get("joint"), float(t.get("multiplier", 1)), float(t.get("offset", 0))) for name, t in tags.items()
        if name in {j.name for j in model.joints}}
    if not coupled.mimics:
        return
    try:
        pm_mimic = pin.buildModelFromUrdf(source, True)
    except ValueError:  # Pinocchio's mimic reader needs each master before its mimic joints
        return
    _check_mimic_against(coupled, pm_mimic)


def _rebuilt(model) -> pin.Model:
    """Pinocchio's model of a parsed description: each joint the plain one of its type (a continuous joint
    a revolute one of angle q), at its placement, moving its body's inertia."""
    pm = pin.Model()
    pm.gravity = pin.Motion(np.array([*model.gravity, 0.0, 0.0, 0.0]))
    ids = []
    for j in model.joints:
        if j.type == "free":
            joint = pin.JointModelFreeFlyer()
        elif j.type == "ball":
            joint = pin.JointModelSpherical()
        elif j.type == "prismatic":
            joint = pin.JointModelPrismaticUnaligned(np.array(j.axis))
        else:
            joint = pin.JointModelRevoluteUnaligned(np.array(j.axis))
        placement = pin.SE3(np.array(j.rotation).reshape(3, 3), np.array(j.translation))
        ids.append(pm.addJoint(0 if j.parent < 0 else ids[j.parent], joint, placement, j.name))
        pm.appendBodyToJoint(ids[-1], _inertia(j), pin.SE3.Identity())
    return pm


def _inertia(j) -> pin.Inertia:
    """The body's inertia from its dynamic parameters (pin.Inertia's constructor refuses some inertias
    that the URDF reader keeps, iCub's among them)."""
    c, I = np.array(j.com), np.array(j.inertia).reshape(3, 3)
    if j.mass == 0:  # its parameters would put the centre of mass at 0/0
        return pin.Inertia(0.0, c, I)
    origin = I + j.mass * (c @ c * np.eye(3) - np.outer(c, c))
    return pin.Inertia.FromDynamicParameters(np.array([j.mass, *(j.mass * c), origin[0, 0], origin[0, 1], origin[1, 1],
                                                       origin[0, 2], origin[1, 2], origin[2, 2]]))


def _random_state(model, joints, seed: int):
    """q (the description's layout: a continuous joint's angle), v and a of the given joints."""
    g = np.random.default_rng(seed)
    parts = []
    for j in joints:
        if j.type in ("free", "ball"):
            quat = g.normal(size=4)
            parts += ([g.normal(size=3)] if j.type == "free" else []) + [quat / np.linalg.norm(quat)]
        else:
            parts.append(g.uniform(-1.0, 1.0, size=1))
    nv = sum(j.nv for j in joints)
    return np.concatenate(parts), g.normal(size=nv), g.normal(size=nv)


def _pin_q(joints, q) -> np.ndarray:
    """Pinocchio's q of the description's: a continuous joint's angle as (cos, sin)."""
    parts, k = [], 0
    for j in joints:
        x = q[k:k + j.nq]
        parts += [np.cos(x), np.sin(x)] if j.type == "continuous" else [x]
        k += j.nq
    return np.concatenate(parts)


def _check_against(model, pm):
    independent = [pm.names[j] for j in range(1, pm.njoints) if not pm.joints[j].shortname().endswith("Mimic")]
    floating = 1 if model.floating_base else 0
    assert [j.name for j in model.joints][floating:] == independent[floating:]
    rebuilt, urdf = PinOracle(_rebuilt(model)), PinOracle(pm)
    for seed in (12, 13):
        q, v, a = _random_state(model, model.joints, seed)
        assert rel_err(rebuilt.rnea(q, v, a), urdf.rnea(_pin_q(model.joints, q), v, a)) <= 1e-12
        assert rel_err(rebuilt.crba(q), urdf.crba(_pin_q(model.joints, q))) <= 1e-12


def _check_mimic_against(coupled, pm_mimic):
    """Pinocchio's mimic model against the uncoupled tree projected by G = d q_full / d q (tau -> G^T tau,
    M -> G^T M G), G and the offsets from the description's couplings."""
    mimics = {m.joint: m for m in coupled.mimics}
    joints = [j for j in coupled.joints if j.name not in mimics]
    full_v = dict(zip((j.name for j in coupled.joints), coupled.v_index))
    full_q = dict(zip((j.name for j in coupled.joints), coupled.q_index))
    G = np.zeros((coupled.nv, sum(j.nv for j in joints)))
    k = 0
    for j in joints:
        G[full_v[j.name]:full_v[j.name] + j.nv, k:k + j.nv] = np.eye(j.nv)
        k += j.nv
    reduced_v = {j.name: sum(i.nv for i in joints[:n]) for n, j in enumerate(joints)}
    for m in coupled.mimics:
        G[full_v[m.joint], reduced_v[m.master]] = m.multiplier
    rebuilt, mimic = PinOracle(_rebuilt(coupled)), PinOracle(pm_mimic)
    q, v, a = _random_state(coupled, joints, 14)
    reduced_q = {j.name: sum(i.nq for i in joints[:n]) for n, j in enumerate(joints)}
    q_full = np.zeros(coupled.nq)
    for j in coupled.joints:
        m = mimics.get(j.name)
        q_full[full_q[j.name]:full_q[j.name] + j.nq] = (
            q[reduced_q[j.name]:reduced_q[j.name] + j.nq] if m is None else m.multiplier * q[reduced_q[m.master]] + m.offset)
    q_pin = _pin_q(joints, q)
    assert rel_err(G.T @ rebuilt.rnea(q_full, G @ v, G @ a), mimic.rnea(q_pin, v, a)) <= 1e-12
    assert rel_err(G.T @ rebuilt.crba(q_full) @ G, mimic.crba(q_pin)) <= 1e-12
