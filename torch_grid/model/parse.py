"""Turn a robot source (URDF, MJCF, pinocchio.Model, mujoco.MjModel, saved model, bundled name) into
a RobotModel.

URDF is parsed by Pinocchio, so joint order, the q/v layout and frame names are Pinocchio's; the one
deliberate difference: a continuous joint has one angle coordinate, where Pinocchio stores (cos, sin).
MJCF is compiled by MuJoCo (mjcf.py), so they are MuJoCo's.
"""
from __future__ import annotations

import math
import os
import re
import sys
import warnings
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np

from . import mjcf
from .description import Frame, Joint, Mimic, RobotModel

ROBOTS_DIR = Path(__file__).parent.parent / "robots"
BUNDLED = {"iiwa14": False, "go2": True, "humanoid": True}  # name -> floating base by default

_REVOLUTE = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0)}
_CONTINUOUS = {"JointModelRUBX": (1.0, 0.0, 0.0), "JointModelRUBY": (0.0, 1.0, 0.0), "JointModelRUBZ": (0.0, 0.0, 1.0)}
_PRISMATIC = {"JointModelPX": (1.0, 0.0, 0.0), "JointModelPY": (0.0, 1.0, 0.0), "JointModelPZ": (0.0, 0.0, 1.0)}
_UNALIGNED = {"JointModelRevoluteUnaligned": "revolute", "JointModelRevoluteUnboundedUnaligned": "continuous",
              "JointModelPrismaticUnaligned": "prismatic"}
_FRAME_KINDS = {"BODY": "body", "JOINT": "joint", "FIXED_JOINT": "fixed_joint", "OP_FRAME": "op", "SENSOR": "sensor"}


def source_to_model(source, floating_base: bool | None, mimic: bool = False) -> RobotModel:
    """Parse `source` into a RobotModel; see `torch_grid.load` for what `source` may be."""
    if not isinstance(mimic, bool):
        raise TypeError(f"mimic must be True or False, got {mimic!r}")
    if floating_base is not None and not isinstance(floating_base, bool):
        raise TypeError(f"floating_base must be None, True or False, got {floating_base!r}")
    if isinstance(source, RobotModel):
        return _check_floating(source, floating_base, "RobotModel")
    if _is_pinocchio_model(source):
        return _check_floating(from_pinocchio(source), floating_base, "pinocchio.Model")
    if type(source).__name__ == "MjModel" and type(source).__module__.startswith("mujoco"):
        return _check_floating(mjcf.from_mujoco(source), floating_base, "mujoco.MjModel")
    if isinstance(source, os.PathLike):
        source = os.fspath(source)
    if not isinstance(source, str):
        raise TypeError(
            "source must be a bundled robot name, a URDF/MJCF path or string, a saved model path, "
            f"a pinocchio.Model or a mujoco.MjModel, got {type(source).__name__}"
        )
    text = source.lstrip()
    if text.startswith("<"):
        return _from_text(text, floating_base, name=None, mimic=mimic)
    if source in BUNDLED:
        return _bundled(source, floating_base)
    path = Path(source).expanduser()
    if not path.is_file():
        bundled = ", ".join(sorted(BUNDLED))
        raise ValueError(f"source {source!r} is neither a bundled robot ({bundled}) nor an existing file")
    text = None if path.suffix == ".json" else path.read_text()
    if text is None or text.lstrip().startswith("{"):  # a saved model, whatever the file's name
        return _check_floating(RobotModel.load(path), floating_base, str(path))
    return _from_text(text, floating_base, name=path.stem, path=path, mimic=mimic)


def from_pinocchio(model, name: str | None = None) -> RobotModel:
    """Convert a pinocchio.Model (revolute, continuous, prismatic, spherical, free-flyer root) to a RobotModel,
    named `name` (default: the model's own name)."""
    joints = []
    for jid in range(1, model.njoints):
        jm = model.joints[jid]
        jname = model.names[jid]
        kind, axis = _joint_kind(jm, jname, model.nq)
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
                # NaN passes through for RobotModel to refuse, naming the joint.
                lower=-math.inf if abs(lo) >= _UNBOUNDED else lo, upper=math.inf if abs(hi) >= _UNBOUNDED else hi,
                armature=_joint_value(jname, "armature", model.armature[jm.idx_v:jm.idx_v + jm.nv]),
            )
        )
    frames = tuple(
        Frame(
            name=f.name, parent=int(f.parentJoint) - 1, rotation=_flat(f.placement.rotation),
            translation=_vec(f.placement.translation), kind=_FRAME_KINDS.get(str(f.type).split(".")[-1], "op"),
        )
        for f in model.frames
    )
    if any(float(w) != 0 for w in model.gravity.angular):  # Pinocchio would accelerate the base by it too
        raise ValueError(f"model.gravity must be linear (angular part 0), got angular part {_vec(model.gravity.angular)}")
    gravity = _vec(model.gravity.linear)
    return RobotModel(name=name or model.name or "robot", joints=tuple(joints), frames=frames, gravity=gravity)


