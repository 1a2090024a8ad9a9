"""Reference implementations the tests compare torch_grid against: Pinocchio and MuJoCo.

No tests here. Everything works on numpy float64 arrays, one state at a time; the `*_batch`
helpers loop over any leading batch shape.

Layouts (see docs/guides/conventions.md):
- torch_grid "pin" q: Pinocchio's q, except a continuous joint has one angle (Pinocchio: cos, sin).
- torch_grid "mujoco" q: MuJoCo's qpos ([pos, quat wxyz, joints]); qvel = [v_lin WORLD, omega LOCAL, ...].
"""
from __future__ import annotations

import re
import site
import sys
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

PACKAGE_ROBOTS = Path(__file__).resolve().parent.parent / "torch_grid" / "robots"
BUNDLED_FLOATING = {"iiwa14": False, "go2": True}
_ERD_SUFFIX = Path("cmeel.prefix") / "share" / "example-robot-data" / "robots"


# --------------------------------------------------------------------------------------------
# generic helpers
# --------------------------------------------------------------------------------------------
def rel_err(ours, ref) -> float:
    """max|ours - ref| / max(max|ref|, 1e-12); shapes must agree exactly."""
    ours = ours.detach().cpu().double().numpy() if hasattr(ours, "detach") else np.asarray(ours, dtype=float)
    ref = ref.detach().cpu().double().numpy() if hasattr(ref, "detach") else np.asarray(ref, dtype=float)
    assert ours.shape == ref.shape, f"shape {ours.shape} != reference shape {ref.shape}"
    if ref.size == 0:
        return 0.0
    return float(np.max(np.abs(ours - ref)) / max(float(np.max(np.abs(ref))), 1e-12))


def batch_apply(fn, *arrays):
    """Apply fn(*one_state_each) over the common leading batch shape of `arrays`.

    Each array's trailing dims are given by `fn`'s per-state convention; the batch shape is taken
    from the first array minus its last dim. fn returns one array or a tuple of arrays.
    """
    batch = arrays[0].shape[:-1]
    flat = [a.reshape(int(np.prod(batch, dtype=int)), *a.shape[len(batch):]) for a in arrays]
    outs = [fn(*(a[i] for a in flat)) for i in range(flat[0].shape[0])]
    if isinstance(outs[0], tuple):
        return tuple(np.stack([o[k] for o in outs]).reshape(*batch, *np.shape(outs[0][k])) for k in range(len(outs[0])))
    return np.stack(outs).reshape(*batch, *np.shape(outs[0]))


def erd_dir() -> Path:
    """example-robot-data's robots directory (installed through cmeel)."""
    roots = [Path(p) for p in site.getsitepackages() + sys.path if p] + [Path(sys.prefix)]
    roots.append(Path(pin.__file__).resolve().parents[4])  # .../cmeel.prefix/lib/pythonX/site-packages/pinocchio
    for r in roots:
        for cand in (r / _ERD_SUFFIX, r / "share" / "example-robot-data" / "robots"):
            if cand.is_dir():
                return cand
    raise FileNotFoundError("example-robot-data robots directory not found (pip install example-robot-data)")


def urdf_path_for(source) -> Path:
    """The URDF file behind a robot source: a bundled name or a path."""
    if isinstance(source, str) and source in BUNDLED_FLOATING:
        return PACKAGE_ROBOTS / f"{source}.urdf"
    return Path(source)


# --------------------------------------------------------------------------------------------
# Pinocchio side
# --------------------------------------------------------------------------------------------
def pin_model_for(source, floating: bool | None) -> pin.Model:
    """Pinocchio model from the same source torch_grid.load gets (bundled name or URDF path)."""
    if floating is None:
        floating = BUNDLED_FLOATING.get(source, False) if isinstance(source, str) else False
    path = str(urdf_path_for(source))
    return pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(path)


def to_pin_q(robot, q) -> np.ndarray:
    """torch_grid pin-layout q (..., nq) -> Pinocchio q (..., pin nq): continuous angle -> (cos, sin)."""
    q = np.asarray(q.detach().cpu().double().numpy() if hasattr(q, "detach") else q, dtype=float)
    parts = []
    for j, iq in zip(robot.model.joints, robot.model.q_index):
        if j.type == "continuous":
            parts += [np.cos(q[..., iq:iq + 1]), np.sin(q[..., iq:iq + 1])]
        else:
            parts.append(q[..., iq:iq + j.nq])
    return np.concatenate(parts, axis=-1)


def pin_forces(pmodel: pin.Model, f) -> list:
    """Pinocchio fext from torch_grid f_ext (nbodies, 6) = [force; torque] per joint frame."""
    if f is None:
        return [pin.Force.Zero() for _ in range(pmodel.njoints)]
    return [pin.Force.Zero()] + [pin.Force(np.asarray(f[i], dtype=float)) for i in range(f.shape[0])]


