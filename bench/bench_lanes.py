"""CPU vector lanes: per-sample time of batched ops (B = 4096, float64, one thread) with the lane
kernels (several samples per instruction, the default) and with the scalar kernels
(torch_grid.set_cpu_lanes(False)), against Pinocchio's C++ per-call time (pinocchio_cpp.py), in one
run; float32 against float64, two threads against one (beside what two threads gain on a pure
arithmetic loop at that moment: machine_cores.py), and a batch of one. Writes a markdown section
to bench/RESULTS.md with --write.

    python bench/bench_lanes.py [--write] [--robots iiwa14 ur5 panda go2 g1]

Pinocchio's code-generated derivatives build once per robot (about 8 minutes for G1) into a cache.
"""
from __future__ import annotations

import argparse
import math
import platform
import re
import subprocess
from pathlib import Path

import torch

import torch_grid
from bench_cpu import ERD, ROBOTS, cases, per_call_us, per_sample_us
from machine_cores import two_thread_ceiling
from pinocchio_codegen import pinocchio_codegen_times
from pinocchio_cpp import pinocchio_cpp_times

HERE = Path(__file__).resolve().parent
ROBOTS.setdefault("ur5", (str(ERD / "ur_description" / "urdf" / "ur5_robot.urdf"), False, None))
ROBOTS.setdefault("panda", (str(ERD / "panda_description" / "urdf" / "panda.urdf"), False, None))
B = 4096


