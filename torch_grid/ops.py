"""The op table: the one description of every op's arguments, output shapes and kernel.

From it come the dispatcher schemas and C++ wrappers (codegen.py), the fake implementations that
let torch.compile propagate shapes (registered here), and argument checking in `Robot`.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from .model import RobotModel

# Argument kinds: tensors with their trailing shape, or integers.
TENSOR_KINDS = {"q": ("nq",), "v": ("nv",), "fext": ("nbodies", 6), "frame_weights": ("nframes", 6)}


@dataclass(frozen=True)
class Arg:
    name: str
    kind: str  # "q", "v", "fext", "frame_weights", "cotangent" (tensors) or "frame", "frames", "reference", "mask"
    optional: bool = False
    shape: tuple = ()  # trailing shape of a cotangent

    @property
    def is_tensor(self) -> bool:
        return self.kind in TENSOR_KINDS or self.kind == "cotangent"

    @property
    def trailing(self) -> tuple:
        return TENSOR_KINDS.get(self.kind, self.shape)


@dataclass(frozen=True)
class OpSpec:
    name: str
    kernel: str  # C++ op struct in csrc/kernels/ops.h
    args: tuple[Arg, ...]
    outputs: tuple[tuple, ...]  # trailing shapes; symbols "nv", "nq", "nbodies", "nparams", "nframes", "nsel"
    forward_mode_of: str = ""  # set on the vector-Jacobian product of that op by forward-mode kernels

    @property
    def tensor_args(self) -> tuple[Arg, ...]:
        return tuple(a for a in self.args if a.is_tensor)

    def schema(self) -> str:
        types = {"frame": "int", "frames": "int[]", "reference": "int", "mask": "int"}
        params = [f"Tensor{'?' if a.optional else ''} {a.name}" if a.is_tensor else f"{types[a.kind]} {a.name}"
                  for a in self.args]
        outs = ", ".join("Tensor" for _ in self.outputs)
        return f"{self.name}({', '.join(params + ['int convention'])}) -> " + (f"({outs})" if len(self.outputs) > 1 else outs)

    def output_shapes(self, model: RobotModel, batch: tuple[int, ...], nsel: int = 0) -> list[tuple[int, ...]]:
        sizes = {"nv": model.nv, "nq": model.nq, "nbodies": model.nbodies, "nparams": 10 * model.nbodies,
                 "nframes": len(model.frames), "nsel": nsel}
        return [tuple(batch) + tuple(sizes.get(d, d) for d in shape) for shape in self.outputs]


Q, QD, QDD, TAU, FEXT = Arg("q", "q"), Arg("qd", "v"), Arg("qdd", "v"), Arg("tau", "v"), Arg("f_ext", "fext", True)
_VALUE_OPS = (
        OpSpec("inverse_dynamics", "InverseDynamics", (Q, QD, QDD, FEXT), (("nv",),)),
        OpSpec("forward_dynamics", "ForwardDynamics", (Q, QD, TAU, FEXT), (("nv",),)),
        OpSpec("crba", "Crba", (Q,), (("nv", "nv"),)),
        OpSpec("minv", "Minv", (Q,), (("nv", "nv"),)),
        OpSpec("generalized_gravity", "GeneralizedGravity", (Q,), (("nv",),)),
        OpSpec("nonlinear_effects", "NonlinearEffects", (Q, QD), (("nv",),)),
        OpSpec("energy", "Energy", (Q, QD), ((3,),)),
        OpSpec("com", "Com", (Q,), ((3,),)),
        OpSpec("jacobian_com", "JacobianCom", (Q,), ((3, "nv"),)),
        OpSpec("ccrba", "Ccrba", (Q, QD), ((6, "nv"), (6,))),
        OpSpec("forward_kinematics", "ForwardKinematics", (Q,), (("nframes", 3), ("nframes", 3, 3))),
        OpSpec("end_effector_pose", "EndEffectorPose", (Q, Arg("frames", "frames")), (("nsel", 6),)),
        OpSpec("frame_jacobian", "FrameJacobian", (Q, Arg("frame", "frame"), Arg("reference", "reference")), ((6, "nv"),)),
        OpSpec("frame_jacobian_dot", "FrameJacobianDot", (Q, QD, Arg("frame", "frame"), Arg("reference", "reference")),
               ((6, "nv"),)),
        OpSpec("inverse_dynamics_vjp", "InverseDynamicsVjp", (Q, QD, QDD, FEXT, Arg("cotangent", "v")),
               (("nv",), ("nv",))),
        OpSpec("inertia_solve", "InertiaSolve", (Q, Arg("x", "v")), (("nv",),)),
        OpSpec("body_velocities", "BodyVelocities", (Q, QD), (("nbodies", 6),)),
        OpSpec("frames_vjp", "FramesVjp", (Q, Arg("weights", "frame_weights")), (("nv",),)),
        OpSpec("inverse_dynamics_gradient", "InverseDynamicsGradient", (Q, QD, QDD, FEXT), (("nv", "nv"), ("nv", "nv"))),
        OpSpec("forward_dynamics_gradient", "ForwardDynamicsGradient", (Q, QD, TAU, FEXT),
               (("nv", "nv"), ("nv", "nv"), ("nv", "nv"))),
        OpSpec("inverse_dynamics_external_force_gradient", "InverseDynamicsExternalForceGradient", (Q,),
               (("nv", "nbodies", 6),)),
        OpSpec("forward_dynamics_external_force_gradient", "ForwardDynamicsExternalForceGradient", (Q,),
               (("nv", "nbodies", 6),)),
        OpSpec("osc_inertia", "OscInertia", (Q, Arg("frame", "frame"), Arg("reference", "reference")), ((6, 6),)),
        OpSpec("cmm_time_variation", "CmmTimeVariation", (Q, QD), ((6, "nv"),)),
        OpSpec("dccrba", "Dccrba", (Q, QD), ((6, "nv"),)),
        OpSpec("coriolis_matrix", "CoriolisMatrix", (Q, QD), (("nv", "nv"),)),
        OpSpec("inverse_dynamics_regressor", "InverseDynamicsRegressor", (Q, QD, QDD), (("nv", "nparams"),)),
        OpSpec("kinetic_energy_regressor", "KineticEnergyRegressor", (Q, QD), (("nparams",),)),
        OpSpec("potential_energy_regressor", "PotentialEnergyRegressor", (Q,), (("nparams",),)),
        OpSpec("forward_dynamics_parameter_gradient", "ForwardDynamicsParameterGradient", (Q, QD, TAU),
               (("nv", "nparams"),)),
)

# Ops whose backward runs their own kernel on dual numbers (csrc/kernels/forward_mode.h): those whose
# outputs are already derivatives, where the gradient is a second-order quantity. (M and M^-1 have
# an O(n^2) backward from inverse-dynamics products instead, in autograd.py.)
FORWARD_MODE_BACKWARD = (
    "jacobian_com", "ccrba", "frame_jacobian", "frame_jacobian_dot", "body_velocities",
    "inverse_dynamics_gradient", "forward_dynamics_gradient", "inverse_dynamics_external_force_gradient",
    "forward_dynamics_external_force_gradient", "osc_inertia", "cmm_time_variation", "dccrba", "coriolis_matrix",
    "inverse_dynamics_regressor", "kinetic_energy_regressor", "potential_energy_regressor",
    "forward_dynamics_parameter_gradient",
)


def forward_mode_backward(op: OpSpec) -> OpSpec:
    """`<op>_backward(inputs..., cotangents..., needs)`: the gradient of sum(cotangent * output) for
    each tensor input (bit i of `needs` asks for input i; the others come back zero)."""
    cotangents = tuple(Arg(f"grad_{k}", "cotangent", True, shape) for k, shape in enumerate(op.outputs))
    return OpSpec(f"{op.name}_backward", f"{op.kernel}Backward", op.args + cotangents + (Arg("needs", "mask"),),
                  tuple(a.trailing for a in op.tensor_args), forward_mode_of=op.name)


OPS: dict[str, OpSpec] = {op.name: op for op in _VALUE_OPS}
OPS.update({f"{name}_backward": forward_mode_backward(OPS[name]) for name in FORWARD_MODE_BACKWARD})


def register_fakes(namespace: str, model: RobotModel) -> None:
    """Shape-only implementations of every op of one robot build, for torch.compile and meta tensors."""
    for spec in OPS.values():
        torch.library.register_fake(f"{namespace}::{spec.name}")(_fake(spec, model))


def _fake(spec: OpSpec, model: RobotModel):
    def fake(q, *args):
        nsel = len(args[0]) if spec.name == "end_effector_pose" else 0
        outs = [q.new_empty(s) for s in spec.output_shapes(model, tuple(q.shape[:-1]), nsel)]
        return outs[0] if len(outs) == 1 else tuple(outs)

    return fake
