"""The op table: the one description of every op's arguments, output shapes and kernel.

From it come the dispatcher schemas and C++ wrappers (codegen.py), the fake implementations that
let torch.compile propagate shapes (registered here), and argument checking in `Robot`.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import torch

from ..model.description import RobotModel

# Tensor argument kinds: their trailing shape (None: the argument's own `shape`). The kind also says
# how the MuJoCo convention's input becomes Pinocchio's, which every kernel computes in: the
# configuration's quaternion is reordered; a velocity, force or acceleration has its base-linear part
# rotated (the acceleration with a term of the op's velocity); the others are the same in both, the
# bodies' inertial parameters (kind "parameters", Pinocchio's order, in the joint frames) among them.
TENSOR_KINDS = {"configuration": ("nq",), "velocity": ("nv",), "acceleration": ("nv",), "force": ("nv",),
                "body_forces": ("nbodies", 6), "frame_weights": ("nframes", 6), "parameters": ("nbodies", 10),
                "plain": None}
INTEGER_KINDS = ("frame", "frames", "reference", "mask", "scheme", "tableau", "integrator", "passive")
# Output kinds, and the reframe each gets in the MuJoCo convention, applied by the generated binding:
# force G x; acceleration G (x + base term); congruence G X G^T (nv x nv); columns X G^T (k x nv);
# force_rows G X (nv x k); plain: none. "twin": the kernel reframes it itself, by a hand-derived formula.
# "workspace": the kernel's scratch, not a result (on the CPU one block per thread, returned expanded over
# the batch; on CUDA one per sample).
OUTPUT_KINDS = ("force", "acceleration", "congruence", "columns", "force_rows", "plain", "twin", "workspace")
SIZES = ("nv", "nq", "nbodies", "nparams", "nframes", "nsel")
# What one call can carry (csrc/batch/batch.h: kMaxIn, kMaxOut), checked when the table is built.
MAX_TENSOR_INPUTS, MAX_OUTPUTS = 8, 5


@dataclass(frozen=True)
class Arg:
    name: str
    kind: str  # one of TENSOR_KINDS or INTEGER_KINDS
    optional: bool = False
    shape: tuple = ()  # trailing shape of a "plain" tensor

    @property
    def is_tensor(self) -> bool:
        return self.kind in TENSOR_KINDS

    @property
    def trailing(self) -> tuple:
        shape = TENSOR_KINDS.get(self.kind)
        return self.shape if shape is None else shape


@dataclass(frozen=True)
class Out:
    name: str
    kind: str  # one of OUTPUT_KINDS
    shape: tuple  # trailing shape; symbols "nv", "nq", "nbodies", "nparams", "nframes", "nsel"


@dataclass(frozen=True)
class OpSpec:
    name: str
    kernel: str  # C++ kernel struct in csrc/kernels/ops.h (for a forward-mode backward, the generated binding)
    args: tuple[Arg, ...]
    outputs: tuple[Out, ...]
    family: str = "dynamics"  # the compilation unit of the robot library it goes in (units build in parallel)
    forward_mode_of: str = ""  # set on the vector-Jacobian product of that op by forward-mode kernels
    jvp_of: str = ""  # set on the Jacobian-vector product of that op by forward-mode kernels
    jvp_wrt: tuple[str, ...] = ()  # the inputs whose tangents a Jacobian-vector product takes
    jvp_in_place: bool = False  # a Jacobian-vector product returning (value, tangent) pairs, trailing dim 2
    mujoco_twin: bool = True  # False: no MuJoCo-convention kernel where the conventions differ (the call refuses)
    # How the op is differentiated (BACKWARD_KINDS, JVP_KINDS), and the dual-number kernels generated for it
    backward: str = "none"
    jvp: str = "none"
    dual_backward: bool = False  # <op>_backward: the kernel on dual numbers, one pass per input coordinate
    dual_jvp: tuple[str, ...] = ()  # <op>_jvp: the kernel on dual numbers along the tangents of these inputs
    contracted: bool = False  # <op>_backward contracts the output with its cotangent inside the kernel
    # CPU kernels on vector lanes, several samples per instruction (csrc/batch/cpu_lanes.h); False where
    # gathering and scattering the samples costs more than the lanes save (bench/bench_lanes.py); a number:
    # lanes for a robot whose outputs are at most that many numbers a sample (on_lanes)
    lanes: bool | int = True
    # (F, X, ...): on a device path (a GPU, or the CPU build of a GPU thread's paths: TG_DEVICE_PATH) the kernel
    # leaves each output X as it is before the last step X <- -F X, and the glue finishes them with one batched
    # matrix product (glue.h: Call::negated_products), where a GPU thread's own loop over it was the larger
    # part of the kernel
    negated_products: tuple[str, ...] = ()

    @property
    def has_dual_backward(self) -> bool:
        return self.dual_backward or self.backward == "dual"

    @property
    def derived(self) -> bool:
        """Whether the op is another op's kernel run on dual numbers (its binding is generated)."""
        return bool(self.forward_mode_of or self.jvp_of)

    @property
    def tensor_args(self) -> tuple[Arg, ...]:
        return tuple(a for a in self.args if a.is_tensor)

    @property
    def twin(self) -> bool:
        """Whether the kernel reframes (some of) its outputs itself in the MuJoCo convention."""
        return any(o.kind == "twin" for o in self.outputs)

    def schema(self) -> str:
        types = {"frame": "int", "frames": "int[]", "reference": "int", "mask": "int", "scheme": "int", "tableau": "int",
                 "integrator": "int", "passive": "int"}
        params = [f"Tensor{'?' if a.optional else ''} {a.name}" if a.is_tensor else f"{types[a.kind]} {a.name}"
                  for a in self.args]
        outs = ", ".join("Tensor" for _ in self.outputs)
        return f"{self.name}({', '.join(params + ['int convention'])}) -> " + (f"({outs})" if len(self.outputs) > 1 else outs)

    def output_shapes(self, model: RobotModel, batch: tuple[int, ...], nsel: int = 0) -> list[tuple[int, ...]]:
        sizes = {**model_sizes(model), "nsel": nsel}
        return [tuple(batch) + tuple(sizes.get(d, d) for d in o.shape) for o in self.outputs]


