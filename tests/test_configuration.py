"""integrate, difference and their Jacobians (torch_grid/space/lie.py) against Pinocchio's Lie
groups (pin.integrate, difference, dIntegrate, dDifference) and MuJoCo's mj_integratePos,
mj_differentiatePos, mjd_quatIntegrate and mjd_subQuat; autograd through them to second order.
The functions need no kernels: most tests run them on a Space; one goes through a built robot."""
from __future__ import annotations

import math

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import torch

import oracles
from pin_models import pin_ball_model
from test_quaternion_joints import BALLS, random_qpos
from torch_grid.space.lie import Space, d_difference, d_integrate, dexp_inverse, difference, integrate

TOL = 1e-10  # Pinocchio and MuJoCo evaluate the same formulas in another order (log near pi)
# rotation scales: generic, beyond pi (the short way back), tiny and zero (the Taylor branches)
SCALES = (1.0, 4.0, 1e-9, 0.0)


def _pin_space(model) -> Space:
    kinds = []
    for j in model.joints[1:]:
        name = j.shortname()
        kinds.append("free" if "FreeFlyer" in name else "ball" if "Spherical" in name else "scalar")
    return Space.of(kinds)


def _mj_space(m) -> Space:
    names = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball"}
    return Space.of([names.get(int(t), "scalar") for t in m.jnt_type])


def _pin_configuration(model, rng) -> np.ndarray:
    lo, hi = np.maximum(model.lowerPositionLimit, -3.0), np.minimum(model.upperPositionLimit, 3.0)
    lo[:3], hi[:3] = -1.0, 1.0
    q = pin.randomConfiguration(model, lo, hi)
    return q


def _t(x) -> torch.Tensor:
    return torch.tensor(np.asarray(x), dtype=torch.float64)


@pytest.fixture(scope="module")
def pin_model():
    """A free root, three ball joints and a revolute one (test_quaternion_joints)."""
    return pin_ball_model()


@pytest.fixture(scope="module")
def mj_model():
    return mujoco.MjModel.from_xml_string(BALLS)


@pytest.mark.parametrize("scale", SCALES)
def test_pin_convention_matches_pinocchio(pin_model, scale):
    model, space, rng = pin_model, _pin_space(pin_model), np.random.default_rng(int(scale * 10) + 1)
    for _ in range(3):
        q, q1 = _pin_configuration(model, rng), _pin_configuration(model, rng)
        v, dt = rng.normal(size=model.nv) * scale, 0.3
        assert np.abs(integrate(space, _t(q), _t(v), dt, 0).numpy() - pin.integrate(model, q, v * dt)).max() <= TOL
        j_q, j_v = d_integrate(space, _t(q), _t(v), dt, 0)
        assert np.abs(j_q.numpy() - pin.dIntegrate(model, q, v * dt, pin.ARG0)).max() <= TOL
        assert np.abs(j_v.numpy() - dt * pin.dIntegrate(model, q, v * dt, pin.ARG1)).max() <= TOL
        # a far point, and one at the scale's distance (tiny and zero differences)
        for q_end in (q1, pin.integrate(model, q, v)):
            assert np.abs(difference(space, _t(q), _t(q_end), 0).numpy() - pin.difference(model, q, q_end)).max() <= TOL
            j0, j1 = d_difference(space, _t(q), _t(q_end), 0)
            assert np.abs(j0.numpy() - pin.dDifference(model, q, q_end, pin.ARG0)).max() <= TOL
            assert np.abs(j1.numpy() - pin.dDifference(model, q, q_end, pin.ARG1)).max() <= TOL


def _quaternion_blocks(m):
    """(qpos address, dof address of the rotation) of each free and ball joint."""
    out = []
    for j in range(m.njnt):
        if m.jnt_type[j] in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL):
            free = m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE
            out.append((m.jnt_qposadr[j] + 3 * free, m.jnt_dofadr[j] + 3 * free))
    return out


