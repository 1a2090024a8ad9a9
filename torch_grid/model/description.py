"""Plain, serializable description of a kinematic tree: everything the kernels are generated from.

A `RobotModel` is independent of Pinocchio once built: it saves to JSON, loads back, and carries a
content hash that keys the kernel build cache. Body `i` is the body moved by joint `i`; fixed
joints are already merged into their parent body, exactly as Pinocchio's model does.
"""
from __future__ import annotations

import difflib
import hashlib
import json
import math
import numbers
import warnings
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

JOINT_TYPES = ("free", "ball", "revolute", "continuous", "prismatic")
FORMAT_VERSION = 1


@dataclass(frozen=True)
class Joint:
    """The joint that moves one body, and that body's inertia, in the joint frame."""

    name: str
    type: str  # one of JOINT_TYPES
    parent: int  # index of the parent body, -1 for the world
    axis: tuple[float, float, float]  # unit axis in the joint frame (unused for "free" and "ball")
    rotation: tuple[float, ...]  # placement in the parent joint frame at q = 0, row-major 3x3
    translation: tuple[float, float, float]
    mass: float
    com: tuple[float, float, float]  # centre of mass in the joint frame
    inertia: tuple[float, ...]  # rotational inertia about the centre of mass, row-major 3x3
    lower: float = -math.pi  # position limits (1-dof joints)
    upper: float = math.pi
    armature: float = 0.0  # rotor inertia on each dof (not a free joint's), added to M's diagonal
    damping: float = 0.0  # passive force -damping qd - stiffness (q - springref) (damping: not a free joint;
    stiffness: float = 0.0  # stiffness: 1-dof joints)
    springref: float = 0.0

    @property
    def nq(self) -> int:
        """Configuration size: a free joint [pos(3), quat(4)], a ball joint [quat(4)], else 1."""
        return {"free": 7, "ball": 4}.get(self.type, 1)

    @property
    def nv(self) -> int:
        """Velocity size: a free joint [v_lin, w], a ball joint the local angular velocity w, else 1."""
        return {"free": 6, "ball": 3}.get(self.type, 1)


@dataclass(frozen=True)
class Frame:
    """A named frame rigidly attached to a body (or to the world when parent is -1)."""

    name: str
    parent: int
    rotation: tuple[float, ...]  # placement in the parent joint frame, row-major 3x3
    translation: tuple[float, float, float]
    kind: str = "op"  # Pinocchio's frame type: body, joint, fixed_joint, op, sensor