def model_sizes(model: RobotModel) -> dict[str, int]:
    """The value of each size symbol of the table for one robot (all but "nsel", a call's frame count)."""
    return {"nv": model.nv, "nq": model.nq, "nbodies": model.nbodies, "nparams": 10 * model.nbodies,
            "nframes": len(model.frames)}


# How an op is differentiated, declared in its entry. Its backward (reverse mode, autograd.py):
#   "formula"   a formula of its own over kernels, mostly the O(n) vector-Jacobian product of inverse dynamics
#               (integrate's and difference's: their vector-Jacobian product kernels, integrate_vjp and difference_vjp);
#   "composed"  a formula over other ops' outputs and backwards (the op's outputs are products of theirs);
#   "dual"      its own kernel on dual numbers (<op>_backward): outputs that are already derivatives;
#   "step"      none: the kernels that fuse a composition (the step, its derivatives, d_integrate, d_difference), which
#               the Robot methods of those names replace by the torch composition whenever anything differentiates them;
#   "none"      none: a derivative computed inside another op's backward, or a second-order tensor.
# Its forward mode (torch.func.jvp, jacfwd, forward_ad; func.py):
#   "backward"  the derivative of its backward with respect to the cotangents (the backward is linear in them);
#   "rule"      a formula of its own;
#   "dual"      its own kernel on dual numbers along `dual_jvp` (<op>_jvp);
#   "none"      refused by name.
BACKWARD_KINDS = ("formula", "composed", "dual", "step", "none")
JVP_KINDS = ("backward", "rule", "dual", "none")

# inverse_dynamics_second_derivatives writes 4 nv^3 numbers a sample, a quarter of them nonzero: on lanes a group
# holds them for every lane before they are scattered, which pays up to about nv = 23 and costs more above
# (bench/RESULTS.md, "Second order on lanes")
SECOND_ORDER_LANES = 50_000

