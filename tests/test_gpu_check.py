"""bench/gpu_check.py with the CPU standing in for the GPU (--cpu): every stage of the GPU check runs
here on small batches, with every kernel output poisoned (TORCH_GRID_POISON_OUTPUTS=1: an entry a
kernel leaves unwritten shows as NaN), so the check cannot rot between GPU runs."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_gpu_check_with_the_cpu_standing_in(tmp_path):
    env = dict(os.environ, TORCH_GRID_POISON_OUTPUTS="1", PYTHONUNBUFFERED="1")
    result = subprocess.run([sys.executable, str(ROOT / "bench" / "gpu_check.py"), "--cpu", "--robots", "iiwa14", "gripper",
                             "--out", str(tmp_path), "--budget", "1500"], env=env, cwd=ROOT, capture_output=True, text=True,
                            timeout=1800)
    last = result.stdout.strip().splitlines()[-1]
    found = re.fullmatch(r"gpu-check: (\d+) passed, (\d+) failed on CPU", last)
    assert found and found.group(2) == "0" and result.returncode == 0, result.stdout[-6000:] + result.stderr[-3000:]
    assert int(found.group(1)) > 700  # every function, both conventions, gradients, batches, the examples
    log = (tmp_path / "check.log").read_text()
    for stage in ("values iiwa14", "batches gripper", "gradients gripper", "teams iiwa14", "device", "mpc", "figures"):
        assert f"---- {stage}: ok" in log, stage
    figures = json.loads((tmp_path / "results.json").read_text())
    assert figures and all({"device", "robot", "op", "dtype", "batch", "us_per_sample", "torch", "commit"} <= set(f)
                           for f in figures)
    assert all(f["us_per_sample"] > 0 for f in figures)
    mpc = {f["op"] for f in figures if f["op"].startswith("mpc[")}
    assert mpc == {"mpc[ilqr iteration]", "mpc[horizon call]", "mpc[riccati pass]", "mpc[rollout]"}, mpc


def test_the_profiled_calls_name_each_kernel_before_it_runs(capsys, monkeypatch):
    """The stage ncu reads section by section calls each listed op once, in the listed order, each named first
    (ncu's report gives the kernels in the order they ran, not which robot they belong to)."""
    sys.path.insert(0, str(ROOT / "bench"))
    import gpu_device
    import torch
    import torch_grid

    robot = torch_grid.load(str(ROOT / "bench" / "gpu" / "models" / "iiwa14.json"))
    assert {name for name, _, _ in gpu_device.PROFILED} <= {"iiwa14", "go2", "g1"}  # robots the figures load
    profiled = (("iiwa14", "inverse_dynamics", 65536), ("iiwa14", "forward_dynamics_derivatives", 256))
    monkeypatch.setattr(gpu_device, "PROFILED", profiled)
    gpu_device.profiled_calls({"iiwa14": robot}, torch.device("cpu"))
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("PROFILED")]
    assert lines == ["PROFILED 1: iiwa14 inverse_dynamics, N = 65536",
                     "PROFILED 2: iiwa14 forward_dynamics_derivatives, N = 256"]


def test_the_team_calls_run_every_team_op(monkeypatch):
    """The stage compute-sanitizer's racecheck watches on a GPU (gpu_device.team_calls: every op with a team path, both
    conventions, float64 and float32) runs, here on the CPU build."""
    sys.path.insert(0, str(ROOT / "bench"))
    import gpu_correctness
    import gpu_device
    import torch
    import torch_grid

    robot = torch_grid.load(str(ROOT / "bench" / "gpu" / "models" / "iiwa14.json"))
    called = []
    calls = {name: (lambda *a, name=name, call=call: called.append(name) or call(*a))
             for name, call in gpu_correctness.TEAM_CALLS.items()}
    monkeypatch.setattr(gpu_correctness, "TEAM_CALLS", calls)
    gpu_device.team_calls(robot, torch.device("cpu"))
    assert sorted(called) == sorted(4 * list(calls)), called


def _gpu_check():
    sys.path.insert(0, str(ROOT / "bench"))
    import gpu_check

    return gpu_check


def test_a_stage_whose_tool_is_missing_fails_alone(tmp_path):
    """A wrapper the machine lacks (compute-sanitizer, ncu, cuda-gdb off the PATH) fails its stage with a status;
    it does not end the whole check before its summary."""
    gpu_check = _gpu_check()
    log = gpu_check.Log(tmp_path / "check.log")
    text, status = gpu_check._spawn(["--stage", "build"], dict(os.environ), 10, log, "missing tool",
                                    [str(tmp_path / "no-such-tool")])
    assert text == "" and status.startswith("not started: ") and "no-such-tool" in status
    assert "---- missing tool: not started" in (tmp_path / "check.log").read_text()


