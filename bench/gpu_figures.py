"""The figures of bench/gpu_check.py: per-sample times on the GPU (CUDA events, data on the device,
after a warm-up) and of the CPU build on the same machine, the cost of a batch-of-one call, and each
CUDA kernel's registers and stack as loaded (cuobjdump) with the occupancy they allow.

Each figure is printed as `FIGURE {json}`; gpu_check.py gathers them into results.json.
"""
from __future__ import annotations

import contextlib
import json
import re
import shutil
import statistics
import subprocess
import time

import torch

from gpu_correctness import TeamPaths, on, states

# OP[teams] entries are placeholders, filled in below (TEAMS), that place each team figure beside its op's
OPS = {
    "inverse_dynamics": lambda v, q, qd, x: v.inverse_dynamics(q, qd, x),
    "inverse_dynamics[teams]": None,
    "forward_dynamics": lambda v, q, qd, x: v.forward_dynamics(q, qd, x),
    "forward_dynamics[teams]": None,
    "crba": lambda v, q, qd, x: v.crba(q),
    "crba[teams]": None,
    "minv": lambda v, q, qd, x: v.minv(q),
    "minv[teams]": None,
    "inverse_dynamics_derivatives": lambda v, q, qd, x: v.inverse_dynamics_derivatives(q, qd, x),
    "inverse_dynamics_derivatives[teams]": None,
    "forward_dynamics_derivatives": lambda v, q, qd, x: v.forward_dynamics_derivatives(q, qd, x),
    "forward_dynamics_derivatives[teams]": None,
    "inverse_dynamics_second_derivatives": lambda v, q, qd, x: v.inverse_dynamics_second_derivatives(q, qd, x),
    "inverse_dynamics_second_derivatives[teams]": None,
    "step[semi_implicit_euler]": lambda v, q, qd, x: v.step(q, qd, x, 0.01, "semi_implicit_euler"),
    "step[semi_implicit_euler][teams]": None,
    "step_derivatives[semi_implicit_euler]": lambda v, q, qd, x: v.step_derivatives(q, qd, x, 0.01, "semi_implicit_euler"),
    "step_derivatives[semi_implicit_euler][teams]": None,
    "step_derivatives[rk4]": lambda v, q, qd, x: v.step_derivatives(q, qd, x, 0.01, "rk4"),
    "step_derivatives[rk4][teams]": None,
    # the torch composition the fused kernel replaces (forward_dynamics, forward_dynamics_derivatives and batched
    # products): on a GPU its coalesced products may beat one thread's loops over the 2 nv x 2 nv matrices
    "step_derivatives[semi_implicit_euler, composed]":
        lambda v, q, qd, x: v._step_derivatives(q, qd, x, 0.01, None, v._params, "semi_implicit_euler")[2:],
}
# The team figures, OP[teams]: OP with the ops' team paths taken (one warp a sample, TORCH_GRID_CUDA_TEAMS=1) for the
# whole measurement, on the device only.
TEAMS = {name: name.removesuffix("[teams]") for name in OPS if name.endswith("[teams]")}
# floats written per sample, for the memory cap below
OUTPUTS = {"inverse_dynamics_second_derivatives": lambda nv: 4 * nv ** 3, "step_derivatives[rk4]": lambda nv: 6 * nv ** 2}
MAX_OUTPUT_BYTES = 8 << 30


def _with_teams(op: str):
    """OPS[op] with the ops' team paths taken (gpu_correctness.TeamPaths)."""
    def call(v, q, qd, x):
        with TeamPaths():
            return OPS[op](v, q, qd, x)
    return call


OPS.update({name: _with_teams(op) for name, op in TEAMS.items()})


def _cuda_seconds(fn, target: float = 0.03) -> tuple[float, float]:
    """(best, median) seconds per call over groups of back-to-back calls timed by CUDA events."""
    fn()
    fn()
    torch.cuda.synchronize()
    start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    start.record()
    fn()
    end.record()
    end.synchronize()
    once = max(start.elapsed_time(end) / 1e3, 1e-6)
    calls = max(1, min(200, int(target / once)))
    times = []
    for _ in range(5):
        start.record()
        for _ in range(calls):
            fn()
        end.record()
        end.synchronize()
        times.append(start.elapsed_time(end) / 1e3 / calls)
    return min(times), statistics.median(times)


def _cpu_seconds(fn, target: float = 0.1) -> tuple[float, float]:
    fn()
    t0 = time.perf_counter()
    fn()
    once = max(time.perf_counter() - t0, 1e-7)
    calls = max(1, min(1000, int(target / once)))
    times = []
    for _ in range(3 if once < 0.5 else 1):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - t0) / calls)
    return min(times), statistics.median(times)