@dataclass(frozen=True)
class Mimic:
    """A coupled joint: q[joint] = multiplier * q[master] + offset (URDF <mimic>)."""

    joint: str
    master: str
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class RobotModel:
    """A robot's kinematic tree, joints in depth-first order (every parent before its children).

    `mimics` couples joints (reduced coordinates, torch_grid/ops/mimic.py); the kernels are those of the
    tree with every joint independent (`kernel_model`), and nq, nv, q_index, v_index are theirs.
    """

    name: str
    joints: tuple[Joint, ...]
    frames: tuple[Frame, ...]
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    mimics: tuple[Mimic, ...] = ()
    # MuJoCo's Euler step (semi_implicit_euler) takes the joint damping implicitly: (M + dt D) qdd = ... (mj_Euler;
    # an MJCF's <flag eulerdamp="disable"/> turns it off). Read by the step, not the kernels' constants.
    eulerdamp: bool = True
    _hash: str = field(default="", compare=False, repr=False)

    def __post_init__(self) -> None:
        validate(self)
        object.__setattr__(self, "_hash", hashlib.sha256(self.to_json().encode()).hexdigest())
        named: dict[str, list[int]] = {}  # frame name -> indices, for frame_index (not a field: not saved)
        for i, f in enumerate(self.frames):
            named.setdefault(f.name, []).append(i)
        object.__setattr__(self, "_frames_named", named)

    # -- sizes and layout --------------------------------------------------------------------
    @property
    def nbodies(self) -> int:
        """The number of moving bodies: one per joint."""
        return len(self.joints)

    @property
    def nq(self) -> int:
        """The size of a configuration q (a free joint counts 7, a ball joint 4)."""
        return sum(j.nq for j in self.joints)

    @property
    def nv(self) -> int:
        """The size of a velocity qd (a free joint counts 6, a ball joint 3)."""
        return sum(j.nv for j in self.joints)

    @property
    def floating_base(self) -> bool:
        """Whether the first joint is free (the first tree's root; other trees may have free roots too)."""
        return bool(self.joints) and self.joints[0].type == "free"

    @property
    def kernel_model(self) -> "RobotModel":
        """The same tree with every joint independent: what the kernels are generated from."""
        return replace(self, mimics=(), eulerdamp=True) if self.mimics or not self.eulerdamp else self

    @property
    def conventions_differ(self) -> bool:
        """Whether the MuJoCo convention differs from Pinocchio's: a quaternion joint (free or ball)."""
        return any(j.type in ("free", "ball") for j in self.joints)

    @property
    def placed_free_joint(self) -> str | None:
        """The first free joint placed away from the world's origin (a pinocchio.Model's FreeFlyer may be), or
        None: MuJoCo's convention has none, a free joint's qpos being its body's world pose."""
        origin = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)  # rotation, translation
        for j in self.joints:
            if j.type == "free" and max(abs(a - b) for a, b in zip(j.rotation + j.translation, origin)) > 1e-12:
                return j.name
        return None

    @property
    def has_armature(self) -> bool:
        """Whether any joint has a rotor armature (added to M's diagonal)."""
        return any(j.armature for j in self.joints)

    @property
    def q_index(self) -> list[int]:
        """First configuration coordinate of each joint."""
        return _offsets([j.nq for j in self.joints])

    @property
    def v_index(self) -> list[int]:
        """First velocity coordinate of each joint."""
        return _offsets([j.nv for j in self.joints])

    @property
    def hash(self) -> str:
        """Content hash (sha256 hex) of the canonical JSON description."""
        return self._hash

    def frame_index(self, frame: str | int, argument: str = "frame") -> int:
        """Index in `frames` of a frame given by name or index; a name several frames share (a URDF link and a
        joint, say) is refused, as Pinocchio's getFrameId refuses it, naming their indices. `argument` names
        the caller's argument in the errors."""
        if isinstance(frame, bool) or not isinstance(frame, (str, numbers.Integral)):
            raise TypeError(f"{argument} must be a frame name or index, got {type(frame).__name__}")
        if isinstance(frame, numbers.Integral):
            frame = int(frame)
            if not 0 <= frame < len(self.frames):
                raise ValueError(f"{argument}: frame index {frame} is out of range [0, {len(self.frames)})")
            return frame
        if frame not in self._frames_named:
            close = difflib.get_close_matches(frame, self._frames_named, n=3)
            hint = f"; did you mean {', '.join(map(repr, close))}?" if close else ""
            raise ValueError(f"{argument}: {self.name!r} has no frame named {frame!r}{hint}")
        found = self._frames_named[frame]
        if len(found) > 1:
            which = ", ".join(f"{i} ({self.frames[i].kind})" for i in found)
            raise ValueError(f"{argument}: {self.name!r} has {len(found)} frames named {frame!r}, at indices {which}; "
                             "give the frame's index")
        return found[0]

    # -- serialization -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The description as plain data (lists, numbers, strings), with its format version."""
        d = asdict(self)
        d.pop("_hash")
        if d["eulerdamp"]:  # the default: a description without it reads the same
            d.pop("eulerdamp")
        d["format"] = FORMAT_VERSION
        return d

    def to_json(self) -> str:
        """The description as canonical JSON: compact, keys sorted (its hash is this text's)."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_dict(cls, d: dict) -> "RobotModel":
        """The model of `to_dict`'s data; ValueError for another format version."""
        if d.get("format") != FORMAT_VERSION:
            raise ValueError(f"model format {d.get('format')!r} is not supported (expected {FORMAT_VERSION})")
        joints = tuple(Joint(**{k: _tuple(v) for k, v in j.items()}) for j in d["joints"])
        frames = tuple(Frame(**{k: _tuple(v) for k, v in f.items()}) for f in d["frames"])
        mimics = tuple(Mimic(**m) for m in d.get("mimics", ()))
        return cls(name=d["name"], joints=joints, frames=frames, gravity=tuple(d["gravity"]), mimics=mimics,
                   eulerdamp=bool(d.get("eulerdamp", True)))

    def save(self, path: str | Path) -> None:
        """Write the description as JSON to `path` (`torch_grid.load(path)` builds it)."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1, sort_keys=True))

    @classmethod
    def load(cls, path: str | Path) -> "RobotModel":
        """The model saved at `path` by `save`."""
        try:
            saved = json.loads(Path(path).read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"{str(path)!r} is not a saved robot model (RobotModel.save writes JSON): {e}") from None
        if not isinstance(saved, dict) or "joints" not in saved:
            raise ValueError(f"{str(path)!r} is JSON but not a saved robot model (RobotModel.save): it has no joints")
        return cls.from_dict(saved)


# -- validation --------------------------------------------------------------------------------
# URDF and MJCF inertias are decimals rounded to a few digits, and Pinocchio rounds again when it
# merges fixed links, so the inertia checks allow an excess this small relative to the trace of the
# body's inertia about its joint origin, the scale at which the body enters the joint-space inertia M.
INERTIA_RTOL = 1e-6
# A joint's diagonal block of M counts as zero below this, relative to the same scale: float rounding.
SINGULAR_RTOL = 1e-12
# Axis norms and rotation matrices: rounding of a computed value passes, a hand-typed approximation not.
UNIT_TOL = 1e-9


def inertia_about_origin(mass: float, com, inertia) -> list[float]:
    """Rotational inertia (row-major 3x3) about the joint frame origin: I_c - m [c]x^2."""
    c2 = com[0] * com[0] + com[1] * com[1] + com[2] * com[2]  # in this order on every Python (3.12's sum() compensates)
    return [inertia[3 * r + k] + mass * ((c2 if r == k else 0.0) - com[r] * com[k]) for r in range(3) for k in range(3)]


def with_armature(model: RobotModel, armature: Mapping[str, float]) -> RobotModel:
    """The same model with the given joints' armature (rotor inertia, kg m^2 or kg), by joint name."""
    if not isinstance(armature, Mapping):
        raise TypeError(f"armature must be a mapping from joint name to value, got {type(armature).__name__}")
    names = [j.name for j in model.joints]
    unknown = [name for name in armature if name not in names]
    if unknown:
        raise ValueError(f"armature: no joint named {unknown[0]!r} (joints: {', '.join(names)})")
    joints = tuple(replace(j, armature=armature[j.name]) if j.name in armature else j for j in model.joints)
    return replace(model, joints=joints)


