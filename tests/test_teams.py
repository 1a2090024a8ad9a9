"""The team paths of the op kernels (csrc/kernels/spatial/team.h), which a GPU runs as one warp per sample
(TORCH_GRID_CUDA_TEAMS=1), run here by 32 CPU threads with a barrier for the warp's sync (tests/team_harness.cpp)
under ThreadSanitizer: no entry of the shared workspace or of the outputs is touched by two lanes without a sync
between them, and the outputs equal the one-thread kernel's in both conventions. The harness is also run with its
syncs left out, where ThreadSanitizer must report the races the syncs prevent. Built for the CPU's own paths in
double and long double (the same kernels, the robot's constants too) with every kernel of the op table
(tests/precision_table.py), it also bounds how far each kernel's rounding leaves it from that computation with
more bits."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from torch_grid.model.parse import source_to_model
from torch_grid.ops import codegen
from torch_grid.ops.build import CSRC, op_namespace

import precision_table
from mjcf_models import DAMPED_FLOATING, TREES

HERE = Path(__file__).resolve().parent
MODELS = HERE.parent / "bench" / "gpu" / "models"
RACE = 66  # the exit status ThreadSanitizer is told to use


# MJCF robots of the other structures: several free trees beside a fixed one, a ball joint in a free tree (tests/
# mjcf_models.py's trees), and damped, sprung joints beside a damped ball joint on a free root (damped_floating)
MJCF = {"trees": TREES, "damped_floating": DAMPED_FLOATING}


def model_of(name: str, directory: Path):
    """One saved robot model, or one of MJCF (written into directory)."""
    if name in MJCF:
        (directory / f"{name}.xml").write_text(MJCF[name])
    return source_to_model(str(directory / f"{name}.xml" if name in MJCF else MODELS / f"{name}.json"), None)


def harness(name: str, directory: Path, precision: bool = False) -> Path:
    """The harness for one saved robot model (or one of MJCF) on its generated sources: built with ThreadSanitizer
    and the CPU paths of a GPU thread (TG_DEVICE_PATHS), or, with precision, the CPU's own paths against long
    double (TG_PRECISION)."""
    model = model_of(name, directory)
    namespace = op_namespace(model, True)
    codegen.write_robot_sources(model, True, False, namespace, directory)
    if precision:
        (directory / "precision_ops.h").write_text(precision_table.table_calls(model))
    exe = directory / ("precision_harness" if precision else "team_harness")
    build = ["-O1", "-DTG_PRECISION"] if precision else ["-O1", "-g", "-fsanitize=thread", "-pthread", "-DTG_DEVICE_PATHS"]
    cmd = [os.environ.get("CXX", "c++"), "-std=c++17", *build,
           f"-DTG_NAMESPACE={namespace}", *(["-DTG_MUJOCO"] if model.conventions_differ else []),
           f"-I{CSRC}", f"-I{directory}", str(HERE / "team_harness.cpp"), "-o", str(exe)]
    subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=600)
    return exe


def run(exe: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, TSAN_OPTIONS=f"halt_on_error=1 exitcode={RACE}")
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=600, env=env)


def expected_lines(name: str) -> list[str]:
    """The "op convention" of each line the harness prints for a robot, sorted."""
    conventions = ["pin", "mujoco"] if name != "iiwa14" else ["pin"]
    ops = ["inverse_dynamics", "forward_dynamics", "crba", "minv", "inverse_dynamics_derivatives", "forward_dynamics_derivatives"]
    expected = [f"{op} {c}" for op in ops for c in conventions] + ["inverse_dynamics_second_derivatives pin"]
    passive = name in ("humanoid", "damped_floating")  # damping and springs: explicit, and (Euler) the damping implicit
    schemes = [s + p for s in ("euler", "semi_implicit_euler") for p in (["", ",passive", ",damped"] if passive else [""])]
    tableaux = [t + p for t in ("midpoint", "rk3", "rk4") for p in (["", ",passive"] if passive else [""])]
    expected += [f"step[{s}] {c}" for s in schemes + tableaux for c in conventions]
    expected += [f"step_derivatives[{s}] {c}" for s in schemes for c in conventions]
    expected += [f"rk_step_derivatives[{t}] {c}" for t in tableaux for c in conventions]
    return sorted(expected)


# go2: a free root; the humanoid: bodies of several joints, damped and sprung; iiwa14: a fixed base (one
# convention); and the MJCF robots above
@pytest.mark.parametrize("name", ["go2", "humanoid", "iiwa14", *MJCF])
def test_a_warp_of_threads_computes_what_one_thread_computes_without_a_race(name, tmp_path):
    exe = harness(name, tmp_path)
    result = run(exe, "3")
    assert result.returncode == 0, result.stdout + result.stderr[-4000:]
    lines = dict(line.rsplit(" ", 1) for line in result.stdout.splitlines())
    assert sorted(lines) == expected_lines(name), result.stdout
    # equal to rounding where the team takes another road (team_harness.cpp): forward dynamics by M^-1 (tau - b),
    # a bias from the RNEA derivatives' pass
    another_road = ("forward_dynamics ", "step[", "rk_step_derivatives[")
    assert all(float(err) <= (1e-11 if op.startswith(another_road) or ",damped" in op else 1e-13)
               for op, err in lines.items()), result.stdout


# How far from long double each kernel may be, relative to its output's largest entry: derivatives through M^-1
# (forward dynamics', the steps') and the operational-space inertia (J M^-1 J^T)^-1 grow with a condition number
# (on G1's worst of 40 random states, rk4's Jacobians 6.5e-12); everything else stays near the rounding of its inputs.
ILL_CONDITIONED = ("forward_dynamics_derivatives", "forward_dynamics_external_force_derivatives",
                   "forward_dynamics_parameter_derivatives", "step_derivatives", "rk_step_derivatives", "osc_inertia")


def precision_bound(line: str) -> float:
    """The bound of a line's "label convention" (an op's name, its integer arguments in brackets)."""
    return 1e-10 if line.split(" ")[0].split("[")[0] in ILL_CONDITIONED else 1e-12


# every kernel of the op table (tests/precision_table.py) on the robots above and G1
@pytest.mark.parametrize("name", ["go2", "humanoid", "iiwa14", "g1", *MJCF])
def test_every_kernel_rounds_as_little_as_long_double_shows(name, tmp_path):
    result = run(harness(name, tmp_path, precision=True), "3")
    assert result.returncode == 0, result.stdout + result.stderr[-4000:]
    lines = dict(line.rsplit(" ", 1) for line in result.stdout.splitlines())
    assert sorted(lines) == precision_table.expected_lines(model_of(name, tmp_path)), result.stdout
    assert all(float(err) <= precision_bound(op) for op, err in lines.items()), result.stdout


def test_the_harness_reports_the_races_that_the_syncs_prevent(tmp_path):
    result = run(harness("go2", tmp_path), "1", "--no-sync")
    assert result.returncode == RACE and "ThreadSanitizer: data race" in result.stderr, result.stdout + result.stderr[-2000:]