def test_the_prebuilt_objects_are_unpacked_once_per_archive(tmp_path):
    """A second call on the same machine finds the same archive's objects unpacked; another archive replaces them."""
    import tarfile

    gpu_check = _gpu_check()
    archive, folder = tmp_path / "prebuilt.tar.xz", tmp_path / "objects"

    def pack(*names):
        for name in names:
            (tmp_path / name).write_bytes(name.encode())
        with tarfile.open(archive, "w:xz") as tar:
            for name in names:
                tar.add(tmp_path / name, arcname=name)

    pack("a.o", "b.o")
    assert gpu_check.unpack_prebuilt(archive, folder) == folder
    assert sorted(p.name for p in folder.glob("*.o")) == ["a.o", "b.o"]
    (folder / "a.o").write_bytes(b"kept")  # not unpacked again: the same archive
    gpu_check.unpack_prebuilt(archive, folder)
    assert (folder / "a.o").read_bytes() == b"kept"
    pack("c.o")
    gpu_check.unpack_prebuilt(archive, folder)
    assert sorted(p.name for p in folder.glob("*.o")) == ["c.o"]


def test_a_stage_that_crashes_after_a_failed_check_is_a_failure_of_its_own():
    """A crash (a signal) or a time limit counts beside the FAIL lines printed before it: the checks after it never ran."""
    gpu_check = _gpu_check()
    assert gpu_check.stage_failed("exit -11", "PASS a\nFAIL b: why\n")
    assert gpu_check.stage_failed("timed out after 90 s", "FAIL b: why\n")
    assert gpu_check.stage_failed("not started: ncu: No such file or directory", "")
    assert gpu_check.stage_failed("exit 9", "PASS calls under compute-sanitizer\n")
    assert not gpu_check.stage_failed("exit 1", "PASS a\nFAIL b: why\n")  # counted by its FAIL line
    assert not gpu_check.stage_failed("ok", "PASS a\n")


def test_a_tool_that_timed_out_on_go2_is_not_run_on_the_humanoid(tmp_path):
    """The second robot under compute-sanitizer's memcheck is left out when the first timed out: its time goes to the
    tools after it."""
    gpu_check = _gpu_check()
    called, statuses = [], {}

    def stage(label, args, limit, extra_env=None, wrapper=()):
        called.append(label)
        if "memcheck" in label or "initcheck" in label:  # each tensor its own allocation under the sanitizer
            assert extra_env == {"PYTORCH_NO_CUDA_MEMORY_CACHING": "1"}, extra_env
        statuses[label] = "timed out after 90 s" if label == "compute-sanitizer memcheck go2" else "ok"
        return ""

    skip = ["resources", "ncu"]
    gpu_check._tools(stage, gpu_check.Log(tmp_path / "check.log"), tmp_path, skip, statuses)
    assert called == ["compute-sanitizer memcheck go2", "compute-sanitizer initcheck go2",
                      "compute-sanitizer racecheck go2 teams"], called
    assert "memcheck humanoid: not run, the go2 stage timed out" in (tmp_path / "check.log").read_text()
    called.clear()
    statuses.clear()
    gpu_check._tools(stage, gpu_check.Log(tmp_path / "check.log"), tmp_path, skip, {})
    assert "compute-sanitizer memcheck humanoid" in called


def test_the_probe_reports_the_step_derivatives_of_each_path(robots, capsys):
    """The diagnostics stage's step_derivatives lines (gpu_probe.py), here on the CPU build of go2: one per
    path (MuJoCo's convention on one thread and on the team path, Pinocchio's), scheme and dt, each with
    its counts of non-finite entries, which the CPU build has none of."""
    sys.path.insert(0, str(ROOT / "bench"))
    import gpu_probe
    import torch

    gpu_probe.step_derivatives("go2", robots["go2"], torch.device("cpu"), False)
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("INFO probe go2 ")]
    paths = [line.split(" dt=")[0].removeprefix("INFO probe go2 ") for line in lines]
    schemes = gpu_probe.SCHEMES
    assert paths == [f"{p} {s}" for p in ("mujoco", "mujoco teams", "pin") for s in schemes for _ in range(2)], lines
    assert all(re.search(r": A 0/3888 non-finite, max diff 0\.0e\+00; B 0/1944 non-finite, max diff 0\.0e\+00$", line)
               for line in lines), lines
