"""Turn a robot source (URDF, MJCF, pinocchio.Model, saved model, bundled name) into a RobotModel.

Descriptions are parsed by Pinocchio, so joint order, the q/v layout and frame names are
Pinocchio's. The one deliberate difference: a continuous joint has one angle coordinate, where
Pinocchio stores (cos, sin).
"""
from __future__ import annotations

import math
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

from .model import Frame, Joint, RobotModel

ROBOTS_DIR = Path(__file__).parent / "robots"
BUNDLED = {"iiwa14": False, "go2": True}  # name -> floating base by default

_REVOLUTE = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0)}
_CONTINUOUS = {"JointModelRUBX": (1.0, 0.0, 0.0), "JointModelRUBY": (0.0, 1.0, 0.0), "JointModelRUBZ": (0.0, 0.0, 1.0)}
_PRISMATIC = {"JointModelPX": (1.0, 0.0, 0.0), "JointModelPY": (0.0, 1.0, 0.0), "JointModelPZ": (0.0, 0.0, 1.0)}
_FRAME_KINDS = {"BODY": "body", "JOINT": "joint", "FIXED_JOINT": "fixed_joint", "OP_FRAME": "op", "SENSOR": "sensor"}


def source_to_model(source, floating_base: bool | None) -> RobotModel:
    """Parse `source` into a RobotModel; see `torch_grid.load` for what `source` may be."""
    if floating_base is not None and not isinstance(floating_base, bool):
        raise TypeError(f"floating_base must be None, True or False, got {floating_base!r}")
    if isinstance(source, RobotModel):
        return _check_floating(source, floating_base, "RobotModel")
    if _is_pinocchio_model(source):
        return _check_floating(from_pinocchio(source), floating_base, "pinocchio.Model")
    if isinstance(source, os.PathLike):
        source = os.fspath(source)
    if not isinstance(source, str):
        raise TypeError(
            "source must be a bundled robot name, a URDF/MJCF path or string, a saved model path "
            f"or a pinocchio.Model, got {type(source).__name__}"
        )
    text = source.lstrip()
    if text.startswith("<"):
        return _from_text(text, floating_base, name=None)
    if source in BUNDLED:
        return _bundled(source, floating_base)
    path = Path(source).expanduser()
    if not path.is_file():
        bundled = ", ".join(sorted(BUNDLED))
        raise ValueError(f"source {source!r} is neither a bundled robot ({bundled}) nor an existing file")
    if path.suffix == ".json":
        return _check_floating(RobotModel.load(path), floating_base, str(path))
    return _from_text(path.read_text(), floating_base, name=path.stem, path=path)


def from_pinocchio(model, name: str | None = None) -> RobotModel:
    """Convert a pinocchio.Model (revolute, continuous, prismatic, free-flyer root) to a RobotModel."""
    import numpy as np

    joints = []
    for jid in range(1, model.njoints):
        jm = model.joints[jid]
        jname = model.names[jid]
        kind, axis = _joint_kind(jm, jname)
        parent = int(model.parents[jid]) - 1
        lo, hi = -math.pi, math.pi
        if kind in ("revolute", "prismatic"):
            lo = float(model.lowerPositionLimit[jm.idx_q])
            hi = float(model.upperPositionLimit[jm.idx_q])
        placement = model.jointPlacements[jid]
        inertia = model.inertias[jid]
        joints.append(
            Joint(
                name=jname, type=kind, parent=parent, axis=axis,
                rotation=_flat(placement.rotation), translation=_vec(placement.translation),
                mass=float(inertia.mass), com=_vec(inertia.lever), inertia=_flat(inertia.inertia),
                lower=lo if np.isfinite(lo) else -math.inf, upper=hi if np.isfinite(hi) else math.inf,
            )
        )
    frames = tuple(
        Frame(
            name=f.name, parent=int(f.parentJoint) - 1, rotation=_flat(f.placement.rotation),
            translation=_vec(f.placement.translation), kind=_FRAME_KINDS.get(str(f.type).split(".")[-1], "op"),
        )
        for f in model.frames
    )
    gravity = _vec(model.gravity.linear)
    return RobotModel(name=name or model.name or "robot", joints=tuple(joints), frames=frames, gravity=gravity)


def _joint_kind(jm, jname: str) -> tuple[str, tuple[float, float, float]]:
    short = jm.shortname()
    if short == "JointModelFreeFlyer":
        return "free", (0.0, 0.0, 0.0)
    if short in _REVOLUTE:
        return "revolute", _REVOLUTE[short]
    if short in _CONTINUOUS:
        return "continuous", _CONTINUOUS[short]
    if short in _PRISMATIC:
        return "prismatic", _PRISMATIC[short]
    if short in ("JointModelRevoluteUnaligned", "JointModelRevoluteUnboundedUnaligned", "JointModelPrismaticUnaligned"):
        axis = _vec(jm.extract().axis)
        n = math.sqrt(sum(a * a for a in axis))
        axis = tuple(a / n for a in axis)
        kind = {"JointModelRevoluteUnaligned": "revolute", "JointModelPrismaticUnaligned": "prismatic"}
        return kind.get(short, "continuous"), axis
    raise ValueError(
        f"joint {jname!r} has type {short.replace('JointModel', '')}, which is not supported "
        "(supported: revolute, continuous, prismatic, fixed, and a free-flyer root)"
    )