@pytest.mark.parametrize("scale", SCALES)
def test_mujoco_convention_matches_mujoco(mj_model, scale):
    """Values against mj_integratePos / mj_differentiatePos; each quaternion's Jacobian blocks against
    mjd_quatIntegrate / mjd_subQuat; the whole Jacobians against central differences of MuJoCo's own
    functions along mj_integratePos."""
    m, space, rng = mj_model, _mj_space(mj_model), np.random.default_rng(int(scale * 10) + 2)
    dt = 0.3
    for _ in range(3):
        q, q1, v = random_qpos(m, rng), random_qpos(m, rng), rng.normal(size=m.nv) * scale
        ref = q.copy()
        mujoco.mj_integratePos(m, ref, v, dt)
        assert np.abs(integrate(space, _t(q), _t(v), dt, 1).numpy() - ref).max() <= TOL
        ref_d = np.zeros(m.nv)
        mujoco.mj_differentiatePos(m, ref_d, 1.0, q, q1)
        assert np.abs(difference(space, _t(q), _t(q1), 1).numpy() - ref_d).max() <= TOL

        j_q, j_v = (j.numpy() for j in d_integrate(space, _t(q), _t(v), dt, 1))
        j0, j1 = (j.numpy() for j in d_difference(space, _t(q), _t(q1), 1))
        for qa, va in _quaternion_blocks(m):
            block = slice(va, va + 3)
            Dquat, Dvel, Dscale = np.zeros(9), np.zeros(9), np.zeros(3)
            mujoco.mjd_quatIntegrate(v[block], dt, Dquat, Dvel, Dscale)
            assert np.abs(j_q[block, block] - Dquat.reshape(3, 3)).max() <= TOL
            assert np.abs(j_v[block, block] - dt * Dvel.reshape(3, 3)).max() <= TOL
            Da, Db = np.zeros((3, 3)), np.zeros((3, 3))
            mujoco.mjd_subQuat(q1[qa:qa + 4], q[qa:qa + 4], Da, Db)  # log(q^-1 q1) = subQuat(q1, q)
            assert np.abs(j1[block, block] - Da).max() <= 1e-10 and np.abs(j0[block, block] - Db).max() <= 1e-10

        def moved(x, e, direction):
            out = x.copy()
            mujoco.mj_integratePos(m, out, e * direction, 1.0)
            return out

        def diff(a, b):
            out = np.zeros(m.nv)
            mujoco.mj_differentiatePos(m, out, 1.0, a, b)
            return out

        def after(x):
            out = x.copy()
            mujoco.mj_integratePos(m, out, v, dt)
            return out

        h = 1e-6
        for k in range(m.nv):
            e = np.eye(m.nv)[k]
            col = (diff(after(q), after(moved(q, h, e))) - diff(after(q), after(moved(q, -h, e)))) / (2 * h)
            assert np.abs(j_q[:, k] - col).max() <= 1e-8, k
            col = (diff(q, moved(q1, h, e)) - diff(q, moved(q1, -h, e))) / (2 * h)
            assert np.abs(j1[:, k] - col).max() <= 1e-8, k
            col = (diff(moved(q, h, e), q1) - diff(moved(q, -h, e), q1)) / (2 * h)
            assert np.abs(j0[:, k] - col).max() <= 1e-8, k


@pytest.mark.parametrize("convention", [0, 1])
def test_quaternions_are_read_normalised(mj_model, convention):
    """A scaled quaternion reads as its unit one, as the kernels (and MuJoCo) read it."""
    space, rng = _mj_space(mj_model), np.random.default_rng(3)
    q, q1, v = (_t(x) for x in (random_qpos(mj_model, rng), random_qpos(mj_model, rng), rng.normal(size=mj_model.nv)))
    scaled = q.clone()
    for qa, _ in _quaternion_blocks(mj_model):
        scaled[qa:qa + 4] *= 2.5
    assert torch.allclose(integrate(space, scaled, v, 1.0, convention), integrate(space, q, v, 1.0, convention),
                          rtol=0, atol=TOL)
    assert torch.allclose(difference(space, scaled, q1, convention), difference(space, q, q1, convention), rtol=0, atol=TOL)