Q, QD, QDD, TAU = Arg("q", "configuration"), Arg("qd", "velocity"), Arg("qdd", "acceleration"), Arg("tau", "force")
FEXT = Arg("f_ext", "body_forces", True)
# the bodies' inertial parameters; absent: the robot's own, compiled in
PARAMS = Arg("params", "parameters", True)
FRAME, REFERENCE = Arg("frame", "frame"), Arg("reference", "reference")
# the joints' damping and springs in a step: 0 left out, 1 explicit, 2 with the damping implicit in the Euler step
PASSIVE = Arg("passive", "passive")
NV, NVxNV, NV3 = ("nv",), ("nv", "nv"), ("nv", "nv", "nv")
_VALUE_OPS = (
        OpSpec("inverse_dynamics", "InverseDynamics", (Q, QD, QDD, FEXT, PARAMS), (Out("tau", "force", NV),),
               backward="formula", jvp="backward", dual_jvp=("q", "qd")),
        OpSpec("forward_dynamics", "ForwardDynamics", (Q, QD, TAU, FEXT, PARAMS), (Out("qdd", "acceleration", NV),),
               backward="formula", jvp="backward"),
        OpSpec("crba", "Crba", (Q, PARAMS), (Out("M", "congruence", NVxNV),), backward="formula", jvp="backward"),
        OpSpec("crba_vjp", "CrbaVjp", (Q, Arg("weight", "plain", shape=NVxNV), PARAMS), (Out("grad_q", "plain", NV),),
               mujoco_twin=False, backward="formula", jvp="rule"),
        OpSpec("mass_product_vjp", "MassProductVjp",
               (Q, Arg("a", "plain", shape=NV), Arg("cotangent", "plain", shape=NV), PARAMS),
               (Out("grad_q", "plain", NV),), mujoco_twin=False, backward="formula", jvp="rule"),
        OpSpec("minv", "Minv", (Q, PARAMS), (Out("Minv", "congruence", NVxNV),), backward="formula", jvp="backward"),
        OpSpec("generalized_gravity", "GeneralizedGravity", (Q, PARAMS), (Out("g", "force", NV),),
               backward="formula", jvp="backward"),
        OpSpec("nonlinear_effects", "NonlinearEffects", (Q, QD, PARAMS), (Out("nle", "twin", NV),),
               backward="formula", jvp="backward"),
        OpSpec("energy", "Energy", (Q, QD, PARAMS), (Out("energy", "plain", (3,)),), backward="formula", jvp="backward"),
        OpSpec("com", "Com", (Q, PARAMS), (Out("com", "plain", (3,)),), "kinematics", backward="formula", jvp="dual",
               dual_backward=True, dual_jvp=("q", "params")),
        OpSpec("jacobian_com", "JacobianCom", (Q, PARAMS), (Out("J", "columns", (3, "nv")),), "kinematics",
               backward="dual", jvp="dual", dual_jvp=("q", "params")),
        OpSpec("ccrba", "Ccrba", (Q, QD, PARAMS), (Out("A", "columns", (6, "nv")), Out("h", "plain", (6,))), "kinematics",
               backward="composed", jvp="dual", dual_jvp=("q", "qd", "params"), dual_backward=True),
        OpSpec("forward_kinematics", "ForwardKinematics", (Q,),
               (Out("positions", "plain", ("nframes", 3)), Out("rotations", "plain", ("nframes", 3, 3))), "kinematics",
               backward="formula", jvp="backward"),
        OpSpec("end_effector_pose", "EndEffectorPose", (Q, Arg("frames", "frames")), (Out("pose", "plain", ("nsel", 6)),),
               "kinematics", backward="formula", jvp="backward"),
        OpSpec("frame_jacobian", "FrameJacobian", (Q, FRAME, REFERENCE), (Out("J", "columns", (6, "nv")),), "kinematics",
               backward="formula", dual_backward=True, jvp="rule"),
        OpSpec("frame_jacobian_vjp", "FrameJacobianVjp", (Q, Arg("weight", "plain", shape=(6, "nv")), FRAME, REFERENCE),
               (Out("grad_q", "plain", NV),), "kinematics", mujoco_twin=False),
        OpSpec("frame_kinematic_hessian", "FrameKinematicHessian", (Q, FRAME, REFERENCE), (Out("H", "plain", (6, "nv", "nv")),),
               "kinematics", mujoco_twin=False),
        OpSpec("frame_jacobian_dot", "FrameJacobianDot", (Q, QD, FRAME, REFERENCE), (Out("Jdot", "twin", (6, "nv")),),
               "kinematics", backward="dual", jvp="dual", dual_jvp=("q", "qd")),
        OpSpec("inverse_dynamics_vjp", "InverseDynamicsVjp", (Q, QD, QDD, FEXT, Arg("cotangent", "force"), PARAMS),
               (Out("grad_q", "twin", NV), Out("grad_qd", "twin", NV)), backward="formula", jvp="rule"),
        OpSpec("inverse_dynamics_vjp_full", "InverseDynamicsVjpFull", (Q, QD, QDD, FEXT, Arg("cotangent", "force"), PARAMS),
               (Out("grad_q", "twin", NV), Out("grad_qd", "twin", NV), Out("grad_qdd", "force", NV),
                Out("tau", "force", NV)), "derivatives", dual_jvp=("q", "qd")),
        OpSpec("inertia_solve", "InertiaSolve", (Q, Arg("x", "force"), PARAMS), (Out("y", "force", NV),),
               backward="formula", jvp="rule"),
        OpSpec("body_velocities", "BodyVelocities", (Q, QD), (Out("v", "plain", ("nbodies", 6)),), "kinematics",
               backward="dual", jvp="rule", dual_jvp=("q",)),
        OpSpec("frames_vjp", "FramesVjp", (Q, Arg("weights", "frame_weights")), (Out("tau", "force", NV),), "kinematics",
               backward="dual", jvp="rule", dual_jvp=("q",)),
        OpSpec("inverse_dynamics_derivatives", "InverseDynamicsDerivatives", (Q, QD, QDD, FEXT, PARAMS),
               (Out("dtau_dq", "twin", NVxNV), Out("dtau_dqd", "twin", NVxNV)), "derivatives",
               backward="composed", jvp="rule"),
        OpSpec("inverse_dynamics_second_derivatives", "InverseDynamicsSecondDerivatives", (Q, QD, QDD, FEXT, PARAMS),
               (Out("d2tau_dq2", "plain", NV3), Out("d2tau_dqd2", "plain", NV3), Out("d2tau_dqdqd", "plain", NV3),
                Out("dM_dq", "plain", NV3)), "second_order", mujoco_twin=False, lanes=SECOND_ORDER_LANES),
        OpSpec("inverse_dynamics_derivatives_vjp", "InverseDynamicsDerivativesVjp",
               (Q, QD, QDD, FEXT, Arg("grad_dtau_dq", "plain", shape=NVxNV), Arg("grad_dtau_dqd", "plain", shape=NVxNV), PARAMS),
               (Out("grad_q", "plain", NV), Out("grad_qd", "plain", NV), Out("grad_qdd", "plain", NV),
                Out("grad_f_ext", "plain", ("nbodies", 6))), "second_order", mujoco_twin=False),
        OpSpec("inverse_dynamics_derivatives_tangent", "InverseDynamicsDerivativesTangent",
               (Q, QD, QDD, FEXT, Arg("t_q", "plain", shape=NV), Arg("t_qd", "plain", shape=NV), Arg("t_qdd", "plain", shape=NV),
                PARAMS),
               (Out("dtau_dq_dot", "plain", NVxNV), Out("dtau_dqd_dot", "plain", NVxNV), Out("M_dot", "plain", NVxNV)),
               "second_order", mujoco_twin=False),
        OpSpec("forward_dynamics_derivatives", "ForwardDynamicsDerivatives", (Q, QD, TAU, FEXT, PARAMS),
               (Out("dqdd_dq", "twin", NVxNV), Out("dqdd_dqd", "twin", NVxNV), Out("dqdd_dtau", "twin", NVxNV)),
               "derivatives", backward="composed", jvp="rule", negated_products=("dqdd_dtau", "dqdd_dq", "dqdd_dqd")),
        OpSpec("integrate", "Integrate", (Q, Arg("v", "plain", shape=NV), Arg("dt", "plain", shape=(1,))),
               (Out("q_next", "twin", ("nq",)),), "kinematics", backward="formula"),
        OpSpec("difference", "Difference", (Q, Arg("q1", "plain", shape=("nq",))),
               (Out("v", "twin", NV),), "kinematics", backward="formula"),
        OpSpec("d_integrate", "DIntegrate", (Q, Arg("v", "plain", shape=NV), Arg("dt", "plain", shape=(1,))),
               (Out("J_q", "twin", NVxNV), Out("J_v", "twin", NVxNV)), "kinematics", backward="step"),
        OpSpec("d_difference", "DDifference", (Q, Arg("q1", "plain", shape=("nq",))),
               (Out("J_q0", "twin", NVxNV), Out("J_q1", "twin", NVxNV)), "kinematics", backward="step"),
        OpSpec("tangent_to_ambient", "TangentToAmbient", (Q, Arg("g", "plain", shape=NV)),
               (Out("grad_q", "twin", ("nq",)),), "kinematics"),
        OpSpec("integrate_vjp", "IntegrateVjp",
               (Q, Arg("v", "plain", shape=NV), Arg("dt", "plain", shape=(1,)), Arg("grad", "plain", shape=("nq",))),
               (Out("grad_q", "twin", ("nq",)), Out("grad_v", "twin", NV), Out("grad_dt", "plain", (1,))), "kinematics"),
        OpSpec("difference_vjp", "DifferenceVjp", (Q, Arg("q1", "plain", shape=("nq",)), Arg("grad", "plain", shape=NV)),
               (Out("grad_q0", "twin", ("nq",)), Out("grad_q1", "twin", ("nq",))), "kinematics"),
        OpSpec("step", "Step",
               (Q, QD, TAU, FEXT, Arg("dt", "plain", shape=(1,)), PARAMS, Arg("scheme", "integrator"), PASSIVE),
               (Out("q_next", "twin", ("nq",)), Out("qd_next", "twin", NV)), "derivatives", backward="step"),
        OpSpec("step_derivatives", "StepDerivatives",
               (Q, QD, TAU, FEXT, Arg("dt", "plain", shape=(1,)), PARAMS, Arg("scheme", "scheme"), PASSIVE),
               (Out("q_next", "twin", ("nq",)), Out("qd_next", "twin", NV), Out("A", "twin", (2, "nv", 2, "nv")),
                Out("B", "twin", (2, "nv", "nv"))), "derivatives", backward="step"),
        OpSpec("rk_step_derivatives", "RkStepDerivatives",
               (Q, QD, TAU, FEXT, Arg("dt", "plain", shape=(1,)), PARAMS, Arg("scheme", "tableau"), PASSIVE),
               (Out("q_next", "twin", ("nq",)), Out("qd_next", "twin", NV), Out("A", "twin", (2, "nv", 2, "nv")),
                Out("B", "twin", (2, "nv", "nv")), Out("work", "workspace", (8, "nv", 3, "nv"))), "derivatives", backward="step"),
        OpSpec("inverse_dynamics_external_force_derivatives", "InverseDynamicsExternalForceDerivatives", (Q,),
               (Out("dtau_dfext", "force_rows", ("nv", "nbodies", 6)),), "derivatives", backward="composed"),
        OpSpec("forward_dynamics_external_force_derivatives", "ForwardDynamicsExternalForceDerivatives", (Q, PARAMS),
               (Out("dqdd_dfext", "force_rows", ("nv", "nbodies", 6)),), "derivatives", backward="composed"),
        OpSpec("osc_inertia", "OscInertia", (Q, FRAME, REFERENCE, PARAMS), (Out("Lambda", "plain", (6, 6)),), "derivatives",
               backward="composed"),
        OpSpec("cmm_time_variation", "CmmTimeVariation", (Q, QD, PARAMS), (Out("Adot", "twin", (6, "nv")),), "kinematics",
               backward="dual", jvp="dual", dual_jvp=("q", "qd", "params")),
        OpSpec("dccrba", "Dccrba", (Q, QD, PARAMS), (Out("dh_dq", "twin", (6, "nv")),), "kinematics",
               backward="dual", jvp="dual", dual_jvp=("q", "qd", "params")),
        OpSpec("coriolis_matrix", "CoriolisMatrix", (Q, QD, PARAMS), (Out("C", "twin", NVxNV),), "derivatives",
               backward="dual", jvp="dual", dual_jvp=("q", "qd", "params")),
        OpSpec("inverse_dynamics_regressor", "InverseDynamicsRegressor", (Q, QD, QDD), (Out("Y", "force_rows", ("nv", "nparams")),),
               "regressors",
               backward="dual", jvp="dual", dual_jvp=("q", "qd", "qdd"), contracted=True, jvp_in_place=True),
        OpSpec("kinetic_energy_regressor", "KineticEnergyRegressor", (Q, QD), (Out("Yk", "plain", ("nparams",)),), "regressors",
               backward="dual", jvp="dual", dual_jvp=("q", "qd")),
        OpSpec("potential_energy_regressor", "PotentialEnergyRegressor", (Q,), (Out("Yp", "plain", ("nparams",)),), "regressors",
               backward="dual", jvp="dual", dual_jvp=("q",)),
        OpSpec("forward_dynamics_parameter_derivatives", "ForwardDynamicsParameterDerivatives", (Q, QD, TAU, PARAMS),
               (Out("dqdd_dparams", "force_rows", ("nv", "nparams")),), "regressors", backward="composed"),
)

