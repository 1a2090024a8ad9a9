"""Second derivatives in MuJoCo's convention on robots with free and ball joints, against central
differences of the MuJoCo-convention first-order functions (themselves checked against MuJoCo) along
MuJoCo's own mj_integratePos, qvel and qacc held fixed: go2 (a free root), "trees" (two free roots and
a ball joint) and "zoo" (a planar root, a ball joint; MJCF models)."""
from __future__ import annotations


import mujoco
import numpy as np
import pytest
import torch

from mjcf_models import TREES, ZOO
from oracles import rel_err

H = 1e-5


@pytest.fixture(scope="module")
def models(robots, mj_sims):
    out = {name: (robots[name], mujoco.MjModel.from_xml_string(text)) for name, text in (("zoo", ZOO), ("trees", TREES))}
    out["go2"] = (robots["go2"], mj_sims["go2"].m)
    return out


def _state(robot, seed):
    g = torch.Generator().manual_seed(seed)
    q = robot.mujoco.random_configuration(1, generator=g)[0]
    qd, x = (torch.randn(robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    f = 3 * torch.randn(robot.nbodies, 6, dtype=torch.float64, generator=g)
    return q, qd, x, f


def _steps(m, q):
    """mj_integratePos(q, +-H e_k) for every k: (2, nv, nq)."""
    out = np.zeros((2, m.nv, m.nq))
    for s, sign in enumerate((1, -1)):
        for k in range(m.nv):
            out[s, k] = q.numpy()
            dv = np.zeros(m.nv)
            dv[k] = sign * H
            mujoco.mj_integratePos(m, out[s, k], dv, 1.0)
    return torch.from_numpy(out)


def _along(fn, plus, minus):
    """Central differences of fn's outputs, the direction last: (..., nv)."""
    hi, lo = fn(plus), fn(minus)
    hi, lo = (hi, lo) if isinstance(hi, tuple) else ((hi,), (lo,))
    return [((a - b) / (2 * H)).movedim(0, -1) for a, b in zip(hi, lo)]


def _differences(fn, m, q, qd, x, f, along_x=False):
    """Central differences of fn(q, qd, x, f)'s outputs along mj_integratePos (q), then along qd, then
    (if asked) along x."""
    nv = qd.shape[-1]
    rep = lambda t: t.expand(nv, *t.shape)  # noqa: E731
    eye = H * torch.eye(nv, dtype=torch.float64)
    out = (_along(lambda p: fn(p, rep(qd), rep(x), rep(f)), *_steps(m, q)),
           _along(lambda s: fn(rep(q), qd + s, rep(x), rep(f)), eye, -eye))
    return out + (_along(lambda s: fn(rep(q), rep(qd), x + s, rep(f)), eye, -eye),) if along_x else out


@pytest.mark.parametrize("name", ["go2", "trees", "zoo"])
def test_inverse_dynamics_second_derivatives(models, name):
    robot, m = models[name]
    view = robot.mujoco
    q, qd, qdd, f = _state(robot, seed=11)
    d2q, d2v, dqdv, dM = view.inverse_dynamics_second_derivatives(q, qd, qdd, f)
    gq, gv, ga = _differences(view.inverse_dynamics_derivatives, m, q, qd, qdd, f, along_x=True)
    assert rel_err(d2q, gq[0]) <= 1e-6
    assert rel_err(dqdv, gv[0]) <= 1e-6
    assert rel_err(d2v, gv[1]) <= 1e-6
    assert rel_err(dM, _along(view.crba, *_steps(m, q))[0]) <= 1e-6
    assert rel_err(dM, ga[0].transpose(-1, -2)) <= 1e-6  # d/dq_k M[i, j] = d/dqdd_j (d tau / dq)[i, k]


@pytest.mark.parametrize("name", ["go2", "trees"])
def test_forward_dynamics_second_derivatives(models, name):
    robot, m = models[name]
    view = robot.mujoco
    q, qd, tau, f = _state(robot, seed=12)
    d2q, d2v, dqdv, dminv = view.forward_dynamics_second_derivatives(q, qd, tau, f)
    gq, gv = _differences(view.forward_dynamics_derivatives, m, q, qd, tau, f)
    assert rel_err(d2q, gq[0]) <= 1e-6
    assert rel_err(dminv, gq[2]) <= 1e-6
    assert rel_err(dqdv, gv[0]) <= 1e-6
    assert rel_err(d2v, gv[1]) <= 1e-6


@pytest.mark.parametrize("reference", ["world", "local", "local_world_aligned"])
@pytest.mark.parametrize("name", ["go2", "trees"])
def test_frame_kinematic_hessian_and_pose_hessian(models, name, reference):
    robot, m = models[name]
    view = robot.mujoco
    q = _state(robot, seed=13)[0]
    plus, minus = _steps(m, q)
    frame = robot.nframes - 1
    H_ = view.frame_kinematic_hessian(q, frame, reference)
    assert rel_err(H_, _along(lambda p: view.frame_jacobian(p, frame, reference), plus, minus)[0]) <= 1e-6
    pose = view.end_effector_pose_second_derivatives(q, [frame])
    assert rel_err(pose, _along(lambda p: view.end_effector_pose_derivatives(p, [frame]), plus, minus)[0]) <= 1e-6


@pytest.mark.parametrize("name", ["go2", "trees"])
def test_broadcast_batches_and_vmap_with_inputs_held_fixed(models, name):
    """The composed MuJoCo-convention tensors broadcast their inputs' batch shapes as the kernels do (q
    unbatched beside a batch of velocities, qdd or f_ext unbatched), and vmap them over some inputs only:
    equal to the call on the expanded inputs and to a loop."""
    robot = models[name][0]
    view = robot.mujoco
    q, _, _, f = _state(robot, 31)
    g = torch.Generator().manual_seed(32)
    qd, x = (torch.randn(3, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    functions = {
        "inverse_dynamics_second_derivatives": lambda q, qd, x: view.inverse_dynamics_second_derivatives(q, qd, x, f),
        "forward_dynamics_second_derivatives": lambda q, qd, x: view.forward_dynamics_second_derivatives(q, qd, x, f),
        "step_second_derivatives": lambda q, qd, x: (view.step_second_derivatives(q, qd, x, 0.01, f_ext=f),),
    }
    for label, fn in functions.items():
        expanded = fn(q.expand(3, -1), qd, x)
        for got, ref in zip(fn(q, qd, x), expanded):
            assert rel_err(got, ref) <= 1e-14, label
        for got, ref in zip(fn(q.expand(3, -1), qd, x[0]), fn(q.expand(3, -1), qd, x[0].expand(3, -1))):
            assert rel_err(got, ref) <= 1e-14, label
        if label != "step_second_derivatives":  # which refuses torch.func transforms
            for got, ref in zip(torch.func.vmap(fn, in_dims=(None, 0, None))(q, qd, x[0]),
                                fn(q.expand(3, -1), qd, x[0].expand(3, -1))):
                assert rel_err(got, ref) <= 1e-12, label