@pytest.mark.parametrize("convention", [0, 1])
@pytest.mark.parametrize("scale", [1.0, 0.0])
def test_gradgradcheck(mj_model, convention, scale):
    """Autograd through the functions and their Jacobians, to second order, at a generic point and at
    zero rotation (the series branches)."""
    space, rng = _mj_space(mj_model), np.random.default_rng(4)
    q, q1 = (_t(random_qpos(mj_model, rng)).requires_grad_(True) for _ in range(2))
    v = (_t(rng.normal(size=mj_model.nv)) * scale).requires_grad_(True)
    for fn, args, matrices in ((lambda q, v: integrate(space, q, v, 0.7, convention), (q, v), False),
                               (lambda q, v: d_integrate(space, q, v, 0.7, convention), (q, v), True),
                               (lambda a, b: difference(space, a, b, convention), (q, q1), False),
                               (lambda a, b: d_difference(space, a, b, convention), (q, q1), True)):
        # by random projections (fast mode) where the outputs are the Jacobians: in full, one backward per
        # output entry (2 nv^2), and nv^2 x nv^2 columns at second order
        assert torch.autograd.gradcheck(fn, args, fast_mode=matrices)
        assert torch.autograd.gradgradcheck(fn, args, fast_mode=True)
    same = q.detach().clone().requires_grad_(True)
    assert torch.autograd.gradgradcheck(lambda a, b: difference(space, a, b, convention), (q, same), fast_mode=True)  # zero angle


def test_robot_methods(robots):
    """Through a robot's views: batches broadcast, float32 follows float64, dt per sample, the argument
    errors name the argument."""
    robot = robots["go2"]
    g = torch.Generator().manual_seed(5)
    for view in (robot.pin, robot.mujoco):
        q, q1 = view.random_configuration(4, generator=g), view.random_configuration(4, generator=g)
        v, dt = torch.randn(3, 1, robot.nv, dtype=torch.float64, generator=g), torch.rand(3, 4, dtype=torch.float64)
        q_next = view.integrate(q, v, dt)
        assert q_next.shape == (3, 4, robot.nq)
        assert torch.allclose(view.difference(q, q_next), v * dt.unsqueeze(-1), rtol=1e-10, atol=1e-10)
        j_q, j_v = view.d_integrate(q, v, dt)
        assert j_q.shape == j_v.shape == (3, 4, robot.nv, robot.nv)
        single = view.d_difference(q[1], q1[1])[1]
        assert torch.allclose(view.d_difference(q, q1)[1][1], single, rtol=1e-14, atol=1e-14)
        assert torch.allclose(view.integrate(q.float(), v.float(), 0.1).double(), view.integrate(q, v, 0.1), atol=1e-5)
        w = v[0].expand(4, -1)
        # vmap sees the composition, a plain call runs the kernel
        torch.testing.assert_close(torch.func.vmap(view.d_integrate)(q, w)[1], view.d_integrate(q, w)[1], rtol=0, atol=1e-13)
        torch._dynamo.reset()
        compiled = torch.compile(view.d_difference, fullgraph=True, backend="aot_eager")
        assert torch.allclose(compiled(q, q1)[0], view.d_difference(q, q1)[0], rtol=1e-14, atol=1e-14)
    with pytest.raises(ValueError, match=r"integrate: v must have shape \(\.\.\., 18\)"):
        robot.integrate(q, q)
    with pytest.raises(TypeError, match="difference: q1 has dtype torch.float32"):
        robot.difference(q, q1.float())
    with pytest.raises(TypeError, match="dt must be a number or a tensor"):
        robot.integrate(q, v, "0.1")
    # batches that do not broadcast: named here, whichever path runs (a tensor dt was blamed, and under autograd
    # the Jacobians' composition raised torch's own error)
    for grad in (False, True):
        with pytest.raises(ValueError, match=r"^d_integrate: the leading batch shapes do not broadcast: q \(4,\), v \(2,\)"):
            robot.d_integrate(q.clone().requires_grad_(grad), v[0, :, :].expand(2, -1), torch.tensor(0.1, dtype=torch.float64))
        with pytest.raises(ValueError, match=r"^d_difference: the leading batch shapes do not broadcast: q0 \(4,\), q1 \(2,\)"):
            robot.d_difference(q.clone().requires_grad_(grad), q1[:2])