def _sym_upper(M):
    M = np.array(M)
    return np.triu(M) + np.triu(M, 1).T


class PinOracle:
    """Pinocchio reference for one model; every method takes one state in Pinocchio's layout."""

    def __init__(self, model: pin.Model):
        self.model = model
        self.data = model.createData()

    def rnea(self, q, v, a, f=None):
        if f is None:
            return pin.rnea(self.model, self.data, q, v, a).copy()
        return pin.rnea(self.model, self.data, q, v, a, pin_forces(self.model, f)).copy()

    def aba(self, q, v, tau, f=None):
        if f is None:
            return pin.aba(self.model, self.data, q, v, tau).copy()
        return pin.aba(self.model, self.data, q, v, tau, pin_forces(self.model, f)).copy()

    def crba(self, q):
        return _sym_upper(pin.crba(self.model, self.data, q))

    def minv(self, q):
        return _sym_upper(pin.computeMinverse(self.model, self.data, q))

    def gravity(self, q):
        return pin.computeGeneralizedGravity(self.model, self.data, q).copy()

    def nle(self, q, v):
        return pin.nonLinearEffects(self.model, self.data, q, v).copy()

    def energy(self, q, v):
        pin.forwardKinematics(self.model, self.data, q, v)
        ke = pin.computeKineticEnergy(self.model, self.data, q, v)
        pe = pin.computePotentialEnergy(self.model, self.data, q)
        return np.array([ke, pe, ke + pe])

    def com(self, q):
        return pin.centerOfMass(self.model, self.data, q).copy()

    def jacobian_com(self, q):
        return pin.jacobianCenterOfMass(self.model, self.data, q).copy()

    def ccrba(self, q, v):
        A = pin.ccrba(self.model, self.data, q, v).copy()
        return A, self.data.hg.vector.copy()

    def forward_kinematics(self, q):
        pin.framesForwardKinematics(self.model, self.data, q)
        pos = np.stack([np.array(T.translation) for T in self.data.oMf])
        rot = np.stack([np.array(T.rotation) for T in self.data.oMf])
        return pos, rot

    def end_effector_pose(self, q, frame_ids):
        pin.framesForwardKinematics(self.model, self.data, q)
        return np.stack([np.concatenate([self.data.oMf[i].translation, pin.rpy.matrixToRpy(self.data.oMf[i].rotation)])
                         for i in frame_ids])

    def frame_jacobian(self, q, frame_id, reference):
        ref = {"local_world_aligned": pin.LOCAL_WORLD_ALIGNED, "local": pin.LOCAL, "world": pin.WORLD}[reference]
        return pin.computeFrameJacobian(self.model, self.data, q, frame_id, ref).copy()


# --------------------------------------------------------------------------------------------
# MuJoCo side
# --------------------------------------------------------------------------------------------
_MJ_COMPILER = '<mujoco><compiler fusestatic="false" discardvisual="true" balanceinertia="false"/></mujoco>'


def _urdf_for_mujoco(text: str) -> str:
    text = re.sub(r"<visual\b.*?</visual>", "", text, flags=re.S)
    text = re.sub(r"<collision\b.*?</collision>", "", text, flags=re.S)
    text = re.sub(r"<visual\b[^>]*/>|<collision\b[^>]*/>", "", text)
    text, n = re.subn(r"(<robot\b[^>]*>)", lambda m: m.group(1) + _MJ_COMPILER, text, count=1)
    assert n == 1, "no <robot> element in the URDF"
    return text