def validate(model: RobotModel) -> None:
    """Raise ValueError, naming the joint, link or frame and the offending value, for a model the
    kernels would turn into silently wrong numbers (or that they do not support)."""
    joints = model.joints
    for i, j in enumerate(joints):
        if j.type not in JOINT_TYPES:
            raise ValueError(f"joint {j.name!r}: type must be one of {JOINT_TYPES}, got {j.type!r}")
        if not -1 <= j.parent < i:
            raise ValueError(f"joint {j.name!r}: parent {j.parent} must precede it (depth-first order)")
        # Depth-first: each subtree is one run of indices (the kernels rely on it), so the parent is
        # the previous joint or one of its ancestors.
        ancestor = i - 1
        while ancestor > j.parent:
            ancestor = joints[ancestor].parent
        if i > 0 and ancestor != j.parent:
            raise ValueError(f"joint {j.name!r}: joints must be in depth-first order (each subtree contiguous), but "
                             f"its parent {joints[j.parent].name if j.parent >= 0 else 'world'!r} is not an ancestor of "
                             f"the joint before it, {joints[i - 1].name!r}")
        if j.type == "free" and j.parent != -1:
            raise ValueError(f"joint {j.name!r}: a free joint is only supported at the root of a tree (its parent "
                             f"the world), but its parent is {joints[j.parent].name!r}")
    for f in model.frames:
        if not -1 <= f.parent < len(joints):
            raise ValueError(f"frame {f.name!r}: parent {f.parent} is not a body index")
    _check_vector("gravity", model.gravity, 3)
    links = _link_names(model)
    for i, j in enumerate(joints):
        _check_joint(j, links.get(i))
    for f in model.frames:
        _check_placement(f"frame {f.name!r}", f.rotation, f.translation)
    _check_moves_inertia(joints)
    _check_mimics(model)


