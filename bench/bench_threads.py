"""Thread scaling of small and large CPU batches: the time of one call on one and on two threads
(torch.set_num_threads) for a light op (inverse_dynamics) and a heavy one
(forward_dynamics_derivatives), forward only, at B = 16, 64, 256 and 4096, and forward_dynamics
forward + backward at B = 64; go2, float64. Prints a markdown table of per-call times and the
two-thread / one-thread ratio: the best call over all repeats, and the best over repeats of a
repeat's median call (on a shared machine a woken thread may wait for a core other processes hold:
the median shows how often). The two thread counts are measured in turn, repeat by repeat.

    python bench/bench_threads.py [--robot go2] [--repeats 15] [--budget 0.02]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import torch_grid  # noqa: E402

BATCHES = (16, 64, 256, 4096)
THREADS = (1, 2)


def call_us(fn: Callable[[], object], threads: int, budget_s: float) -> tuple[float, float]:
    """The best and the median time of one call, in µs, over about `budget_s` seconds of calls (at
    least 3) on `threads` threads."""
    torch.set_num_threads(threads)
    fn()
    times: list[float] = []
    start = time.perf_counter()
    while len(times) < 3 or time.perf_counter() - start < budget_s:
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times) * 1e6, statistics.median(times) * 1e6


def cases(robot: torch_grid.Robot) -> list[tuple[str, int, Callable[[], object]]]:
    """(label, batch size, call) for every measured case."""
    g = torch.Generator().manual_seed(0)
    nv = robot.model.nv

    def vector(b: int, grad: bool = False) -> torch.Tensor:
        return torch.randn(b, nv, generator=g, dtype=torch.float64, requires_grad=grad)

    out = []
    for name in ("inverse_dynamics", "forward_dynamics_derivatives"):
        for b in BATCHES:
            args = (robot.random_configuration(b, generator=g), vector(b), vector(b))
            out.append((name, b, lambda f=getattr(robot, name), args=args: f(*args)))
    b = 64
    q, qd, tau = robot.random_configuration(b, generator=g).requires_grad_(), vector(b, True), vector(b, True)

    def forward_backward() -> None:
        robot.forward_dynamics(q, qd, tau).sum().backward()

    out.append(("forward_dynamics forward + backward", b, forward_backward))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robot", default="go2")
    parser.add_argument("--repeats", type=int, default=15, help="repeats per case and thread count")
    parser.add_argument("--budget", type=float, default=0.02, help="seconds of calls per repeat")
    args = parser.parse_args()
    robot = torch_grid.load(args.robot)
    threads_before = torch.get_num_threads()
    print(f"{args.robot}, float64, torch {torch.__version__}, {torch.get_num_threads()} threads available; "
          f"µs per call, {args.repeats} repeats\n")
    print("| op | B | best, 1 thread | 2 threads | 2 / 1 | median, 1 thread | 2 threads | 2 / 1 |\n"
          "|---|---|---|---|---|---|---|---|")
    for label, b, fn in cases(robot):
        best = {t: [float("inf"), float("inf")] for t in THREADS}
        for _ in range(args.repeats):
            for t in THREADS:
                best[t] = [min(x, y) for x, y in zip(best[t], call_us(fn, t, args.budget))]
        cells = [f"{best[1][k]:.1f} | {best[2][k]:.1f} | {best[2][k] / best[1][k]:.2f}" for k in (0, 1)]
        print(f"| {label} | {b} | {' | '.join(cells)} |", flush=True)
    torch.set_num_threads(threads_before)


if __name__ == "__main__":
    main()