# Pinocchio's default limits are +-DBL_MAX: unbounded.
_UNBOUNDED = sys.float_info.max


def _joint_kind(jm, jname: str, nq: int) -> tuple[str, tuple[float, float, float]]:
    short = jm.shortname()
    if short == "JointModelFreeFlyer":
        return "free", (0.0, 0.0, 0.0)
    if short == "JointModelSpherical":
        return "ball", (0.0, 0.0, 0.0)
    if short in _REVOLUTE:
        return "revolute", _REVOLUTE[short]
    if short in _CONTINUOUS:
        return "continuous", _CONTINUOUS[short]
    if short in _PRISMATIC:
        return "prismatic", _PRISMATIC[short]
    if short in _UNALIGNED:
        # The axis as Pinocchio moves the joint by it, read from the motion subspace S = [linear; angular]
        # (the Python binding of RevoluteUnboundedUnaligned has no `axis`). Not normalised: Pinocchio
        # scales the motion by a non-unit axis, which RobotModel refuses, naming the joint.
        data = jm.createData()
        jm.calc(data, np.zeros(nq))
        kind, motion = _UNALIGNED[short], np.asarray(data.S).reshape(6)
        return kind, _vec(motion[:3] if kind == "prismatic" else motion[3:])
    hint = ("; a pinocchio.Model with mimic joints is not read: load the URDF itself with mimic=True"
            if short == "JointModelMimic" else "")
    raise ValueError(
        f"joint {jname!r} has type {short.replace('JointModel', '')}, which is not supported "
        f"(supported: revolute, continuous, prismatic, spherical, fixed, and a free-flyer root){hint}"
    )


def _joint_value(jname: str, what: str, values) -> float:
    """A joint's one value of a per-dof coefficient (the model holds one per joint)."""
    values = [float(v) for v in values]
    if any(v != values[0] for v in values):
        raise ValueError(f"joint {jname!r}: {what} differs between its dofs ({values}), which is not supported")
    return values[0] if values else 0.0


def _from_text(text: str, floating_base: bool | None, name: str | None, path: Path | None = None,
               mimic: bool = False) -> RobotModel:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise ValueError(f"{path if path is not None else 'source'} is not well-formed XML ({e})") from None
    if root.tag == "robot":
        _reject_urdf_features(root)
        mimics = _mimic_joints(root, mimic)
        _check_urdf_numbers(root)
        model = _parse_urdf(text, bool(floating_base), name or root.get("name") or "robot")
        return replace(model, mimics=mimics) if mimics else model
    if root.tag == "mujoco":
        _check_mjcf_numbers(root)
        return _check_floating(mjcf.from_mjcf(text, path, name), floating_base, "MJCF model")
    raise ValueError(f"source: expected a URDF <robot> or an MJCF <mujoco> document, got <{root.tag}>")


def _reject_urdf_features(root: ET.Element) -> None:
    for j in root.iter("joint"):
        if j.get("type") in ("planar", "floating", "spherical"):
            raise ValueError(f"joint {j.get('name')!r} has type {j.get('type')}, which is not supported")
    up: dict[str, tuple[str, str | None]] = {}  # child link -> (joint, parent link)
    for j in root.iter("joint"):
        if j.find("child") is None:
            continue
        child = j.find("child").get("link")
        if child in up:
            raise ValueError(f"link {child!r} is the child of several joints (a kinematic loop), which is not supported")
        up[child] = (j.get("name"), _attribute(j.find("parent"), "link"))
    _reject_closed_chains(up)


def _reject_closed_chains(up: dict[str, tuple[str, str | None]]) -> None:
    """Refuse joints whose links lead back to themselves (a joint from a link to itself, or a closed chain
    of them), given each child link's (joint, parent link): no root reaches them, and Pinocchio's URDF
    reader dropped them, with every link and joint they carry, without a word."""
    rooted: set[str] = set()  # links whose ancestors end at a root
    for start in up:
        path, link = [], start
        while link in up and link not in rooted:
            if link in path:
                chain = path[path.index(link):] + [link]
                joints = ", ".join(repr(up[c][0]) for c in chain[:-1])
                raise ValueError(f"joints {joints} form a closed chain of links ({' <- '.join(chain)}) that no root link "
                                 "reaches, which is not supported (Pinocchio's URDF reader drops them, and every link "
                                 "below them)")
            path.append(link)
            link = up[link][1]
        rooted.update(path)