def check_triangle_inequality(model: RobotModel, strict: bool = False) -> None:
    """Warn, or raise ValueError where `strict`, naming every body whose principal moments of inertia
    about the centre of mass break the triangle inequality (one larger than the sum of the other two),
    in one message for the whole model.

    No distribution of mass has such an inertia, but it is still symmetric positive semi-definite: the
    dynamics are well defined (Pinocchio computes them) and published URDFs carry some. So `validate`,
    which runs on every model built, leaves it alone, and `load` calls this once per robot."""
    links = _link_names(model)
    broken = []
    for i, j in enumerate(model.joints):
        low, mid, high = _symmetric_eigenvalues(j.inertia)
        if high > low + mid + INERTIA_RTOL * _origin_inertia_trace(j):
            broken.append(f"{_body_label(j, links.get(i))} has principal moments ({low:.9g}, {mid:.9g}, {high:.9g}): "
                          f"{high:.9g} > {low:.9g} + {mid:.9g}")
    if not broken:
        return
    message = ("inertia about the centre of mass must satisfy the triangle inequality (no rigid body has a principal "
               f"moment larger than the sum of the other two), but {'; '.join(broken)}")
    if strict:
        raise ValueError(message)
    warnings.warn(f"{message}. The dynamics are computed with these inertias as given, as Pinocchio does; "
                  "load(..., strict_inertia=True) refuses them", stacklevel=3)  # at load's caller


def _check_mimics(model: RobotModel) -> None:
    """Each mimic couples a one-dof joint to another one-dof joint, once, and following the masters
    ends at an independent joint (no cycle)."""
    kinds = {j.name: j.type for j in model.joints}
    coupled = set()
    for m in model.mimics:
        who = f"mimic joint {m.joint!r}"
        for role, name in (("joint", m.joint), ("master", m.master)):
            if name not in kinds:
                raise ValueError(f"{who}: {role} {name!r} is not a joint of the model")
            if kinds[name] not in ("revolute", "continuous", "prismatic"):
                raise ValueError(f"{who}: {role} {name!r} is a {kinds[name]} joint; only one-dof joints can be coupled")
        if m.joint == m.master:
            raise ValueError(f"{who}: mimics itself; a mimic joint follows another joint")
        if m.joint in coupled:
            raise ValueError(f"{who}: mimics {m.master!r}, but a joint can mimic one other joint only once")
        for name in ("multiplier", "offset"):
            _check_number(f"{who}: {name}", getattr(m, name))
        coupled.add(m.joint)
    master = {m.joint: m.master for m in model.mimics}
    for m in model.mimics:
        seen, name = [m.joint], m.master
        while name in master:
            if name in seen:
                raise ValueError(f"mimic joint {m.joint!r}: its masters form a cycle ({' -> '.join(seen + [name])})")
            seen.append(name)
            name = master[name]


def _link_names(model: RobotModel) -> dict[int, str]:
    """Body index -> its first body frame, the link the source file names (absent in hand-built models)."""
    names: dict[int, str] = {}
    for f in model.frames:
        if f.kind == "body" and f.parent >= 0:
            names.setdefault(f.parent, f.name)
    return names


def _body_label(j: Joint, link: str | None) -> str:
    """How messages name a body: by its joint, and by its link where the source file names one."""
    return f"joint {j.name!r}" if link is None else f"joint {j.name!r} (link {link!r})"


