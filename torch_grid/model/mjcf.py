"""MJCF sources and `mujoco.MjModel`s, read from MuJoCo's compiled model: what MuJoCo simulates.

MuJoCo's compiler has already applied defaults, converted degrees, computed inertias from geoms and
ordered bodies depth first; this module only re-expresses its tree as a RobotModel:

- a body with several joints becomes a chain of one-dof joints. MuJoCo moves a body by its joints
  in order, each about its own anchor in the body frame (B = B0 T(a1) J1 T(-a1) T(a2) J2 T(-a2)...),
  so joint k's frame sits at anchor a_k, at a_k - a_(k-1) from the one before; the body's inertia
  goes to the last joint, the others are massless;
- a body without joints is welded to its parent: its inertia joins the parent's, its frame is kept;
- joint, dof and body order are MuJoCo's; bodies and sites are frames, with MuJoCo's names.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from .description import Frame, Joint, RobotModel


def from_mjcf(text: str, path: Path | None, name: str | None) -> RobotModel:
    """Compile an MJCF document (from its file when there is one, so relative includes and assets
    resolve) with MuJoCo and convert the result."""
    mujoco = _mujoco()
    try:
        m = mujoco.MjModel.from_xml_path(str(path)) if path is not None else mujoco.MjModel.from_xml_string(text)
    except ValueError as e:
        raise ValueError(f"source: MuJoCo could not compile the MJCF: {e}") from None
    return from_mujoco(m, name)


def from_mujoco(m, name: str | None = None) -> RobotModel:
    """Convert a compiled `mujoco.MjModel` (hinge, slide and ball joints, and free joints at the roots of
    trees)."""
    mujoco = _mujoco()
    names = _Names(mujoco, m)
    _refuse_unmodelled_couplings(mujoco, m, names)
    _warn_unmodelled(mujoco, m, names)
    springs, dampers = _passive_switches(mujoco, m)
    joints: list[dict] = []
    # MuJoCo body b's frame in the frame of the RobotModel body that carries it: (body, R, p)
    carrier: list[tuple[int, np.ndarray, np.ndarray]] = [(-1, np.eye(3), np.zeros(3))]
    for b in range(1, m.nbody):
        body, Rp, pp = carrier[m.body_parentid[b]]
        R, p = Rp @ _quat(m.body_quat[b]), Rp @ m.body_pos[b] + pp
        anchor = np.zeros(3)
        for jid in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]):
            jname, kind = names.joint(jid), int(m.jnt_type[jid])
            if kind == _FREE:
                # qpos is the body's world pose: the joint sits at the world origin (MuJoCo allows a
                # free joint only alone, in a body under the world).
                R, p, placement = np.eye(3), np.zeros(3), (np.eye(3), np.zeros(3))
            else:
                # A slide's anchor does not move anything: keep the previous one.
                a = anchor if kind == _SLIDE else m.jnt_pos[jid]
                Rj, pj = (R, p + R @ a) if jid == m.body_jntadr[b] else (np.eye(3), a - anchor)
                # MuJoCo moves a hinge or slide by qpos - ref (qpos0): the motion at -ref joins the
                # placement. A ball's qpos is its rotation from the body frame, whatever qpos0.
                ref, axis = float(m.qpos0[m.jnt_qposadr[jid]]), np.asarray(m.jnt_axis[jid], dtype=float)
                if kind == _HINGE:
                    placement = (Rj @ _axis_angle(axis, -ref), pj)
                elif kind == _SLIDE:
                    placement = (Rj, pj - ref * (Rj @ axis))
                else:
                    placement = (Rj, pj)
                anchor = np.array(a, dtype=float)
            if kind in (_FREE, _BALL):
                lower, upper = -math.pi, math.pi
            elif m.jnt_limited[jid]:
                lower, upper = (float(x) for x in m.jnt_range[jid])
            else:
                lower, upper = -math.inf, math.inf
            joints.append(dict(
                name=jname, type=_KIND[kind], parent=body,
                axis=(0.0, 0.0, 0.0) if kind in (_FREE, _BALL) else _tuple(m.jnt_axis[jid]),
                rotation=_tuple(placement[0].reshape(-1)), translation=_tuple(placement[1]),
                lower=lower, upper=upper, **_dof_coefficients(m, jid, jname, kind, springs, dampers), inertia=_Inertia.zero(),
            ))
            body, R, p = len(joints) - 1, np.eye(3), np.zeros(3)
        if m.body_jntnum[b]:
            p = -anchor  # the body frame, seen from its last joint's frame
        carrier.append((body, R, p))
        if body >= 0:  # bodies welded to the world do not move
            ipos, iquat = _used_pose(m.body_ipos[b], m.body_iquat[b], m.body_sameframe[b])
            Ri = R @ _quat(iquat)
            own = _Inertia(float(m.body_mass[b]), R @ ipos + p, Ri @ np.diag(m.body_inertia[b]) @ Ri.T)
            joints[body]["inertia"] = joints[body]["inertia"] + own
    frames = [Frame(name=names.body(b), parent=carrier[b][0], rotation=_tuple(carrier[b][1].reshape(-1)),
                    translation=_tuple(carrier[b][2]), kind="body") for b in range(m.nbody)]
    for s in range(m.nsite):
        b = m.site_bodyid[s]
        body, R, p = carrier[b]
        pos, quat = _used_pose(m.site_pos[s], m.site_quat[s], m.site_sameframe[s],
                               _used_pose(m.body_ipos[b], m.body_iquat[b], m.body_sameframe[b]))
        frames.append(Frame(name=names.site(s), parent=body, rotation=_tuple((R @ _quat(quat)).reshape(-1)),
                            translation=_tuple(R @ pos + p), kind="op"))
    gravity = np.zeros(3) if m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_GRAVITY) else m.opt.gravity
    return RobotModel(
        name=name or names.model() or "robot",
        joints=tuple(Joint(**{k: v for k, v in j.items() if k != "inertia"}, **j["inertia"].fields()) for j in joints),
        frames=tuple(frames), gravity=_tuple(gravity),
        eulerdamp=not m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP),
    )


_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3  # mjtJoint
_KIND = {_FREE: "free", _BALL: "ball", _SLIDE: "prismatic", _HINGE: "revolute"}
_DOFS = {_FREE: 6, _BALL: 3, _SLIDE: 1, _HINGE: 1}


def _dof_coefficients(m, jid: int, jname: str, kind: int, springs: bool, dampers: bool) -> dict:
    """Armature, damping, stiffness and spring reference of a joint (one value over a free or ball
    joint's dofs, as MJCF sets them; a ball's spring reference is a quaternion, which the model refuses
    with a stiffness); no stiffness where the model turns its springs off, no damping where its dampers.
    MuJoCo's nonlinear terms of either (a second coefficient: damping="c0 c1") are refused."""
    dofs = slice(m.jnt_dofadr[jid], m.jnt_dofadr[jid] + _DOFS[kind])
    # MuJoCo 4's higher coefficients (absent before it: no rows)
    damping_poly, stiffness_poly = getattr(m, "dof_dampingpoly", None), getattr(m, "jnt_stiffnesspoly", None)
    for what, rows in (("damping", np.zeros((0,)) if damping_poly is None else damping_poly[dofs]),
                       ("stiffness", np.zeros((0,)) if stiffness_poly is None else stiffness_poly[jid:jid + 1])):
        if np.any(rows != 0):
            raise ValueError(f"joint {jname!r}: {what} has nonlinear coefficients {rows[0].tolist()} (MJCF "
                             f'{what}="c0 c1 ..."), which are not supported: give one coefficient')
    springref = float(m.qpos_spring[m.jnt_qposadr[jid]]) if _DOFS[kind] == 1 else 0.0
    return dict(armature=_one(jname, "armature", m.dof_armature[dofs]),
                damping=_one(jname, "damping", m.dof_damping[dofs]) if dampers else 0.0,
                stiffness=float(m.jnt_stiffness[jid]) if springs else 0.0, springref=springref)


