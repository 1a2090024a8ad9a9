"""torch_grid (Pinocchio convention) against Pinocchio itself, on four robots.

float64: rel_err <= 1e-9; float32 inputs: rel_err <= 1e-4 against the float64 Pinocchio value.
rel_err = max|ours - ref| / max(max|ref|, 1e-12) over the whole batch.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import torch

from torch_grid import conventions
from oracles import PinOracle, batch_apply, pin_forces, rel_err, to_pin_q

ROBOTS = ["iiwa14", "go2", "g1", "tiago"]
TOL = {torch.float64: 1e-9, torch.float32: 1e-4}
REFERENCES = ["local_world_aligned", "local", "world"]


@pytest.fixture(params=ROBOTS)
def robot_name(request):
    return request.param


def as_tuple(x):
    return x if isinstance(x, tuple) else (x,)


# --------------------------------------------------------------------------------------------
# states and frames
# --------------------------------------------------------------------------------------------
def make_states(robot, batch_shape, seed=0):
    """Random float64 states: q (pin layout), qd, qdd, tau, f_ext, from a seeded generator."""
    g = torch.Generator().manual_seed(seed)
    q = robot.random_configuration(*batch_shape, dtype=torch.float64, generator=g)
    assert q.shape == (*batch_shape, robot.nq) and q.dtype == torch.float64
    nv, nb = robot.nv, robot.nbodies

    def randn(*shape, scale=1.0):
        return scale * torch.randn(*batch_shape, *shape, generator=g, dtype=torch.float64)

    return dict(q=q, qd=randn(nv), qdd=randn(nv), tau=randn(nv, scale=10.0), f_ext=randn(nb, 6, scale=5.0))


def cast(states, dtype):
    return {k: v.to(dtype) for k, v in states.items()}


def frames_to_test(robot):
    """A few frames to test, by name: the last frame, one in the middle, and the first body frame."""
    names = robot.frame_names
    picks = [names[-1], names[len(names) // 2]]
    body = [f.name for f in robot.model.frames if f.kind == "body"]
    return list(dict.fromkeys(picks + body[:1] + body[-1:]))


def reference(robot, pmodel, s, fn, keys):
    """Pinocchio value over the batch: fn(oracle, q_pin, *[s[k] for k in keys]) per state."""
    oracle = PinOracle(pmodel)
    arrays = [to_pin_q(robot, s["q"])] + [s[k].double().numpy() for k in keys]
    return batch_apply(lambda qp, *rest: fn(oracle, qp, *rest), *arrays)


# --------------------------------------------------------------------------------------------
# the cases: name -> (ours(api, s), reference function on one state, the state keys it uses)
# --------------------------------------------------------------------------------------------
CASES = {
    "inverse_dynamics": (lambda r, s: r.inverse_dynamics(s["q"], s["qd"], s["qdd"]),
                         lambda o, q, v, a: o.rnea(q, v, a), ["qd", "qdd"]),
    "inverse_dynamics_fext": (lambda r, s: r.inverse_dynamics(s["q"], s["qd"], s["qdd"], f_ext=s["f_ext"]),
                              lambda o, q, v, a, f: o.rnea(q, v, a, f), ["qd", "qdd", "f_ext"]),
    "rnea": (lambda r, s: r.rnea(s["q"], s["qd"], s["qdd"]), lambda o, q, v, a: o.rnea(q, v, a), ["qd", "qdd"]),
    "forward_dynamics": (lambda r, s: r.forward_dynamics(s["q"], s["qd"], s["tau"]),
                         lambda o, q, v, t: o.aba(q, v, t), ["qd", "tau"]),
    "forward_dynamics_fext": (lambda r, s: r.forward_dynamics(s["q"], s["qd"], s["tau"], f_ext=s["f_ext"]),
                              lambda o, q, v, t, f: o.aba(q, v, t, f), ["qd", "tau", "f_ext"]),
    "aba": (lambda r, s: r.aba(s["q"], s["qd"], s["tau"]), lambda o, q, v, t: o.aba(q, v, t), ["qd", "tau"]),
    "crba": (lambda r, s: r.crba(s["q"]), lambda o, q: o.crba(q), []),
    "minv": (lambda r, s: r.minv(s["q"]), lambda o, q: o.minv(q), []),
    "generalized_gravity": (lambda r, s: r.generalized_gravity(s["q"]), lambda o, q: o.gravity(q), []),
    "nonlinear_effects": (lambda r, s: r.nonlinear_effects(s["q"], s["qd"]), lambda o, q, v: o.nle(q, v), ["qd"]),
    "energy": (lambda r, s: r.energy(s["q"], s["qd"]), lambda o, q, v: o.energy(q, v), ["qd"]),
    "com": (lambda r, s: r.com(s["q"]), lambda o, q: o.com(q), []),
    "jacobian_com": (lambda r, s: r.jacobian_com(s["q"]), lambda o, q: o.jacobian_com(q), []),
    "ccrba": (lambda r, s: r.ccrba(s["q"], s["qd"]), lambda o, q, v: o.ccrba(q, v), ["qd"]),
    "forward_kinematics": (lambda r, s: r.forward_kinematics(s["q"]), lambda o, q: o.forward_kinematics(q), []),
}


def check(name, ours, ref, tol, dtype):
    ours, ref = as_tuple(ours), as_tuple(ref)
    assert len(ours) == len(ref), f"{name}: {len(ours)} outputs, expected {len(ref)}"
    for k, (o, r) in enumerate(zip(ours, ref)):
        assert isinstance(o, torch.Tensor) and o.dtype == dtype, f"{name}[{k}]: got {type(o)} {getattr(o, 'dtype', '')}"
        err = rel_err(o, r)
        assert err <= tol, f"{name}[{k}]: rel_err {err:.3e} > {tol:.0e} (max|ref| {np.abs(r).max():.3e})"


# --------------------------------------------------------------------------------------------
# tests
# --------------------------------------------------------------------------------------------
def test_layout_matches_pinocchio(robots, pin_models, robot_name):
    robot, pm = robots.get(robot_name), pin_models.get(robot_name)
    n_cont = sum(j.type == "continuous" for j in robot.model.joints)
    assert robot.joint_names == list(pm.names[1:])
    assert robot.frame_names == [f.name for f in pm.frames]
    assert (robot.nq, robot.nv, robot.nbodies, robot.nframes) == (pm.nq - n_cont, pm.nv, pm.njoints - 1, pm.nframes)
    assert robot.floating_base == (pm.joints[1].shortname() == "JointModelFreeFlyer")
    assert to_pin_q(robot, robot.neutral_configuration()).tolist() == pytest.approx(list(pin.neutral(pm)))


def test_random_configuration(robots, pin_models, robot_name):
    robot, pm = robots.get(robot_name), pin_models.get(robot_name)
    g = torch.Generator().manual_seed(1)
    q = robot.random_configuration(3, 2, generator=g)
    assert q.shape == (3, 2, robot.nq) and q.dtype == torch.float64
    q2 = robot.random_configuration(3, 2, generator=torch.Generator().manual_seed(1))
    assert torch.equal(q, q2), "same seed must give the same configurations"
    qp = to_pin_q(robot, q)
    for j, jm in zip(robot.model.joints, list(pm.joints)[1:]):
        if j.type == "free":
            quat = qp[..., jm.idx_q + 3:jm.idx_q + 7]
            assert np.allclose(np.linalg.norm(quat, axis=-1), 1.0, atol=1e-12), "quaternion is not unit"
        elif j.type in ("revolute", "prismatic"):
            x = qp[..., jm.idx_q]
            assert np.all(x >= j.lower - 1e-12) and np.all(x <= j.upper + 1e-12), f"{j.name} outside its limits"


@pytest.mark.parametrize("batch_shape", [(5,), (2, 3), ()], ids=["b5", "b2x3", "unbatched"])
@pytest.mark.parametrize("case", list(CASES))
def test_against_pinocchio_float64(robots, pin_models, robot_name, case, batch_shape):
    robot, pm = robots.get(robot_name), pin_models.get(robot_name)
    s = make_states(robot, batch_shape, seed=10)
    ours_fn, ref_fn, keys = CASES[case]
    check(case, ours_fn(robot, s), reference(robot, pm, s, ref_fn, keys), TOL[torch.float64], torch.float64)


@pytest.mark.parametrize("case", list(CASES))
def test_against_pinocchio_float32(robots, pin_models, robot_name, case):
    robot, pm = robots.get(robot_name), pin_models.get(robot_name)
    s = make_states(robot, (4,), seed=20)
    ours_fn, ref_fn, keys = CASES[case]
    ref = reference(robot, pm, s, ref_fn, keys)  # float64 reference from the float64 state
    check(case, ours_fn(robot, cast(s, torch.float32)), ref, TOL[torch.float32], torch.float32)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["f64", "f32"])
@pytest.mark.parametrize("reference_frame", REFERENCES)
def test_frame_jacobian(robots, pin_models, robot_name, reference_frame, dtype):
    robot, pm = robots.get(robot_name), pin_models.get(robot_name)
    s = make_states(robot, (2, 2), seed=30)
    for frame in frames_to_test(robot):
        fid = pm.getFrameId(frame)
        ref = reference(robot, pm, s, lambda o, q: o.frame_jacobian(q, fid, reference_frame), [])
        ours = robot.frame_jacobian(s["q"].to(dtype), frame, reference=reference_frame)
        check(f"frame_jacobian({frame!r}, {reference_frame})", ours, ref, TOL[dtype], dtype)
    if reference_frame == "local_world_aligned":  # the default reference
        frame = frames_to_test(robot)[0]
        ref = reference(robot, pm, s, lambda o, q: o.frame_jacobian(q, pm.getFrameId(frame), "local_world_aligned"), [])
        check("frame_jacobian default reference", robot.frame_jacobian(s["q"].to(dtype), frame), ref, TOL[dtype], dtype)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["f64", "f32"])
def test_end_effector_pose(robots, pin_models, robot_name, dtype):
    robot, pm = robots.get(robot_name), pin_models.get(robot_name)
    s = make_states(robot, (3, 2), seed=40)
    frames = frames_to_test(robot)[:2]
    ids = [pm.getFrameId(f) for f in frames]
    ref = reference(robot, pm, s, lambda o, q: o.end_effector_pose(q, ids), [])
    check("end_effector_pose(names)", robot.end_effector_pose(s["q"].to(dtype), frames), ref, TOL[dtype], dtype)
    check("end_effector_pose(indices)", robot.end_effector_pose(s["q"].to(dtype), ids), ref, TOL[dtype], dtype)


def _rpy_matrix(rpy):
    """Rz(yaw) Ry(pitch) Rx(roll) of angles (..., 3)."""
    return torch.stack([torch.tensor(pin.rpy.rpyToMatrix(*a)) for a in rpy.reshape(-1, 3).tolist()]).reshape(*rpy.shape, 3)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["f64", "f32"])
def test_end_effector_pose_at_pitch_of_a_right_angle(robots, dtype):
    """At pitch +-pi/2 R fixes only roll -+ yaw: the angles must still give back the frame's rotation (they were
    each read from rounding noise there)."""
    robot = robots["go2"]
    q = robot.pin.neutral_configuration(4, dtype=torch.float64)
    for k, angles in enumerate([(0.3, np.pi / 2, 0.2), (0.3, -np.pi / 2, 0.2), (-2.0, np.pi / 2, 1.0), (0.4, 0.5, 0.6)]):
        q[k, 3:7] = torch.tensor(pin.Quaternion(pin.rpy.rpyToMatrix(*angles)).coeffs())  # the base's, xyzw
    for view, qv in ((robot.pin, q), (robot.mujoco, conventions.of(robot).q_pin_to_mujoco(q))):
        rotation = view.forward_kinematics(qv)[1][:, robot.frame_index("base")]
        pose = view.end_effector_pose(qv.to(dtype), ["base"])[:, 0].double()
        assert rel_err(_rpy_matrix(pose[:, 3:]), rotation) <= TOL[dtype] / 10
        assert rel_err(pose[:, 4].abs()[:3], torch.full((3,), np.pi / 2, dtype=torch.float64)) <= TOL[dtype] / 10


def test_energy_is_sum(robots, robot_name):
    robot = robots.get(robot_name)
    s = make_states(robot, (4,), seed=50)
    e = robot.energy(s["q"], s["qd"])
    assert rel_err(e[..., 2], e[..., 0] + e[..., 1]) <= 1e-12


def test_joint_angles_of_any_size(robots, pin_models):
    """The kernels' sine and cosine (a vectorised range reduction and polynomial, the C library past
    2^24 or for non-finite angles) against Pinocchio's, over angles from subnormal to 1e12 and at
    multiples of pi/2, where the reduction cancels most digits."""
    robot, pm = robots.get("iiwa14"), pin_models.get("iiwa14")
    g = torch.Generator().manual_seed(60)
    j = torch.arange(1, 8, dtype=torch.float64)
    rows = [
        torch.rand(7, generator=g, dtype=torch.float64) * 6.3 - 3.15,
        j * (np.pi / 2),
        (torch.rand(7, generator=g, dtype=torch.float64) - 0.5) * 2e5,
        (1e6 + j) * (np.pi / 2),
        torch.tensor([2.0**24 - 0.5, 2.0**24, 2.0**24 + 1, -(2.0**24), 1e17, -3e20, 1e300], dtype=torch.float64),
        (torch.rand(7, generator=g, dtype=torch.float64) - 0.5) * 2e12,
        torch.tensor([1e-300, -0.0, 5e-324, 1e-9, -1e-5, 0.7853981633974483, -2.356194490192345], dtype=torch.float64),
    ]
    s = {"q": torch.stack(rows)}
    for case in ("forward_kinematics", "crba"):
        ours_fn, ref_fn, keys = CASES[case]
        check(case, ours_fn(robot, s), reference(robot, pm, s, ref_fn, keys), 1e-12, torch.float64)
    frame = frames_to_test(robot)[0]
    ref = reference(robot, pm, s, lambda o, q: o.frame_jacobian(q, pm.getFrameId(frame), "local_world_aligned"), [])
    check("frame_jacobian", robot.frame_jacobian(s["q"], frame), ref, 1e-12, torch.float64)
    bad = s["q"][:2].clone()
    bad[0, 3], bad[1, 5] = float("nan"), float("inf")
    assert torch.isnan(robot.crba(bad)).any(dim=(-2, -1)).all(), "a non-finite angle must not read as a finite one"


# --------------------------------------------------------------------------------------------
# convention selection
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("robot_name", ["iiwa14", "tiago"])
@pytest.mark.parametrize("case", list(CASES))
def test_fixed_base_mujoco_is_noop(robots, robot_name, case):
    robot = robots.get(robot_name)
    s = make_states(robot, (3,), seed=60)
    ours_fn = CASES[case][0]
    default = as_tuple(ours_fn(robot, s))
    for api in ("mujoco", "pin"):
        other = as_tuple(ours_fn(getattr(robot, api), s))
        assert len(other) == len(default)
        for k, (o, d) in enumerate(zip(other, default)):
            err = rel_err(o, d)
            assert err <= 1e-12, f"{case}[{k}]: robot.{api} differs from robot on a fixed base ({err:.2e})"


@pytest.mark.parametrize("case", list(CASES))
def test_pin_namespace_is_default(robots, case):
    robot = robots.get("go2")
    s = make_states(robot, (3,), seed=65)
    ours_fn = CASES[case][0]
    for o, d in zip(as_tuple(ours_fn(robot.pin, s)), as_tuple(ours_fn(robot, s)), strict=True):
        assert rel_err(o, d) <= 1e-12, f"{case}: robot.pin differs from robot (default convention 'pin')"


def test_three_ways_to_choose_mujoco_convention(robots):
    import torch_grid

    robot = robots.get("go2")
    g = torch.Generator().manual_seed(70)
    q_mj = robot.mujoco.random_configuration(4, generator=g)
    qd = torch.randn(4, robot.nv, generator=g, dtype=torch.float64)
    via_namespace = robot.mujoco.crba(q_mj)
    id_namespace = robot.mujoco.inverse_dynamics(q_mj, qd, qd)
    old = robot.convention
    try:
        robot.convention = "mujoco"
        via_attribute = robot.crba(q_mj)
        id_attribute = robot.inverse_dynamics(q_mj, qd, qd)
    finally:
        robot.convention = old
    loaded = torch_grid.load("go2", convention="mujoco")
    assert loaded.convention == "mujoco"
    assert rel_err(via_attribute, via_namespace) <= 1e-12
    assert rel_err(loaded.crba(q_mj), via_namespace) <= 1e-12
    assert rel_err(id_attribute, id_namespace) <= 1e-12
    assert rel_err(loaded.inverse_dynamics(q_mj, qd, qd), id_namespace) <= 1e-12
    # and it really is a different convention on a floating base (the base block is rotated)
    q_pin = q_mj.clone()
    q_pin[..., 3:7] = q_mj[..., [4, 5, 6, 3]]
    assert rel_err(robot.pin.crba(q_pin), via_namespace) > 1e-6


def test_free_joint_placed_away_from_the_origin(tmp_path):
    """A pinocchio.Model whose FreeFlyer has a placement: Pinocchio's convention is Pinocchio's (the placement
    before the joint's motion); MuJoCo's, whose free-joint qpos is the body's world pose, is refused (by load,
    the Robot's views and conventions.of), naming the joint."""
    import torch_grid
    from pin_models import _inertia, _se3

    model = pin.Model()
    root = model.addJoint(0, pin.JointModelFreeFlyer(), _se3([0.3, -0.2, 0.5], [0.4, -0.1, 0.7]), "placed_root")
    model.appendBodyToJoint(root, _inertia(2.0, [0.02, 0.01, -0.03], [0.03, 0.04, 0.05]), pin.SE3.Identity())
    arm = model.addJoint(root, pin.JointModelRY(), _se3([0.1, 0.0, 0.2], [0.2, 0.05, 0.0]), "arm")
    model.appendBodyToJoint(arm, _inertia(0.7, [0.1, 0.0, 0.01], [0.002, 0.005, 0.006]), pin.SE3.Identity())
    for joint in (root, arm):
        model.addJointFrame(joint)
    converted = torch_grid.from_pinocchio(model)
    assert converted.placed_free_joint == "placed_root"
    with pytest.raises(ValueError, match="convention='mujoco' needs each free joint at the world's origin.*'placed_root'"):
        torch_grid.load(model, convention="mujoco", cache_dir=tmp_path)
    with pytest.raises(ValueError, match=r"conventions.of\('.*'\): free joint 'placed_root' is placed away"):
        torch_grid.conventions.of(converted)
    robot = torch_grid.load(model, cache_dir=tmp_path)
    for attempt in (lambda: robot.mujoco, lambda: setattr(robot, "convention", "mujoco")):
        with pytest.raises(ValueError, match="free joint 'placed_root' placed away from the world's origin"):
            attempt()
    oracle = PinOracle(model)
    s = make_states(robot, (3,), seed=5)
    q, v, a, tau = (s[k].numpy() for k in ("q", "qd", "qdd", "tau"))
    assert rel_err(robot.inverse_dynamics(s["q"], s["qd"], s["qdd"]), batch_apply(oracle.rnea, q, v, a)) <= TOL[torch.float64]
    assert rel_err(robot.forward_dynamics(s["q"], s["qd"], s["tau"]), batch_apply(oracle.aba, q, v, tau)) <= TOL[torch.float64]
    pos, _ = robot.forward_kinematics(s["q"])
    data = model.createData()
    for b in range(3):
        pin.framesForwardKinematics(model, data, q[b])
        for name in ("placed_root", "arm"):
            assert rel_err(pos[b, robot.frame_index(name)], data.oMf[model.getFrameId(name)].translation) <= 1e-12
    # the derivatives, with external forces: Pinocchio's, and the step's along integrate (placement not moved)
    f = s["f_ext"]
    dq, dv = robot.inverse_dynamics_derivatives(s["q"], s["qd"], s["qdd"], f)
    gq, gv, _ = robot.forward_dynamics_derivatives(s["q"], s["qd"], s["tau"], f)
    for b in range(3):
        ref = pin.computeRNEADerivatives(model, data, q[b], v[b], a[b], pin_forces(model, f[b]))
        assert rel_err(dq[b], ref[0]) <= 1e-9 and rel_err(dv[b], ref[1]) <= 1e-9
        pin.computeABADerivatives(model, data, q[b], v[b], tau[b], pin_forces(model, f[b]))
        assert rel_err(gq[b], data.ddq_dq) <= 1e-8 and rel_err(gv[b], data.ddq_dv) <= 1e-8
    nv, h, eye = robot.nv, 1e-6, torch.eye(2 * robot.nv, dtype=torch.float64)
    x0, v0, u0 = s["q"][0], s["qd"][0], s["tau"][0]
    for integrator in ("semi_implicit_euler", "rk4"):
        A = robot.step_derivatives(x0, v0, u0, 0.01, integrator)[0]
        ends = [robot.step(robot.integrate(x0.expand(2 * nv, -1), sign * h * eye[:, :nv]), v0 + sign * h * eye[:, nv:],
                           u0, 0.01, integrator) for sign in (1, -1)]
        fd = torch.cat([robot.difference(ends[1][0], ends[0][0]), ends[0][1] - ends[1][1]], -1).T / (2 * h)
        assert rel_err(A, fd) <= 1e-6, integrator