def _from_text(text: str, floating_base: bool | None, name: str | None, path: Path | None = None) -> RobotModel:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise ValueError(f"source is not well-formed XML ({e})") from None
    if root.tag == "robot":
        _reject_urdf_features(root)
        return _parse_urdf(text, bool(floating_base), name or root.get("name") or "robot")
    if root.tag == "mujoco":
        _reject_mjcf_features(root)
        return _parse_mjcf(text, root, floating_base, name or root.get("model") or "robot", path)
    raise ValueError(f"source: expected a URDF <robot> or an MJCF <mujoco> document, got <{root.tag}>")


def _reject_urdf_features(root: ET.Element) -> None:
    for j in root.iter("joint"):
        if j.find("mimic") is not None:
            raise ValueError(f"joint {j.get('name')!r} has type mimic, which is not supported")
        if j.get("type") in ("planar", "floating", "spherical"):
            raise ValueError(f"joint {j.get('name')!r} has type {j.get('type')}, which is not supported")
    children = [j.find("child").get("link") for j in root.iter("joint") if j.find("child") is not None]
    seen = set()
    for c in children:
        if c in seen:
            raise ValueError(f"link {c!r} is the child of several joints (a kinematic loop), which is not supported")
        seen.add(c)


def _reject_mjcf_features(root: ET.Element) -> None:
    for eq in root.iter("equality"):
        for c in eq:
            raise ValueError(f"MJCF equality constraint <{c.tag}> (a kinematic loop or coupling) is not supported")
    for j in root.iter("joint"):
        if j.get("type") == "ball":
            raise ValueError(f"joint {j.get('name')!r} has type ball, which is not supported")


def _parse_urdf(text: str, floating: bool, name: str) -> RobotModel:
    pin = _pinocchio("parse a URDF")
    try:
        if floating:
            model = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
        else:
            model = pin.buildModelFromXML(text)
    except Exception as e:  # Pinocchio raises a bare RuntimeError/ValueError with its own message
        raise ValueError(f"source: Pinocchio could not parse the URDF: {e}") from None
    return from_pinocchio(model, name)


def _parse_mjcf(text: str, root: ET.Element, floating_base: bool | None, name: str, path: Path | None) -> RobotModel:
    pin = _pinocchio("parse an MJCF file")
    has_free = any(j.get("type") == "free" for j in root.iter("joint")) or any(True for _ in root.iter("freejoint"))
    if floating_base is False and has_free:
        raise ValueError("floating_base=False, but the MJCF file has a free joint")
    with tempfile.TemporaryDirectory() as tmp:
        # MJCF may include files relative to itself: parse the original path when there is one.
        target = path if path is not None else Path(tmp) / "model.xml"
        if path is None:
            target.write_text(text)
        try:
            if floating_base and not has_free:
                model = pin.buildModelFromMJCF(str(target), pin.JointModelFreeFlyer())
            else:
                model = pin.buildModelFromMJCF(str(target))
        except Exception as e:
            raise ValueError(f"source: Pinocchio could not parse the MJCF file: {e}") from None
    return from_pinocchio(model, name)


def _bundled(name: str, floating_base: bool | None) -> RobotModel:
    default = BUNDLED[name]
    if floating_base is None or floating_base == default:
        return RobotModel.load(ROBOTS_DIR / f"{name}.json")
    return _parse_urdf((ROBOTS_DIR / f"{name}.urdf").read_text(), floating_base, name)


def _check_floating(model: RobotModel, floating_base: bool | None, what: str) -> RobotModel:
    if floating_base is not None and floating_base != model.floating_base:
        have = "a floating" if model.floating_base else "a fixed"
        raise ValueError(f"floating_base={floating_base} contradicts the {what}, which has {have} base")
    return model


def _is_pinocchio_model(obj) -> bool:
    return type(obj).__name__ == "Model" and type(obj).__module__.startswith("pinocchio")


def _pinocchio(why: str):
    try:
        import pinocchio
    except ImportError:
        raise ImportError(f"Pinocchio is needed to {why}: pip install pin") from None
    return pinocchio


def _flat(m) -> tuple[float, ...]:
    return tuple(float(x) for x in m.reshape(-1))


def _vec(v) -> tuple[float, float, float]:
    return tuple(float(x) for x in v)
