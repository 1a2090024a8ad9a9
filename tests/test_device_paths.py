"""The code paths a GPU thread takes (kernels/spatial/spatial.h: TG_DEVICE_PATH; per-depth slots for the
forward passes, joint placements rebuilt rather than stored, one-row product blocks, related columns found
as they go, one sine and cosine at a time) compiled for the CPU with TORCH_GRID_DEVICE_PATHS=1, and held
equal to the CPU's own paths on every public function, both conventions. The outputs and the stack start
as NaN (TORCH_GRID_POISON_OUTPUTS), as a GPU thread may find its local memory, so that an entry written
nowhere or a local read before it is set shows."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import torch_grid

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
sys.path.insert(0, str(BENCH))

import gpu_correctness as calls  # noqa: E402  (every public function's call, as the GPU check makes it)

# Ops whose last product the glue does on a device path (the op table's negated_products), also in float32,
# where it is a float32 product of the kernel's rounded outputs, and so under autocast, which must leave it so
FLOAT32 = ("forward_dynamics_derivatives",)


def outputs(robot) -> dict:
    """Every public function's outputs, both conventions, on fixed inputs; FLOAT32's also in float32, with and
    without autocast to bfloat16."""
    value_calls = calls.value_calls(robot)
    out = {f"{conv} {op}": calls.tensors(call(view, *calls.states(view, 5, seed=3)))
           for conv, view in calls.views(robot) for op, call in value_calls.items()}
    for conv, view in calls.views(robot):
        for op in FLOAT32:
            inputs = calls.on(calls.states(view, (2, 3), seed=4), "cpu", torch.float32)
            out[f"{conv} {op} float32"] = calls.tensors(value_calls[op](view, *inputs))
            with torch.autocast("cpu", dtype=torch.bfloat16):
                out[f"{conv} {op} autocast float32"] = calls.tensors(value_calls[op](view, *inputs))
    return out


SCRIPT = """
import sys, torch, torch_grid
sys.path.insert(0, {tests!r})
from test_device_paths import outputs
torch.save(outputs(torch_grid.load({model!r})), {path!r})
"""


@pytest.mark.parametrize("name", ["go2", "humanoid"])
def test_the_gpu_code_paths_compute_what_the_cpu_paths_compute(name, tmp_path):
    model = str(BENCH / "gpu" / "models" / f"{name}.json")
    path = tmp_path / "device_paths.pt"
    # no lane kernels: a GPU thread runs the scalar kernels
    env = dict(os.environ, TORCH_GRID_DEVICE_PATHS="1", TORCH_GRID_LANES="1", TORCH_GRID_POISON_OUTPUTS="1")
    script = SCRIPT.format(tests=str(Path(__file__).resolve().parent), model=model, path=str(path))
    subprocess.run([sys.executable, "-c", script], env=env, cwd=ROOT, check=True, timeout=1200)
    device_paths = torch.load(path)
    for key, ref in outputs(torch_grid.load(model)).items():
        single = key.endswith("float32")
        why = calls.compare(device_paths[key], ref, 1e-5 if single else 1e-12, dtype=torch.float32 if single else None)
        assert why is None, (key, why)