def extra_cases(name: str) -> dict:
    """Functions beyond bench_cpu's table (no Pinocchio counterpart there): steps, their derivatives, a
    backward through the forward-mode kernels, second order, the frames."""
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    g = torch.Generator().manual_seed(0)
    q = robot.random_configuration(B, generator=g)
    qd, qdd = (torch.randn(B, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    frames = list(range(robot.nframes))[-2:]
    weight = torch.randn(B, 6, robot.nv, dtype=torch.float64, generator=g)
    return {
        "step (semi-implicit Euler)": lambda: robot.step(q, qd, qdd, 1e-3),
        "step (rk4)": lambda: robot.step(q, qd, qdd, 1e-3, "rk4"),
        "step_derivatives (semi-implicit Euler)": lambda: robot.step_derivatives(q, qd, qdd, 1e-3),
        "step_derivatives (rk4)": lambda: robot.step_derivatives(q, qd, qdd, 1e-3, "rk4"),
        "inverse_dynamics_second_derivatives": lambda: robot.inverse_dynamics_second_derivatives(q, qd, qdd),
        "forward_kinematics": lambda: robot.forward_kinematics(q),
        "end_effector_pose": lambda: robot.end_effector_pose(q, frames),
        "frame_jacobian backward (forward mode)": lambda: torch.autograd.grad(
            (robot.frame_jacobian(q.requires_grad_(True), frames[-1]) * weight).sum(), q)[0],
    }


def timed(fn, lanes: bool, measure=None) -> float:
    """measure(fn) (per-sample µs at B by default) with the lane kernels on or off."""
    previous = torch_grid.set_cpu_lanes(lanes)
    try:
        return measure(fn) if measure else per_sample_us(fn, B)
    finally:
        torch_grid.set_cpu_lanes(previous)


def robot_rows(name: str) -> tuple[list[list], dict]:
    """Rows (function, scalar, lanes, lanes / scalar, Pinocchio C++, lanes / Pinocchio) and the summary
    figures of one robot."""
    src, floating, bundled = ROBOTS[name]
    pin_us = pinocchio_cpp_times(src, floating, batch=B)
    codegen = pinocchio_codegen_times(src, floating, batch=B)
    rows, ratios = [], []
    for function, (fn, _) in cases(name).items():
        s, lane = timed(fn, False), timed(fn, True)
        p = pin_us.get(function)
        rows.append([function, s, lane, lane / s, p, lane / p if p else None])
        if p:
            ratios.append(lane / p)
    for function, fn in extra_cases(name).items():
        s, lane = timed(fn, False), timed(fn, True)
        rows.append([function, s, lane, lane / s, None, None])
    robot = torch_grid.load(bundled or src, floating_base=floating)
    g = torch.Generator().manual_seed(1)
    q = robot.random_configuration(B, generator=g)
    qd, tau = (torch.randn(B, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    q32, qd32, tau32 = q.float(), qd.float(), tau.float()
    summary = {"geomean of lanes / Pinocchio C++": math.exp(sum(map(math.log, ratios)) / len(ratios))}
    for row in rows:
        if row[0] in ("forward_dynamics_derivatives", "inverse_dynamics_derivatives"):
            summary[f"{row[0]}: lanes / Pinocchio code-generated ({codegen[row[0]]:.3f} µs)"] = row[2] / codegen[row[0]]
    summary["Pinocchio code generation, build s (both)"] = codegen["compile_s"]
    for label, fn, fn32 in (("inverse_dynamics", lambda: robot.inverse_dynamics(q, qd, tau),
                             lambda: robot.inverse_dynamics(q32, qd32, tau32)),
                            ("forward_dynamics_derivatives", lambda: robot.forward_dynamics_derivatives(q, qd, tau),
                             lambda: robot.forward_dynamics_derivatives(q32, qd32, tau32))):
        summary[f"float32 / float64, {label}"] = per_sample_us(fn32, B) / per_sample_us(fn, B)
        summary[f"2 threads speed-up, {label}"] = two_thread_speedup(fn)
        summary[f"2 threads speed-up of an arithmetic loop, just after {label}"] = two_thread_ceiling()
    one = [x[:1] for x in (q, qd, tau)]
    call = lambda: robot.inverse_dynamics(*one)  # noqa: E731
    summary["batch of one, inverse_dynamics µs (lanes on / off)"] = tuple(timed(call, on, per_call_us) for on in (True, False))
    return rows, summary


def two_thread_speedup(fn, rounds: int = 5) -> float:
    """One thread's best per-sample time over two threads', one and two threads taken in turn `rounds` times:
    this machine's two virtual CPUs share a core's arithmetic at some moments and not at others
    (machine_cores.py), and a single pair can fall either side of such a change."""
    threads = torch.get_num_threads()
    one, two = float("inf"), float("inf")
    try:
        for _ in range(rounds):
            torch.set_num_threads(1)
            one = min(one, per_sample_us(fn, B))
            torch.set_num_threads(2)
            two = min(two, per_sample_us(fn, B))
    finally:
        torch.set_num_threads(threads)
    return one / two


def instruction_set() -> str:
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    found = [f for f in ("avx512f", "avx2", "fma") if re.search(rf"\b{f}\b", flags)]
    lanes = subprocess.run(["c++", "-march=native", "-dM", "-E", "-x", "c++", "/dev/null"], capture_output=True, text=True).stdout
    width = 8 if "__AVX512F__" in lanes else 4 if "__AVX__" in lanes else 2
    return f"{', '.join(found) or 'no AVX'}; {width} lanes of double"


def section(results: dict) -> str:
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor())
    lines = ["## CPU vector lanes", "",
             f"Per-sample µs, B = {B}, float64, one thread; {cpu} ({instruction_set()}); torch {torch.__version__}. "
             "`scalar`: torch_grid.set_cpu_lanes(False); `lanes`: the default. Pinocchio: its C++ per call "
             "(bench/pinocchio_cpp.py), same run; its code-generated derivatives (CppADCodeGen, "
             "bench/pinocchio_codegen.py) below each table.", ""]
    for name, (rows, summary) in results.items():
        lines += [f"### {name}", "", "| function | scalar | lanes | lanes / scalar | Pinocchio C++ | lanes / Pinocchio |",
                  "|---|---:|---:|---:|---:|---:|"]
        for f, s, lane, r, p, rp in rows:
            lines.append(f"| {f} | {s:.3f} | {lane:.3f} | {r:.2f} | {'' if p is None else f'{p:.3f}'} | "
                         f"{'' if rp is None else f'{rp:.2f}'} |")
        lines += [""] + [f"- {k}: " + (f"{v[0]:.2f} / {v[1]:.2f}" if isinstance(v, tuple) else f"{v:.2f}")
                         for k, v in summary.items()] + [""]
    return "\n".join(lines)


def write(text: str) -> None:
    path = HERE / "RESULTS.md"
    old = path.read_text()
    start = old.find("## CPU vector lanes")
    if start < 0:
        new = old.rstrip() + "\n\n" + text + "\n"
    else:
        end = old.find("\n## ", start + 1)
        new = old[:start] + text + ("\n" + old[end + 1:] if end >= 0 else "\n")
    path.write_text(new)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robots", nargs="*", default=["iiwa14", "ur5", "panda", "go2", "g1"])
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    results = {name: robot_rows(name) for name in args.robots}
    text = section(results)
    print(text)
    if args.write:
        write(text)


if __name__ == "__main__":
    main()