@pytest.mark.parametrize("name", ["go2", "trees"])
def test_integrate_and_difference_kernels_are_the_composition(robots, pin_models, mj_sims, name):
    """integrate, difference and their Jacobians d_integrate and d_difference are one kernel call each (the
    Jacobians' when nothing differentiates them), and the torch composition otherwise: the two agree on every
    joint type (turns of zero, 1e-9, about one and beyond 2 pi; a difference across the quaternions'
    hemispheres, of nearly equal and of random configurations), a (2, 3) batch with a dt per sample, a zero
    quaternion (the identity) and a NaN one (NaN in that sample alone), float32 too; the kernels against
    Pinocchio's integrate, difference, dIntegrate and dDifference (go2) and MuJoCo's mj_integratePos and
    mj_differentiatePos (trees) directly."""
    robot = robots[name]
    g = torch.Generator().manual_seed(9)
    quat = 3  # the free root's quaternion: q[3:7] in both layouts (xyzw, wxyz)
    for view in (robot.pin, robot.mujoco):
        q = view.random_configuration(2, 3, generator=g)
        scale = torch.tensor([[0.0, 1e-9, 1.0], [3.0, 10.0, 1.0]], dtype=torch.float64).unsqueeze(-1)
        v = torch.randn(2, 3, robot.nv, dtype=torch.float64, generator=g) * scale
        dt = torch.rand(3, dtype=torch.float64, generator=g) + 0.5
        q[0, 1, quat:quat + 4] = 0
        q[1, 2, quat] = float("nan")
        kernel = view.integrate(q, v, dt)
        composed = integrate(robot._space, q, v, dt, view._convention)
        assert torch.isnan(kernel[1, 2, quat:quat + 4]).any() and torch.isfinite(kernel[1, 2, quat + 4:]).all()
        assert torch.isfinite(kernel.flatten(0, 1)[:5]).all()  # the other samples
        _assert_same(kernel, composed)
        torch.testing.assert_close(view.integrate(q.float(), v.float(), dt.float())[torch.isfinite(kernel)].double(),
                                   kernel[torch.isfinite(kernel)], rtol=0, atol=1e-5)
        one = view.integrate(q[0, 2], v[0, 2], 0.25)
        _assert_same(one, integrate(robot._space, q[0, 2], v[0, 2], 0.25, view._convention))  # a batch of one, a number as dt
        for fused, composed in zip(view.d_integrate(q, v, dt), view.d_integrate(q, v.clone().requires_grad_(), dt)):
            _assert_same(fused, composed)
        for fused, composed in zip(view.d_integrate(q[0, 2], v[0, 2], 0.25), view.d_integrate(q[0, 2], v[0, 2], torch.tensor(
                0.25, dtype=torch.float64, requires_grad=True))):
            _assert_same(fused, composed)
        flipped = kernel.clone()
        flipped[0, :, quat:quat + 4] *= -1  # the same rotations, the other hemisphere
        others = view.random_configuration(2, 3, generator=g)
        for q1 in (kernel, flipped, others, q):
            fused = view.difference(q, q1)
            _assert_same(fused, difference(robot._space, q, q1, view._convention))
            assert torch.isfinite(fused.flatten(0, 1)[:5]).all()
            for jacobian, composed in zip(view.d_difference(q, q1), view.d_difference(q.clone().requires_grad_(), q1)):
                _assert_same_jacobian(jacobian, composed)
                assert torch.isfinite(jacobian.flatten(0, 1)[:5]).all()
        steps = view.difference(q, kernel)[0, 2]
        torch.testing.assert_close(steps, v[0, 2] * dt[2], rtol=0, atol=1e-12)
        torch.testing.assert_close(view.difference(q.float(), others.float()).double(), view.difference(q, others),
                                   rtol=0, atol=1e-4, equal_nan=True)
        for single, double in zip(view.d_difference(q.float(), others.float()) + view.d_integrate(q.float(), v.float(), dt.float()),
                                  view.d_difference(q, others) + view.d_integrate(q, v, dt)):
            torch.testing.assert_close(single.double(), double, rtol=0, atol=1e-4, equal_nan=True)
    q, v = robot.pin.random_configuration(generator=g), torch.randn(robot.nv, dtype=torch.float64, generator=g)
    q1 = robot.pin.random_configuration(generator=g)
    if name == "go2":
        model = pin_models[name]
        reference = pin.integrate(model, q.numpy(), 0.3 * v.numpy())
        assert np.abs(robot.pin.integrate(q, v, 0.3).numpy() - reference).max() <= 1e-12
        assert np.abs(robot.pin.difference(q, q1).numpy() - pin.difference(model, q.numpy(), q1.numpy())).max() <= 1e-12
        j_q, j_v = robot.pin.d_integrate(q, v, 0.3)
        assert np.abs(j_q.numpy() - pin.dIntegrate(model, q.numpy(), 0.3 * v.numpy(), pin.ARG0)).max() <= 1e-12
        assert np.abs(j_v.numpy() - 0.3 * pin.dIntegrate(model, q.numpy(), 0.3 * v.numpy(), pin.ARG1)).max() <= 1e-12
        for j, arg in zip(robot.pin.d_difference(q, q1), (pin.ARG0, pin.ARG1)):
            assert np.abs(j.numpy() - pin.dDifference(model, q.numpy(), q1.numpy(), arg)).max() <= 1e-12
    else:
        m = mj_sims[name].m
        qm, qm1 = robot.mujoco.random_configuration(generator=g), robot.mujoco.random_configuration(generator=g)
        reference = qm.numpy().copy()
        mujoco.mj_integratePos(m, reference, v.numpy(), 0.3)
        assert np.abs(robot.mujoco.integrate(qm, v, 0.3).numpy() - reference).max() <= 1e-12
        reference = np.zeros(m.nv)
        mujoco.mj_differentiatePos(m, reference, 1.0, qm.numpy(), qm1.numpy())
        assert np.abs(robot.mujoco.difference(qm, qm1).numpy() - reference).max() <= 1e-12
        j_q, j_u, j_0, j_1 = _mujoco_tangent_jacobians(m, qm.numpy(), 0.3 * v.numpy(), qm1.numpy())
        for fused, reference in zip(robot.mujoco.d_integrate(qm, v, 0.3) + robot.mujoco.d_difference(qm, qm1),
                                    (j_q, 0.3 * j_u, j_0, j_1)):
            assert np.abs(fused.numpy() - reference).max() <= 1e-8
    raw = robot._ops.d_integrate(q, v.clone().requires_grad_(), torch.full((1,), 0.3, dtype=torch.float64), 0)[1]
    with pytest.raises(NotImplementedError, match=r"d_integrate kernel has no derivative; differentiate Robot.d_integrate"):
        raw.sum().backward()
    raw = robot._ops.d_difference(q, q1.clone().requires_grad_(), 0)[0]
    with pytest.raises(NotImplementedError, match=r"d_difference kernel has no derivative; differentiate Robot.d_difference"):
        raw.sum().backward()


