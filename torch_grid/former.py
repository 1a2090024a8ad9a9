"""The public names' spellings, and the former ones kept for one release with a DeprecationWarning
(CHANGELOG.md)."""
from __future__ import annotations

import warnings

CONVENTIONS = {"pin": 0, "mujoco": 1}
# Former names, kept for one release (CHANGELOG.md): of the conventions, and of the derivative functions
# (one suffix now: _derivatives for the first derivatives, _second_derivatives for the second).
FORMER_CONVENTIONS = {"pinocchio": "pin", "mjx": "mujoco"}
FORMER_NAMES = {
    "inverse_dynamics_gradient": "inverse_dynamics_derivatives",
    "forward_dynamics_gradient": "forward_dynamics_derivatives",
    "end_effector_pose_gradient": "end_effector_pose_derivatives",
    "centroidal_map_gradient": "centroidal_map_derivatives",
    "inverse_dynamics_external_force_gradient": "inverse_dynamics_external_force_derivatives",
    "forward_dynamics_external_force_gradient": "forward_dynamics_external_force_derivatives",
    "forward_dynamics_parameter_gradient": "forward_dynamics_parameter_derivatives",
    "inverse_dynamics_second_order": "inverse_dynamics_second_derivatives",
    "forward_dynamics_second_order": "forward_dynamics_second_derivatives",
    "end_effector_pose_hessian": "end_effector_pose_second_derivatives",
}


def convention_name(value, stacklevel: int = 3) -> str:
    """"pin" or "mujoco": a convention's name (any case), a former spelling with a DeprecationWarning
    attributed `stacklevel` frames up (the user's line, so that Python's default filters show it)."""
    name = value.lower() if isinstance(value, str) else None
    if name in FORMER_CONVENTIONS:
        warnings.warn(f"convention {value!r} is now {FORMER_CONVENTIONS[name]!r}; the former name goes in 0.3",
                      DeprecationWarning, stacklevel=stacklevel)
        return FORMER_CONVENTIONS[name]
    if name not in CONVENTIONS:
        raise ValueError(f"convention must be 'pin' or 'mujoco', got {value!r}")
    return name
