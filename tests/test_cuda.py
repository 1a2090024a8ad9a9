"""CUDA: every kernel of a generated robot compiles with nvcc (here, without a GPU), the CUDA glue
compiles, and on a GPU the CUDA ops equal the CPU ops of the same robot."""
from __future__ import annotations

import os
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import torch

from torch_grid.ops import codegen, cuda_report
from torch_grid.ops.build import CSRC
from torch_grid.ops.table import OPS

from functions import FUNCTIONS

NVCC = shutil.which("nvcc") or (os.environ.get("CUDA_HOME") and str(Path(os.environ["CUDA_HOME"]) / "bin" / "nvcc"))
needs_nvcc = pytest.mark.skipif(not NVCC or not Path(NVCC).exists(), reason="nvcc is not installed")
needs_gpu = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
# Compiler reports of unchanged units are reused across runs (cuda_report.compile_unit: keyed by the
# compiler, the flags and the text of every source a unit can include).
NVCC_CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "torch_grid_tests" / "nvcc"
# The kernels with a team path (csrc/kernels/spatial/team.h: a warp a sample), and the most stack a lane of one
# may take on the G1 humanoid, by convention: the sample's workspace is in shared memory (one thread a sample takes
# 8-42 KB for these), and the MuJoCo twins' leader alone reframes the outputs, with arrays of its own.
TEAM_KERNELS = {"InverseDynamics", "ForwardDynamics", "Crba", "Minv", "InverseDynamicsDerivatives", "ForwardDynamicsDerivatives",
                "InverseDynamicsSecondDerivatives", "Step", "StepDerivatives", "RkStepDerivatives"}
TEAM_STACK = {"pin": 2048, "mujoco": 6144}
# a second-derivative lane holds a column's 6x6 terms and a pair's vectors (ptxas on G1: 2672 bytes); a Runge-Kutta
# lane its stage's configuration and the tableau beside the stage dynamics' variables (2336, MuJoCo's 5296)
TEAM_STACK_OF = {"InverseDynamicsSecondDerivatives": {"pin": 3072}, "RkStepDerivatives": {"pin": 2560, "mujoco": 6144}}


@pytest.fixture(scope="module")
def go2_sources(tmp_path_factory, robots):
    """Generated sources of a floating robot with both conventions (every template instantiated)."""
    directory = tmp_path_factory.mktemp("cuda_sources")
    codegen.write_robot_sources(robots["go2"].model, True, True, "torch_grid_nvcc_check", directory)
    codegen.write_glue_source(directory)
    return directory


@needs_nvcc
def test_every_float32_kernel_compiles_with_nvcc(go2_sources):
    """Every op's CUDA kernel for a floating robot, both conventions, in float32, compiled to device code
    (PTX): each is a kernel entry there. The float64 ones, host side and machine code included, are
    compiled by the stack-budget test below, for a humanoid, with the build's own flags."""
    units = sorted(go2_sources.glob("*_f32.cu"))
    text = "".join(u.read_text() for u in go2_sources.glob("*.cu"))
    for op in OPS.values():
        for scalar in ("float", "double"):
            for conv in ("tg::PIN", "tg::MUJOCO") if op.mujoco_twin else ("tg::PIN",):
                assert f"tg::cuda_launch<tg::bind::{op.kernel}, Robot, {scalar}, {conv}>" in text

    # Device code only and unoptimised: what this test checks is that every template instantiates in
    # float and compiles (the host pass and ptxas add three quarters of the time and nothing float-specific).
    flags = ["-std=c++17", "-Xcicc", "-O0", "-arch=sm_90", "-ptx"]
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        messages = list(pool.map(lambda u: cuda_report.compile_unit(NVCC, flags, u, ".ptx", NVCC_CACHE, keep_output=True), units))
    for text in messages:
        assert "warning" not in text.lower(), text[-4000:]
    mangled = [line.split()[2].split("(")[0] for u in units for line in u.with_suffix(".ptx").read_text().splitlines()
               if line.startswith(".visible .entry ")]
    entries = set(cuda_report._demangle(mangled))
    for op in OPS.values():
        for conv in (0, 1) if op.mujoco_twin else (0,):
            name = f"void tg::batch_kernel<tg::bind::{op.kernel}, torch_grid_nvcc_check::Robot, float, {conv}>(tg::Batch)"
            assert name in entries, f"{op.name} (convention {conv}): no float32 kernel entry {name}"
    # and the team kernels (a warp a sample) of the ops with a team path
    teams = {e.split("<tg::bind::")[1].split(",")[0] for e in entries if e.startswith("void tg::team_kernel<")}
    assert teams == TEAM_KERNELS, teams


