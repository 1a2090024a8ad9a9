"""Plain, serializable description of a kinematic tree: everything the kernels are generated from.

A `RobotModel` is independent of Pinocchio once built: it saves to JSON, loads back, and carries a
content hash that keys the kernel build cache. Body `i` is the body moved by joint `i`; fixed
joints are already merged into their parent body, exactly as Pinocchio's model does.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

JOINT_TYPES = ("free", "revolute", "continuous", "prismatic")
FORMAT_VERSION = 1


@dataclass(frozen=True)
class Joint:
    """The joint that moves one body, and that body's inertia, in the joint frame."""

    name: str
    type: str  # one of JOINT_TYPES
    parent: int  # index of the parent body, -1 for the world
    axis: tuple[float, float, float]  # unit axis in the joint frame (unused for "free")
    rotation: tuple[float, ...]  # placement in the parent joint frame at q = 0, row-major 3x3
    translation: tuple[float, float, float]
    mass: float
    com: tuple[float, float, float]  # centre of mass in the joint frame
    inertia: tuple[float, ...]  # rotational inertia about the centre of mass, row-major 3x3
    lower: float = -math.pi  # position limits (1-dof joints)
    upper: float = math.pi

    @property
    def nq(self) -> int:
        return 7 if self.type == "free" else 1

    @property
    def nv(self) -> int:
        return 6 if self.type == "free" else 1


@dataclass(frozen=True)
class Frame:
    """A named frame rigidly attached to a body (or to the world when parent is -1)."""

    name: str
    parent: int
    rotation: tuple[float, ...]  # placement in the parent joint frame, row-major 3x3
    translation: tuple[float, float, float]
    kind: str = "op"  # Pinocchio's frame type: body, joint, fixed_joint, op, sensor


@dataclass(frozen=True)
class RobotModel:
    """A robot's kinematic tree, joints in depth-first order (every parent before its children)."""

    name: str
    joints: tuple[Joint, ...]
    frames: tuple[Frame, ...]
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    _hash: str = field(default="", compare=False, repr=False)

    def __post_init__(self) -> None:
        for i, j in enumerate(self.joints):
            if j.type not in JOINT_TYPES:
                raise ValueError(f"joint {j.name!r}: type must be one of {JOINT_TYPES}, got {j.type!r}")
            if not -1 <= j.parent < i:
                raise ValueError(f"joint {j.name!r}: parent {j.parent} must precede it (depth-first order)")
            if j.type == "free" and j.parent != -1:
                raise ValueError(f"joint {j.name!r}: a free joint is only supported at the root")
        for f in self.frames:
            if not -1 <= f.parent < len(self.joints):
                raise ValueError(f"frame {f.name!r}: parent {f.parent} is not a body index")
        object.__setattr__(self, "_hash", hashlib.sha256(self.to_json().encode()).hexdigest())

    # -- sizes and layout --------------------------------------------------------------------
    @property
    def nbodies(self) -> int:
        return len(self.joints)

    @property
    def nq(self) -> int:
        return sum(j.nq for j in self.joints)

    @property
    def nv(self) -> int:
        return sum(j.nv for j in self.joints)

    @property
    def floating_base(self) -> bool:
        return bool(self.joints) and self.joints[0].type == "free"

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

    # -- serialization -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("_hash")
        d["format"] = FORMAT_VERSION
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_dict(cls, d: dict) -> "RobotModel":
        if d.get("format") != FORMAT_VERSION:
            raise ValueError(f"model format {d.get('format')!r} is not supported (expected {FORMAT_VERSION})")
        joints = tuple(Joint(**{k: _tuple(v) for k, v in j.items()}) for j in d["joints"])
        frames = tuple(Frame(**{k: _tuple(v) for k, v in f.items()}) for f in d["frames"])
        return cls(name=d["name"], joints=joints, frames=frames, gravity=tuple(d["gravity"]))

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1, sort_keys=True))

    @classmethod
    def load(cls, path: str | Path) -> "RobotModel":
        return cls.from_dict(json.loads(Path(path).read_text()))


def _offsets(sizes: list[int]) -> list[int]:
    out, acc = [], 0
    for s in sizes:
        out.append(acc)
        acc += s
    return out


def _tuple(v):
    return tuple(v) if isinstance(v, list) else v