def test_integrate_composition_with_more_steps_than_states(robots):
    """dt of a batch beyond q's and v's (one state at several steps, states (3,) against dt (2, 1)): the
    compositions of integrate and d_integrate take the batch of all three, as the kernels do (they failed on a
    quaternion joint's product and at their Jacobians' identity blocks)."""
    robot = robots["go2"]
    g = torch.Generator().manual_seed(12)
    for view in (robot.pin, robot.mujoco):
        q = view.random_configuration(3, generator=g)
        v = torch.randn(robot.nv, dtype=torch.float64, generator=g)
        for q, dt in ((q[0], torch.tensor([0.1, 0.5, 2.0], dtype=torch.float64)),
                      (q, torch.tensor([[0.1], [2.0]], dtype=torch.float64))):
            _assert_same(view.integrate(q, v, dt), integrate(robot._space, q, v, dt, view._convention))
            for fused, composed in zip(view.d_integrate(q, v, dt), view.d_integrate(q, v.clone().requires_grad_(), dt)):
                assert composed.shape == fused.shape
                _assert_same(fused, composed)


def test_a_continuous_joint_differs_by_the_shorter_turn(robots, pin_models):
    """A continuous joint's coordinate is an angle: difference wraps it to (-pi, pi], Pinocchio's difference of its
    (cos, sin) joint, in the kernel and in the composition, in both views (MuJoCo has no continuous joint), angles far
    beyond 2 pi included; the other joints' coordinates subtract as they are; the gradient of a wrapped difference is
    still -1 and 1 (d_difference, and autograd through difference's backward kernel and through the composition)."""
    robot, model = robots["tiago"], pin_models["tiago"]
    wheels = [iq for j, iq in zip(robot.model.joints, robot.model.q_index) if j.type == "continuous"]
    assert wheels, "tiago's wheels are continuous joints"
    g = torch.Generator().manual_seed(4)
    q0, q1 = robot.pin.random_configuration(2, 8, generator=g), robot.pin.random_configuration(2, 8, generator=g)
    q0[..., wheels] = 20 * torch.rand(2, 8, len(wheels), dtype=torch.float64, generator=g) - 10
    q1[..., wheels] = 20 * torch.rand(2, 8, len(wheels), dtype=torch.float64, generator=g) - 10
    q1[0, 0, wheels] = q0[0, 0, wheels] + 3.0  # less than a half turn: as it is
    reference = torch.as_tensor(np.stack([pin.difference(model, a, b) for a, b in zip(
        oracles.to_pin_q(robot, q0.flatten(0, 1)), oracles.to_pin_q(robot, q1.flatten(0, 1)))])).unflatten(0, (2, 8))
    for view in (robot.pin, robot.mujoco):
        kernel = view.difference(q0, q1)
        _assert_same(kernel, difference(robot._space, q0, q1, view._convention))
        torch.testing.assert_close(kernel, reference, rtol=0, atol=1e-12)
        turns = (q1 - q0)[..., wheels] - kernel[..., wheels]
        torch.testing.assert_close(turns / (2 * math.pi), torch.round(turns / (2 * math.pi)), rtol=0, atol=1e-12)
        assert (kernel[..., wheels].abs() <= math.pi).all() and (kernel[..., wheels].abs() > 0.5).any()
        torch.testing.assert_close(kernel[0, 0, wheels], torch.full((len(wheels),), 3.0, dtype=torch.float64), rtol=0, atol=1e-12)
        j0, j1 = view.d_difference(q0, q1)
        eye = torch.eye(robot.nv, dtype=torch.float64).expand_as(j1)
        assert torch.equal(j0, -eye) and torch.equal(j1, eye)
        leaves, w = (q0.clone().requires_grad_(), q1.clone().requires_grad_()), torch.randn(robot.nv, dtype=torch.float64, generator=g)
        fused = torch.autograd.grad((view.difference(*leaves) * w).sum(), leaves)
        composed = torch.autograd.grad((difference(robot._space, *leaves, view._convention) * w).sum(), leaves)
        for a, b in zip(fused, composed):
            torch.testing.assert_close(a, b, rtol=0, atol=1e-13)
        torch.testing.assert_close(fused[1], w.expand_as(fused[1]), rtol=0, atol=1e-13)