# Views of the entries: the ops with a <op>_backward kernel (those whose outputs are already derivatives, where the
# gradient is a second-order quantity), and of those the ones that contract the output with its cotangent
# inside the kernel (the output itself would not fit a GPU thread on dual numbers: Y is nv x 10 nbodies).
FORWARD_MODE_BACKWARD = tuple(op.name for op in _VALUE_OPS if op.has_dual_backward)
CONTRACTED = tuple(op.name for op in _VALUE_OPS if op.contracted)


def forward_mode_backward(op: OpSpec) -> OpSpec:
    """`<op>_backward(inputs..., cotangents..., needs)`: the gradient of sum(cotangent * output) for
    each tensor input (bit i of `needs` asks for input i; the others come back zero)."""
    cotangents = tuple(Arg(f"grad_{o.name}", "plain", True, o.shape) for o in op.outputs)
    grads = tuple(Out(f"grad_{a.name}", "plain", a.trailing) for a in op.tensor_args)
    return OpSpec(f"{op.name}_backward", f"{op.kernel}Backward", op.args + cotangents + (Arg("needs", "mask"),),
                  grads, f"{op.family}_backward", forward_mode_of=op.name)


def forward_mode_jvp(op: OpSpec, wrt: tuple[str, ...]) -> OpSpec:
    """`<op>_jvp(inputs..., tangents...)`: the derivative of every output along the tangents of the
    inputs named in `wrt` (the other inputs held fixed; a null tangent is zero). For an op with jvp_in_place
    each output is its (value, tangent) pairs, of shape (..., *shape, 2)."""
    args = {a.name: a for a in op.tensor_args}
    tangents = tuple(Arg(f"{name}_dot", "plain", True, args[name].trailing) for name in wrt)
    in_place = op.jvp_in_place
    outputs = tuple(Out(f"{o.name}_dot", "plain", tuple(o.shape) + ((2,) if in_place else ())) for o in op.outputs)
    return OpSpec(f"{op.name}_jvp", f"{op.kernel}Jvp", op.args + tangents, outputs, "derivatives_backward",
                  jvp_of=op.name, jvp_wrt=wrt, jvp_in_place=in_place)