def _mimic_joints(root: ET.Element, couple: bool) -> tuple[Mimic, ...]:
    """The URDF's mimic joints, coupled when `couple` (mimic=True, as pinocchio.buildModelFromUrdf's
    mimic=True model); else they are independent joints, as in its default model: say so once."""
    # (a fixed joint's <mimic> moves nothing: Pinocchio ignores it, and so do we)
    found = [(j.get("name"), j.find("mimic")) for j in root.iter("joint")
             if j.find("mimic") is not None and j.get("type") != "fixed"]
    if not found:
        return ()
    if couple:
        return tuple(Mimic(joint=name, master=m.get("joint"), multiplier=_urdf_float(name, m, "multiplier", 1.0),
                           offset=_urdf_float(name, m, "offset", 0.0)) for name, m in found)
    listed = ", ".join(f"{name!r} (mimics {m.get('joint')!r})" for name, m in found)
    warnings.warn(f"the URDF's mimic joints {listed} are independent joints, as in pinocchio.buildModelFromUrdf's "
                  "default model (load(..., mimic=True) couples them)", stacklevel=4)
    return ()


def _urdf_float(joint: str, element: ET.Element, attribute: str, default: float) -> float:
    text = element.get(attribute)
    if text is None:
        return default
    if not _URDF_NUMBER.fullmatch(text):
        raise ValueError(f"joint {joint!r}: <mimic {attribute}> must be a decimal number, got {text!r}")
    return float(text)


