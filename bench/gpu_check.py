"""The GPU check: one command that proves every function on a CUDA device against the CPU build of
the same machine and measures the first GPU figures.

    python3 bench/gpu_check.py [--cpu] [--budget 480] [--out DIR] [--robots iiwa14 go2 g1 humanoid gripper]
                               [--skip STAGE ... | --only STAGE ...]

It needs no Pinocchio or MuJoCo: the robots are the saved models in bench/gpu/models (written by
bench/gpu_prebuild.py, which also compiles their CUDA units ahead into .gpu/prebuilt.tar.xz; when that
archive is there, a build takes each object whose digest matches the unit it generates, and compiles
the others). Stages run as separate processes, each with its own time limit, so a crash or hang in one
leaves the others' results: the builds; per robot, every function's values (float64 and float32, both
conventions), batch sizes and memory layouts, gradients, double backward, forward mode and vmap, and
the functions given inertial parameters, and the ops' team paths (one warp per sample, TORCH_GRID_CUDA_TEAMS=1);
the device stages (streams, CUDA graphs, torch.compile, the examples, the local-memory reservation and the
budget refusal); compute-sanitizer's memcheck and initcheck, and racecheck on the team paths; the kernels'
resources (cuobjdump), one kernel's achieved occupancy and twelve kernels' ncu sections
(gpu_device.PROFILED: throughput, memory traffic, warp stalls); the MPC path
(gpu_mpc.py: examples/ilqr.py's go2 task, 256 samples by 50 knots, and its parts, eager and from CUDA
graphs, against the CPU build); the figures. Into --out (default $OUT, else bench/gpu):
check.log, results.json (one record per figure), resources.txt, sanitizer.log and ncu.txt.

--cpu runs the same checks with the CPU standing in for the GPU (small batches; the CUDA-only checks
are skipped), so the script is exercised without a GPU. The last line printed is
`gpu-check: N passed, M failed on <device name>`.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

from gpu_models import MODELS, MODELS_DIR  # noqa: E402

PREBUILT = ROOT / ".gpu" / "prebuilt.tar.xz"
PER_ROBOT = ("values", "batches", "gradients", "parameters", "teams")
# every stage --skip and --only name (the builds always run)
STAGES = (*PER_ROBOT, "device", "probe", "refusal", "reservation", "cuda-gdb", "resources", "memcheck", "initcheck", "ncu",
          "racecheck", "mpc", "figures")


# -- one stage, in its own process ----------------------------------------------------------------

def _robot(name: str):
    import torch_grid

    return torch_grid.load(str(MODELS_DIR / f"{name}.json"))


def run_stage(stage: str, robot: str | None, cpu: bool, threads: int) -> int:
    import faulthandler

    import torch

    faulthandler.enable()  # a crash prints the Python stack
    torch.set_num_threads(threads)
    device = torch.device("cpu" if cpu else "cuda")
    import gpu_correctness as correctness
    import gpu_device
    import gpu_figures

    checks = correctness.Checks(f"{robot}" if robot else stage)
    if stage == "build":
        start = time.monotonic()
        r = _robot(robot)
        print(f"INFO {robot}: loaded in {time.monotonic() - start:.1f} s ({r})", flush=True)
        checks.run("build", lambda: None)
    elif stage == "values":
        errors: dict[str, float] = {}
        correctness.values(checks, _robot(robot), device, 7, errors)
        for key, err in sorted(errors.items(), key=lambda kv: -kv[1]):
            print(f"INFO {robot} float32 error {key}: {err:.2e}", flush=True)
    elif stage == "batches":
        sizes = [1, 7, 33] if cpu else [1, 7, 255, 5000]
        r = _robot(robot)
        correctness.batches(checks, r, device, sizes)
        correctness.layouts(checks, r, device)
    elif stage == "gradients":
        correctness.gradients(checks, _robot(robot), device, 5)
    elif stage == "parameters":
        correctness.parameters(checks, _robot(robot), device)
    elif stage == "teams":
        correctness.teams(checks, _robot(robot), device, [1, 7, 33] if cpu else [1, 7, 255, 5000])
    elif stage == "device":
        gpu_device.streams(checks, _robot("go2"), device)
        gpu_device.graphs(checks, _robot("go2"), device)
        gpu_device.compiled(checks, _robot("iiwa14"), device)
        gpu_device.examples(checks, device)
    elif stage == "mpc":
        import gpu_mpc

        gpu_mpc.mpc(checks, device, _meta(cpu), *((8, 10) if cpu else (256, 50)))
    elif stage == "refusal":
        gpu_device.refusal(checks, _robot("g1"), device)
    elif stage == "reservation":
        gpu_device.reservation(checks, _robot("g1"), device)
    elif stage == "figures":
        meta = _meta(cpu)
        robots = {name: _robot(name) for name in ("iiwa14", "go2", "g1") if (MODELS_DIR / f"{name}.json").exists()}
        if cpu:
            robots = {k: v for k, v in robots.items() if k == robot} or robots
            gpu_figures.timings(robots, device, [], [1, 16], meta, dtypes=(torch.float64,))
        else:
            gpu_figures.call_overhead(robots["iiwa14"], device, meta)
            gpu_figures.timings(robots, device, [1, 16, 256, 1024, 4096, 65536], [1, 16, 256, 4096], meta)
    elif stage == "probe":
        import gpu_probe

        if robot == "runtime":
            loaded = _robot("iiwa14")  # the glue mapped before it is looked for
            gpu_probe.runtime()
            gpu_probe.glue_error(loaded)
        else:
            loaded = _robot(robot)
            gpu_probe.rk_workspace(robot, loaded, device)
            gpu_probe.step_derivatives(robot, loaded, device, os.environ.get("TORCH_GRID_POISON_OUTPUTS") == "1")
    elif stage == "sanitized_calls":
        gpu_device.small_calls(_robot(robot), device)
        checks.run("calls under compute-sanitizer", lambda: None)
    elif stage == "team_calls":
        gpu_device.team_calls(_robot(robot), device)
        checks.run("team calls under compute-sanitizer", lambda: None)
    elif stage == "profiled_call":
        gpu_device.profiled_call(_robot("go2"), device)
    elif stage == "profiled_calls":
        gpu_device.profiled_calls({name: _robot(name) for name in {r for r, _, _ in gpu_device.PROFILED}}, device)
    elif stage == "resources":
        from torch_grid.ops.build import _REGISTERED, op_namespace

        libraries = {name: _REGISTERED[op_namespace(_robot(name).model.kernel_model, True)]
                     for name in ("iiwa14", "go2", "g1", "humanoid", "gripper") if (MODELS_DIR / f"{name}.json").exists()}
        text = gpu_figures.resources(libraries)
        print(text, flush=True)
    else:
        raise SystemExit(f"unknown stage {stage!r}")
    return 1 if checks.failed else 0


def _meta(cpu: bool) -> dict:
    import torch

    # .gpu/commit, written beside the prebuilt objects, names the commit a copied working tree came from
    commit = (ROOT / ".gpu" / "commit").read_text().strip() if (ROOT / ".gpu" / "commit").exists() else "unknown"
    if commit == "unknown":
        try:
            commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                                    timeout=10).stdout.strip() or commit
        except (OSError, subprocess.TimeoutExpired):
            pass
    device = "CPU" if cpu else torch.cuda.get_device_name()
    return {"device": device, "torch": torch.__version__, "commit": commit}


# -- the whole check -------------------------------------------------------------------------------

class Log:
    def __init__(self, path: Path):
        self.file = open(path, "w")

    def __call__(self, line: str = "") -> None:
        print(line, flush=True)
        self.file_only(line + "\n")

    def file_only(self, text: str) -> None:
        self.file.write(text)
        self.file.flush()


def unpack_prebuilt(archive: Path, folder: Path) -> Path:
    """The archive's objects in `folder`, unpacked unless an earlier run unpacked this same archive there."""
    digest = hashlib.sha256(archive.read_bytes()).hexdigest()
    marker = folder / "archive.sha256"
    if marker.is_file() and marker.read_text() == digest:
        return folder
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    with tarfile.open(archive) as tar:
        tar.extractall(folder, filter="data")  # plain files: the objects
    marker.write_text(digest)
    return folder


