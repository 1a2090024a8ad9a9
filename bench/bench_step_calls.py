"""Per-call time of Robot.step (float64, Pinocchio's convention, one thread, nothing differentiated) for
each scheme and batch size, beside forward_dynamics', integrate's, difference's, their Jacobians' (d_integrate,
d_difference) and state_cost's on the same inputs, and forward and backward calls: integrate's and difference's
(the gradients of q and v, of q0 and q1), inverse_dynamics' (of q and qd; of q, qd and qdd), forward_dynamics' and
the first scheme's step (of q, qd and tau): what a rollout of small batches pays a step, an MPC iteration a state cost, and a loss a gradient. Run it against two checkouts in turn for an A/B (PYTHONPATH=<checkout>).

    python bench/bench_step_calls.py [--robots iiwa14 go2] [--integrators semi_implicit_euler rk4]
"""
from __future__ import annotations

import argparse
import time

import torch

import torch_grid
from bench_cpu import ROBOTS

BATCHES = (1, 8, 256, 4096)


def per_call_us(fn, batch: int, repeats: int = 5) -> float:
    """Best over `repeats` groups of calls (about 2000 samples a group) of the mean call, in µs."""
    fn()
    n = max(1, 2000 // batch)
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t) / n)
    return best * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=["iiwa14", "go2"])
    parser.add_argument("--integrators", nargs="+", default=["semi_implicit_euler", "rk4"])
    args = parser.parse_args()
    torch.set_num_threads(1)
    others = ("forward_dynamics", "integrate", "difference", "d_integrate", "d_difference", "state_cost",
              "integrate + backward", "difference + backward", "inverse_dynamics + backward",
              f"{args.integrators[0]} step + backward", "inverse_dynamics + backward (q, qd, qdd)",
              "forward_dynamics + backward")
    print("| robot | B | " + " | ".join(args.integrators + list(others)) + " |")
    print("|---|---:|" + "---:|" * (len(args.integrators) + len(others)))
    for name in args.robots:
        src, floating, bundled = ROBOTS[name]
        robot = torch_grid.load(bundled or src, floating_base=floating)
        g = torch.Generator().manual_seed(0)
        for batch in BATCHES:
            q = robot.random_configuration(batch, generator=g)
            qd, tau = (torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
            times = [per_call_us(lambda i=i: robot.step(q, qd, tau, 1e-3, i), batch) for i in args.integrators]
            times.append(per_call_us(lambda: robot.forward_dynamics(q, qd, tau), batch))
            times.append(per_call_us(lambda: robot.integrate(q, qd, 1e-3), batch))
            q1 = robot.integrate(q, qd, 0.1)
            times.append(per_call_us(lambda: robot.difference(q, q1), batch))
            times.append(per_call_us(lambda: robot.d_integrate(q, qd, 1e-3), batch))
            times.append(per_call_us(lambda: robot.d_difference(q, q1), batch))
            w = torch.ones(2 * robot.nv, dtype=torch.float64)
            times.append(per_call_us(lambda: robot.state_cost(q1, qd, q, tau, w), batch))
            qg, vg, q1g = (x.clone().requires_grad_() for x in (q, qd, q1))
            times.append(per_call_us(lambda: torch.autograd.grad(robot.integrate(qg, vg, 1e-3).sum(), (qg, vg)), batch))
            times.append(per_call_us(lambda: torch.autograd.grad(robot.difference(qg, q1g).sum(), (qg, q1g)), batch))
            times.append(per_call_us(lambda: torch.autograd.grad(robot.inverse_dynamics(qg, vg, tau).sum(), (qg, vg)), batch))
            tg = tau.clone().requires_grad_()
            times.append(per_call_us(lambda: torch.autograd.grad(
                sum(x.sum() for x in robot.step(qg, vg, tg, 1e-3, args.integrators[0])), (qg, vg, tg)), batch))
            times.append(per_call_us(lambda: torch.autograd.grad(robot.inverse_dynamics(qg, vg, tg).sum(), (qg, vg, tg)), batch))
            times.append(per_call_us(lambda: torch.autograd.grad(robot.forward_dynamics(qg, vg, tg).sum(), (qg, vg, tg)), batch))
            print(f"| {name} | {batch} | " + " | ".join(f"{t:.1f}" for t in times) + " |", flush=True)


if __name__ == "__main__":
    main()