# A number as urdfdom, Pinocchio's URDF reader, reads one: leading whitespace allowed, nothing after it
# (a trailing space already fails). Its vectors are such numbers separated by spaces.
_URDF_NUMBER = re.compile(r"\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_URDF_ZEROED = "; urdfdom, Pinocchio's URDF reader, would silently set this <inertial> to 0 from that element on"


def _check_urdf_numbers(root: ET.Element) -> None:
    """Refuse a number urdfdom cannot read (NaN and inf included), naming the link or joint.

    In a joint, urdfdom refuses the whole file without saying where. In a link's <inertial> (origin,
    mass, inertia, read in that order) it only logs the error and keeps the link with the element that
    failed and those after it at 0, and Pinocchio builds the model from that: a NaN mass became a
    massless link."""
    for link in root.findall("link"):  # direct children only, as urdfdom reads them
        inertial = link.find("inertial")
        if inertial is None:
            continue
        where = f"link {link.get('name')!r}: <inertial>"
        for element in ("mass", "inertia"):
            if inertial.find(element) is None:
                raise ValueError(f"{where} must hold one <{element}> element, got none{_URDF_ZEROED}")
        _urdf_pose(where, inertial.find("origin"), _URDF_ZEROED)
        mass = _urdf_number(f"{where}<mass value>", _attribute(inertial.find("mass"), "value"), _URDF_ZEROED)
        if mass < 0:
            raise ValueError(f"{where}<mass value> must be >= 0, got {mass!r}")
        inertia = inertial.find("inertia")
        for name in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
            _urdf_number(f"{where}<inertia {name}>", _attribute(inertia, name), _URDF_ZEROED)
    for joint in root.findall("joint"):
        where = f"joint {joint.get('name')!r}: "
        _urdf_pose(where, joint.find("origin"), "")
        xyz = _attribute(joint.find("axis"), "xyz")
        if xyz is not None:
            _urdf_vector(f"{where}<axis xyz>", xyz, "")
        for name in ("lower", "upper"):
            value = _attribute(joint.find("limit"), name)
            if value is not None:
                _urdf_number(f"{where}<limit {name}>", value, "")


def _urdf_pose(where: str, origin: ET.Element | None, note: str) -> None:
    for name in ("xyz", "rpy"):
        value = _attribute(origin, name)
        if value is not None:
            _urdf_vector(f"{where}<origin {name}>", value, note)


def _urdf_vector(what: str, text: str, note: str) -> None:
    pieces = [p for p in text.split(" ") if p]
    if len(pieces) != 3 or not all(_URDF_NUMBER.fullmatch(p) and math.isfinite(float(p)) for p in pieces):
        raise ValueError(f"{what} must be 3 finite decimal numbers separated by spaces, got {text!r}{note}")


def _urdf_number(what: str, text: str | None, note: str) -> float:
    if text is None or not _URDF_NUMBER.fullmatch(text) or not math.isfinite(float(text)):
        got = "no such attribute" if text is None else repr(text)
        raise ValueError(f"{what} must be a finite decimal number, got {got}{note}")
    return float(text)


def _attribute(element: ET.Element | None, name: str) -> str | None:
    return None if element is None else element.get(name)


def _check_mjcf_numbers(root: ET.Element) -> None:
    """Refuse, naming the element, a non-finite number (MuJoCo's compiler would carry it into the
    model) and a negative <inertial> mass or diagonal inertia."""
    parents = {child: parent for parent in root.iter() for child in parent}
    for element in root.iter():
        for name, text in element.attrib.items():
            values = _floats(text)
            if name not in ("name", "class", "childclass") and values and not all(map(math.isfinite, values)):
                raise ValueError(f"{_mjcf_where(element, parents)}: {name} must hold finite numbers only, got {text!r}")
        if element.tag == "inertial":
            for name in ("mass", "diaginertia"):
                values = _floats(element.get(name, ""))
                if values and min(values) < 0:
                    raise ValueError(f"{_mjcf_where(element, parents)}: {name} must be >= 0, got "
                                     f"{element.get(name)!r}")


def _floats(text: str) -> list[float] | None:
    """The numbers in an attribute, or None when it is not numeric (a name, a keyword, a file)."""
    try:
        return [float(p) for p in text.split()]
    except ValueError:
        return None


def _mjcf_where(element: ET.Element, parents: dict[ET.Element, ET.Element]) -> str:
    """`MJCF <tag name=...>`, or the nearest named enclosing element for an unnamed one."""
    if element.get("name") is not None:
        return f"MJCF <{element.tag} name={element.get('name')!r}>"
    up = parents.get(element)
    while up is not None and up.get("name") is None:
        up = parents.get(up)
    return f"MJCF <{element.tag}>" + ("" if up is None else f" in <{up.tag} name={up.get('name')!r}>")


def _parse_urdf(text: str, floating: bool, name: str) -> RobotModel:
    pin = _pinocchio("parse a URDF")
    try:
        if floating:
            model = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
        else:
            model = pin.buildModelFromXML(text)
    except Exception as e:  # Pinocchio raises a bare RuntimeError/ValueError with its own message
        # urdfdom, its reader, prints why on the C++ stderr only (unseen in a notebook): say it here
        problem = _urdf_structure_problem(ET.fromstring(text))
        raise ValueError(f"source: Pinocchio could not parse the URDF: {e}" + (f" ({problem})" if problem else "")) from None
    return from_pinocchio(model, name)


_URDF_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")


def _urdf_structure_problem(root: ET.Element) -> str | None:
    """The first of the errors urdfdom refuses a URDF for but reports on stderr only, or None."""
    if not root.get("name"):
        return "<robot> has no name"
    links = [link.get("name") for link in root.findall("link")]
    joints = root.findall("joint")
    if not links:
        return "the URDF has no <link>"
    for what, names in (("link", links), ("joint", [j.get("name") for j in joints])):
        if not all(names):
            return f"a <{what}> has no name"
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            return f"{what} {repeated[0]!r} is declared more than once"
    children = set()
    for j in joints:
        problem = _urdf_joint_problem(j, set(links))
        if problem:
            return f"joint {j.get('name')!r}: {problem}"
        children.add(j.find("child").get("link"))
    roots = [link for link in links if link not in children]
    if len(roots) != 1:
        return f"a URDF has one root link (the child of no joint), got {len(roots)}: {', '.join(map(repr, roots))}"
    return None


def _urdf_joint_problem(j: ET.Element, links: set[str]) -> str | None:
    kind = j.get("type")
    if kind not in _URDF_JOINT_TYPES:
        return f"type must be one of {', '.join(_URDF_JOINT_TYPES)}, got {kind!r}"
    for end in ("parent", "child"):
        link = _attribute(j.find(end), "link")
        if link is None:
            return f"has no <{end} link=...>"
        if link not in links:
            return f"its {end} link {link!r} is not a <link> of the URDF"
    limit = j.find("limit")
    if limit is None and kind in ("revolute", "prismatic"):
        return f"a {kind} joint needs a <limit>"
    needed = (("limit", ("effort", "velocity"), ()), ("mimic", (), ("multiplier", "offset")),
              ("dynamics", (), ("damping", "friction")))
    for tag, required, optional in needed:
        element = j.find(tag)
        for name in (required + optional) if element is not None else ():
            value = element.get(name)
            if value is None and name in required:
                return f"<{tag}> has no {name}"
            if value is not None and not _URDF_NUMBER.fullmatch(value):
                return f"<{tag} {name}> must be a decimal number, got {value!r}"
    if j.find("mimic") is not None and not j.find("mimic").get("joint"):
        return "<mimic> names no joint"
    return None


def _bundled(name: str, floating_base: bool | None) -> RobotModel:
    default = BUNDLED[name]
    if floating_base is None or floating_base == default:
        return RobotModel.load(ROBOTS_DIR / f"{name}.json")
    mjcf_path = ROBOTS_DIR / f"{name}.xml"
    if mjcf_path.exists():  # an MJCF's free joint is part of the description
        return _check_floating(mjcf.from_mjcf(mjcf_path.read_text(), mjcf_path, name), floating_base, f"{name!r}")
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
