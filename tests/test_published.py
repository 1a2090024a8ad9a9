"""Published URDFs (example-robot-data) built and checked against Pinocchio: a representative set
in more depth (Baxter, 19 joints with mimic gripper joints read as independent joints; a 6-axis arm;
a floating quadruped; PR2, 30 joints with continuous and prismatic ones), then every URDF of the
package (slow: one build each)."""
from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
import torch

import torch_grid
from oracles import PinOracle, batch_apply, erd_dir, rel_err, to_pin_q
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


@pytest.mark.slow
@pytest.mark.parametrize("path", _urdfs())
def test_every_example_robot_data_urdf(path):
    """Every URDF of example-robot-data loads and matches Pinocchio (inverse dynamics, M, forward
    dynamics), or is refused for a reason listed in test_validation.REFUSED_PUBLISHED or an
    unsupported feature the README documents; with its mimic joints coupled too (mimic=True), against
    Pinocchio's mimic model."""
    source = str(erd_dir() / path)
    floating = False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # mimic joints read as independent
            try:
                robot = torch_grid.load(source, floating_base=floating)
            except ValueError as e:
                if "has no moving joint" not in str(e):  # a lone body (a drone): it moves on a free joint
                    raise
                floating = True
                robot = torch_grid.load(source, floating_base=floating)
    except ValueError as e:
        documented = REFUSED_PUBLISHED.get(path)
        assert (documented and documented in str(e)) or "not supported" in str(e) or \
            "Pinocchio could not parse" in str(e), f"{path}: {e}"
        return
    pm = pin.buildModelFromUrdf(source, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(source)
    _check_against(robot, pm)
    try:
        coupled = torch_grid.load(source, floating_base=floating, mimic=True)
    except ValueError as e:  # a <mimic> naming no joint of the file: Pinocchio's mimic reader refuses it too
        assert "is not a joint of the model" in str(e), e
        with pytest.raises(ValueError):
            pin.buildModelFromUrdf(source, True)
        return
    if not coupled.model.mimics:
        return
    try:
        pm_mimic = pin.buildModelFromUrdf(source, True)
    except ValueError:  # Pinocchio's mimic reader needs each master before its mimic joints
        _check_projection(coupled, robot, source)
    else:
        _check_against(coupled, pm_mimic)


def _check_projection(coupled, robot, source):
    """M = G^T M_full G and tau = G^T tau_full, G read from the URDF's <mimic> tags here."""
    names = robot.joint_names
    G = torch.zeros(robot.nv, coupled.nv, dtype=torch.float64)
    mimic = {j.get("name"): j.find("mimic") for j in ET.parse(source).getroot().iter("joint") if j.find("mimic") is not None}
    for k, name in enumerate(names):
        m = mimic.get(name)
        master, scale = (m.get("joint"), float(m.get("multiplier", 1))) if m is not None else (name, 1.0)
        G[k, coupled.joint_names.index(master)] = scale
    q = coupled.random_configuration(2, generator=torch.Generator().manual_seed(13))
    q_full = torch.zeros(2, robot.nq, dtype=torch.float64)
    for k, name in enumerate(names):
        m = mimic.get(name)
        master = m.get("joint") if m is not None else name
        x = q[:, coupled.joint_names.index(master)]
        q_full[:, k] = x if m is None else float(m.get("multiplier", 1)) * x + float(m.get("offset", 0))
    qd = torch.randn(2, coupled.nv, dtype=torch.float64)
    assert rel_err(coupled.crba(q), G.mT @ robot.crba(q_full) @ G) <= 1e-9
    assert rel_err(coupled.inverse_dynamics(q, qd, qd), robot.inverse_dynamics(q_full, qd @ G.mT, qd @ G.mT) @ G) <= 1e-9


def _check_against(robot, pm):
    independent = [pm.names[j] for j in range(1, pm.njoints) if not pm.joints[j].shortname().endswith("Mimic")]
    assert robot.joint_names[1 if robot.floating_base else 0:] == independent[1 if robot.floating_base else 0:]
    g = torch.Generator().manual_seed(12)
    q = robot.random_configuration(2, generator=g)
    qd, qdd = (torch.randn(2, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    oracle, qp = PinOracle(pm), _pin_q(robot, q)
    tau = batch_apply(oracle.rnea, qp, qd.numpy(), qdd.numpy())
    assert rel_err(robot.inverse_dynamics(q, qd, qdd), tau) <= 1e-9
    assert rel_err(robot.crba(q), batch_apply(oracle.crba, qp)) <= 1e-9
    assert rel_err(robot.forward_dynamics(q, qd, torch.from_numpy(tau)), qdd) <= 1e-7


def _pin_q(robot, q):
    """Pinocchio's q of the robot's own coordinates: a continuous joint's angle as (cos, sin)."""
    if robot.model.mimics:  # reduced coordinates: the independent joints, in order
        joints = [j for j in robot.model.joints if j.name in set(robot.joint_names)]
        parts, k = [], 0
        for j in joints:
            x = q[..., k:k + j.nq].numpy()
            parts += [np.cos(x), np.sin(x)] if j.type == "continuous" else [x]
            k += j.nq
        return np.concatenate(parts, axis=-1)
    return to_pin_q(robot, q)