# Jacobian-vector products on dual numbers (autograd.py): along q and qd, the gradient of lam . tau with
# respect to q, qd and qdd (M lam) and tau, in one pass (the backwards of inverse_dynamics_vjp, and of
# inverse_dynamics_derivatives in MuJoCo's convention with quaternions), tau alone (d(M x) along q) and
# the body velocities (-J lam along q), and the frames' vector-Jacobian product along q (the tangent of
# forward_kinematics' and end_effector_pose's backward: their Hessians by torch.func.hessian).
# The ops with a <op>_jvp kernel, and along which inputs: those whose forward mode it is (jvp "dual"), and the
# products the forward-mode rules of others are made of.
KERNEL_JVP = {op.name: op.dual_jvp for op in _VALUE_OPS if op.jvp == "dual"}
FORWARD_MODE_JVP = tuple((op.name, op.dual_jvp) for op in _VALUE_OPS if op.dual_jvp and op.jvp != "dual")

# The ops whose values do not depend on the bodies' inertias (kinematics, the regressors): those without a
# "parameters" argument (check_table), which a view of Robot.with_parameters runs as they are.
INERTIA_FREE = ("integrate", "difference", "d_integrate", "d_difference", "tangent_to_ambient", "integrate_vjp",
                "difference_vjp", "forward_kinematics", "end_effector_pose", "frame_jacobian", "frame_jacobian_vjp",
                "frame_kinematic_hessian", "frame_jacobian_dot", "body_velocities", "frames_vjp",
                "inverse_dynamics_external_force_derivatives", "inverse_dynamics_regressor", "kinetic_energy_regressor",
                "potential_energy_regressor")