def timings(robots: dict, device: torch.device, sizes: list[int], cpu_sizes: list[int], meta: dict,
            dtypes=(torch.float64, torch.float32)) -> None:
    """One FIGURE line per (robot, op, dtype, batch) on the device and on the CPU build: every robot's figures of the
    first dtype (float64, the targets') before any of the next, so that a stage cut short by its time limit has
    them."""
    cpu_label = f"CPU build, {torch.get_num_threads()} threads ({meta['device']} machine)"
    for dtype in dtypes:
        for name, robot in robots.items():
            view = robot.pin
            base = on(states(view, max(sizes + cpu_sizes), seed=11)[:3], "cpu", dtype)
            for op, call in OPS.items():
                per_sample = OUTPUTS.get(TEAMS.get(op, op), lambda nv: 0)(robot.nv) * (8 if dtype == torch.float64 else 4)
                for where, batch_sizes in (("device", sizes), ("cpu", cpu_sizes)):
                    if (where == "device" and device.type != "cuda") or (where == "cpu" and op in TEAMS):
                        continue
                    for n in batch_sizes:
                        if per_sample * n > MAX_OUTPUT_BYTES:
                            print(f"INFO {name} {op} {dtype} N = {n}: skipped, {per_sample * n / 2**30:.0f} GiB of "
                                  "outputs", flush=True)
                            continue
                        x = [t[:n].to(device if where == "device" else "cpu") for t in base]
                        timed = OPS[TEAMS[op]] if op in TEAMS else call
                        with TeamPaths() if op in TEAMS else contextlib.nullcontext():
                            best, median = (_cuda_seconds if where == "device" else _cpu_seconds)(
                                lambda x=x, timed=timed: timed(view, *x))
                        record = {"device": meta["device"] if where == "device" else cpu_label, "robot": name, "op": op,
                                  "dtype": str(dtype).replace("torch.", ""), "batch": n,
                                  "us_per_sample": best * 1e6 / n, "us_per_call_median": median * 1e6,
                                  "torch": meta["torch"], "commit": meta["commit"]}
                        print("FIGURE " + json.dumps(record), flush=True)
                        del x
            if device.type == "cuda":
                torch.cuda.empty_cache()


def call_overhead(robot, device: torch.device, meta: dict) -> None:
    """Wall time of a batch-of-one call through Robot: back to back (dispatch and launch) and with a
    synchronisation after each (the round trip)."""
    view = robot.pin
    q, qd, x = on(states(view, 1, seed=12)[:3], device)
    for sync in (False, True):
        view.inverse_dynamics(q, qd, x)
        wait = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
        wait()
        best = float("inf")
        for _ in range(5):
            t0 = time.perf_counter()
            for _ in range(200):
                view.inverse_dynamics(q, qd, x)
                if sync:
                    wait()
            wait()
            best = min(best, (time.perf_counter() - t0) / 200)
        record = {"device": meta["device"] if device.type == "cuda" else "CPU", "robot": robot.name,
                  "op": f"call_overhead[inverse_dynamics{', synchronized' if sync else ''}]", "dtype": "float64",
                  "batch": 1, "us_per_sample": best * 1e6, "torch": meta["torch"], "commit": meta["commit"]}
        print("FIGURE " + json.dumps(record), flush=True)


def _kernel_of(mangled: str) -> tuple[str, str, str] | None:
    """(kernel struct, scalar, convention) of a mangled tg::batch_kernel<tg::bind::K, Robot, S, C> name, the struct
    marked [team] for a tg::team_kernel (a warp a sample)."""
    bind = re.search(r"4bind(\d+)", mangled)
    tail = re.search(r"E([df])Li(\d)EEEvNS_5BatchE(i?)$", mangled)
    team = "team_kernel" in mangled
    if not (team or "batch_kernel" in mangled) or not bind or not tail or team != (tail.group(3) == "i"):
        return None
    start = bind.end()
    return (mangled[start:start + int(bind.group(1))] + (" [team]" if team else ""), "double" if tail.group(1) == "d" else "float",
            "mjx" if tail.group(2) == "1" else "pin")


def _cuda_tool(name: str) -> str | None:
    from torch_grid.ops.build import cuda_home

    home = cuda_home()
    found = shutil.which(name) or (str(home / "bin" / name) if home and (home / "bin" / name).exists() else None)
    return found


def resources(libraries: dict[str, str], threads_per_block: int = 128) -> str:
    """Each CUDA kernel's registers and stack as compiled into the loaded libraries, and the occupancy
    they allow at threads_per_block (a register file of 65536, 64 warps an SM, 32 blocks an SM)."""
    cuobjdump = _cuda_tool("cuobjdump")
    if not cuobjdump:
        return "cuobjdump not found\n"
    lines = [f"{'robot':10s} {'kernel':52s} {'scalar':6s} {'conv':6s} {'regs':>4s} {'stack B':>8s} {'occupancy':>9s}"]
    for robot, library in libraries.items():
        dump = subprocess.run([cuobjdump, "--dump-resource-usage", library], capture_output=True, text=True)
        found = re.findall(r"Function (_Z\w+):?[\s\S]{0,200}?REG:(\d+)[\s\S]{0,80}?STACK:(\d+)", dump.stdout)
        if not found:
            lines.append(f"{robot}: no kernel read from cuobjdump's output: {(dump.stdout + dump.stderr)[:1500]!r}")
        for name, regs, stack in found:
            kernel = _kernel_of(name)
            if not kernel:
                lines.append(f"{robot}: {name} (not a batch kernel) REG {regs} STACK {stack}")
                continue
            op, scalar, conv = kernel
            regs_i = int(regs)
            warps_per_block = threads_per_block // 32
            per_warp = ((max(regs_i, 1) * 32 + 255) // 256) * 256
            blocks = min(32, (65536 // per_warp) // warps_per_block, 64 // warps_per_block)
            # a team kernel's blocks are also bounded by their shared memory, which cuobjdump does not give here
            occupancy = "-" if op.endswith("[team]") else f"{blocks * warps_per_block / 64:.3f}"
            lines.append(f"{robot:10s} {op:52s} {scalar:6s} {conv:6s} {regs_i:4d} {int(stack):8d} {occupancy:>9s}")
    return "\n".join(lines) + "\n"
