"""Armature (rotor inertia on a dof): set by name on a URDF robot and checked against Pinocchio with
the same model.armature, values and derivatives (float64, rel_err <= 1e-9); the MJCF side is checked
against MuJoCo in test_mjcf.py."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import torch

import torch_grid
from oracles import PinOracle, batch_apply, pin_model_for, rel_err, to_pin_q

TOL = 1e-9
ROBOTS = {"iiwa14": False, "go2": True}


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def case(request, tmp_path_factory):
    """(robot with armature, Pinocchio model with the same armature)."""
    name = request.param
    pm = pin_model_for(name, ROBOTS[name])
    names = list(pm.names[1:])
    armature = {n: 0.05 * (k + 1) for k, n in enumerate(names) if pm.joints[k + 1].nv == 1}
    robot = torch_grid.load(name, armature=armature, cache_dir=tmp_path_factory.mktemp("cache"))
    for n, value in armature.items():
        pm.armature[pm.joints[pm.getJointId(n)].idx_v] = value
    return robot, pm


def states(robot, seed):
    g = torch.Generator().manual_seed(seed)
    q = robot.random_configuration(3, generator=g)
    return q, torch.randn(3, robot.nv, dtype=torch.float64, generator=g), torch.randn(3, robot.nv, dtype=torch.float64,
                                                                                     generator=g)


def test_values_match_pinocchio(case):
    robot, pm = case
    q, v, a = states(robot, 1)
    o, qp = PinOracle(pm), to_pin_q(robot, q)
    vn, an = v.numpy(), a.numpy()
    assert rel_err(robot.crba(q), batch_apply(o.crba, qp)) <= TOL
    assert rel_err(robot.minv(q), batch_apply(o.minv, qp)) <= TOL
    tau = batch_apply(o.rnea, qp, vn, an)
    assert rel_err(robot.inverse_dynamics(q, v, a), tau) <= TOL
    assert rel_err(robot.forward_dynamics(q, v, torch.from_numpy(tau)), a) <= TOL
    assert rel_err(robot.energy(q, v), batch_apply(o.energy, qp, vn)) <= TOL
    # The armature is on M's diagonal only: against the same robot without it.
    plain = PinOracle(pin_model_for(robot.model.name, robot.floating_base))
    added = robot.crba(q).numpy() - batch_apply(plain.crba, qp)
    want = np.broadcast_to(np.diag(np.asarray(pm.armature)), added.shape)
    assert np.asarray(pm.armature).max() > 0 and np.abs(added - want).max() <= 1e-12


def test_derivatives_match_pinocchio(case):
    robot, pm = case
    q, v, a = states(robot, 2)
    data = pm.createData()

    def rnea_derivatives(qp, vp, ap):
        pin.computeRNEADerivatives(pm, data, qp, vp, ap)
        return data.dtau_dq.copy(), data.dtau_dv.copy()

    def aba_derivatives(qp, vp, tp):
        pin.computeABADerivatives(pm, data, qp, vp, tp)
        Minv = np.triu(data.Minv) + np.triu(data.Minv, 1).T
        return data.ddq_dq.copy(), data.ddq_dv.copy(), Minv

    qp = to_pin_q(robot, q)
    ref = batch_apply(rnea_derivatives, qp, v.numpy(), a.numpy())
    for ours, want in zip(robot.inverse_dynamics_derivatives(q, v, a), ref):
        assert rel_err(ours, want) <= TOL
    tau = robot.inverse_dynamics(q, v, a)
    ref = batch_apply(aba_derivatives, qp, v.numpy(), tau.numpy())
    for ours, want in zip(robot.forward_dynamics_derivatives(q, v, tau), ref):
        assert rel_err(ours, want) <= TOL


def test_autograd_includes_armature(case):
    robot, _ = case
    q, v, a = states(robot, 3)
    tau = robot.inverse_dynamics(q, v, a).requires_grad_(True)
    robot.forward_dynamics(q, v, tau).sum().backward()
    Minv = robot.minv(q)
    assert rel_err(tau.grad, Minv.sum(dim=-2)) <= TOL  # d(sum qdd)/dtau = 1^T M^-1


def test_armature_arguments_are_checked():
    with pytest.raises(ValueError, match="no joint named 'elbow'"):
        torch_grid.load("iiwa14", armature={"elbow": 0.1})
    with pytest.raises(ValueError, match="armature must be >= 0"):
        torch_grid.load("iiwa14", armature={"iiwa_joint_1": -0.1})
    with pytest.raises(TypeError, match="mapping"):
        torch_grid.load("iiwa14", armature=[0.1] * 7)
    with pytest.raises(ValueError, match="free joint"):
        torch_grid.load("go2", armature={"root_joint": 0.1})
