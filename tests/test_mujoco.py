"""torch_grid's MuJoCo convention against real MuJoCo, and torch_grid.conventions as the oracle.

Floating robots (go2, g1), float64, rel_err <= 1e-9. States are MuJoCo's: qpos = [pos, quat wxyz,
joints], qvel = [v_lin WORLD, omega LOCAL, rates], qacc, qfrc. Three comparisons per function:
  robot.mujoco.X                          vs MuJoCo
  conventions(robot.pin.X)                vs robot.mujoco.X    (the fused kernel twin agrees with the oracle)
  conventions(Pinocchio's own X)          vs MuJoCo            (the oracle itself is right)
"""
from __future__ import annotations

import numpy as np
import pytest
import torch

from oracles import G_matrix, PinOracle, batch_apply, rel_err, to_pin_q

ROBOTS = ["go2", "g1"]
TOL = 1e-9
BATCH = (2, 3)


@pytest.fixture(params=ROBOTS)
def robot_name(request):
    return request.param


@pytest.fixture(scope="module")
def C():
    from torch_grid import conventions

    return conventions


def as_tuple(x):
    return x if isinstance(x, tuple) else (x,)


def quat_xyzw_to_wxyz(q):
    """pin-layout floating q -> MuJoCo qpos (independent of torch_grid.conventions)."""
    out = q.clone()
    out[..., 3:7] = q[..., [6, 3, 4, 5]]
    return out


def make_states(robot, seed=0):
    g = torch.Generator().manual_seed(seed)
    q_pin = robot.random_configuration(*BATCH, dtype=torch.float64, generator=g)
    nv = robot.nv

    def randn(scale=1.0):
        return scale * torch.randn(*BATCH, nv, generator=g, dtype=torch.float64)

    return dict(q_pin=q_pin, q=quat_xyzw_to_wxyz(q_pin), qd=randn(), qdd=randn(), tau=randn(10.0))