@needs_nvcc
def test_cuda_stack_budget_on_a_humanoid(erd_robots_dir):
    """Per-thread local memory of every float64 CUDA kernel of the G1 humanoid (floating, both
    conventions), compiled for sm_90 as a build compiles it: at most 64 KiB, and the core kernels at
    most half of what they took before their workspaces were cut."""
    from torch_grid.model.parse import source_to_model

    model = source_to_model(str(erd_robots_dir / "g1_description" / "urdf" / "g1_29dof_rev_1_0.urdf"), True)
    usages = cuda_report.report(model, ("float64",), "sm_90", NVCC, cache=NVCC_CACHE)
    assert {(u.op, u.convention) for u in usages} == {(name, c) for name, op in OPS.items()
                                                      for c in (("pin", "mujoco") if op.mujoco_twin else ("pin",))}
    halved = {"inverse_dynamics": 8272, "crba": 18032, "forward_dynamics": 28768, "minv": 92896,
              "forward_dynamics_derivatives": 110288}  # bytes before; each convention must halve it
    for u in usages:
        assert u.stack <= cuda_report.DEFAULT_BUDGET, \
            f"{u.op} ({u.convention}): {u.stack} bytes of stack per thread, budget {cuda_report.DEFAULT_BUDGET}"
    for u in usages:
        if u.op in halved and u.kernel == "thread":
            assert u.stack <= halved[u.op] // 2, f"{u.op} ({u.convention}): {u.stack} bytes, more than half of {halved[u.op]}"
    # a team kernel keeps its sample's workspace in shared memory: a lane's stack holds its own variables alone
    teams = [u for u in usages if u.kernel == "team"]
    twins = {op.kernel: op.mujoco_twin for op in OPS.values()}
    assert {(OPS[u.op].kernel, u.convention) for u in teams} == {(k, c) for k in TEAM_KERNELS
                                                                 for c in (("pin", "mujoco") if twins[k] else ("pin",))}
    for u in teams:
        budget = TEAM_STACK_OF.get(OPS[u.op].kernel, TEAM_STACK)[u.convention]
        assert u.stack <= budget, f"{u.op} [team] ({u.convention}): {u.stack} bytes of stack per thread, budget {budget}"


def test_compile_cache_reuses_only_unchanged_inputs(tmp_path):
    """cuda_report.compile_unit's cache: a second call with the same inputs does not run the compiler and
    gives its messages and output back; a changed header beside the unit, changed flags or a failure
    are never served from it."""
    calls = tmp_path / "calls"
    nvcc = tmp_path / "nvcc"
    nvcc.write_text("#!/bin/sh\n"
                    "[ \"$1\" = --version ] && { echo 'fake nvcc 1.0'; exit 0; }\n"
                    f"echo x >> {calls}\n"
                    "for a; do case $a in -DFAIL) echo broken >&2; exit 1;; esac; done\n"
                    "while [ \"$1\" != -o ]; do shift; done\n"
                    f"cat {tmp_path}/src/robot.h > \"$2\"; echo 'ptxas info: 8 registers' >&2\n")
    nvcc.chmod(0o755)
    src = tmp_path / "src"
    src.mkdir()
    unit, header = src / "unit.cu", src / "robot.h"
    unit.write_text('#include "robot.h"\n')
    header.write_text("// one\n")
    cache = tmp_path / "cache"

    def compile_(flags=("-O3",)):
        unit.with_suffix(".ptx").unlink(missing_ok=True)
        messages = cuda_report.compile_unit(str(nvcc), list(flags), unit, ".ptx", cache, keep_output=True)
        return messages, unit.with_suffix(".ptx").read_text(), len(calls.read_text().split())

    assert compile_() == ("ptxas info: 8 registers\n", "// one\n", 1)
    assert compile_() == ("ptxas info: 8 registers\n", "// one\n", 1)  # served from the cache
    header.write_text("// two\n")
    assert compile_() == ("ptxas info: 8 registers\n", "// two\n", 2)
    assert compile_(("-O0",))[2] == 3
    with pytest.raises(RuntimeError, match="nvcc failed on unit.cu:\nbroken"):
        compile_(("-DFAIL",))
    with pytest.raises(RuntimeError, match="broken"):
        compile_(("-DFAIL",))
    assert len(calls.read_text().split()) == 5


