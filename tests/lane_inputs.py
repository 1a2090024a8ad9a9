"""Inputs for any op of the op table, by argument kind: what tests/test_lanes.py runs every op on."""
from __future__ import annotations

import torch

from torch_grid.ops.table import OPS, OpSpec, model_sizes


def differentiated_inputs(spec: OpSpec) -> int:
    """How many inputs a backward op's mask has bits for: the tensor inputs of the op it differentiates."""
    value = OPS.get(spec.forward_mode_of or spec.jvp_of)
    return len(value.tensor_args) if value else len(spec.tensor_args)


def op_arguments(robot, spec: OpSpec, batch: int, generator: torch.Generator, convention: int) -> list:
    """Random arguments of `spec` for `batch` samples (the op's convention), in the op's order."""
    sizes = {**model_sizes(robot.model), "nsel": 2}
    view = robot.mujoco if convention else robot

    def randn(*shape):
        return 0.5 * torch.randn(batch, *shape, dtype=torch.float64, generator=generator)

    args = []
    for a in spec.args:
        if a.kind == "configuration":
            args.append(view.random_configuration(batch, generator=generator))
        elif a.kind == "parameters":
            params = robot.inertial_parameters().reshape(-1, 10).expand(batch, -1, -1)
            args.append(params * (1 + 0.1 * torch.rand(params.shape, dtype=torch.float64, generator=generator)))
        elif a.is_tensor:
            shape = [sizes.get(d, d) for d in a.trailing]
            x = randn(*shape)
            args.append(x.abs() * 1e-2 + 1e-3 if a.name in ("dt", "h") else x)
        elif a.kind == "frame":
            args.append(robot.nframes - 1)
        elif a.kind == "frames":
            args.append([0, robot.nframes - 1])
        elif a.kind == "reference":
            args.append(2)
        elif a.kind == "mask":
            args.append((1 << differentiated_inputs(spec)) - 1)
        elif a.kind == "scheme":
            args.append(1)
        elif a.kind in ("tableau", "integrator"):
            args.append(4)  # rk4
        elif a.kind == "passive":
            args.append(1)
        else:
            raise AssertionError(f"no test input for argument kind {a.kind!r} ({spec.name}.{a.name})")
    return args
