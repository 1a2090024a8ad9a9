"""CPU batches split across threads by work (csrc/torch/glue.h, Call::run; ops/table.py, cpu_grain), handed out in
pieces, several a thread: the results on one and on two threads are bitwise equal, and the grain of each op
in a robot's table, the fewest samples the glue gives a thread, is the fewest that hold CPU_THREAD_NS of the
op's estimated work."""
from __future__ import annotations

import pytest
import torch

import torch_grid
from torch_grid.ops import codegen
from torch_grid.ops.table import CPU_SAMPLE_US, CPU_THREAD_NS, OPS, cpu_grain, cpu_sample_ns

BATCHES = (1, 7, 64, 1000)


def _inputs(robot, name: str, batch: int, dtype: torch.dtype) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(batch)
    q = robot.random_configuration(batch, generator=g).to(dtype)
    if name == "crba":
        return (q,)
    nv = robot.model.nv
    return (q, torch.randn(batch, nv, generator=g, dtype=torch.float64).to(dtype),
            torch.randn(batch, nv, generator=g, dtype=torch.float64).to(dtype))


def _call(robot, name: str, args: tuple[torch.Tensor, ...]):
    if name == "step_derivatives (rk4)":  # a kernel with a workspace, zeroed for each chunk of a piece
        return robot.step_derivatives(*args, 1e-3, "rk4")
    return getattr(robot, name)(*args)


def _same_on_one_and_two_threads(robot, name: str, args: tuple[torch.Tensor, ...]) -> bool:
    outputs = []
    for threads in (1, 2):
        torch.set_num_threads(threads)
        out = _call(robot, name, args)
        outputs.append(out if isinstance(out, tuple) else (out,))
    return all(torch.equal(one, two) for one, two in zip(*outputs))


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("name", ["inverse_dynamics", "forward_dynamics_derivatives", "crba", "step_derivatives (rk4)"])
def test_one_and_two_threads_bitwise_equal(robots, name: str, dtype: torch.dtype) -> None:
    robot = robots["go2"]
    threads = torch.get_num_threads()
    try:
        for batch in BATCHES:
            assert _same_on_one_and_two_threads(robot, name, _inputs(robot, name, batch, dtype)), \
                f"{name}, B = {batch}, {dtype}"
    finally:
        torch.set_num_threads(threads)
        torch_grid.empty_cache()  # the outputs' kept blocks would be handed to a later test's outputs of their size


@pytest.mark.parametrize("robot_name", ["iiwa14", "go2"])
def test_grain_is_the_least_work_worth_a_thread(robots, robot_name: str) -> None:
    model = robots[robot_name].model
    table = codegen.table_unit(model, mujoco=False, cuda=False, namespace="tg_threads")
    for op in OPS.values():
        grain, ns = cpu_grain(op, model), cpu_sample_ns(op, model)
        assert grain * ns >= CPU_THREAD_NS and (grain == 1 or (grain - 1) * ns < CPU_THREAD_NS), op.name
        assert f", {grain}}},  // {op.name}\n" in table, op.name  # what the glue splits by


def test_every_estimate_names_a_value_op() -> None:
    assert set(CPU_SAMPLE_US) <= {name for name, op in OPS.items() if not op.derived}