@pytest.mark.parametrize("name", ["go2", "trees"])
def test_integrate_and_difference_gradients_through_the_kernels(robots, name):
    """Under autograd's reverse mode integrate and difference still run their kernels, their backwards one kernel
    each (integrate_vjp, difference_vjp: ops/lie_backward.py): the gradients of q, v and dt (integrate) and of q0 and q1
    (difference) equal the composition's on every joint type, with a (2, 3) batch broadcast against a (3,) one,
    quaternions of norm 1.7, and a zero one, whose gradient is the identity's (as every op's: tangent_to_ambient)
    where the composition's is not; a NaN quaternion makes its own sample's gradients NaN alone; gradcheck, and
    gradgradcheck (the second backward through the composition's Jacobians)."""
    robot = robots[name]
    g = torch.Generator().manual_seed(11)
    quat = 3  # the free root's quaternion: q[3:7] in both layouts
    for view in (robot.pin, robot.mujoco):
        q, q1 = view.random_configuration(2, 3, generator=g), view.random_configuration(2, 3, generator=g)
        q[..., quat:quat + 4] *= 1.7
        identity = q.clone()
        q[0, 1, quat:quat + 4] = 0
        identity[0, 1, quat:quat + 4] = torch.tensor([1.0, 0, 0, 0] if view.convention == "mujoco" else [0, 0, 0, 1.0])
        v = torch.randn(3, robot.nv, dtype=torch.float64, generator=g)
        dt = torch.rand(2, 3, dtype=torch.float64, generator=g) + 0.5
        calls = ((view.integrate, lambda q, v, dt: integrate(robot._space, q, v, dt, view._convention), (q, v, dt)),
                 (view.difference, lambda a, b: difference(robot._space, a, b, view._convention), (q, q1)))
        for method, composition, args in calls:
            kernel_in = [x.clone().requires_grad_() for x in args]
            composed_in = [identity.clone().requires_grad_()] + [x.clone().requires_grad_() for x in args[1:]]
            out = method(*kernel_in)
            assert type(out.grad_fn).__name__ != "CatBackward0"  # the kernel's backward, not the composition's
            weight = torch.randn(out.shape, dtype=torch.float64, generator=g)
            grads = torch.autograd.grad((out * weight).sum(), kernel_in)
            for a, b in zip(grads, torch.autograd.grad((composition(*composed_in) * weight).sum(), composed_in)):
                torch.testing.assert_close(a, b, rtol=0, atol=1e-12)
            small = [x[:1, :1] if x.dim() > 2 or x is dt else x[:1] for x in args]
            small = [x.detach().clone().requires_grad_() for x in small]
            assert torch.autograd.gradcheck(method, small)
            assert torch.autograd.gradgradcheck(method, small, fast_mode=True)
        nan = q.clone()
        nan[1, 2, quat] = float("nan")
        for method, args in ((view.integrate, (nan, v.expand(2, 3, -1), dt)), (view.difference, (nan, q1))):
            inputs = [x.clone().requires_grad_() for x in args]
            grads = torch.autograd.grad(method(*inputs).sum(), inputs)
            for grad in grads:
                assert torch.isnan(grad[1, 2]).any() and torch.isfinite(grad.flatten(0, 1)[:5]).all()