def _passive_switches(mujoco, m) -> tuple[bool, bool]:
    """Whether MuJoCo applies the joints' springs and their dampers: <flag spring="disable"/> and
    damper="disable" (passive="disable" before MuJoCo 3.3) turn them off."""
    off = int(m.opt.disableflags)
    bit = lambda name: int(getattr(mujoco.mjtDisableBit, name, 0))  # noqa: E731  (0: a flag this MuJoCo lacks)
    passive = not off & bit("mjDSBL_PASSIVE")
    return passive and not off & bit("mjDSBL_SPRING"), passive and not off & bit("mjDSBL_DAMPER")


def _one(jname: str, what: str, values: np.ndarray) -> float:
    if np.any(values != values[0]):
        raise ValueError(f"joint {jname!r}: {what} differs between its dofs ({values.tolist()}), which is not supported")
    return float(values[0])


class _Inertia:
    """Mass, centre of mass and rotational inertia about it, in one frame; + is the composite body."""

    def __init__(self, mass: float, com: np.ndarray, about_com: np.ndarray):
        self.mass, self.com, self.about_com = mass, np.asarray(com, dtype=float), np.asarray(about_com, dtype=float)

    @classmethod
    def zero(cls) -> "_Inertia":
        return cls(0.0, np.zeros(3), np.zeros((3, 3)))

    def __add__(self, other: "_Inertia") -> "_Inertia":
        mass = self.mass + other.mass
        com = (self.mass * self.com + other.mass * other.com) / mass if mass > 0 else np.zeros(3)
        about = self.about_com + other.about_com
        for part in (self, other):  # parallel axes: each part's offset from the new centre
            d = part.com - com
            about = about + part.mass * (d @ d * np.eye(3) - np.outer(d, d))
        return _Inertia(mass, com, about)

    def fields(self) -> dict:
        return dict(mass=self.mass, com=_tuple(self.com), inertia=_tuple(self.about_com.reshape(-1)))


