"""The triangle inequality of principal moments warns (strict_inertia=True refuses it), while the
inertias the kernels cannot compute with stay refused: a published robot that breaks it,
example-robot-data's romeo_small, loads with one warning and matches Pinocchio."""
from __future__ import annotations

import warnings

import pinocchio as pin
import pytest
import torch

import torch_grid
from oracles import PinOracle, batch_apply, erd_dir, rel_err, to_pin_q
from test_validation import inertial, urdf

ROMEO_SMALL = "romeo_description/urdf/romeo_small.urdf"


def test_romeo_small_loads_with_one_warning_and_matches_pinocchio():
    source = str(erd_dir() / ROMEO_SMALL)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        robot = torch_grid.load(source)
    assert len(record) == 1, [str(w.message) for w in record]
    message = str(record[0].message)
    for words in ("joint 'RShoulderYaw' (link 'RShoulderYawLink')", "(0.000661781583, 0.000679363273, 0.00656531014)",
                  "triangle inequality", "strict_inertia=True"):
        assert words in message, f"{words!r} not in {message!r}"
    assert record[0].filename == __file__  # points at the load() call

    pm = pin.buildModelFromUrdf(source)
    assert robot.joint_names == list(pm.names[1:])
    g = torch.Generator().manual_seed(5)
    q = robot.random_configuration(3, generator=g)
    qd, tau = (torch.randn(3, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    oracle, qp = PinOracle(pm), to_pin_q(robot, q)
    assert rel_err(robot.forward_dynamics(q, qd, tau), batch_apply(oracle.aba, qp, qd.numpy(), tau.numpy())) <= 1e-10
    assert rel_err(robot.crba(q), batch_apply(oracle.crba, qp)) <= 1e-10
    qdd = torch.randn(3, robot.nv, dtype=torch.float64, generator=g)
    assert rel_err(robot.inverse_dynamics(q, qd, qdd), batch_apply(oracle.rnea, qp, qd.numpy(), qdd.numpy())) <= 1e-10


def test_strict_inertia_refuses_romeo_small_naming_the_links():
    with pytest.raises(ValueError) as info:
        torch_grid.load(str(erd_dir() / ROMEO_SMALL), strict_inertia=True)
    message = str(info.value)
    for words in ("joint 'RShoulderYaw' (link 'RShoulderYawLink')", "joint 'RElbowYaw' (link 'RElbowYawLink')",
                  "triangle inequality", "0.00656531014 > 0.000661781583 + 0.000679363273"):
        assert words in message, f"{words!r} not in {message!r}"


def test_strict_inertia_must_be_a_bool():
    with pytest.raises(TypeError, match="strict_inertia must be True or False, got 'yes'"):
        torch_grid.load("iiwa14", strict_inertia="yes")


@pytest.mark.parametrize("strict", [False, True])
@pytest.mark.parametrize(
    "forearm, words",
    [
        (inertial(izz="-0.005"), ["positive semi-definite", "-0.005"]),
        (inertial(ixx="0.01", iyy="0.01", ixy="0.02"), ["positive semi-definite", "-0.01"]),
        (inertial(iyy="inf"), ["inertia", "inf"]),
        (inertial(ixx="nan"), ["ixx", "nan"]),
        (inertial(mass="-1"), ["mass", "-1"]),
    ],
)
def test_impossible_inertias_stay_errors(forearm, words, strict):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an error, not a warning
        with pytest.raises(ValueError) as info:
            torch_grid.load(urdf(forearm=forearm), strict_inertia=strict)
    message = str(info.value)
    for w in ["forearm", *words]:
        assert w in message, f"{w!r} not in {message!r}"
    assert "triangle" not in message


def test_massless_moving_subtree_stays_an_error():
    with pytest.raises(ValueError, match="joint 'elbow': the links it moves have no mass and no inertia"):
        torch_grid.load(urdf(forearm=""))


def test_thin_rod_on_the_triangle_equality_gives_no_warning():
    rod = torch_grid.model.parse.source_to_model(urdf(forearm=inertial(ixx="0.02", iyy="0.02", izz="0")), False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        torch_grid.check_triangle_inequality(rod, strict=True)
        torch_grid.check_triangle_inequality(rod)