def _mujoco_tangent_jacobians(m, q: np.ndarray, u: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, ...]:
    """The tangent Jacobians of mj_integratePos(q, u) along q and u, and of mj_differentiatePos(q, q1) along q
    and q1, by central differences of MuJoCo's own functions (a step of 1e-6 along each tangent direction)."""
    def step(x, e):
        out = x.copy()
        mujoco.mj_integratePos(m, out, e, 1.0)
        return out

    def diff(a, b):
        out = np.zeros(m.nv)
        mujoco.mj_differentiatePos(m, out, 1.0, a, b)
        return out

    eps, end = 1e-6, step(q, u)
    jacobians = [np.zeros((m.nv, m.nv)) for _ in range(4)]
    for k in range(m.nv):
        for sign in (1.0, -1.0):
            e = np.zeros(m.nv)
            e[k] = sign * eps
            moved = (diff(end, step(step(q, e), u)), diff(end, step(q, u + e)), diff(step(q, e), q1), diff(q, step(q1, e)))
            for jacobian, x in zip(jacobians, moved):
                jacobian[:, k] += sign * x / (2 * eps)
    return tuple(jacobians)


def _assert_same_jacobian(kernel: torch.Tensor, composed: torch.Tensor) -> None:
    """A Jacobian's kernel values are the composition's to rounding. Of a NaN quaternion the kernel's NaN stays in
    that joint's block, where the composition's products spread it over the block's whole rows: each NaN of the
    kernel is one of the composition's, and each sample with a NaN in one has a NaN in the other."""
    composed = composed.detach()
    assert (torch.isnan(composed) | ~torch.isnan(kernel)).all()
    assert torch.equal(torch.isnan(kernel).flatten(-2).any(-1), torch.isnan(composed).flatten(-2).any(-1))
    finite = torch.isfinite(composed)
    torch.testing.assert_close(kernel[finite], composed[finite], rtol=0, atol=1e-13)


def _assert_same(kernel: torch.Tensor, composed: torch.Tensor) -> None:
    """The kernel's values are the composition's to rounding, NaN where it is NaN."""
    composed = composed.detach()
    assert torch.equal(torch.isnan(kernel), torch.isnan(composed))
    finite = torch.isfinite(composed)
    torch.testing.assert_close(kernel[finite], composed[finite], rtol=0, atol=1e-13)