class _Names:
    """MuJoCo's names, and a stand-in for an unnamed object: body3, joint2, site0."""

    def __init__(self, mujoco, m):
        self._mujoco, self._m = mujoco, m

    def _get(self, kind, index: int, stem: str) -> str:
        return self._mujoco.mj_id2name(self._m, kind, index) or f"{stem}{index}"

    def body(self, b: int) -> str:
        return self._get(self._mujoco.mjtObj.mjOBJ_BODY, b, "body")

    def joint(self, j: int) -> str:
        return self._get(self._mujoco.mjtObj.mjOBJ_JOINT, j, "joint")

    def site(self, s: int) -> str:
        return self._get(self._mujoco.mjtObj.mjOBJ_SITE, s, "site")

    def model(self) -> str | None:
        return bytes(self._m.names).split(b"\0", 1)[0].decode() or None  # the first of MuJoCo's names


def _refuse_unmodelled_couplings(mujoco, m, names: _Names) -> None:
    """Raise for what would change the dynamics torch_grid computes without it being modelled."""
    obj = mujoco.mjtObj
    # MuJoCo applies no equality constraint under <flag equality="disable"/> or constraint="disable"
    off = int(m.opt.disableflags) & int(mujoco.mjtDisableBit.mjDSBL_EQUALITY | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    for e in range(0 if off else m.neq):
        ename = mujoco.mj_id2name(m, obj.mjOBJ_EQUALITY, e) or f"equality{e}"
        raise ValueError(f"MJCF equality constraint {ename!r} couples bodies or joints, which is not supported")
    for t in range(m.ntendon):
        tname = mujoco.mj_id2name(m, obj.mjOBJ_TENDON, t) or f"tendon{t}"
        for what, value in (("stiffness", m.tendon_stiffness[t]), ("damping", m.tendon_damping[t]),
                            ("armature", getattr(m, "tendon_armature", np.zeros(m.ntendon))[t]),
                            ("nonlinear stiffness", getattr(m, "tendon_stiffnesspoly", np.zeros((m.ntendon, 1)))[t]),
                            ("nonlinear damping", getattr(m, "tendon_dampingpoly", np.zeros((m.ntendon, 1)))[t])):
            if np.any(value != 0):
                raise ValueError(f"MJCF tendon {tname!r} has {what} {value}: its passive forces couple joints, "
                                 "which is not supported")
    for b in range(m.nbody):
        if m.body_gravcomp[b] != 0:
            raise ValueError(f"body {names.body(b)!r} has gravcomp {m.body_gravcomp[b]}, which is not supported")
    if getattr(m, "nflex", 0):
        fname = mujoco.mj_id2name(m, obj.mjOBJ_FLEX, 0) or "flex0"
        raise ValueError(f"MJCF flex {fname!r} ({m.nflex} in all) is a deformable object: its elastic forces and "
                         "contacts act on its vertices' joints, which is not supported")
    for j in range(m.njnt):
        if getattr(m, "jnt_springyield", np.zeros(m.njnt))[j] > 0 and m.jnt_stiffness[j] != 0:
            raise ValueError(f"joint {names.joint(j)!r} has springyield {m.jnt_springyield[j]}: its spring's rest "
                             "position moves as the simulation runs (plasticity), which is not supported")
    for a in range(m.nu):
        # MuJoCo adds an actuator's armature and damping to its transmission's inertia and passive force
        # (times gear^2 on a joint), with or without its control
        for what in ("armature", "damping", "dampingpoly"):
            value = getattr(m, f"actuator_{what}", np.zeros((m.nu, 1)))[a]
            if np.any(value != 0):
                aname = mujoco.mj_id2name(m, obj.mjOBJ_ACTUATOR, a) or f"actuator{a}"
                raise ValueError(f"MJCF actuator {aname!r} has {what} {np.ravel(value).tolist()}: it adds to its "
                                 f"transmission's {'inertia' if what == 'armature' else 'passive forces'}, which "
                                 "is not supported; give the joint the equivalent (times gear^2) instead")


def _warn_unmodelled(mujoco, m, names: _Names) -> None:
    """One warning listing what MuJoCo simulates beyond the rigid-body dynamics torch_grid computes."""
    bits = {k: int(v) for k, v in mujoco.mjtDisableBit.__members__.items()}
    off = int(m.opt.disableflags)
    if off & bits["mjDSBL_CONSTRAINT"]:  # the whole constraint solver: contacts, limits and friction loss
        off |= bits["mjDSBL_CONTACT"] | bits["mjDSBL_LIMIT"] | bits["mjDSBL_FRICTIONLOSS"]
    found = []
    if m.nu:
        found.append(f"{m.nu} actuators")
    if m.ntendon:
        acts = ["actuation"] + [what for what, bit in (("limits", "mjDSBL_LIMIT"), ("friction loss", "mjDSBL_FRICTIONLOSS"))
                                if not off & bits[bit]]
        found.append(f"{m.ntendon} tendons ({', '.join(acts)})")
    if not off & bits["mjDSBL_CONTACT"] and (m.npair or np.any((m.geom_contype != 0) | (m.geom_conaffinity != 0))):
        found.append(f"contacts{f' ({m.npair} explicit pairs)' if m.npair else ''}")
    limited = [names.joint(j) for j in range(m.njnt) if m.jnt_limited[j]]
    if limited and not off & bits["mjDSBL_LIMIT"]:
        found.append(f"joint limits ({', '.join(limited[:5])}{', ...' if len(limited) > 5 else ''})")
    if np.any(m.dof_frictionloss != 0) and not off & bits["mjDSBL_FRICTIONLOSS"]:
        found.append("joint friction loss")
    if getattr(m, "nplugin", 0):
        found.append(f"{m.nplugin} plugins (the forces they apply)")
    if m.opt.density > 0 or m.opt.viscosity > 0:
        found.append("fluid forces")
    if int(m.opt.enableflags) & int(getattr(mujoco.mjtEnableBit, "mjENBL_SLEEP", 0)):
        found.append("sleep (MuJoCo's step stops trees that come to rest; step here does not)")
    if int(m.opt.enableflags) & int(getattr(mujoco.mjtEnableBit, "mjENBL_INVDISCRETE", 0)):
        found.append("invdiscrete (mj_inverse of a discrete step's acceleration; inverse_dynamics here is continuous-time)")
    if found:
        warnings.warn(f"the MJCF model has {'; '.join(found)}: torch_grid computes the rigid-body dynamics "
                      "without them", stacklevel=4)


_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def _used_pose(pos, quat, sameframe: int, inertial=None) -> tuple[np.ndarray, np.ndarray]:
    """The pose in its body's frame that MuJoCo's kinematics use (mj_local2Global): where the compiler
    marked the frame as the body's or the inertial frame (mjtSameFrame: within its ~1e-6 tolerance, or
    pos and quat edited on the MjModel after compiling), MuJoCo takes that frame and ignores the
    stored pos or quat. inertial: the body's inertial pose, for a site."""
    pos, quat = np.asarray(pos, dtype=float), np.asarray(quat, dtype=float)
    if sameframe == 1:  # mjSAMEFRAME_BODY
        return np.zeros(3), _IDENTITY
    if sameframe == 2:  # mjSAMEFRAME_INERTIA
        return inertial
    if sameframe == 3:  # mjSAMEFRAME_BODYROT
        return pos, _IDENTITY
    if sameframe == 4:  # mjSAMEFRAME_INERTIAROT
        return pos, inertial[1]
    return pos, quat


def _quat(q) -> np.ndarray:
    """Rotation matrix of MuJoCo's unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by angle about the unit axis (Rodrigues)."""
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)


def _tuple(v) -> tuple[float, ...]:
    return tuple(float(x) for x in np.asarray(v).reshape(-1))


def _mujoco():
    try:
        import mujoco
    except ImportError:
        raise ImportError("MuJoCo is needed to read MJCF: pip install mujoco") from None
    return mujoco
