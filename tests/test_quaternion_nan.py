"""A NaN or infinite quaternion entry is NaN in every output and gradient of its sample, in both
conventions, on a free joint (go2) and a ball joint: a diverged state never steps to a finite one.
The other samples of the batch are those of a run without it, and a quaternion of zero norm still
reads as the identity (MuJoCo's mj_normalizeQuat, the reference: a NaN norm stays NaN, only a norm
below mjMINVAL becomes the identity)."""
from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest
import torch

import torch_grid
from oracles import rel_err

# a ball joint under the world with a hinge child
BALL = """
<mujoco model="ball_hinge">
  <option gravity="0.2 -0.3 -9.81"/>
  <worldbody>
    <body name="upper" pos="0 0 1" euler="10 -5 20">
      <joint name="shoulder" type="ball" pos="0.01 0 0.02"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 -0.05" size="0.03"/>
      <body name="lower" pos="0.3 0 -0.05">
        <joint name="elbow" type="hinge" axis="0 1 0" pos="0.01 0 0"/>
        <geom type="capsule" fromto="0 0 0 0.25 0.02 0" size="0.025"/>
      </body>
    </body>
  </worldbody>
</mujoco>"""
INTEGRATORS = ("semi_implicit_euler", "rk4")
DT = 0.01
TOL = 1e-12


@pytest.fixture(scope="module")
def ball():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "the MJCF model has contacts")
        return torch_grid.load(BALL)


@pytest.fixture(params=["go2", "ball"])
def robot(request, robots):
    return robots["go2"] if request.param == "go2" else request.getfixturevalue("ball")


def _quaternion(robot: torch_grid.Robot) -> tuple[int, int]:
    """First q index of the robot's (only) quaternion and first v index of its rotation."""
    free, balls = torch_grid.conventions.free_joints(robot.model), torch_grid.conventions.ball_joints(robot.model)
    if free:
        return free[0][0] + 3, free[0][1] + 3
    return balls[0], robot.model.v_index[robot.model.q_index.index(balls[0])]


