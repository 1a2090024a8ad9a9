"""Pinocchio C++ algorithms that its Python bindings lack, as test oracles: pinocchio_second_order.cpp
compiled once (cached by source, flags and compiler) against the `pin` wheel's headers, fed a
pinocchio.Model written out joint by joint."""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from pinocchio_cpp import cmeel_prefix, library_definitions  # noqa: E402

SOURCE = Path(__file__).with_name("pinocchio_second_order.cpp")
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "torch_grid_tests"

_TYPES = {"JointModelRX": "RX", "JointModelRY": "RY", "JointModelRZ": "RZ", "JointModelRevoluteUnaligned": "RU",
          "JointModelRUBX": "RUBX", "JointModelRUBY": "RUBY", "JointModelRUBZ": "RUBZ",
          "JointModelRevoluteUnboundedUnaligned": "RUBU", "JointModelPX": "PX", "JointModelPY": "PY",
          "JointModelPZ": "PZ", "JointModelPrismaticUnaligned": "PU", "JointModelFreeFlyer": "FF",
          "JointModelSpherical": "SPH"}


def _binary() -> Path:
    prefix = cmeel_prefix()
    include = prefix / "include"
    if not (include / "eigen3" / "Eigen" / "Core").exists():
        raise RuntimeError(f"{include / 'eigen3'} is missing: pip install cmeel-eigen")
    flags = ["-std=c++17", "-O2", "-DNDEBUG", *library_definitions(prefix), f"-I{include}", f"-I{include / 'eigen3'}"]
    flags = [f for f in flags if f != "-DPINOCCHIO_WITH_URDFDOM"]
    compiler = os.environ.get("CXX", "c++")
    # Keyed by what decides the binary, not by where the headers are: each fresh environment of the same
    # pin wheel (a CI's virtual environment) reuses it.
    portable = [f.replace(str(prefix), "<cmeel>") for f in flags]
    key = hashlib.sha256("\0".join([SOURCE.read_text(), compiler, *portable, pin.__version__]).encode()).hexdigest()
    target = CACHE / key[:16] / SOURCE.stem
    if not target.exists():
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_name(f"{SOURCE.stem}.{os.getpid()}.partial")
        build = subprocess.run([compiler, *flags, str(SOURCE), "-o", str(partial)], capture_output=True, text=True)
        if build.returncode != 0:
            raise RuntimeError(f"compiling {SOURCE} failed:\n{build.stderr[-4000:]}")
        partial.replace(target)
    return target


def _num(x) -> str:
    return repr(float(x))


def _describe(model: pin.Model, nsamples: int) -> list[str]:
    lines = [f"{model.nq} {model.nv} {model.njoints - 1} {nsamples}", " ".join(map(_num, model.gravity.linear))]
    for j in range(1, model.njoints):
        joint = model.joints[j]
        name = joint.shortname()
        if name not in _TYPES:
            raise ValueError(f"joint {model.names[j]!r}: type {name} is not written out for the C++ oracle")
        axis = getattr(joint, "axis", np.zeros(3))
        X, I = model.jointPlacements[j], model.inertias[j]
        inertia = I.inertia
        lines.append(" ".join([_TYPES[name], str(model.parents[j]), *map(_num, np.asarray(axis, dtype=float)),
                               *map(_num, X.rotation.reshape(-1)), *map(_num, X.translation), _num(I.mass),
                               *map(_num, I.lever), *map(_num, [inertia[0, 0], inertia[0, 1], inertia[1, 1],
                                                                  inertia[0, 2], inertia[1, 2], inertia[2, 2]])]))
    return lines


def rnea_second_order(model: pin.Model, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, ...]:
    """Pinocchio's (d2tau_dqdq, d2tau_dvdv, dtau_dqdv, dtau_dadq), each (n, nv, nv, nv), for states
    q (n, nq) (Pinocchio's layout), v and a (n, nv)."""
    q, v, a = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, v, a))
    header = _describe(model, len(q))
    samples = [" ".join(map(_num, np.concatenate([q[s], v[s], a[s]]))) for s in range(len(q))]
    run = subprocess.run([str(_binary())], input="\n".join(header + samples) + "\n", capture_output=True, text=True)
    if run.returncode != 0:
        raise RuntimeError(f"{SOURCE.stem} failed ({run.returncode}):\n{run.stderr[-4000:]}")
    nv = model.nv
    out = np.array(run.stdout.split(), dtype=float).reshape(len(q), 4, nv, nv, nv)
    return tuple(out[:, t] for t in range(4))