class MjSim:
    """A MuJoCo model built from a URDF so that it matches Pinocchio / torch_grid on the same file.

    qpos/qvel given to the methods use torch_grid's MuJoCo layout, which is MuJoCo's own layout
    once the joint orders agree (checked by `check_joint_order`).
    """

    def __init__(self, m: mujoco.MjModel):
        self.m = m
        self.d = mujoco.MjData(m)
        self.floating = m.njnt > 0 and m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
        self.root = 1  # first body below the world: the robot's root link

    def joint_names(self) -> list[str]:
        return [self.m.joint(i).name for i in range(self.m.njnt)]

    def check_joint_order(self, names: list[str]) -> None:
        """MuJoCo's joint order must equal torch_grid's (free joint names may differ)."""
        mj = self.joint_names()
        k = int(self.floating)
        assert len(mj) == len(names) and mj[k:] == list(names[k:]), (
            "MuJoCo joint order differs from torch_grid's, so qpos/qvel layouts would not coincide:\n"
            f"  mujoco:     {mj}\n  torch_grid: {list(names)}")
        assert self.m.nq == sum(1 if self.m.jnt_type[i] != 0 else 7 for i in range(self.m.njnt))

    def _set(self, qpos, qvel=None):
        d = self.d
        mujoco.mj_resetData(self.m, d)
        d.qpos[:] = qpos
        d.qvel[:] = 0.0 if qvel is None else qvel

    def full_m(self, qpos):
        self._set(qpos)
        mujoco.mj_forward(self.m, self.d)
        M = np.zeros((self.m.nv, self.m.nv))
        mujoco.mj_fullM(self.m, self.d, M)
        return M

    def qfrc_inverse(self, qpos, qvel, qacc):
        self._set(qpos, qvel)
        self.d.qacc[:] = qacc
        mujoco.mj_inverse(self.m, self.d)
        return self.d.qfrc_inverse.copy()

    def qfrc_bias(self, qpos, qvel):
        self._set(qpos, qvel)
        mujoco.mj_forward(self.m, self.d)
        return self.d.qfrc_bias.copy()

    def qacc(self, qpos, qvel, qfrc):
        self._set(qpos, qvel)
        self.d.qfrc_applied[:] = qfrc
        mujoco.mj_forward(self.m, self.d)
        return self.d.qacc.copy()

    def jac_body(self, qpos, body: str):
        self._set(qpos)
        mujoco.mj_forward(self.m, self.d)
        jacp, jacr = np.zeros((3, self.m.nv)), np.zeros((3, self.m.nv))
        mujoco.mj_jacBody(self.m, self.d, jacp, jacr, self.m.body(body).id)
        return np.concatenate([jacp, jacr])

    def jac_subtree_com(self, qpos):
        self._set(qpos)
        mujoco.mj_forward(self.m, self.d)
        jacp = np.zeros((3, self.m.nv))
        mujoco.mj_jacSubtreeCom(self.m, self.d, jacp, self.root)
        return jacp

    def subtree_com(self, qpos):
        self._set(qpos)
        mujoco.mj_forward(self.m, self.d)
        return self.d.subtree_com[self.root].copy()

    def body_poses(self, qpos, bodies):
        """World positions (n, 3) and rotations (n, 3, 3) of the named bodies' frames."""
        self._set(qpos)
        mujoco.mj_forward(self.m, self.d)
        ids = [self.m.body(b).id for b in bodies]
        return self.d.xpos[ids].copy(), self.d.xmat[ids].reshape(-1, 3, 3).copy()

    def energy(self, qpos, qvel):
        """[kinetic, potential, kinetic + potential] via mj_energyPos / mj_energyVel."""
        self._set(qpos, qvel)
        mujoco.mj_forward(self.m, self.d)
        mujoco.mj_energyPos(self.m, self.d)
        mujoco.mj_energyVel(self.m, self.d)
        pe, ke = float(self.d.energy[0]), float(self.d.energy[1])
        return np.array([ke, pe, ke + pe])


def mujoco_from_urdf(urdf_path, floating: bool, joint_names: list[str] | None = None) -> MjSim:
    """MuJoCo model of a URDF robot set up to match Pinocchio (MuJoCo's options set to Pinocchio's model)."""
    spec = mujoco.MjSpec.from_string(_urdf_for_mujoco(Path(urdf_path).read_text()))
    if floating:
        spec.worldbody.first_body().add_freejoint()
    m = spec.compile()
    m.opt.gravity[:] = (0.0, 0.0, -9.81)
    m.opt.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONSTRAINT | mujoco.mjtDisableBit.mjDSBL_DAMPER
                           | mujoco.mjtDisableBit.mjDSBL_SPRING)
    assert np.all(m.dof_armature == 0.0), "MuJoCo model has armature; it would not match Pinocchio"
    sim = MjSim(m)
    if joint_names is not None:
        sim.check_joint_order(joint_names)
    return sim


def mujoco_from_mjcf(text: str) -> MjSim:
    """MuJoCo model of an MJCF with contacts and limits off (the rigid-body dynamics torch_grid
    computes); its centroidal quantities are those of every tree (the world body's subtree)."""
    m = mujoco.MjModel.from_xml_string(text)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    sim = MjSim(m)
    sim.root = 0
    return sim


# --------------------------------------------------------------------------------------------
# numpy reference of the pin <-> MuJoCo transforms (docs/guides/conventions.md), used to validate this harness
# --------------------------------------------------------------------------------------------
def quat_wxyz_to_R(qw):
    w, x, y, z = qw
    return pin.Quaternion(w, x, y, z).normalized().toRotationMatrix()


def G_matrix(qpos, nv):
    G = np.eye(nv)
    G[:3, :3] = quat_wxyz_to_R(qpos[3:7])
    return G