def _state(robot: torch_grid.Robot, convention: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(3)
    q = getattr(robot, convention).random_configuration(3, generator=g)
    qd, tau = (torch.randn(3, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    return q, qd, tau


def _outputs(view, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor) -> dict[str, torch.Tensor]:
    """Every checked output by name, each (batch, ...), nothing requiring grad: step_derivatives is its kernel."""
    positions, rotations = view.forward_kinematics(q)
    out = {"frame positions": positions, "frame rotations": rotations,
           "forward_dynamics": view.forward_dynamics(q, qd, tau), "crba": view.crba(q)}
    for integrator in INTEGRATORS:
        q_next, qd_next = view.step(q, qd, tau, DT, integrator)
        A, B = view.step_derivatives(q, qd, tau, DT, integrator)
        out.update({f"{integrator} q'": q_next, f"{integrator} qd'": qd_next, f"{integrator} A": A,
                    f"{integrator} B": B})
    return out


def _differentiated(view, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor) -> dict[str, torch.Tensor]:
    """step_derivatives under autograd (composed in torch) and the gradients of sum(q') + sum(qd') with
    respect to q, qd and tau."""
    out = {}
    for integrator in INTEGRATORS:
        x = [t.clone().requires_grad_() for t in (q, qd, tau)]
        A, B = view.step_derivatives(*x, DT, integrator)
        q_next, qd_next = view.step(*x, DT, integrator)
        grads = torch.autograd.grad(q_next.sum() + qd_next.sum(), x)
        out.update({f"{integrator} A": A.detach(), f"{integrator} B": B.detach()})
        out.update({f"{integrator} d/d{name}": g for name, g in zip(("q", "qd", "tau"), grads)})
    return out


def _all_paths(view, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor) -> list[tuple[str, dict]]:
    return [("kernel", _outputs(view, q, qd, tau)), ("autograd", _differentiated(view, q, qd, tau))]


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_nonfinite_quaternion_poisons_its_sample_only(robot, convention, bad):
    view, (a, _) = getattr(robot, convention), _quaternion(robot)
    q, qd, tau = _state(robot, convention)
    q[1, a + 1] = bad
    good = [0, 2]
    paths, alone = _all_paths(view, q, qd, tau), dict(_all_paths(view, q[good], qd[good], tau[good]))
    for path, outputs in paths:
        for name, x in outputs.items():
            # only an entry the same in every good sample (the world frame, M's zeros between two legs)
            # may be finite, and then it is that value; every entry that varies with the state is not
            finite, fixed = torch.isfinite(x[1]), (x[good] == x[good[0]]).all(0)
            assert not (finite & ~fixed).any(), f"{path} {name}: a finite entry for a quaternion with {bad}"
            assert torch.equal(x[1][finite], x[good[0]][finite]), f"{path} {name}"
            assert rel_err(x[good], alone[path][name]) <= TOL, f"{path} {name}: the other samples changed"
    kernel, composed = (outputs for _, outputs in paths)
    for integrator in INTEGRATORS:
        for name in (f"{integrator} A", f"{integrator} B"):
            assert rel_err(kernel[name][good], composed[name][good]) <= TOL, name


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_configuration_space_propagates_a_nonfinite_quaternion(robot, convention, bad):
    """integrate and difference, composed in torch (the step under autograd): the joint's quaternion and
    rotation, and their gradients, NaN on the bad sample alone."""
    view, (a, angular) = getattr(robot, convention), _quaternion(robot)
    q, v, _ = _state(robot, convention)
    q1 = view.integrate(q, v, 0.3)
    q[1, a + 1] = bad
    good = [0, 2]

    def run(rows: list[int]) -> list[torch.Tensor]:
        x = [t[rows].clone().requires_grad_() for t in (q, v, q1)]
        turned, log = view.integrate(x[0], x[1], DT)[:, a:a + 4], view.difference(x[0], x[2])[:, angular:angular + 3]
        return [turned, log, *torch.autograd.grad(turned.sum() + log.sum(), x)]

    for got, alone in zip(run([0, 1, 2]), run(good)):
        assert rel_err(got[good], alone) <= TOL
    turned, log, dq, dv, dq1 = run([0, 1, 2])
    for x in (turned[1], log[1], dq[1, a:a + 4], dv[1, angular:angular + 3], dq1[1, a:a + 4]):
        assert not torch.isfinite(x).any()


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_zero_quaternion_reads_as_identity(robot, convention):
    """A quaternion of zero norm, or of one below mjMINVAL, gives the unit quaternion's finite outputs and
    gradients (but along the quaternion's own coordinates, whose gradient is its normalisation's)."""
    view, (a, _) = getattr(robot, convention), _quaternion(robot)
    q, qd, tau = _state(robot, convention)
    identity = q.clone()
    identity[:, a:a + 4] = torch.tensor([1.0, 0, 0, 0] if convention == "mujoco" else [0, 0, 0, 1.0])
    zero, tiny = identity.clone(), identity.clone()
    zero[:, a:a + 4] = 0
    tiny[:, a:a + 4] *= 1e-16
    ref = dict(_all_paths(view, identity, qd, tau))
    for x in (zero, tiny):
        for path, outputs in _all_paths(view, x, qd, tau):
            for name, out in outputs.items():
                expected = ref[path][name]
                assert torch.isfinite(out).all(), f"{path} {name}"
                if name.endswith("d/dq"):
                    out, expected = _off_quaternion(out, a), _off_quaternion(expected, a)
                assert rel_err(out, expected) <= TOL, f"{path} {name}"


def _off_quaternion(g: torch.Tensor, a: int) -> torch.Tensor:
    return torch.cat([g[..., :a], g[..., a + 4:]], dim=-1)


def test_mujoco_normalize_quat_propagates_nan():
    """The reference: mj_normalizeQuat leaves a NaN, makes an infinite entry NaN, and reads a quaternion
    of norm below mjMINVAL (zero) as the identity."""
    m = mujoco.MjModel.from_xml_string(BALL)
    for quat, expected in (([np.nan, 0, 0, 0], [np.nan, 0, 0, 0]), ([0, np.inf, 0, 0], [0, np.nan, 0, 0]),
                           ([0, 0, 0, 0], [1, 0, 0, 0]), ([1e-16, 0, 0, 0], [1, 0, 0, 0])):
        qpos = np.array(quat + [0.3])
        mujoco.mj_normalizeQuat(m, qpos)
        np.testing.assert_array_equal(qpos, expected + [0.3])