@needs_nvcc
def test_cuda_glue_compiles(go2_sources):
    from torch.utils.cpp_extension import include_paths

    candidates = [os.environ.get("CUDA_HOME", ""), "/usr/local/cuda", str(Path(NVCC).resolve().parent.parent)]
    cuda_include = next(Path(c) / "include" for c in candidates if c and (Path(c) / "include" / "cuda_runtime.h").exists())
    # A CPU build of torch ships c10/cuda but not this one CMake-generated header; supply it.
    stub = go2_sources / "stub" / "c10" / "cuda" / "impl"
    stub.mkdir(parents=True, exist_ok=True)
    (stub / "cuda_cmake_macros.h").write_text("#pragma once\n#define C10_CUDA_BUILD_SHARED_LIBS\n")
    cmd = ["c++", "-std=c++20", "-fsyntax-only", "-DTG_WITH_CUDA", str(go2_sources / "glue.cpp"),
           f"-I{CSRC}", f"-I{go2_sources}", f"-I{cuda_include}", f"-I{go2_sources / 'stub'}"]
    cmd += [f"-I{p}" for p in include_paths()]
    result = subprocess.run(cmd, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-4000:]


ROBOTS = ["iiwa14", "go2", "g1", "tiago"]


def _inputs(robot, dtype, device, batch=64):
    g = torch.Generator().manual_seed(7)
    q = robot.random_configuration(batch, dtype=torch.float64, generator=g)
    v, a = (torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    f = torch.randn(batch, robot.nbodies, 6, dtype=torch.float64, generator=g)
    return [x.to(dtype=dtype, device=device) for x in (q, v, a, f)]


def _calls(view, q, v, a, f):
    """name -> every public function's outputs, flattened, on these inputs."""
    for name, (call, arity) in FUNCTIONS.items():
        out = call(view, view._robot, *(q, v, a, f)[:arity])
        yield name, torch.cat([x.flatten(1) for x in (out if isinstance(out, tuple) else (out,))], 1)


def _gradients(view, q, v, a, f):
    """name -> gradients of a fixed weighting of each function's outputs, with respect to its inputs."""
    for name, (call, arity) in FUNCTIONS.items():
        leaves = [x.clone().requires_grad_(True) for x in (q, v, a, f)[:arity]]
        out = call(view, view._robot, *leaves)
        outs = out if isinstance(out, tuple) else (out,)
        weights = [torch.linspace(-1, 1, o.numel(), dtype=o.dtype, device=o.device).view(o.shape) for o in outs]
        torch.autograd.backward(outs, weights)
        yield name, torch.cat([leaf.grad.flatten(1) for leaf in leaves], 1)


@needs_gpu
@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_cuda_equals_cpu(robots, name, dtype, tol, convention):
    robot = robots[name]
    view = getattr(robot, convention)
    cpu = dict(_calls(view, *_inputs(robot, dtype, "cpu")))
    cuda = dict(_calls(view, *_inputs(robot, dtype, "cuda")))
    for key, ref in cpu.items():
        got = cuda[key]
        assert got.device.type == "cuda" and got.dtype == dtype
        err = (got.cpu() - ref).abs().max() / ref.abs().max().clamp_min(1e-30)
        assert err <= tol, f"{name} {convention} {key}: CUDA vs CPU relative error {err:.2e}"


@needs_gpu
@pytest.mark.parametrize("name", ["iiwa14", "go2"])
@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_cuda_gradients_equal_cpu(robots, name, convention):
    """Every backward (first order, inverse-dynamics products, forward-mode kernels) on CUDA."""
    view = getattr(robots[name], convention)
    cpu = dict(_gradients(view, *_inputs(robots[name], torch.float64, "cpu")))
    cuda = dict(_gradients(view, *_inputs(robots[name], torch.float64, "cuda")))
    for key, ref in cpu.items():
        err = (cuda[key].cpu() - ref).abs().max() / ref.abs().max().clamp_min(1e-30)
        assert err <= 1e-10, f"{name} {convention} {key}: CUDA vs CPU gradient relative error {err:.2e}"


@needs_gpu
def test_cuda_runs_on_current_stream(robots):
    robot = robots["go2"]
    q, v, a, _ = _inputs(robot, torch.float64, "cuda", batch=4096)
    stream = torch.cuda.Stream()
    with torch.cuda.stream(stream):
        tau = robot.inverse_dynamics(q, v, a)
    stream.synchronize()
    assert torch.allclose(tau.cpu(), robot.inverse_dynamics(q.cpu(), v.cpu(), a.cpu()), rtol=1e-12, atol=1e-12)