def _check_joint(j: Joint, link: str | None) -> None:
    who = f"joint {j.name!r}"
    body = _body_label(j, link)
    _check_vector(f"{who}: axis", j.axis, 3)
    _check_placement(who, j.rotation, j.translation)
    for limit in ("lower", "upper"):
        value = getattr(j, limit)
        if not _is_number(value) or math.isnan(value):
            raise ValueError(f"{who}: {limit} limit must be a number or +-inf (unbounded), got {value!r}")
    if j.type not in ("free", "ball"):
        norm = math.hypot(*j.axis)
        if abs(norm - 1) > UNIT_TOL:
            raise ValueError(f"{who}: axis must be a unit vector, got {j.axis!r} (norm {norm:.9g})")
    for name in ("armature", "damping", "stiffness", "springref"):
        value = getattr(j, name)
        _check_number(f"{who}: {name}", value)
        if name != "springref" and value < 0:
            raise ValueError(f"{who}: {name} must be >= 0, got {value!r}")
        if value != 0 and (j.type == "free" or (j.type == "ball" and name in ("stiffness", "springref"))):
            raise ValueError(f"{who}: {name} on a {j.type} joint is not supported, got {value!r}")
    _check_number(f"{body}: mass", j.mass)
    if j.mass < 0:
        raise ValueError(f"{body}: mass must be >= 0, got {j.mass!r}")
    _check_vector(f"{body}: com", j.com, 3)
    _check_vector(f"{body}: inertia", j.inertia, 9)
    _check_inertia(body, j)


def _check_inertia(body: str, j: Joint) -> None:
    """Symmetric and positive semi-definite (the triangle inequality is `check_triangle_inequality`'s)."""
    inertia = j.inertia
    tol = INERTIA_RTOL * _origin_inertia_trace(j)
    for r, k in ((0, 1), (0, 2), (1, 2)):
        if abs(inertia[3 * r + k] - inertia[3 * k + r]) > tol:
            rk, kr = "xyz"[r] + "xyz"[k], "xyz"[k] + "xyz"[r]
            raise ValueError(f"{body}: inertia must be symmetric, got I{rk}={inertia[3 * r + k]!r} "
                             f"but I{kr}={inertia[3 * k + r]!r}")
    low, mid, high = _symmetric_eigenvalues(inertia)
    if low < -tol:
        raise ValueError(f"{body}: inertia about the centre of mass must be positive semi-definite, got principal "
                         f"moments ({low:.9g}, {mid:.9g}, {high:.9g})")


def _check_moves_inertia(joints: tuple[Joint, ...]) -> None:
    """Refuse a joint whose motion moves neither mass nor inertia: M is then singular at every q.

    Where the joint's subtree holds mass beyond its own body, whether M is singular depends on the
    configuration, so only joints whose descendants are all massless are decided here, from their
    own body (a massless subtree, or a point mass on a revolute axis)."""
    heavy_below = [False] * len(joints)  # some descendant has mass or inertia
    for i in reversed(range(len(joints))):
        p = joints[i].parent
        if p >= 0:
            heavy_below[p] = heavy_below[p] or heavy_below[i] or _has_inertia(joints[i])
    for j, below in zip(joints, heavy_below):
        if below:
            continue
        scale = _origin_inertia_trace(j)
        if not _has_inertia(j):
            raise ValueError(f"joint {j.name!r}: the links it moves have no mass and no inertia, so the "
                             "joint-space inertia matrix is singular")
        if j.type == "prismatic" and j.mass == 0:
            raise ValueError(f"joint {j.name!r}: the links it moves have no mass (only rotational inertia, "
                             "which a sliding joint does not move), so the joint-space inertia matrix is singular")
        if j.type in ("revolute", "continuous") and _axis_inertia(j) <= SINGULAR_RTOL * scale:
            mass = "no mass" if j.mass == 0 else f"mass {j.mass!r} centred at {j.com!r}, on the axis"
            raise ValueError(f"joint {j.name!r}: the links it moves have no inertia about its axis {j.axis!r} "
                             f"({mass}, and no rotational inertia about it), so the joint-space inertia "
                             "matrix is singular")
        if j.type == "ball":
            low = _symmetric_eigenvalues(inertia_about_origin(j.mass, j.com, j.inertia))[0]
            if low <= SINGULAR_RTOL * scale:
                raise ValueError(f"joint {j.name!r}: a ball joint's links need a positive definite rotational inertia "
                                 f"about the joint, got smallest principal moment {low:.9g} there, so the joint-space "
                                 "inertia matrix is singular")
        if j.type == "free":
            low = _symmetric_eigenvalues(j.inertia)[0]
            if j.mass == 0 or low <= SINGULAR_RTOL * scale:
                raise ValueError(f"joint {j.name!r}: a free body needs mass and a positive definite rotational "
                                 f"inertia, got mass {j.mass!r} and smallest principal moment {low:.9g}, so the "
                                 "joint-space inertia matrix is singular")


