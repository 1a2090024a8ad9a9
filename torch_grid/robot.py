"""`Robot`: a built robot's ops as torch functions, in Pinocchio's or MuJoCo's convention."""
from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Sequence

import torch

from .former import CONVENTIONS, FORMER_NAMES, convention_name
from .model.description import RobotModel, inertia_about_origin
from .ops import mujoco_second_order
from .ops.arguments import check_arguments, check_tensor, forward_mode, reference_code
from .ops.dispatch import dispatch, kernel_call
from .ops.eager import EagerOps
from .ops.fd_second_order import second_order
from .ops.func import FuncOps
from .ops.mimic import Coupling
from .ops.pose import PoseDerivatives
from .ops.table import OPS, model_sizes
from .optim.costs import CostFunctions
from .optim.horizon import HorizonFunctions
from .optim.inertial import check_physical
from .space.lie import Space
from .step.compiled import step_op
from .step.configuration import ConfigurationFunctions
from .step.integrators import StepFunctions
from .step.passive import PassiveForces


class _Functions(ConfigurationFunctions, StepFunctions, CostFunctions, HorizonFunctions, PoseDerivatives):
    """The rigid-body functions, evaluated in one convention (`_convention`, 0 pin or 1 mujoco).

    Tensors may have any leading batch shape; batch shapes of the arguments broadcast. All tensor
    arguments must share one device and one dtype (float32 or float64); outputs have them too.
    """

    _robot: "Robot"
    _convention: int
    _params: torch.Tensor | None = None  # bound by with_parameters

    def __getattr__(self, name: str):
        # a former name of a function (FORMER_NAMES): the function, with a DeprecationWarning
        if name in FORMER_NAMES:
            warnings.warn(f"{name} is now {FORMER_NAMES[name]}; the former name goes in 0.3", DeprecationWarning,
                          stacklevel=2)
            return getattr(self, FORMER_NAMES[name])
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    # -- description: the robot's, the same in every convention ------------------------------------
    name = property(lambda self: self._robot.model.name, doc="The robot's name.")
    nq = property(lambda self: (self._robot._coupling or self._robot.model).nq,
                  doc="Configuration size (a continuous joint has one angle; mimic joints coupled by load(..., "
                      "mimic=True) have none).")
    nv = property(lambda self: (self._robot._coupling or self._robot.model).nv, doc="Velocity size.")
    nbodies = property(lambda self: self._robot.model.nbodies, doc="Moving bodies (one per joint): len(body_names).")
    nframes = property(lambda self: len(self._robot.model.frames), doc="Number of frames: len(frame_names).")
    floating_base = property(lambda self: self._robot.model.floating_base,
                             doc="Whether the first joint is a free joint (q starts with a position and a quaternion, "
                                 "qd with a 6-d velocity).")
    joint_names = property(lambda self: self._robot._coupling.joint_names if self._robot._coupling else self.body_names,
                           doc="The joints whose coordinates make up q and qd, in order.")
    body_names = property(lambda self: [j.name for j in self._robot.model.joints],
                          doc="The moving bodies, each named by the joint that moves it, mimic joints included: the rows "
                              "of f_ext, params and inertial_parameters(), in order (nbodies of them).")
    includes_passive_forces = property(
        lambda self: self._robot._with_passive,
        doc="Whether the dynamics include the joints' damping and springs (the model has some, and load's "
            "passive_forces did not turn them off).")
    frame_names = property(lambda self: [f.name for f in self._robot.model.frames],
                           doc="The frames, in the order of forward_kinematics' outputs; a function's `frame` "
                               "argument is one of these names or its index.")
    robot = property(lambda self: self._robot, doc="The Robot these functions belong to (a Robot's is itself).")

    def inverse_dynamics(self, q, qd, qdd, f_ext=None, params=None) -> torch.Tensor:
        """Joint forces tau (..., nv) = M qdd + C qd + g - J^T f_ext (- passive_forces, when included).

        q (..., nq), qd (..., nv), qdd (..., nv); f_ext (..., nbodies, 6): a spatial force
        [force; torque] on each body, in its joint frame (Pinocchio's fext without the universe);
        params (..., nbodies, 10): the bodies' inertial parameters (with_parameters), the robot's own
        when None.
        """
        tau = dispatch(self, "inverse_dynamics", q, qd, qdd, f_ext, self._parameters(params))
        return tau - self._robot._passive(q, qd) if self._robot._with_passive else tau

    rnea = inverse_dynamics

    def forward_dynamics(self, q, qd, tau, f_ext=None, params=None) -> torch.Tensor:
        """Joint accelerations qdd (..., nv) by the articulated-body algorithm, under tau (+ passive_forces,
        when included); f_ext and params as in inverse_dynamics."""
        tau = self._robot._passive.added("forward_dynamics", q, qd, tau) if self._robot._with_passive else tau
        return dispatch(self, "forward_dynamics", q, qd, tau, f_ext, self._parameters(params))

    aba = forward_dynamics

    def crba(self, q, params=None) -> torch.Tensor:
        """Joint-space inertia matrix M (..., nv, nv), full and symmetric; params as in inverse_dynamics."""
        return dispatch(self, "crba", q, self._parameters(params))

    def minv(self, q, params=None) -> torch.Tensor:
        """Inverse inertia matrix M^-1 (..., nv, nv), computed directly (not by inverting M); params as in
        inverse_dynamics."""
        return dispatch(self, "minv", q, self._parameters(params))

    def generalized_gravity(self, q, params=None) -> torch.Tensor:
        """Gravity joint forces g(q) (..., nv); params as in inverse_dynamics."""
        return dispatch(self, "generalized_gravity", q, self._parameters(params))

    def nonlinear_effects(self, q, qd, params=None) -> torch.Tensor:
        """C(q, qd) qd + g(q) (..., nv): the rigid-body inverse dynamics at zero acceleration, without the passive
        forces inverse_dynamics subtracts where it includes them (MuJoCo's qfrc_bias); params as in
        inverse_dynamics."""
        return dispatch(self, "nonlinear_effects", q, qd, self._parameters(params))

    def energy(self, q, qd, params=None) -> torch.Tensor:
        """[kinetic, potential, mechanical] energy (..., 3); potential: gravity's, zero at the world origin, and
        the joint springs' sum of stiffness (q - springref)^2 / 2 where the dynamics include them (as
        MuJoCo's mj_energyPos); params as in inverse_dynamics."""
        energy = dispatch(self, "energy", q, qd, self._parameters(params))
        passive = self._robot._passive
        if not (self._robot._with_passive and passive.springs):
            return energy
        spring = passive.spring_energy(q).unsqueeze(-1)
        return energy + torch.cat([torch.zeros_like(spring), spring, spring], dim=-1)

    def com(self, q, params=None) -> torch.Tensor:
        """Centre of mass of the whole robot in the world frame (..., 3); params as in inverse_dynamics."""
        return dispatch(self, "com", q, self._parameters(params))

    def jacobian_com(self, q, params=None) -> torch.Tensor:
        """Centre-of-mass Jacobian d com / d qd (..., 3, nv); params as in inverse_dynamics."""
        return dispatch(self, "jacobian_com", q, self._parameters(params))

    def ccrba(self, q, qd, params=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Centroidal momentum matrix A (..., 6, nv) and momentum h = A qd (..., 6), [linear; angular];
        params as in inverse_dynamics."""
        return dispatch(self, "ccrba", q, qd, self._parameters(params))

    def forward_kinematics(self, q) -> tuple[torch.Tensor, torch.Tensor]:
        """World positions (..., nframes, 3) and rotations (..., nframes, 3, 3) of every frame in frame_names."""
        return dispatch(self, "forward_kinematics", q)

    def end_effector_pose(self, q, frames: Sequence[str | int]) -> torch.Tensor:
        """[x, y, z, roll, pitch, yaw] (..., len(frames), 6) of each listed frame, R = Rz(yaw) Ry(pitch) Rx(roll)."""
        if isinstance(frames, (str, int)):
            raise TypeError(f"end_effector_pose: frames must be a list of frame names or indices, got {frames!r}")
        indices = [self._robot.frame_index(f, "end_effector_pose: frames") for f in frames]
        return dispatch(self, "end_effector_pose", q, indices)

    def frame_jacobian(self, q, frame: str | int, reference: str = "local_world_aligned") -> torch.Tensor:
        """Jacobian (..., 6, nv), rows [linear; angular], of a frame, as Pinocchio's getFrameJacobian.

        reference: "local_world_aligned" (frame origin, world axes), "local" (frame axes) or
        "world" (spatial velocity at the world origin).
        """
        return dispatch(self, "frame_jacobian", q, self._robot.frame_index(frame, "frame_jacobian: frame"),
                        reference_code("frame_jacobian", reference))

    def frame_kinematic_hessian(self, q, frame: str | int, reference: str = "local_world_aligned") -> torch.Tensor:
        """Kinematic Hessian (..., 6, nv, nv) of a frame: H[..., :, j, k] = d J[..., :, j] / dq_k along the
        tangent, J = frame_jacobian(q, frame, reference) (Pinocchio's getFrameKinematicHessian).
        In the MuJoCo convention, d/dq_k of its Jacobian (qvel's frame) along mj_integratePos's tangent."""
        index = self._robot.frame_index(frame, "frame_kinematic_hessian: frame")
        ref = reference_code("frame_kinematic_hessian", reference)
        if self._differs():
            check_tensor("frame_kinematic_hessian", "q", q, (self._robot.nq,), q)
            return mujoco_second_order.frame_kinematic_hessian(self._robot, q, index, ref)
        return dispatch(self, "frame_kinematic_hessian", q, index, ref)

    def frame_jacobian_dot(self, q, qd, frame: str | int, reference: str = "local_world_aligned") -> torch.Tensor:
        """Time derivative (..., 6, nv) of frame_jacobian at velocity qd (Pinocchio's
        getFrameJacobianTimeVariation); in MuJoCo's convention, of its Jacobian with qvel fixed."""
        return dispatch(self, "frame_jacobian_dot", q, qd, self._robot.frame_index(frame, "frame_jacobian_dot: frame"),
                        reference_code("frame_jacobian_dot", reference))

    def body_velocities(self, q, qd) -> torch.Tensor:
        """Spatial velocity [linear; angular] (..., nbodies, 6) of each body, in its joint frame."""
        return dispatch(self, "body_velocities", q, qd)

    def inverse_dynamics_derivatives(self, q, qd, qdd, f_ext=None, params=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Analytic (d tau / dq, d tau / dqd), each (..., nv, nv), of inverse_dynamics.

        Derivatives along the tangent space: for a floating base in Pinocchio's convention, the
        local increment q (+) dq (as pinocchio.computeRNEADerivatives); in MuJoCo's convention,
        mj_integratePos's increment, with qvel and qacc held fixed in MuJoCo's frame. f_ext and params
        as in inverse_dynamics.
        """
        dq, dqd = dispatch(self, "inverse_dynamics_derivatives", q, qd, qdd, f_ext, self._parameters(params))
        if not self._robot._with_passive:
            return dq, dqd
        # - passive_forces adds stiffness and damping to the diagonals.
        damping, stiffness, _ = self._robot._passive.coefficients(dq)
        return dq + torch.diag_embed(stiffness), dqd + torch.diag_embed(damping)

    def forward_dynamics_derivatives(self, q, qd, tau, f_ext=None,
                                     params=None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Analytic (d qdd / dq, d qdd / dqd, d qdd / dtau), each (..., nv, nv), of forward_dynamics.

        Tangent derivatives as in inverse_dynamics_derivatives; d qdd / dtau = M^-1.
        """
        params = self._parameters(params)
        if not self._robot._with_passive:
            return dispatch(self, "forward_dynamics_derivatives", q, qd, tau, f_ext, params)
        # qdd = FD(q, qd, tau + passive(q, qd)): the chain rule through the passive forces' diagonals.
        dq, dqd, minv = dispatch(self, "forward_dynamics_derivatives", q, qd,
                                 self._robot._passive.added("forward_dynamics_derivatives", q, qd, tau), f_ext, params)
        damping, stiffness, _ = self._robot._passive.coefficients(minv)
        return dq - minv * stiffness, dqd - minv * damping, minv

    def inverse_dynamics_second_derivatives(self, q, qd, qdd, f_ext=None, params=None) -> tuple[torch.Tensor, ...]:
        """Analytic second derivatives of inverse_dynamics, each (..., nv, nv, nv), tau's index first:

            d2tau_dq2[i, j, k]   = d/dq_k  (d tau / dq)[i, j]
            d2tau_dqd2[i, j, k]  = d/dqd_k (d tau / dqd)[i, j]
            d2tau_dqdqd[i, j, k] = d/dqd_k (d tau / dq)[i, j]
            dM_dq[i, j, k]       = d/dq_k M[i, j]

        Pinocchio's ComputeRNEASecondOrderDerivatives layout (d2tau_dqdq, d2tau_dvdv, dtau_dqdv,
        dtau_dadq), with f_ext; tangent derivatives as in inverse_dynamics_derivatives, so on a floating
        base d2tau_dq2 is not symmetric in j, k. Passive forces are linear in q and qd: no term here.
        In the MuJoCo convention, the derivatives of its first derivatives along mj_integratePos's tangent,
        qvel and qacc held fixed in MuJoCo's frame; with free joints, composed in torch from Pinocchio's
        tensors (torch_grid/ops/mujoco_second_order.py).
        """
        params = self._parameters(params)
        if self._differs():  # composed in torch: its arguments checked here, as an op's are
            nv, nbodies = self._robot.nv, self._robot.nbodies
            check_arguments("inverse_dynamics_second_derivatives", (
                ("q", q, (self._robot.nq,)), ("qd", qd, (nv,)), ("qdd", qdd, (nv,)), ("f_ext", f_ext, (nbodies, 6)),
                ("params", params, (nbodies, 10))))
            return mujoco_second_order.inverse_dynamics_second_derivatives_mujoco(self._robot, q, qd, qdd, f_ext, params)
        return dispatch(self, "inverse_dynamics_second_derivatives", q, qd, qdd, f_ext, params)

    def forward_dynamics_second_derivatives(self, q, qd, tau, f_ext=None, params=None) -> tuple[torch.Tensor, ...]:
        """Second derivatives of forward_dynamics, each (..., nv, nv, nv), in the layout of
        inverse_dynamics_second_derivatives: (d2qdd_dq2, d2qdd_dqd2, d2qdd_dqdqd, d2qdd_dtaudq) with
        d2qdd_dtaudq[i, j, k] = d/dq_k (M^-1)[i, j].

        Closed form at qdd = forward_dynamics(q, qd, tau): differentiating ID(q, qd, qdd(x)) = tau
        twice, with Z = d qdd / dx,
            d2qdd/dx_j dx_k = -M^-1 (d2tau/dx_j dx_k + dM/dx_j Z_k + dM/dx_k Z_j)
        (dM/dx only along q), from inverse_dynamics_second_derivatives and forward_dynamics_derivatives, in
        either convention.
        """
        qdd = self.forward_dynamics(q, qd, tau, f_ext, params)
        z_q, z_qd, minv = self.forward_dynamics_derivatives(q, qd, tau, f_ext, params)
        return second_order(self.inverse_dynamics_second_derivatives(q, qd, qdd, f_ext, params), z_q, z_qd, minv)

    def _differs(self) -> bool:
        """Whether this view is MuJoCo's convention of a robot on which it differs from Pinocchio's."""
        return self._convention == 1 and self._robot.model.conventions_differ

    def passive_forces(self, q, qd) -> torch.Tensor:
        """MuJoCo's qfrc_passive of the joints' damping and stiffness (..., nv):
        -damping qd - stiffness (q - springref), damping on the dofs of hinge, slide and ball joints, stiffness
        on hinge and slide joints, whether or not the other functions include it
        (`load(..., passive_forces=...)`); zero for a model without them."""
        coupling = self._robot._coupling
        if coupling is None:
            return self._robot._passive(q, qd)
        check_tensor("passive_forces", "q", q, (self._robot.nq,), q)
        check_tensor("passive_forces", "qd", qd, (self._robot.nv,), q)
        return coupling.rows(self._robot._passive(coupling.q(q), coupling.v(qd)), -1)

    def inverse_dynamics_external_force_derivatives(self, q) -> torch.Tensor:
        """d inverse_dynamics / d f_ext (..., nv, nbodies, 6) = -J_k^T, J_k body k's Jacobian in its joint frame."""
        if forward_mode((q,)):
            return -self._body_jacobians(q)
        return dispatch(self, "inverse_dynamics_external_force_derivatives", q)

    def forward_dynamics_external_force_derivatives(self, q, params=None) -> torch.Tensor:
        """d forward_dynamics / d f_ext (..., nv, nbodies, 6) = M^-1 J_k^T; params as in inverse_dynamics."""
        params = self._parameters(params)
        if forward_mode((q, params)):
            return (self.minv(q, params) @ self._body_jacobians(q).flatten(-2)).unflatten(-1, (self._robot.nbodies, 6))
        return dispatch(self, "forward_dynamics_external_force_derivatives", q, params)

    def _body_jacobians(self, q) -> torch.Tensor:
        """(..., nv, nbodies, 6): [m, k] = J_k e_m, from body_velocities (linear in qd), which has a forward
        mode: the external-force gradients in forward mode (their kernels have none)."""
        eye = torch.eye(self._robot.nv, dtype=q.dtype, device=q.device)
        return self.body_velocities(q.unsqueeze(-2), eye)

    def osc_inertia(self, q, frame: str | int, reference: str = "local_world_aligned", params=None) -> torch.Tensor:
        """Operational-space inertia Lambda = (J M^-1 J^T)^-1 (..., 6, 6) of a frame, J its Jacobian in
        `reference` (as frame_jacobian). Lambda exists only where J has full rank 6: a frame moved by
        fewer than 6 dofs raises ValueError; at a singular configuration of a frame that has 6 or more,
        the entries are huge (1e46 on iiwa14 at q = 0, J M^-1 J^T being singular up to rounding), inf or NaN:
        check the conditioning of J rather than isfinite. params as in inverse_dynamics."""
        robot = self._robot
        index, ref = robot.frame_index(frame, "osc_inertia: frame"), reference_code("osc_inertia", reference)
        dofs = robot._frame_dofs(index)
        if dofs < 6:
            raise ValueError(f"osc_inertia: frame {robot.frame_names[index]!r} is moved by {dofs} dofs; its operational-"
                             "space inertia exists only for a frame with full 6-dof mobility")
        params = self._parameters(params)
        if forward_mode((q, params)):  # composed of ops that have a forward mode (the kernel has none)
            J = self.frame_jacobian(q, index, reference)
            return torch.linalg.inv(J @ self.minv(q, params) @ J.mT)
        return dispatch(self, "osc_inertia", q, index, ref, params)

    def cmm_time_variation(self, q, qd, params=None) -> torch.Tensor:
        """dA (..., 6, nv) with dh/dt = A qdd + dA qd (Pinocchio's dAg, computeCentroidalMapTimeVariation; in
        MuJoCo's convention, for its A and qacc). Only its product with qd is A's time derivative times qd: its
        columns are not each one's time derivative (that matrix is centroidal_map_derivatives(q) contracted with
        qd). params as in inverse_dynamics."""
        return dispatch(self, "cmm_time_variation", q, qd, self._parameters(params))

    def dccrba(self, q, qd, params=None) -> torch.Tensor:
        """d h / dq (..., 6, nv) of the centroidal momentum h = A qd, qd held fixed (in MuJoCo's
        convention, qvel fixed in MuJoCo's frame); dh/dqd is A itself; params as in inverse_dynamics."""
        return dispatch(self, "dccrba", q, qd, self._parameters(params))

    def centroidal_map_derivatives(self, q, params=None) -> torch.Tensor:
        """d A / dq (..., 6, nv, nv) of the centroidal momentum matrix: [..., i, j, k] = d A_ij / dq_k
        along the tangent (as dccrba). Column j of A is the momentum at qd = e_j, so this is
        dccrba at each unit velocity: nv times its cost. params as in inverse_dynamics."""
        params = self._parameters(params)
        nv = self._robot.nv
        check_arguments("centroidal_map_derivatives", (("q", q, (self._robot.nq,)),
                                                       ("params", params, (self._robot.nbodies, 10))))
        unit = torch.eye(nv, dtype=q.dtype, device=q.device)
        dh = self.dccrba(q.unsqueeze(-2).expand(*q.shape[:-1], nv, q.shape[-1]), unit.expand(*q.shape[:-1], nv, nv),
                         None if params is None else params.unsqueeze(-3))
        return dh.movedim(-3, -2)

    def coriolis_matrix(self, q, qd, params=None) -> torch.Tensor:
        """C (..., nv, nv) with C qd + g = nonlinear_effects: Pinocchio's computeCoriolisMatrix (dM/dt - 2C
        skew-symmetric). In MuJoCo's convention C = G (C_pin G^T + M K) with K = d(G^T)/dt (G maps Pinocchio's
        velocities to MuJoCo's), so that C qd + g is MuJoCo's bias force and dM/dt - 2C is skew-symmetric there
        too. params as in inverse_dynamics."""
        return dispatch(self, "coriolis_matrix", q, qd, self._parameters(params))

    def inverse_dynamics_regressor(self, q, qd, qdd) -> torch.Tensor:
        """Y (..., nv, 10 nbodies): the bodies' part of inverse_dynamics(q, qd, qdd) = Y @ inertial_parameters()
        plus the terms free of them (armature, passive and external forces)."""
        return dispatch(self, "inverse_dynamics_regressor", q, qd, qdd)

    def kinetic_energy_regressor(self, q, qd) -> torch.Tensor:
        """(..., 10 nbodies): the bodies' kinetic energy = regressor @ inertial_parameters() (the rotors' armature
        not included)."""
        return dispatch(self, "kinetic_energy_regressor", q, qd)

    def potential_energy_regressor(self, q) -> torch.Tensor:
        """(..., 10 nbodies): gravity's potential energy = regressor @ inertial_parameters() (the joint springs' not
        included)."""
        return dispatch(self, "potential_energy_regressor", q)

    def forward_dynamics_parameter_derivatives(self, q, qd, tau, f_ext=None, params=None) -> torch.Tensor:
        """d forward_dynamics / d inertial_parameters (..., nv, 10 nbodies) = -M^-1 Y at qdd = FD, at the
        parameters params; f_ext and params as in inverse_dynamics."""
        params = self._parameters(params)
        # composed of ops: under forward mode (the kernel has none), and with external forces (which move
        # qdd, where the kernel evaluates Y, and nothing else)
        if f_ext is not None or forward_mode((q, qd, tau, params)):
            qdd = self.forward_dynamics(q, qd, tau, f_ext, params)
            return -(self.minv(q, params) @ self.inverse_dynamics_regressor(q, qd, qdd))
        if self._robot._with_passive:
            tau = self._robot._passive.added("forward_dynamics_parameter_derivatives", q, qd, tau)
        return dispatch(self, "forward_dynamics_parameter_derivatives", q, qd, tau, params)

    def inertial_parameters(self, dtype: torch.dtype | None = None, device=None) -> torch.Tensor:
        """(10 nbodies,) each body's [m, m c, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz] in Pinocchio's order:
        c the centre of mass and I the rotational inertia about the joint frame origin, float64 on the CPU
        unless dtype, device say otherwise; on a view of with_parameters, its parameters, (..., 10 nbodies),
        in their own dtype and on their own device unless dtype, device say otherwise."""
        if dtype is not None and dtype not in (torch.float32, torch.float64):  # an integer dtype truncated them
            raise TypeError(f"inertial_parameters: dtype must be torch.float32 or torch.float64, got {dtype}")
        if self._params is not None:
            return self._params.flatten(-2).to(dtype=dtype or self._params.dtype, device=device or self._params.device)
        dtype, device = dtype or torch.float64, device or "cpu"
        rows = []
        for j in self._robot.model.joints:
            I = inertia_about_origin(j.mass, j.com, j.inertia)
            rows.append([j.mass, *(j.mass * c for c in j.com), I[0], I[1], I[4], I[2], I[5], I[8]])
        return torch.tensor(rows, dtype=dtype, device=device).reshape(-1)

    def with_parameters(self, params: torch.Tensor, check: bool = False) -> "RobotView":
        """A view of these functions computing with the inertial parameters `params` instead of the robot's
        own: every function whose value depends on them uses them; the others (kinematics, regressors,
        the configuration space) compute as they do on the robot.

        Args:
            params: (..., nbodies, 10), each body's [m, m c, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz] in
                Pinocchio's order (c the centre of mass in the joint frame, I the rotational inertia about
                the joint frame origin), as inertial_parameters().view(nbodies, 10); leading dimensions
                broadcast against the states' (one set per sample for domain randomisation). Gradients
                flow back to it.
            check: raise ValueError, naming the body, where the parameters are not physically consistent
                (not finite, a negative mass, a massless body with a first moment or an inertia, or a
                pseudo-inertia that is not positive semidefinite) or make the joint-space inertia matrix
                singular (a joint whose bodies, its own and those below it, are all massless).

        Returns:
            A RobotView in this one's convention.
        """
        view = self._with(params, "with_parameters")
        if check:
            check_physical(params, self.body_names, parents=[j.parent for j in self._robot.model.joints])
        return view

    def _with(self, params: torch.Tensor, function: str) -> "RobotView":
        """with_parameters(params) for `function`, which a wrong shape's error names."""
        nbodies = self._robot.nbodies
        if not isinstance(params, torch.Tensor) or params.dim() < 2 or tuple(params.shape[-2:]) != (nbodies, 10):
            shape = tuple(params.shape) if isinstance(params, torch.Tensor) else type(params).__name__
            raise ValueError(f"{function}: params must be a tensor of shape (..., {nbodies}, 10), got {shape}")
        if params.dtype not in (torch.float32, torch.float64):  # check=True read truncated masses
            raise TypeError(f"{function}: params must be float32 or float64, got {params.dtype}")
        return RobotView(self._robot, self._convention, params)

    def _parameters(self, params: torch.Tensor | None) -> torch.Tensor | None:
        """The inertial parameters a call computes with: its own argument, else the view's."""
        return self._params if params is None else params

    def _kernel_call(self, name: str, *args):
        """Op `name` of the kernels (every joint independent), in this view's convention."""
        return kernel_call(self, name, *args)


class RobotView(_Functions):
    """A robot's functions in one fixed convention: `robot.pin` (Pinocchio's) or `robot.mujoco` (MuJoCo's).

    It has every function of its Robot and the robot's sizes and names (nq, nv, nbodies, nframes,
    joint_names, body_names, frame_names, floating_base, name), `frame_index`, `model`, `save`, `convention`
    and `robot`, the Robot itself; its `pin` and `mujoco` are the same view (its inertial parameters included)
    in either convention. A view holds no state of its own: it is cheap to make and safe to share between
    threads.
    """

    def __init__(self, robot: "Robot", convention: int, params: torch.Tensor | None = None):
        """Made by `robot.pin`, `robot.mujoco` and `with_parameters`; convention: 0 (Pinocchio's) or 1
        (MuJoCo's); params: the inertial parameters the view computes with (None: the robot's)."""
        self._robot = robot
        self._convention = convention
        self._params = params

    @property
    def convention(self) -> str:
        """This view's convention: "pin" or "mujoco"."""
        return "mujoco" if self._convention else "pin"

    @property
    def pin(self) -> "RobotView":
        """This view in Pinocchio's convention."""
        return RobotView(self._robot, 0, self._params)

    @property
    def mujoco(self) -> "RobotView":
        """This view in MuJoCo's convention (as Robot.mujoco, which raises where the robot was loaded with
        enable_mujoco_kernels=False and has a free or ball joint, or has a free joint placed away from the origin)."""
        return RobotView(self._robot, self._robot._convention_code("mujoco"), self._params)

    @property
    def model(self) -> RobotModel:
        """The robot's description (Robot.model)."""
        return self._robot.model

    def frame_index(self, frame: str | int, argument: str = "frame") -> int:
        """Index in frame_names of a frame given by name or index (Robot.frame_index)."""
        return self._robot.frame_index(frame, argument)

    def save(self, path: str | Path) -> None:
        """Write the robot's model description (Robot.save)."""
        self._robot.save(path)

    def __repr__(self) -> str:
        given = ", given inertial parameters" if self._params is not None else ""
        return f"<{self._robot.name} functions, {self.convention} convention{given}>"


class Robot(_Functions):
    """A robot with generated kernels. Create it with `torch_grid.load`.

    Its functions use the default convention (`robot.convention`); `robot.pin` and `robot.mujoco`
    are views that always use one convention.
    """

    def __init__(self, model: RobotModel, namespace: str, convention: str = "pin", mujoco_kernels: bool = True,
                 passive_forces: bool = True, cache_dir: str | None = None):
        self._robot = self  # the description properties read it, joint_names below among them
        self.model = model
        self._coupling = Coupling(model) if model.mimics else None
        types = {j.name: j.type for j in model.joints}
        self._space = Space.of([types[name] for name in self.joint_names])
        self._passive = PassiveForces(model)
        if self._coupling is not None and self._passive.any:
            raise ValueError(f"robot {model.name!r}: mimic joints together with joint damping or stiffness are not "
                             "supported")
        self._include_passive = passive_forces
        self._cache_dir = cache_dir  # where its kernels were found or built: a pickled copy looks there too
        self._with_passive = passive_forces and self._passive.any
        # semi_implicit_euler's velocity update solves with M + dt D (mj_Euler), where D is not zero
        self._implicit_damping = self._with_passive and model.eulerdamp and self._passive.damps
        self._ops = getattr(torch.ops, namespace)
        self._func = FuncOps(self._ops, model.kernel_model)
        self._eager = EagerOps(self._ops, model.kernel_model)
        self._enable_mujoco_kernels = mujoco_kernels
        self._mujoco_kernels = (mujoco_kernels and not model.placed_free_joint) or not model.conventions_differ
        sizes = model_sizes(model)
        # op -> (position, trailing shape) of each tensor argument, for the checks of every call
        self._tensor_args = {name: [(k, torch.Size(sizes.get(d, d) for d in a.trailing))
                                    for k, a in enumerate(spec.args) if a.is_tensor] for name, spec in OPS.items()}
        self.convention = convention
        step_op(self)  # the step's op for torch.compile, defined here rather than inside a trace

    @property
    def convention(self) -> str:
        """Default convention of this handle's functions: "pin" or "mujoco" (settable)."""
        return "mujoco" if self._convention else "pin"

    @convention.setter
    def convention(self, value: str) -> None:
        self._convention = self._convention_code(value)

    @property
    def pin(self) -> RobotView:
        """The robot's functions in Pinocchio's convention, whatever `convention` is (a RobotView)."""
        return RobotView(self, 0)

    @property
    def mujoco(self) -> RobotView:
        """The robot's functions in MuJoCo's convention, whatever `convention` is (a RobotView).

        Raises ValueError for a robot with a free or ball joint loaded with enable_mujoco_kernels=False, or with
        a free joint placed away from the world's origin (a pinocchio.Model's FreeFlyer may be).
        """
        return RobotView(self, self._convention_code("mujoco"))

    def frame_index(self, frame: str | int, argument: str = "frame") -> int:
        """Index in frame_names of a frame given by name or index; a name several frames share (a URDF link and
        a joint, say) is refused, as Pinocchio's getFrameId refuses it, naming their indices."""
        return self.model.frame_index(frame, argument)

    def _frame_dofs(self, index: int) -> int:
        """Number of dofs on the chain from frame `index` to the root: those that move it (a mimic joint
        and its master in the chain count once)."""
        model, body, dofs = self.model, self.model.frames[index].parent, set()
        while body >= 0:
            vi = model.v_index[body]
            dofs.update(range(vi, vi + model.joints[body].nv))
            body = model.joints[body].parent
        return len({self._coupling.v_src[k] for k in dofs} if self._coupling else dofs)

    def save(self, path: str | Path) -> None:
        """Write the model description (JSON); `torch_grid.load(path)` rebuilds it, with neither Pinocchio
        nor MuJoCo."""
        self.model.save(path)

    def __reduce__(self):
        """Pickles as its model and options (pickle, copy.deepcopy, torch.save, spawned workers): the
        receiving process loads it again, from its kernel cache or by building it."""
        return _restore, (self.model.to_json(), self.convention, self._enable_mujoco_kernels, self._include_passive,
                          self._cache_dir)

    def _convention_code(self, value: str) -> int:
        code = CONVENTIONS[convention_name(value, stacklevel=4)]  # a former name's warning: the setter's caller
        if code and not self._mujoco_kernels:
            placed = self.model.placed_free_joint
            raise ValueError(f"convention='mujoco': robot {self.name!r} was built with enable_mujoco_kernels=False" if not placed
                             else f"convention='mujoco': robot {self.name!r} has free joint {placed!r} placed away from "
                             "the world's origin, where MuJoCo's convention has each free joint (its qpos is its world pose)")
        return code

    def __repr__(self) -> str:
        base = "floating" if self.floating_base else "fixed"
        passive = ", passive forces" if self.includes_passive_forces else ""
        return f"<Robot {self.name!r}: {base} base, nq={self.nq}, nv={self.nv}, {self.convention} convention{passive}>"


def _restore(model_json: str, convention: str, enable_mujoco_kernels: bool, passive_forces: bool = True,
             cache_dir: str | None = None) -> "Robot":
    from . import load

    return load(RobotModel.from_dict(json.loads(model_json)), convention=convention,
                enable_mujoco_kernels=enable_mujoco_kernels, passive_forces=passive_forces, cache_dir=cache_dir)
