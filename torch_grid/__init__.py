"""torch_grid: robot-specific rigid-body dynamics kernels as batched torch ops (CPU and CUDA),
in Pinocchio's or MuJoCo's convention."""
from __future__ import annotations

import os

import sys as _sys
from collections.abc import Mapping
from dataclasses import replace as _replace
from pathlib import Path

from .former import convention_name
from .model.description import Frame, Joint, RobotModel, check_triangle_inequality, with_armature
from .model.parse import BUNDLED, from_pinocchio, source_to_model
from .ops.autograd import register_autograd
from .ops.build import build as _build
from .ops.build import release_kept_blocks, set_cpu_lanes
from .optim.costs import log_barrier, quadratic_barrier
from .optim.inertial import log_cholesky_to_parameters, parameters_to_log_cholesky, pseudo_inertia
from .robot import Robot, RobotView
from .space import conventions
from .step.integrators import INTEGRATORS

_sys.modules[f"{__name__}.conventions"] = conventions  # `import torch_grid.conventions`: the public module

__all__ = ["load", "Robot", "RobotView", "RobotModel", "Joint", "Frame", "conventions", "from_pinocchio", "BUNDLED",
           "INTEGRATORS", "log_barrier", "quadratic_barrier", "empty_cache", "pseudo_inertia", "log_cholesky_to_parameters",
           "parameters_to_log_cholesky", "set_cpu_lanes"]
__version__ = "0.1.0"


def __dir__() -> list[str]:
    """dir(torch_grid): __all__ and __version__; the submodules and the helpers load() imports are not
    part of the public face."""
    return sorted([*__all__, "__version__"])


_AUTOGRAD_DONE: set[str] = set()


def empty_cache() -> int:
    """Free the memory of CPU outputs that were deleted but kept for reuse; returns its bytes.

    An output above 128 KiB is, once freed, kept and handed to the next output of the same size,
    so that a loop over one batch size maps and zeroes its memory once. Up to a quarter of the
    machine's memory (at least 1 GiB; TORCH_GRID_KEEP_MB sets it) is kept in at most 256 blocks, the
    longest-kept blocks making room for newer ones. Like torch.cuda.empty_cache, this returns it to the system.
    """
    return release_kept_blocks()


def load(source, *, floating_base: bool | None = None, convention: str = "pin", enable_mujoco_kernels: bool = True,
         armature: Mapping[str, float] | None = None, passive_forces: bool | None = None, eulerdamp: bool | None = None,
         mimic: bool = False, strict_inertia: bool = False, cache_dir: str | Path | None = None) -> Robot:
    """Build (or reuse from the cache) a robot's kernels and return its `Robot`.

    source: a bundled robot name (BUNDLED: "iiwa14", "go2", "humanoid"), a URDF path or XML string,
    an MJCF path or string, a saved model (.json, see Robot.save), a `pinocchio.Model`, a
    `mujoco.MjModel` or a `RobotModel`. MJCF is compiled by MuJoCo: joint, dof and body order are MuJoCo's.
    floating_base: None takes the source's own choice (a bundled robot's default, fixed for a URDF,
    floating when an MJCF's first joint is free); True adds a free-flyer root to a URDF (an MJCF must
    declare its own free joint).
    convention: default convention of the returned handle, "pin" or "mujoco" (refused for a robot with a free
    joint placed away from the world's origin, as a pinocchio.Model's FreeFlyer may be: MuJoCo's qpos of a
    free joint is its body's world pose).
    enable_mujoco_kernels: False builds Pinocchio-convention kernels only (a smaller build); a
    floating robot then refuses convention="mujoco".
    armature: rotor inertia per joint name, replacing the source's (an MJCF's `armature`, a
    pinocchio.Model's `armature`; 0 in a URDF), for 1-dof and ball joints. It adds to M's diagonal and so
    enters inverse and forward dynamics, M^-1, the kinetic energy and their derivatives, as in
    Pinocchio and MuJoCo.
    passive_forces: whether inverse_dynamics, forward_dynamics and their gradients include the
    joints' damping and stiffness (Robot.passive_forces, MuJoCo's qfrc_passive). None follows the
    source: an MJCF's are included, as mj_forward and mj_inverse do; a URDF or pinocchio.Model has
    none, as Pinocchio's algorithms ignore them.
    eulerdamp: whether semi_implicit_euler takes the joints' damping implicitly, as MuJoCo's Euler
    integrator does (mj_Euler): qd' = qd + dt (M + dt D)^-1 (tau + passive - bias), D the damping. None
    follows the source: an MJCF's flag (on unless it has <flag eulerdamp="disable"/>), on otherwise.
    It changes nothing on a model without damping or whose passive forces are left out.
    mimic: a URDF's mimic joints are independent joints by default (pinocchio.buildModelFromUrdf's
    default; a warning says so); True couples them, q_mimic = multiplier q_master + offset, in
    reduced coordinates (nq, nv and joint_names count the independent joints only), as
    pinocchio.buildModelFromUrdf(..., mimic=True): every function is the uncoupled one projected by
    the constant G = d q_full / d q (M -> G^T M G, tau -> G^T tau, J -> J G), and forward dynamics
    and M^-1 solve with the reduced M.
    strict_inertia: a body whose principal moments of inertia break the triangle inequality (one larger
    than the sum of the other two: no mass distribution has them, but the inertia is still positive
    semi-definite, and Pinocchio simulates it) gets a warning naming it by default; True refuses it
    with ValueError. Inertias that are negative, not finite or not positive semi-definite, and joints
    that move no mass, are always refused.
    cache_dir: where compiled kernels are kept (default $TORCH_GRID_CACHE or ~/.cache/torch_grid).
    """
    if not isinstance(enable_mujoco_kernels, bool):
        raise TypeError(f"load: enable_mujoco_kernels must be True or False, got {enable_mujoco_kernels!r}")
    if passive_forces is not None and not isinstance(passive_forces, bool):
        raise TypeError(f"load: passive_forces must be None, True or False, got {passive_forces!r}")
    if eulerdamp is not None and not isinstance(eulerdamp, bool):
        raise TypeError(f"load: eulerdamp must be None, True or False, got {eulerdamp!r}")
    if not isinstance(strict_inertia, bool):
        raise TypeError(f"load: strict_inertia must be True or False, got {strict_inertia!r}")
    model = source_to_model(source, floating_base, mimic)
    check_triangle_inequality(model, strict=strict_inertia)
    if eulerdamp is not None and eulerdamp != model.eulerdamp:
        model = _replace(model, eulerdamp=eulerdamp)
    if armature is not None:
        model = with_armature(model, armature)
    convention = convention_name(convention)
    placed = model.placed_free_joint
    if convention == "mujoco" and placed:
        raise ValueError(f"load: convention='mujoco' needs each free joint at the world's origin (its qpos is its world "
                         f"pose); free joint {placed!r} is placed away from it")
    if convention == "mujoco" and model.conventions_differ and not enable_mujoco_kernels:
        raise ValueError("load: convention='mujoco' needs enable_mujoco_kernels=True for a robot with a free or ball joint")
    namespace = _build(model.kernel_model, mujoco=enable_mujoco_kernels and not placed, cache_dir=cache_dir)
    if namespace not in _AUTOGRAD_DONE:
        register_autograd(namespace, model.kernel_model)
        _AUTOGRAD_DONE.add(namespace)
    return Robot(model, namespace, convention=convention, mujoco_kernels=enable_mujoco_kernels,
                 passive_forces=passive_forces is not False,
                 cache_dir=None if cache_dir is None else os.path.abspath(os.path.expanduser(cache_dir)))
