"""torch.compile of the plant step: traced ops per step, the compile time of a 20-step go2 rollout of a
small MLP policy (first forward, first backward, fullgraph=True), and eager forward + backward of one
semi-implicit Euler step against its forward (go2, float64, one thread, best of repeats).

    python bench/bench_compile.py
"""
from __future__ import annotations

import time

import torch

import torch_grid
from torch_grid.step.integrators import INTEGRATORS


def _ops_per_step(view, batch: int = 4) -> dict[str, int]:
    nv = view.nv
    q, qd, tau = view.random_configuration(batch), torch.randn(batch, nv, dtype=torch.float64), torch.zeros(batch, nv,
                                                                                                             dtype=torch.float64)
    counts = {}
    for integrator in INTEGRATORS:
        torch._dynamo.reset()
        counts[integrator] = torch._dynamo.explain(lambda *x: view.step(*x, 0.01, integrator))(q, qd, tau).op_count
    return counts


def _compile_times(view, steps: int = 20, batch: int = 64) -> tuple[float, float]:
    nq, nv = view.nq, view.nv
    policy = torch.nn.Sequential(torch.nn.Linear(nq + nv, 64), torch.nn.Tanh(), torch.nn.Linear(64, nv)).double()

    def rollout(q, qd):
        cost = 0
        for _ in range(steps):
            q, qd = view.step(q, qd, policy(torch.cat([q, qd], dim=-1)), 0.01)
            cost = cost + (qd ** 2).sum()
        return cost

    torch._dynamo.reset()
    compiled = torch.compile(rollout, fullgraph=True)
    q, qd = view.random_configuration(batch), torch.zeros(batch, nv, dtype=torch.float64)
    t = time.perf_counter()
    cost = compiled(q, qd)
    t_forward = time.perf_counter() - t
    t = time.perf_counter()
    cost.backward()
    return t_forward, time.perf_counter() - t


def _best(fn, repeats: int = 200) -> float:
    fn()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _eager_ratio(view, batch: int) -> tuple[float, float]:
    nv = view.nv
    q, qd = view.random_configuration(batch), torch.randn(batch, nv, dtype=torch.float64)
    tau = torch.randn(batch, nv, dtype=torch.float64, requires_grad=True)

    def forward():
        with torch.no_grad():
            view.step(q, qd, tau, 0.01)

    def forward_backward():
        q_next, qd_next = view.step(q, qd, tau, 0.01)
        (q_next.sum() + qd_next.sum()).backward()

    return _best(forward) * 1e6, _best(forward_backward) * 1e6


def main() -> None:
    torch.set_num_threads(1)
    robot = torch_grid.load("go2")
    print("traced ops per step (torch._dynamo.explain), go2:")
    for convention in ("pin", "mujoco"):
        print(f"  {convention}: {_ops_per_step(getattr(robot, convention))}")
    forward, backward = _compile_times(robot.pin)
    print(f"compile of a 20-step rollout (B = 64, MLP 64): first forward {forward:.1f} s, first backward {backward:.1f} s")
    for batch in (1, 64):
        fwd, both = _eager_ratio(robot.pin, batch)
        print(f"eager semi-implicit Euler step, B = {batch}: forward {fwd:.0f} us, forward + backward {both:.0f} us "
              f"({both / fwd:.1f}x)")


if __name__ == "__main__":
    main()