OPS: dict[str, OpSpec] = {op.name: op for op in _VALUE_OPS}
OPS.update({f"{name}_backward": forward_mode_backward(OPS[name]) for name in FORWARD_MODE_BACKWARD})
OPS.update({f"{name}_jvp": forward_mode_jvp(OPS[name], wrt) for name, wrt in FORWARD_MODE_JVP + tuple(KERNEL_JVP.items())})


def check_table(table: dict[str, OpSpec]) -> None:
    """Raise ValueError for an op the glue, the generated bindings or the kernels could not carry, when
    the table is built rather than at the op's first call or the robot's compilation."""
    shapes = {"force": NV, "acceleration": NV, "congruence": NVxNV}
    for op in table.values():
        names = [a.name for a in op.args] + [o.name for o in op.outputs]
        if len(set(names)) != len(names) or not all(n.isidentifier() for n in names):
            raise ValueError(f"op {op.name}: argument and output names must be distinct identifiers, got {names}")
        for a in op.args:
            if not a.is_tensor and a.kind not in INTEGER_KINDS:
                raise ValueError(f"op {op.name}: argument {a.name!r} has an unknown kind {a.kind!r}")
            for d in a.trailing if a.is_tensor else ():
                if not isinstance(d, int) and d not in SIZES:
                    raise ValueError(f"op {op.name}: argument {a.name!r} has an unknown size {d!r}")
        for o in op.outputs:
            if o.kind not in OUTPUT_KINDS:
                raise ValueError(f"op {op.name}: output {o.name!r} has an unknown kind {o.kind!r}")
            if any(not isinstance(d, int) and d not in SIZES for d in o.shape):
                raise ValueError(f"op {op.name}: output {o.name!r} has an unknown size in {o.shape}")
            if (o.kind in shapes and tuple(o.shape) != shapes[o.kind] or o.kind == "columns" and
                    (len(o.shape) != 2 or o.shape[1] != "nv") or o.kind == "force_rows" and o.shape[:1] != NV):
                raise ValueError(f"op {op.name}: output {o.name!r} of kind {o.kind!r} cannot have the shape {o.shape}")
        if len(op.tensor_args) > MAX_TENSOR_INPUTS or len(op.outputs) > MAX_OUTPUTS:
            raise ValueError(f"op {op.name}: {len(op.tensor_args)} tensor inputs and {len(op.outputs)} outputs, at most "
                             f"{MAX_TENSOR_INPUTS} and {MAX_OUTPUTS} (csrc/batch/batch.h)")
        if not op.args or op.args[0].kind != "configuration" or any(a.kind == "configuration" for a in op.args[1:]):
            raise ValueError(f"op {op.name}: the first argument, and only it, must be the configuration (it fixes batch, "
                             "dtype, device)")
        velocities = [a for a in op.args if a.kind == "velocity"]
        if (any(a.kind == "acceleration" for a in op.args) or any(o.kind == "acceleration" for o in op.outputs)) and \
                len(velocities) != 1:
            raise ValueError(f"op {op.name}: an acceleration is converted with the op's velocity, so it needs exactly one "
                             f"velocity argument, got {len(velocities)}")
        integers = [a.kind for a in op.args if not a.is_tensor and a.kind != "mask"]
        if "frames" in integers and integers[-1] != "frames" or integers.count("frames") > 1:
            raise ValueError(f"op {op.name}: a 'frames' list must be the op's last integer argument (it takes the rest)")
        if op.backward not in BACKWARD_KINDS or op.jvp not in JVP_KINDS:
            raise ValueError(f"op {op.name}: backward must be one of {BACKWARD_KINDS} and jvp one of {JVP_KINDS}, got "
                             f"{op.backward!r} and {op.jvp!r}")
        if op.jvp == "dual" and list(op.dual_jvp) != [a.name for a in op.tensor_args]:
            raise ValueError(f"op {op.name}: a forward mode by dual numbers is along every tensor input, in order (dual_jvp "
                             f"{op.dual_jvp}, inputs {[a.name for a in op.tensor_args]})")
        if op.contracted and (not op.has_dual_backward or len(op.outputs) != 1 or
                              op.outputs[0].kind not in ("force_rows", "plain")):
            raise ValueError(f"op {op.name}: a contracted op has a forward-mode backward and one output of kind "
                             "'force_rows' or 'plain'")
        value = table.get(op.forward_mode_of or op.jvp_of, op)
        if (value.name in INERTIA_FREE) == any(a.kind == "parameters" for a in value.args):
            raise ValueError(f"op {value.name}: an op takes the inertial parameters (an argument of kind 'parameters') "
                             "exactly when its value depends on them, and is otherwise listed in INERTIA_FREE")
        if op.derived and any(d == "nsel" for a in op.tensor_args for d in a.trailing):
            raise ValueError(f"op {op.name}: a forward-mode kernel needs compile-time sizes, not 'nsel'")
        if not isinstance(op.lanes, bool) and (op.lanes < 1 or any(d == "nsel" for o in op.outputs for d in o.shape)):
            raise ValueError(f"op {op.name}: lanes is True, False or the most output numbers a sample on lanes (at least "
                             f"1, outputs of compile-time sizes), got {op.lanes!r}")
        # (nv, nv) outputs that nothing reframes after the kernel
        square = {o.name for o in op.outputs if o.shape == ("nv", "nv") and o.kind in ("twin", "plain")}
        if op.negated_products and (len(op.negated_products) < 2 or not square.issuperset(op.negated_products)
                                    or op.has_dual_backward
                                    or any(op.name in (o.forward_mode_of, o.jvp_of) for o in table.values())):
            raise ValueError(f"op {op.name}: negated_products names a factor and at least one product among its own "
                             f"(nv, nv) outputs of kind 'twin' or 'plain' {sorted(square)}, on an op whose kernel no "
                             f"other kernel runs on dual numbers, got {op.negated_products}")


