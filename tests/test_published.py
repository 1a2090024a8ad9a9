"""A representative set of published URDFs (example-robot-data) built and checked against Pinocchio:
Baxter (19 joints, its mimic gripper joints read as independent joints), a 6-axis arm, a floating
quadruped, and PR2 (30 joints, continuous and prismatic ones among them). Every other URDF of the
package is swept at parse level in test_validation.py."""
from __future__ import annotations

import warnings

import pinocchio as pin
import pytest
import torch

import torch_grid
from oracles import PinOracle, batch_apply, erd_dir, rel_err, to_pin_q

ROBOTS = {
    "baxter_description/urdf/baxter.urdf": False,
    "ur_description/urdf/ur5_robot.urdf": False,
    "solo_description/robots/solo12.urdf": True,
    "pr2_description/urdf/pr2.urdf": False,
}


@pytest.mark.parametrize("path, floating", sorted(ROBOTS.items()), ids=lambda x: str(x).split("/")[-1])
def test_published_robot_matches_pinocchio(path, floating, tmp_path):
    source = str(erd_dir() / path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Baxter's mimic gripper joints
        robot = torch_grid.load(source, floating_base=floating, cache_dir=tmp_path)
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
