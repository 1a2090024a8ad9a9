"""Every differentiable public function of a robot, as one table (no oracle imported: bench/gpu_check.py
runs it on a machine without Pinocchio or MuJoCo)."""
from __future__ import annotations

import torch


def last_frame(robot):
    return robot.nframes - 1


# function -> (call on a view with the robot and (q, qd, qdd or tau, f_ext), how many of those it takes)
FUNCTIONS = {
    "inverse_dynamics": (lambda v, r, *x: v.inverse_dynamics(*x), 4),
    "forward_dynamics": (lambda v, r, *x: v.forward_dynamics(*x), 4),
    "nonlinear_effects": (lambda v, r, *x: v.nonlinear_effects(*x), 2),
    "energy": (lambda v, r, *x: v.energy(*x), 2),
    "generalized_gravity": (lambda v, r, q: v.generalized_gravity(q), 1),
    "com": (lambda v, r, q: v.com(q), 1),
    "forward_kinematics": (lambda v, r, q: v.forward_kinematics(q), 1),
    "end_effector_pose": (lambda v, r, q: v.end_effector_pose(q, [last_frame(r), 2, last_frame(r)]), 1),
    "crba": (lambda v, r, q: v.crba(q), 1),
    "minv": (lambda v, r, q: v.minv(q), 1),
    "jacobian_com": (lambda v, r, q: v.jacobian_com(q), 1),
    "ccrba": (lambda v, r, q, qd: v.ccrba(q, qd), 2),
    "frame_jacobian": (lambda v, r, q: torch.stack([v.frame_jacobian(q, last_frame(r), ref)
                                                    for ref in ("world", "local", "local_world_aligned")]), 1),
    "frame_jacobian_dot": (lambda v, r, q, qd: torch.stack([v.frame_jacobian_dot(q, qd, last_frame(r), ref)
                                                            for ref in ("world", "local", "local_world_aligned")]), 2),
    "end_effector_pose_derivatives": (lambda v, r, q: v.end_effector_pose_derivatives(q, [last_frame(r), 2]), 1),
    "body_velocities": (lambda v, r, *x: v.body_velocities(*x), 2),
    "inverse_dynamics_derivatives": (lambda v, r, *x: v.inverse_dynamics_derivatives(*x), 4),
    "forward_dynamics_derivatives": (lambda v, r, *x: v.forward_dynamics_derivatives(*x), 4),
    "inverse_dynamics_external_force_derivatives": (lambda v, r, q: v.inverse_dynamics_external_force_derivatives(q), 1),
    "forward_dynamics_external_force_derivatives": (lambda v, r, q: v.forward_dynamics_external_force_derivatives(q), 1),
    "osc_inertia": (lambda v, r, q: v.osc_inertia(q, last_frame(r), "local"), 1),
    "cmm_time_variation": (lambda v, r, *x: v.cmm_time_variation(*x), 2),
    "dccrba": (lambda v, r, *x: v.dccrba(*x), 2),
    "centroidal_map_derivatives": (lambda v, r, q: v.centroidal_map_derivatives(q), 1),
    "coriolis_matrix": (lambda v, r, *x: v.coriolis_matrix(*x), 2),
    "inverse_dynamics_regressor": (lambda v, r, *x: v.inverse_dynamics_regressor(*x), 3),
    "kinetic_energy_regressor": (lambda v, r, *x: v.kinetic_energy_regressor(*x), 2),
    "potential_energy_regressor": (lambda v, r, q: v.potential_energy_regressor(q), 1),
    "forward_dynamics_parameter_derivatives": (lambda v, r, *x: v.forward_dynamics_parameter_derivatives(*x), 3),
    "passive_forces": (lambda v, r, *x: v.passive_forces(*x), 2),
}