check_table(OPS)

# How a CPU batch is split across threads (csrc/torch/glue.h, Call::run): by work, not by samples. A thread is given
# at least cpu_grain samples, CPU_THREAD_NS of the op's estimated work, well above what waking it costs (a few
# µs on an idle core; a fixed 16 samples a thread woke one for 12 µs of go2's inverse_dynamics). The estimate
# of a value op: its time per sample on one thread measured on go2 (µs; nv = 18, float64, B = 256), scaled to
# another robot by nv / 18; 1 µs for an op not listed. A few x off is close enough (iiwa14's measured times
# are within 0.4-2.6x of the scaled ones, and an estimate too low only keeps a small batch on fewer threads).
CPU_THREAD_NS = 50e3
CPU_SAMPLE_US = {
    "inverse_dynamics": 0.76, "forward_dynamics": 2.9, "crba": 0.69, "crba_vjp": 2.1, "mass_product_vjp": 1.1,
    "minv": 1.9, "generalized_gravity": 0.74, "nonlinear_effects": 0.75, "energy": 0.40, "com": 0.21,
    "jacobian_com": 0.28, "ccrba": 0.58, "forward_kinematics": 0.65, "end_effector_pose": 0.25,
    "frame_jacobian": 0.084, "frame_jacobian_vjp": 0.12, "frame_kinematic_hessian": 0.43, "frame_jacobian_dot": 0.11,
    "inverse_dynamics_vjp": 1.7, "inverse_dynamics_vjp_full": 1.8, "inertia_solve": 1.1, "body_velocities": 0.34,
    "frames_vjp": 0.59, "inverse_dynamics_derivatives": 3.6, "inverse_dynamics_second_derivatives": 34,
    "inverse_dynamics_derivatives_vjp": 25, "inverse_dynamics_derivatives_tangent": 40, "forward_dynamics_derivatives": 6.8,
    "integrate": 0.05, "difference": 0.1, "d_integrate": 0.3, "d_difference": 0.3, "tangent_to_ambient": 0.03,
    "integrate_vjp": 0.3, "difference_vjp": 0.4, "step": 3.0, "step_derivatives": 7.7,
    "rk_step_derivatives": 50, "inverse_dynamics_external_force_derivatives": 0.83,
    "forward_dynamics_external_force_derivatives": 3.8, "osc_inertia": 2.5, "cmm_time_variation": 2.1, "dccrba": 2.1,
    "coriolis_matrix": 2.2, "inverse_dynamics_regressor": 3.1, "kinetic_energy_regressor": 0.40,
    "potential_energy_regressor": 0.20, "forward_dynamics_parameter_derivatives": 7.4,
}


