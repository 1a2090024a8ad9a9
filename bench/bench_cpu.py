"""CPU benchmark: per-sample time of batched torch_grid ops (B = 4096, float64) on one thread and
on all threads, against Pinocchio's per-call time through Python; first build and warm reload
times of each robot. Writes a markdown table to bench/RESULTS.md with --write.

    python bench/bench_cpu.py [--write] [--robots iiwa14 go2 g1]
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
import torch

import torch_grid

HERE = Path(__file__).resolve().parent
ERD = Path(sys.prefix) / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages" / \
    "cmeel.prefix" / "share" / "example-robot-data" / "robots"
ROBOTS = {
    "iiwa14": (str(torch_grid.parse.ROBOTS_DIR / "iiwa14.urdf"), False, "iiwa14"),
    "go2": (str(torch_grid.parse.ROBOTS_DIR / "go2.urdf"), True, "go2"),
    "g1": (str(ERD / "g1_description" / "urdf" / "g1_29dof_rev_1_0.urdf"), True, None),
}
B = 4096


def per_sample_us(fn, batch: int, seconds: float = 1.0) -> float:
    """Best over repeats of the time of one batched call, divided by the batch size (the
    machine is shared: the minimum is the stable estimate, as for Pinocchio below)."""
    fn()
    times = []
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline or len(times) < 5:
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times) / batch * 1e6


def per_call_us(fn, calls: int = 20000) -> float:
    fn()
    best = float("inf")
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(calls // 5):
            fn()
        best = min(best, (time.perf_counter() - t) / (calls // 5) * 1e6)
    return best


def build_times(name: str) -> tuple[float, float]:
    """(first build, warm load in a new process after `import torch`), seconds, in a fresh cache."""
    src, floating, bundled = ROBOTS[name]
    source = bundled or src
    script = ("import time, torch; t = time.perf_counter(); import torch_grid; "
              f"torch_grid.load({source!r}, floating_base={floating!r}); print(time.perf_counter() - t)")
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, TORCH_GRID_CACHE=cache)
        first, warm = (float(subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                                            check=True).stdout.split()[-1]) for _ in range(2))
    return first, warm


def cases(name: str):
    """name -> (torch_grid batched call, Pinocchio single call) for one robot."""
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    model = pin.buildModelFromUrdf(src, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(src)
    data = model.createData()
    g = torch.Generator().manual_seed(0)
    q = robot.random_configuration(B, generator=g)
    qd, qdd = (torch.randn(B, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    frame = robot.nframes - 1
    qn, vn, an = (x[0].numpy() for x in (q, qd, qdd))
    return {
        "inverse_dynamics": (lambda: robot.inverse_dynamics(q, qd, qdd), lambda: pin.rnea(model, data, qn, vn, an)),
        "crba": (lambda: robot.crba(q), lambda: pin.crba(model, data, qn)),
        "minv": (lambda: robot.minv(q), lambda: pin.computeMinverse(model, data, qn)),
        "forward_dynamics": (lambda: robot.forward_dynamics(q, qd, qdd), lambda: pin.aba(model, data, qn, vn, an)),
        "frame_jacobian": (lambda: robot.frame_jacobian(q, frame),
                           lambda: pin.computeFrameJacobian(model, data, qn, frame, pin.LOCAL_WORLD_ALIGNED)),
        "inverse_dynamics_gradient": (lambda: robot.inverse_dynamics_gradient(q, qd, qdd),
                                      lambda: pin.computeRNEADerivatives(model, data, qn, vn, an)),
        "forward_dynamics_gradient": (lambda: robot.forward_dynamics_gradient(q, qd, qdd),
                                      lambda: pin.computeABADerivatives(model, data, qn, vn, an)),
    }


def forward_and_backward_us(fn, inputs, batch: int, seconds: float = 1.0) -> tuple[float, float]:
    """Per-sample time of fn(*inputs) alone and of it plus a backward with respect to every input,
    one thread."""
    def both():
        leaves = [x.detach().requires_grad_(True) for x in inputs]
        out = fn(*leaves)
        sum(o.sum() for o in (out if isinstance(out, tuple) else (out,))).backward()

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    times = per_sample_us(lambda: fn(*inputs), batch), per_sample_us(both, batch, seconds)
    torch.set_num_threads(threads)
    return times


def backward_ratio(name: str) -> tuple[float, float]:
    """forward_dynamics alone and forward + backward (q, qd, tau), per sample, 1 thread."""
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    g = torch.Generator().manual_seed(0)
    inputs = [robot.random_configuration(B, generator=g)] + \
        [torch.randn(B, robot.nv, dtype=torch.float64, generator=g) for _ in range(2)]
    return forward_and_backward_us(robot.forward_dynamics, inputs, B)


def second_order(name: str, batch: int = 256) -> list[tuple[str, float, float]]:
    """(function, forward, forward + backward) per sample, 1 thread, for functions whose backward is
    second order (q, qd and qdd all requiring grad)."""
    src, floating, bundled = ROBOTS[name]
    robot = torch_grid.load(bundled or src, floating_base=floating)
    g = torch.Generator().manual_seed(0)
    inputs = [robot.random_configuration(batch, generator=g)] + \
        [torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2)]
    frame = robot.nframes - 1
    functions = {
        "crba": (lambda q, qd, qdd: robot.crba(q)),
        "minv": (lambda q, qd, qdd: robot.minv(q)),
        "frame_jacobian": (lambda q, qd, qdd: robot.frame_jacobian(q, frame)),
        "coriolis_matrix": (lambda q, qd, qdd: robot.coriolis_matrix(q, qd)),
        "inverse_dynamics_gradient": (lambda q, qd, qdd: robot.inverse_dynamics_gradient(q, qd, qdd)),
    }
    return [(fn_name, *forward_and_backward_us(fn, inputs, batch, seconds=0.5)) for fn_name, fn in functions.items()]


def bench_robot(name: str) -> list[tuple]:
    rows = []
    threads = torch.get_num_threads()
    for fn_name, (ours, theirs) in cases(name).items():
        torch.set_num_threads(1)
        one = per_sample_us(ours, B)
        torch.set_num_threads(threads)
        many = per_sample_us(ours, B)
        ref = per_call_us(theirs)
        rows.append((name, fn_name, one, many, ref))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="*", default=list(ROBOTS))
    parser.add_argument("--write", action="store_true", help="write bench/RESULTS.md")
    args = parser.parse_args()
    threads = torch.get_num_threads()
    lines = [f"| robot | function | 1 thread | {threads} threads | Pinocchio per call | 1 thread ≤ Pinocchio |",
             "|---|---|---|---|---|---|"]
    builds = ["| robot | nq | nv | first build (s) | warm load, new process (s) |", "|---|---|---|---|---|"]
    grads = ["| robot | forward_dynamics (µs/sample) | forward + backward (µs/sample) | ratio |", "|---|---|---|---|"]
    second = ["| robot | function | forward (µs/sample) | forward + backward (µs/sample) |", "|---|---|---|---|"]
    for name in args.robots:
        for robot, fn, one, many, ref in bench_robot(name):
            lines.append(f"| {robot} | {fn} | {one:.3f} | {many:.3f} | {ref:.3f} | {'yes' if one <= ref else 'NO'} |")
            print(lines[-1], flush=True)
        forward, both = backward_ratio(name)
        grads.append(f"| {name} | {forward:.3f} | {both:.3f} | {both / forward:.2f} |")
        print(grads[-1], flush=True)
        for fn, forward, both in second_order(name):
            second.append(f"| {name} | {fn} | {forward:.2f} | {both:.1f} |")
            print(second[-1], flush=True)
        first, warm = build_times(name)
        src, floating, bundled = ROBOTS[name]
        r = torch_grid.load(bundled or src, floating_base=floating)
        builds.append(f"| {name} | {r.nq} | {r.nv} | {first:.1f} | {warm:.2f} |")
        print(builds[-1], flush=True)
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    header = (f"## CPU, {datetime.date.today()}\n\nMachine: {cpu}, {os.cpu_count()} cores; torch {torch.__version__}, "
              f"Pinocchio {pin.__version__}; batch B = {B}, float64. Pinocchio is called once per sample from "
              "Python (its usual use); torch_grid's time is one batched call divided by B, in µs per sample, "
              "including the allocation of the batched output.\n")
    text = header + "\n" + "\n".join(lines) + "\n\nFirst build: all functions, both conventions, float32 + float64, CPU, " \
        "into an empty cache; warm load: `torch_grid.load` in a new process after `import torch`.\n\n" + "\n".join(builds) + \
        "\n\nAutograd: forward_dynamics alone against forward + backward with respect to q, qd and tau " \
        "(one thread, float64, B = 4096).\n\n" + "\n".join(grads) + \
        "\n\nSecond-order backwards (M, M^-1 from inverse-dynamics products; the others by the forward-mode " \
        "dual-number kernels), with respect to every input, one thread, float64, B = 256.\n\n" + "\n".join(second) + "\n"
    print(text)
    if args.write:
        (HERE / "RESULTS.md").write_text("# Benchmark results\n\nProduced by `python bench/bench_cpu.py --write`.\n\n" + text)


if __name__ == "__main__":
    main()