def stage_failed(status: str, text: str) -> bool:
    """Whether a stage's end is a failure of its own, beside the FAIL lines it printed: a time limit, a tool that could
    not start, a crash (a signal: the checks after the one under way never ran, whichever failed before it), or an
    error exit that printed no FAIL line."""
    return status.startswith(("timed out", "not started", "exit -")) or (status != "ok" and "FAIL " not in text)


def _spawn(args: list[str], env: dict, timeout: float, log: Log, label: str, wrapper=()) -> tuple[str, str]:
    """Run one stage process (and whatever it starts) within timeout; return (its output, status)."""
    cmd = [*wrapper, sys.executable, str(Path(__file__).resolve()), *args]
    start = time.monotonic()
    try:
        proc = subprocess.Popen(cmd, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                start_new_session=True)
    except OSError as e:  # a tool missing from the machine fails its stage, not the whole check
        status = f"not started: {cmd[0]}: {e.strerror or e}"
        log(f"---- {label}: {status}")
        return "", status
    try:
        raw, _ = proc.communicate(timeout=max(timeout, 1))
        status = "ok" if proc.returncode == 0 else f"exit {proc.returncode}"
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raw, _ = proc.communicate()
        status = f"timed out after {timeout:.0f} s"
    text = raw.decode(errors="replace")
    log(f"---- {label}: {status} in {time.monotonic() - start:.0f} s")
    log.file_only(text)
    return text, status


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cpu", action="store_true", help="the CPU stands in for the GPU (small batches)")
    parser.add_argument("--budget", type=float, default=480.0, help="seconds for the whole check")
    parser.add_argument("--out", default=os.environ.get("OUT") or str(HERE / "gpu"))
    parser.add_argument("--robots", nargs="+", default=list(MODELS), choices=list(MODELS))
    parser.add_argument("--skip", nargs="*", default=[], choices=STAGES, help="stages to leave out")
    parser.add_argument("--only", nargs="*", choices=STAGES, help="the stages to run (and the builds), the others left out")
    parser.add_argument("--stage", help=argparse.SUPPRESS)
    parser.add_argument("--robot", help=argparse.SUPPRESS)
    parser.add_argument("--threads", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.stage:
        return run_stage(args.stage, args.robot, args.cpu, args.threads or os.cpu_count() or 1)
    if args.only is not None:
        args.skip = [s for s in STAGES if s not in args.only or s in args.skip]

    deadline = time.monotonic() + args.budget
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log = Log(out / "check.log")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    cores = os.cpu_count() or 1
    workers = 1 if args.cpu else min(4, cores)
    common = ["--cpu"] if args.cpu else []
    log(f"gpu-check: {time.strftime('%Y-%m-%d %H:%M:%S')}, budget {args.budget:.0f} s, {cores} cores, "
        f"{'CPU standing in for the GPU' if args.cpu else 'CUDA'}")
    log(subprocess.run([sys.executable, "-c", "import torch, sys; print('python', sys.version.split()[0], 'torch', "
                        "torch.__version__, 'cuda', torch.version.cuda, torch.cuda.is_available() and "
                        "torch.cuda.get_device_name())"], capture_output=True, text=True).stdout.strip())
    if not args.cpu:
        log(subprocess.run(["nvidia-smi", "--query-gpu=name,memory.total,driver_version,clocks.sm", "--format=csv,noheader"],
                           capture_output=True, text=True).stdout.strip())
        env.setdefault("TORCH_GRID_CUDA_ARCH", "sm_90")
        # one folder a machine, not one a run: a second call on the machine while it is still lent (--only mpc
        # figures, say) finds the robots built (the same tree: an entry's key covers the kernels' sources, codegen
        # and the op table, not every module of the build)
        env.setdefault("TORCH_GRID_CACHE", str(Path(tempfile.gettempdir()) / "torch_grid_gpu_check"))
        if PREBUILT.exists():
            prebuilt = unpack_prebuilt(PREBUILT, Path(tempfile.gettempdir()) / "torch_grid_prebuilt")
            env["TORCH_GRID_PREBUILT"] = str(prebuilt)
            log(f"prebuilt CUDA objects: {len(list(prebuilt.glob('*.o')))} from {PREBUILT.name}")
        else:
            log(f"no {PREBUILT.relative_to(ROOT)}: every CUDA unit is compiled here (bench/gpu_prebuild.py makes it)")
    log(f"TORCH_GRID_CACHE={env.get('TORCH_GRID_CACHE', '(default)')}")
    outputs: dict[str, str] = {}
    statuses: dict[str, str] = {}
    failures: list[str] = []
    crashed: list[tuple] = []  # stages that died of a segmentation fault, rerun under cuda-gdb for a native stack

    def stage(label: str, args_: list[str], limit: float, extra_env: dict | None = None, wrapper=()) -> str:
        left = deadline - time.monotonic()
        if left < 5:
            failures.append(f"{label}: not run (out of time)")
            log(f"---- {label}: not run, out of time")
            return ""
        text, status = _spawn(args_ + common, {**env, **(extra_env or {})}, min(limit, left), log, label, wrapper)
        outputs[label], statuses[label] = text, status
        if stage_failed(status, text):
            failures.append(f"{label}: {status}")
        if status == f"exit {-signal.SIGSEGV}" and not wrapper and not args.cpu:
            crashed.append((label, args_, extra_env))
        return text

    def parallel(jobs: list[tuple[str, list[str], float, dict]]) -> None:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(lambda job: stage(*job), jobs))

    robots = [r for r in args.robots if (MODELS_DIR / f"{r}.json").exists()]
    threads = ["--threads", str(max(1, cores // workers))]
    # launches synchronous, so that a fault names its op; outputs poisoned, so that an unwritten entry shows
    blocking = {"CUDA_LAUNCH_BLOCKING": "1", "TORCH_GRID_POISON_OUTPUTS": "1"}
    # 1. builds: the glue once, then every robot at once
    stage("build iiwa14", ["--stage", "build", "--robot", "iiwa14"], 300)
    parallel([(f"build {r}", ["--stage", "build", "--robot", r], 300, {}) for r in robots if r != "iiwa14"])
    # 2. correctness, several processes at once
    jobs = [(f"{kind} {r}", ["--stage", kind, "--robot", r, *threads], 240, blocking) for kind in PER_ROBOT for r in robots]
    jobs += [("device", ["--stage", "device", *threads], 240, blocking)]
    # diagnostics of the failures earlier runs showed (gpu_probe.py)
    jobs += [(f"probe {r}", ["--stage", "probe", "--robot", r, *threads], 60, {}) for r in ("go2", "humanoid") if r in robots]
    jobs += [("probe go2 poisoned", ["--stage", "probe", "--robot", "go2", *threads], 60, blocking)] if "go2" in robots else []
    jobs += [("probe runtime", ["--stage", "probe", "--robot", "runtime", *threads], 60, {})]
    if "g1" in robots:
        jobs += [("refusal", ["--stage", "refusal", *threads], 120, {})]
    parallel([j for j in jobs if j[0].split()[0] not in args.skip])
    # alone on the device: it takes all but 1 GiB of the free memory, and a stage beside it would take, for its own
    # kernels' local memory, the memory that the first launch it checks must find once torch's cache is emptied
    if "g1" in robots and "reservation" not in args.skip:
        stage("reservation", ["--stage", "reservation", *threads], 120)
    for label, args_, extra_env in crashed[:2] if "cuda-gdb" not in args.skip else []:
        from gpu_figures import _cuda_tool

        text, _ = _spawn(args_ + common, {**env, **(extra_env or {})}, min(90, max(deadline - time.monotonic(), 1)), log,
                         f"{label} under cuda-gdb",
                         [_cuda_tool("cuda-gdb") or "cuda-gdb", "-q", "-batch", "-ex", "run", "-ex", "bt", "--args"])
        print(text[-3000:], flush=True)
    # 3. tools, then 4. the figures, alone on the machine
    if not args.cpu:
        _tools(stage, log, out, args.skip, statuses)
    if "mpc" not in args.skip:
        stage("mpc", ["--stage", "mpc"], 120)
    if "figures" not in args.skip:
        stage("figures", ["--stage", "figures", "--robot", robots[0]], 300 if not args.cpu else 120)
    return _summary(log, out, outputs, failures, args.cpu)


def _tools(stage, log: Log, out: Path, skip: list[str], statuses: dict[str, str]) -> None:
    from gpu_figures import _cuda_tool

    tool = lambda name: _cuda_tool(name) or name  # noqa: E731
    if "resources" not in skip:
        (out / "resources.txt").write_text(stage("resources", ["--stage", "resources"], 60))
    sanitizer = []
    for kind in ("memcheck", "initcheck"):
        for robot in ("go2", "humanoid") if kind == "memcheck" else ("go2",):
            if kind in skip:
                continue
            if robot != "go2" and statuses.get(f"compute-sanitizer {kind} go2", "").startswith("timed out"):
                # the larger robot under the same tool would time out too: its time left to the stages after it
                log(f"---- compute-sanitizer {kind} {robot}: not run, the go2 stage timed out")
                continue
            # torch's caching allocator off: each tensor its own allocation, so that an access past an output's end
            # (else inside a block torch cached) and a read of memory nothing wrote (else written for an earlier
            # tensor) are seen
            text = stage(f"compute-sanitizer {kind} {robot}", ["--stage", "sanitized_calls", "--robot", robot], 90,
                         extra_env={"PYTORCH_NO_CUDA_MEMORY_CACHING": "1"},
                         wrapper=[tool("compute-sanitizer"), "--tool", kind, "--error-exitcode", "9", "--print-limit", "20"])
            sanitizer.append(f"==== {kind} {robot}\n{text}")
        if kind == "memcheck" and "ncu" not in skip:
            metrics = ",".join(["sm__warps_active.avg.pct_of_peak_sustained_active", "sm__maximum_warps_per_active_cycle_pct",
                                "launch__registers_per_thread", "launch__occupancy_limit_registers", "launch__block_size",
                                "launch__grid_size", "gpu__time_duration.sum"])
            text = stage("ncu", ["--stage", "profiled_call"], 60,
                         wrapper=[tool("ncu"), "--clock-control", "none", "--target-processes", "all", "-k",
                                  "regex:batch_kernel", "--launch-skip", "1", "--launch-count", "1", "--metrics", metrics])
            from gpu_device import NCU_SECTIONS, PROFILED

            sections = [a for name in NCU_SECTIONS for a in ("--section", name)]
            text += "\n" + stage("ncu sections", ["--stage", "profiled_calls"], 150,
                                 wrapper=[tool("ncu"), "--clock-control", "none", "--target-processes", "all", "-k",
                                          "regex:(batch|team)_kernel", "--launch-count", str(len(PROFILED)), *sections])
            (out / "ncu.txt").write_text(text)
    # the team kernels' shared workspaces: no lane reads an entry another lane writes without a sync between them
    if "racecheck" not in skip:
        text = stage("compute-sanitizer racecheck go2 teams", ["--stage", "team_calls", "--robot", "go2"], 60,
                     extra_env={"TORCH_GRID_CUDA_TEAMS": "1"},
                     wrapper=[tool("compute-sanitizer"), "--tool", "racecheck", "--error-exitcode", "9", "--print-limit", "20"])
        sanitizer.append(f"==== racecheck go2 teams\n{text}")
    (out / "sanitizer.log").write_text("\n".join(sanitizer))


def _summary(log: Log, out: Path, outputs: dict[str, str], failures: list[str], cpu: bool) -> int:
    passed, failed, figures = 0, [], []
    for label, text in outputs.items():
        for line in text.splitlines():
            if line.startswith("PASS "):
                passed += 1
            elif line.startswith("FAIL "):
                failed.append(line[5:])
            elif line.startswith("FIGURE "):
                figures.append(json.loads(line[7:]))
            if line.startswith(("FAIL ", "INFO ", "SKIP ")) or "Error" in line:
                print(f"  [{label}] {line[:400]}", flush=True)
    (out / "results.json").write_text(json.dumps(figures, indent=1) + "\n")
    for line in failed + failures:
        log(f"FAILED: {line}")
    log(f"{len(figures)} figures in {out / 'results.json'}")
    name = "CPU" if cpu else _device_name()
    log(f"gpu-check: {passed} passed, {len(failed) + len(failures)} failed on {name}")
    return 1 if failed or failures else 0


def _device_name() -> str:
    text = subprocess.run([sys.executable, "-c", "import torch; print(torch.cuda.get_device_name())"], capture_output=True,
                          text=True).stdout.strip()
    return text or "an unknown device"


if __name__ == "__main__":
    sys.exit(main())