def cpu_sample_ns(op: OpSpec, model: RobotModel) -> float:
    """The estimated time of one sample of `op` on one CPU thread, in ns (CPU_SAMPLE_US). A forward-mode op
    runs its value op's kernel on dual numbers, about 4x its time per lane: one lane in a Jacobian-vector
    product, one per input coordinate in a backward."""
    value = OPS[op.forward_mode_of or op.jvp_of] if op.derived else op
    lanes = 1
    if op.forward_mode_of:
        sizes = model_sizes(model)
        lanes = sum(math.prod(sizes.get(d, d) for d in a.trailing) for a in value.tensor_args)
    return 1e3 * CPU_SAMPLE_US.get(value.name, 1.0) * model.nv / 18 * (4 * lanes if op.derived else 1)


def cpu_grain(op: OpSpec, model: RobotModel) -> int:
    """The fewest samples of `op` a CPU thread is given: CPU_THREAD_NS of estimated work."""
    return max(1, math.ceil(CPU_THREAD_NS / cpu_sample_ns(op, model)))


def on_lanes(op: OpSpec, model: RobotModel) -> bool:
    """Whether `model`'s library runs `op` on CPU vector lanes (OpSpec.lanes): a number bounds the outputs of
    a sample, since a group holds theirs for every lane at once."""
    if isinstance(op.lanes, bool):
        return op.lanes
    sizes = model_sizes(model)
    return sum(math.prod(sizes.get(d, d) for d in o.shape) for o in op.outputs) <= op.lanes


def register_fakes(namespace: str, model: RobotModel) -> None:
    """Shape-only implementations of every op of one robot build, for torch.compile and meta tensors."""
    for spec in OPS.values():
        torch.library.register_fake(f"{namespace}::{spec.name}")(_fake(spec, model))


def _fake(spec: OpSpec, model: RobotModel):
    tensors = [k for k, a in enumerate(spec.args) if a.is_tensor]

    def fake(q, *args):
        # As the glue: one device and dtype (a meta tensor among CPU ones dispatches here).
        for k in tensors[1:]:
            x = args[k - 1]
            if x is not None and (x.device != q.device or x.dtype != q.dtype):
                raise RuntimeError(f"{spec.name}: {spec.args[k].name} must have the device and dtype of q "
                                   f"({q.device}, {q.dtype}), got {x.device}, {x.dtype}")
        nsel = len(args[0]) if spec.name == "end_effector_pose" else 0
        # As the glue: the tensor arguments' leading dimensions broadcast (q unbatched, x batched)
        batch = tuple(torch.broadcast_shapes(*(
            x.shape[:x.dim() - len(spec.args[k].trailing)] for k, x in zip(tensors, (q, *(args[k - 1] for k in tensors[1:])))
            if x is not None)))
        outs = [q.new_empty(s[len(batch):]).expand(s) if o.kind == "workspace" and q.device.type == "cpu"
                else q.new_empty(s) for o, s in zip(spec.outputs, spec.output_shapes(model, batch, nsel))]
        return outs[0] if len(outs) == 1 else tuple(outs)

    return fake


def op_signature() -> str:
    """Hash of the op table as the glue and a robot library both see it: the ops, in order, with their
    schemas and the products the glue finishes. A robot library and the glue must agree on it; it is part of a
    robot's op namespace."""
    text = "\n".join(f"{op.kernel} {op.schema()} {' '.join(op.negated_products)}" for op in OPS.values())
    return hashlib.sha256(text.encode()).hexdigest()[:16]