def _has_inertia(j: Joint) -> bool:
    return j.mass != 0 or any(x != 0 for x in j.inertia)


def _origin_inertia_trace(j: Joint) -> float:
    """Trace of the body's inertia about its joint origin (diagonal magnitudes, so never negative)."""
    return sum(abs(j.inertia[4 * k]) for k in range(3)) + 2 * j.mass * sum(c * c for c in j.com)


def _axis_inertia(j: Joint) -> float:
    """Moment of inertia of the body about the joint axis through the joint origin."""
    a, c, inertia = j.axis, j.com, j.inertia
    about_com = sum(a[r] * inertia[3 * r + k] * a[k] for r in range(3) for k in range(3))
    along = sum(x * y for x, y in zip(a, c))
    return about_com + j.mass * (sum(x * x for x in c) - along * along)


def _check_placement(who: str, rotation: tuple[float, ...], translation: tuple[float, float, float]) -> None:
    _check_vector(f"{who}: rotation", rotation, 9)
    _check_vector(f"{who}: translation", translation, 3)
    r = rotation
    orthonormal = all(abs(sum(r[3 * a + k] * r[3 * b + k] for k in range(3)) - (a == b)) <= UNIT_TOL
                      for a in range(3) for b in range(a, 3))
    det = (r[0] * (r[4] * r[8] - r[5] * r[7]) - r[1] * (r[3] * r[8] - r[5] * r[6])
           + r[2] * (r[3] * r[7] - r[4] * r[6]))
    if not orthonormal or det < 0:
        raise ValueError(f"{who}: rotation must be a rotation matrix (orthonormal rows, determinant +1), "
                         f"got {rotation!r} (determinant {det:.9g})")


def _check_vector(what: str, values, size: int) -> None:
    if (not isinstance(values, (tuple, list)) or len(values) != size
            or not all(_is_number(x) and math.isfinite(x) for x in values)):
        raise ValueError(f"{what} must be {size} finite numbers, got {values!r}")


def _check_number(what: str, value) -> None:
    if not _is_number(value) or not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, got {value!r}")


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _symmetric_eigenvalues(m: tuple[float, ...]) -> tuple[float, float, float]:
    """Ascending eigenvalues of the symmetric part of a row-major 3x3 matrix (cyclic Jacobi rotations)."""
    a = [[(m[3 * r + k] + m[3 * k + r]) / 2 for k in range(3)] for r in range(3)]
    for _ in range(32):  # converges quadratically: about six sweeps leave exact zeros off the diagonal
        if a[0][1] == a[0][2] == a[1][2] == 0:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if a[p][q] == 0:
                continue
            theta = (a[q][q] - a[p][p]) / (2 * a[p][q])
            t = math.copysign(1.0, theta) / (abs(theta) + math.hypot(theta, 1.0))
            c = 1 / math.hypot(t, 1.0)
            s = t * c
            for row in a:  # A <- A P, then A <- P^T A, with P the rotation in the (p, q) plane
                row[p], row[q] = c * row[p] - s * row[q], s * row[p] + c * row[q]
            a[p], a[q] = [c * x - s * y for x, y in zip(a[p], a[q])], [s * x + c * y for x, y in zip(a[p], a[q])]
            a[p][q] = a[q][p] = 0.0  # their exact value; what rounding leaves would never settle
    low, mid, high = sorted(a[k][k] for k in range(3))
    return low, mid, high


def _offsets(sizes: list[int]) -> list[int]:
    out, acc = [], 0
    for s in sizes:
        out.append(acc)
        acc += s
    return out


def _tuple(v):
    return tuple(v) if isinstance(v, list) else v