def bodies_to_test(robot):
    body = [f.name for f in robot.model.frames if f.kind == "body"]
    return list(dict.fromkeys([body[0], body[1], body[len(body) // 2], body[-1]]))


def mj_ref(sim, s, fn, keys):
    return batch_apply(lambda *a: fn(sim, *a), *[s[k].numpy() for k in ["q", *keys]])


# MuJoCo reference per function: (fn(sim, qpos, ...), the state keys after q)
MJ_REF = {
    "crba": (lambda m, q: m.full_m(q), []),
    "minv": (lambda m, q: np.linalg.inv(m.full_m(q)), []),
    "inverse_dynamics": (lambda m, q, v, a: m.qfrc_inverse(q, v, a), ["qd", "qdd"]),
    "rnea": (lambda m, q, v, a: m.qfrc_inverse(q, v, a), ["qd", "qdd"]),
    "nonlinear_effects": (lambda m, q, v: m.qfrc_bias(q, v), ["qd"]),
    "generalized_gravity": (lambda m, q: m.qfrc_bias(q, np.zeros(m.m.nv)), []),
    "forward_dynamics": (lambda m, q, v, t: m.qacc(q, v, t), ["qd", "tau"]),
    "aba": (lambda m, q, v, t: m.qacc(q, v, t), ["qd", "tau"]),
    "jacobian_com": (lambda m, q: m.jac_subtree_com(q), []),
    "com": (lambda m, q: m.subtree_com(q), []),
    "energy": (lambda m, q, v: m.energy(q, v), ["qd"]),
}

# torch_grid in MuJoCo convention: fn(api, s)
OURS = {
    "crba": lambda r, s: r.crba(s["q"]),
    "minv": lambda r, s: r.minv(s["q"]),
    "inverse_dynamics": lambda r, s: r.inverse_dynamics(s["q"], s["qd"], s["qdd"]),
    "rnea": lambda r, s: r.rnea(s["q"], s["qd"], s["qdd"]),
    "nonlinear_effects": lambda r, s: r.nonlinear_effects(s["q"], s["qd"]),
    "generalized_gravity": lambda r, s: r.generalized_gravity(s["q"]),
    "forward_dynamics": lambda r, s: r.forward_dynamics(s["q"], s["qd"], s["tau"]),
    "aba": lambda r, s: r.aba(s["q"], s["qd"], s["tau"]),
    "jacobian_com": lambda r, s: r.jacobian_com(s["q"]),
    "com": lambda r, s: r.com(s["q"]),
    "energy": lambda r, s: r.energy(s["q"], s["qd"]),
    "ccrba": lambda r, s: r.ccrba(s["q"], s["qd"]),
    "forward_kinematics": lambda r, s: r.forward_kinematics(s["q"]),
}


class PinBatched:
    """Pinocchio itself behind robot.pin's method names (torch in, torch out, any batch shape)."""

    def __init__(self, robot, pmodel):
        self.robot, self.oracle = robot, PinOracle(pmodel)

    def _run(self, fn, q, *rest):
        out = batch_apply(fn, to_pin_q(self.robot, q), *[x.numpy() for x in rest])
        return tuple(torch.from_numpy(o) for o in out) if isinstance(out, tuple) else torch.from_numpy(out)

    def inverse_dynamics(self, q, v, a):
        return self._run(self.oracle.rnea, q, v, a)

    def forward_dynamics(self, q, v, tau):
        return self._run(self.oracle.aba, q, v, tau)

    rnea, aba = inverse_dynamics, forward_dynamics

    def crba(self, q):
        return self._run(self.oracle.crba, q)

    def minv(self, q):
        return self._run(self.oracle.minv, q)

    def generalized_gravity(self, q):
        return self._run(self.oracle.gravity, q)

    def jacobian_com(self, q):
        return self._run(self.oracle.jacobian_com, q)

    def com(self, q):
        return self._run(self.oracle.com, q)

    def energy(self, q, v):
        return self._run(self.oracle.energy, q, v)

    def ccrba(self, q, v):
        return self._run(self.oracle.ccrba, q, v)

    def forward_kinematics(self, q):
        return self._run(self.oracle.forward_kinematics, q)

    def frame_jacobian(self, q, frame, reference="local_world_aligned"):
        fid = self.robot.frame_names.index(frame)
        return self._run(lambda qp: self.oracle.frame_jacobian(qp, fid, reference), q)


def via_conventions(C, pin_api, case, s):
    """MuJoCo-convention value of `case` from a Pinocchio-convention backend and the transforms of docs/guides/conventions.md."""
    qp, qd = s["q_pin"], s["qd"]
    vp = C.v_mujoco_to_pin(qp, qd)
    if case == "crba" or case == "minv":
        return C.congruence_pin_to_mujoco(qp, getattr(pin_api, case)(qp))
    if case in ("inverse_dynamics", "rnea", "nonlinear_effects"):
        qdd = torch.zeros_like(qd) if case == "nonlinear_effects" else s["qdd"]
        return C.covector_pin_to_mujoco(qp, pin_api.inverse_dynamics(qp, vp, C.a_mujoco_to_pin(qp, vp, qdd)))
    if case == "generalized_gravity":
        return C.covector_pin_to_mujoco(qp, pin_api.generalized_gravity(qp))
    if case in ("forward_dynamics", "aba"):
        return C.a_pin_to_mujoco(qp, vp, pin_api.forward_dynamics(qp, vp, C.covector_mujoco_to_pin(qp, s["tau"])))
    if case == "jacobian_com":
        return C.columns_pin_to_mujoco(qp, pin_api.jacobian_com(qp))
    if case == "ccrba":
        A, h = pin_api.ccrba(qp, vp)
        return C.columns_pin_to_mujoco(qp, A), h
    if case == "energy":
        return pin_api.energy(qp, vp)
    if case in ("com", "forward_kinematics"):
        return getattr(pin_api, case)(qp)
    raise KeyError(case)


def check(name, ours, ref):
    ours, ref = as_tuple(ours), as_tuple(ref)
    assert len(ours) == len(ref), f"{name}: {len(ours)} outputs, expected {len(ref)}"
    for k, (o, r) in enumerate(zip(ours, ref)):
        assert isinstance(o, torch.Tensor) and o.dtype == torch.float64, f"{name}[{k}]: {type(o)}"
        err = rel_err(o, r)
        assert err <= TOL, f"{name}[{k}]: rel_err {err:.3e} > {TOL:.0e} (max|ref| {np.abs(np.asarray(r)).max():.3e})"


# --------------------------------------------------------------------------------------------
# the harness itself: MuJoCo vs Pinocchio with numpy transforms (no torch_grid involved)
# --------------------------------------------------------------------------------------------
def test_harness_mujoco_matches_pinocchio(pin_models, mj_sims, robot_name):
    pm, sim = pin_models.get(robot_name), mj_sims.get(robot_name)
    P, rng = PinOracle(pm), np.random.default_rng(0)
    for _ in range(3):
        qp = np.concatenate([rng.normal(size=3), (lambda u: u / np.linalg.norm(u))(rng.normal(size=4)),
                             rng.uniform(-1, 1, size=pm.nq - 7)])
        qm = np.concatenate([qp[:3], qp[[6, 3, 4, 5]], qp[7:]])
        v, a, u = rng.normal(size=(3, pm.nv))
        G, w = G_matrix(qm, pm.nv), v[3:6]
        wxv = np.concatenate([np.cross(w, v[:3]), np.zeros(pm.nv - 3)])
        assert rel_err(sim.full_m(qm), G @ P.crba(qp) @ G.T) <= 1e-12
        assert rel_err(sim.qfrc_inverse(qm, G @ v, G @ (a + wxv)), G @ P.rnea(qp, v, a)) <= 1e-12
        assert rel_err(sim.qfrc_bias(qm, G @ v), G @ P.rnea(qp, v, -wxv)) <= 1e-12
        assert rel_err(sim.qacc(qm, G @ v, u), G @ (P.aba(qp, v, G.T @ u) + wxv)) <= 1e-10
        assert rel_err(sim.energy(qm, G @ v), P.energy(qp, v)) <= 1e-12
        assert rel_err(sim.jac_subtree_com(qm), P.jacobian_com(qp) @ G.T) <= 1e-12


# --------------------------------------------------------------------------------------------
# torch_grid (MuJoCo convention) vs MuJoCo
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", list(MJ_REF))
def test_mujoco_convention_vs_mujoco(robots, mj_sims, robot_name, case):
    robot, sim = robots.get(robot_name), mj_sims.get(robot_name)
    sim.check_joint_order(robot.joint_names)
    s = make_states(robot, seed=1)
    fn, keys = MJ_REF[case]
    check(case, OURS[case](robot.mujoco, s), mj_ref(sim, s, fn, keys))


def test_frame_jacobian_vs_mj_jacBody(robots, mj_sims, robot_name):
    robot, sim = robots.get(robot_name), mj_sims.get(robot_name)
    s = make_states(robot, seed=2)
    for body in bodies_to_test(robot):
        ref = mj_ref(sim, s, lambda m, q: m.jac_body(q, body), [])
        check(f"frame_jacobian({body!r})", robot.mujoco.frame_jacobian(s["q"], body, "local_world_aligned"), ref)


def test_forward_kinematics_vs_mujoco_bodies(robots, mj_sims, robot_name):
    robot, sim = robots.get(robot_name), mj_sims.get(robot_name)
    s = make_states(robot, seed=3)
    bodies = bodies_to_test(robot)
    idx = [robot.frame_names.index(b) for b in bodies]
    pos, rot = robot.mujoco.forward_kinematics(s["q"])
    ref_pos, ref_rot = mj_ref(sim, s, lambda m, q: m.body_poses(q, bodies), [])
    check("forward_kinematics positions", pos[..., idx, :], ref_pos)
    check("forward_kinematics rotations", rot[..., idx, :, :], ref_rot)


def test_mujoco_random_configuration(robots, robot_name, C):
    robot = robots.get(robot_name)
    q = robot.mujoco.random_configuration(5, generator=torch.Generator().manual_seed(4))
    assert q.shape == (5, robot.nq) and q.dtype == torch.float64
    assert torch.allclose(q[..., 3:7].norm(dim=-1), torch.ones(5, dtype=torch.float64), atol=1e-12)
    q_pin = C.q_mujoco_to_pin(q, True)
    for j, iq in zip(robot.model.joints[1:], robot.model.q_index[1:]):
        assert torch.all(q_pin[..., iq] >= j.lower - 1e-12) and torch.all(q_pin[..., iq] <= j.upper + 1e-12), j.name


# --------------------------------------------------------------------------------------------
# torch_grid.conventions: the readable oracle
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", list(OURS))
def test_fused_kernel_matches_conventions_oracle(robots, robot_name, case, C):
    robot = robots.get(robot_name)
    s = make_states(robot, seed=5)
    check(case, OURS[case](robot.mujoco, s), via_conventions(C, robot.pin, case, s))


def test_fused_frame_jacobian_matches_conventions_oracle(robots, robot_name, C):
    robot = robots.get(robot_name)
    s = make_states(robot, seed=6)
    for frame in bodies_to_test(robot) + [robot.frame_names[-1]]:
        for ref in ("local_world_aligned", "local", "world"):
            ours = robot.mujoco.frame_jacobian(s["q"], frame, ref)
            check(f"frame_jacobian({frame!r}, {ref})", ours, C.columns_pin_to_mujoco(s["q_pin"], robot.pin.frame_jacobian(s["q_pin"], frame, ref)))


@pytest.mark.parametrize("case", list(MJ_REF))
def test_conventions_on_pinocchio_match_mujoco(robots, pin_models, mj_sims, robot_name, case, C):
    robot, sim = robots.get(robot_name), mj_sims.get(robot_name)
    s = make_states(robot, seed=7)
    fn, keys = MJ_REF[case]
    check(case, via_conventions(C, PinBatched(robot, pin_models.get(robot_name)), case, s), mj_ref(sim, s, fn, keys))


def test_conventions_frame_jacobian_on_pinocchio_match_mujoco(robots, pin_models, mj_sims, robot_name, C):
    robot, sim = robots.get(robot_name), mj_sims.get(robot_name)
    s = make_states(robot, seed=8)
    pin_api = PinBatched(robot, pin_models.get(robot_name))
    for body in bodies_to_test(robot):
        ours = C.columns_pin_to_mujoco(s["q_pin"], pin_api.frame_jacobian(s["q_pin"], body))
        check(f"conventions frame_jacobian({body!r})", ours, mj_ref(sim, s, lambda m, q: m.jac_body(q, body), []))


def test_conventions_layout_and_round_trips(robots, robot_name, C):
    robot = robots.get(robot_name)
    s = make_states(robot, seed=9)
    qp, qm, v = s["q_pin"], s["q"], s["qd"]
    assert torch.equal(C.q_pin_to_mujoco(qp, True), qm)
    assert torch.equal(C.q_mujoco_to_pin(qm, True), qp)
    # v_lin_pin = R^T v_lin_mujoco with R from the base quaternion; everything past the base untouched
    w, x, y, z = qm[..., 3:7].unbind(-1)
    R = torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(*BATCH, 3, 3)
    vp = C.v_mujoco_to_pin(qp, v)
    expected = v.clone()
    expected[..., :3] = (R.transpose(-1, -2) @ v[..., :3, None])[..., 0]
    assert rel_err(vp, expected) <= 1e-12
    assert rel_err(C.covector_mujoco_to_pin(qp, v), expected) <= 1e-12
    for name, there, back in [
        ("v", lambda x: C.v_mujoco_to_pin(qp, x), lambda x: C.v_pin_to_mujoco(qp, x)),
        ("a", lambda x: C.a_mujoco_to_pin(qp, vp, x), lambda x: C.a_pin_to_mujoco(qp, vp, x)),
        ("covector", lambda x: C.covector_mujoco_to_pin(qp, x), lambda x: C.covector_pin_to_mujoco(qp, x)),
    ]:
        assert rel_err(back(there(s["qdd"])), s["qdd"]) <= 1e-12, f"{name} round trip"