def test_random_configuration_keeps_a_one_sided_limit():
    """A joint bounded on one side only (a pinocchio.Model's limit left at +-DBL_MAX on the other) is drawn
    within Pinocchio's limits, from its bound, rather than between the bound and the default [-pi, pi]."""
    import torch_grid

    model = pin.Model()
    inertia = pin.Inertia(1.0, np.array([0.1, 0.0, 0.0]), np.diag([0.01, 0.02, 0.03]))
    for name, joint, parent in (("slide", pin.JointModelPZ(), 0), ("hinge", pin.JointModelRY(), 1)):
        jid = model.addJoint(parent, joint, pin.SE3.Identity(), name)
        model.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
    model.lowerPositionLimit[0], model.upperPositionLimit[1] = 5.0, -4.0  # slide >= 5, hinge <= -4
    robot = torch_grid.load(model)
    assert (robot.model.joints[0].upper, robot.model.joints[1].lower) == (math.inf, -math.inf)
    for view in (robot.pin, robot.mujoco):
        q = view.random_configuration(1000, generator=torch.Generator().manual_seed(0)).numpy()
        assert (q >= model.lowerPositionLimit).all() and (q <= model.upperPositionLimit).all()
        assert q[:, 0].max() > 5 + 1.5 and q[:, 1].min() < -4 - 2 * math.pi + 0.5  # a width of 2 and 2 pi


@pytest.mark.parametrize("angle", [0.0101, 0.03, 0.3, math.pi - 1e-6])
def test_float32_jacobians_and_their_derivatives_follow_float64(angle):
    """In float32 the tangent Jacobians of a free joint in Pinocchio's convention, and their derivatives (those of the
    step Hessians and of autograd through them), keep float32's digits just above the small-angle series' range and
    near a half turn, where their closed forms cancel: against float64 at the same (rounded) inputs."""
    space, gen = Space.of(["free"]), torch.Generator().manual_seed(5)
    axis = torch.randn(8, 3, generator=gen, dtype=torch.float64)
    v = torch.cat([torch.randn(8, 3, generator=gen, dtype=torch.float64),
                   angle * axis / axis.norm(dim=-1, keepdim=True)], dim=-1).float().double()
    q = torch.cat([torch.randn(8, 3, dtype=torch.float64), torch.tensor([[0.0, 0.0, 0.0, 1.0]]).expand(8, 4)], dim=-1)
    q1 = integrate(space, q, v, 1.0, 0).float().double()

    def derivatives(q, v, q1):
        j_v = torch.func.vmap(torch.func.jacfwd(lambda u: d_integrate(space, q[0], u, 1.0, 0)[1]))(v)
        carried = torch.func.jacfwd(torch.func.jacfwd(lambda u: dexp_inverse(space, u, q[0, :6], 0)))  # Runge-Kutta's
        return d_integrate(space, q, v, 1.0, 0)[1], j_v, d_difference(space, q, q1, 0)[1], torch.func.vmap(carried)(v)

    for low, high in zip(derivatives(q.float(), v.float(), q1.float()), derivatives(q, v, q1)):
        scale = high.flatten(1).abs().amax(1).view(-1, *[1] * (high.dim() - 1))
        assert ((low.double() - high).abs() / scale).max() < 1e-5


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_difference_gradient_at_a_half_turn(dtype):
    """Two orientations a half turn apart (the relative quaternion's w exactly 0, as for a target flipped about an
    axis): the reverse-mode Jacobian of difference is finite and equals the forward-mode one."""
    space = Space.of(["ball"])
    q0, q1 = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype), torch.tensor([0.0, 0.0, 1.0, 0.0], dtype=dtype)
    forward = torch.func.jacfwd(lambda a, b: difference(space, a, b, 0), argnums=(0, 1))(q0, q1)
    reverse = torch.func.jacrev(lambda a, b: difference(space, a, b, 0), argnums=(0, 1))(q0, q1)
    for f, r in zip(forward, reverse):
        assert torch.isfinite(r).all()
        torch.testing.assert_close(r, f)


def test_dexp_inverse_second_derivative_at_a_half_turn():
    """dexp^-1's second derivative (the Runge-Kutta step Hessians') at a rotation of pi, where the cotangent of
    its closed form turns infinite: against central differences of its first derivative."""
    space = Space.of(["ball"])
    u = torch.tensor([0.6, 0.0, 0.8], dtype=torch.float64) * torch.pi
    w = torch.tensor([0.3, -1.2, 0.7], dtype=torch.float64)
    jacobian = torch.func.jacfwd(lambda x: dexp_inverse(space, x, w, 0))
    hessian = torch.func.jacfwd(jacobian)(u)
    h = 1e-5
    fd = torch.stack([(jacobian(u + h * e) - jacobian(u - h * e)) / (2 * h) for e in torch.eye(3, dtype=u.dtype)], -1)
    assert ((hessian - fd).abs().max() / fd.abs().max()) < 1e-7
