"""The MPC path's figures for bench/gpu_check.py: examples/ilqr.py's go2 task (256 samples, a horizon
of 50: 12 800 knots a horizon call) on the device and on the CPU build with the machine's threads.
One iLQR iteration, and its parts timed alone: the horizon call (every knot's step Jacobians and cost
derivatives), the Riccati pass (a few small torch ops a knot) and a rollout (T step calls); on CUDA the
rollout and the Riccati pass also replayed from CUDA graphs, which first must give the eager values.

Each figure is a `FIGURE {json}` line as gpu_figures.py's, its op `mpc[<part>]`, with `ms_per_call`.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "examples"))
import ilqr  # noqa: E402

from gpu_correctness import Checks, compare  # noqa: E402

INTEGRATOR = "semi_implicit_euler"


def _seconds(fn, device: torch.device, repeats: int = 3) -> float:
    """The best wall time of fn over repeats, the device synchronised around each call."""
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    fn()
    sync()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        sync()
        best = min(best, time.perf_counter() - t0)
    return best


def _graphed(fn):
    """fn() captured in a CUDA graph after a warm-up on a side stream: (replay, the captured outputs)."""
    side = torch.cuda.Stream()
    side.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(side):
        for _ in range(2):
            fn()
    torch.cuda.current_stream().wait_stream(side)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        out = fn()
    return graph.replay, out


def mpc(checks: Checks, device: torch.device, meta: dict, batch: int = 256, T: int = 50, iterations: int = 3) -> None:
    """FIGURE lines of the MPC path on `device` and, where `device` is CUDA, on the CPU build too."""
    for where in [device, torch.device("cpu")] if device.type == "cuda" else [device]:
        label = meta["device"] if where.type == "cuda" else f"CPU build, {torch.get_num_threads()} threads"
        for part, seconds in _parts(checks, where, batch, T, iterations).items():
            record = {"device": label, "robot": "go2", "op": f"mpc[{part}]", "dtype": "float64", "batch": batch,
                      "horizon": T, "ms_per_call": seconds * 1e3, "us_per_sample": seconds * 1e6 / batch,
                      "torch": meta["torch"], "commit": meta["commit"]}
            print("FIGURE " + json.dumps(record), flush=True)
    checks.run("mpc figures", lambda: None)


def _parts(checks: Checks, where: torch.device, batch: int, T: int, iterations: int) -> dict[str, float]:
    """Seconds a call of an iteration and of each part on one device."""
    view, q0, qd0, U, dt, running, terminal = ilqr.balance_problem(str(where), batch, T)

    def rollout():
        return ilqr.rollout(view, q0, qd0, U, dt, INTEGRATOR)

    def horizon():
        return view.horizon(Q[:, :-1], V[:, :-1], U, dt, INTEGRATOR, costs=running(T))

    Q, V = rollout()
    h = horizon()
    Vx, Vxx = (sum(getattr(view, n)(Q[:, -1], V[:, -1], **kw)[i] for n, kw in terminal) for i in (1, 2))
    parts = {
        # a solve's time over its iterations (its first rollout and cost, about a line search step, included);
        # rtol = gtol = 0: every sample runs every iteration (none converges), as a controller's would
        "ilqr iteration": _seconds(lambda: ilqr.ilqr(view, q0, qd0, U, dt, running, terminal, iterations, INTEGRATOR,
                                                     rtol=0, gtol=0, log=lambda *_: None), where, 2) / iterations,
        "horizon call": _seconds(horizon, where),
        "riccati pass": _seconds(lambda: ilqr.backward_pass(h, Vx, Vxx, 1e-6), where),
        "rollout": _seconds(rollout, where),
    }
    if where.type == "cuda":
        parts.update(_graph_parts(checks, view, q0, qd0, U, dt, h, Vx, Vxx, where))
    return parts


def _graph_parts(checks: Checks, view, q0, qd0, U, dt, h, Vx, Vxx, device: torch.device) -> dict[str, float]:
    """The rollout and the Riccati pass replayed from CUDA graphs, on inputs changed after the capture:
    their times, for each whose replay gives the eager values. A part that cannot be captured (an op
    that synchronises with the host) is reported, not timed."""
    rollout_in = [t.clone() for t in (q0, qd0, U)]
    riccati_in = [{k: v.clone() for k, v in h.items()}, Vx.clone(), Vxx.clone()]

    def perturb_rollout():
        rollout_in[1].add_(0.1)
        rollout_in[2].mul_(1.01)

    def perturb_riccati():
        for t in riccati_in[0].values():
            t.mul_(1.01)

    cases = {"rollout": (lambda: ilqr.rollout(view, *rollout_in, dt, INTEGRATOR), perturb_rollout, 1e-12),
             "riccati pass": (lambda: ilqr.backward_pass(*riccati_in, 1e-6), perturb_riccati, 1e-9)}
    parts = {}
    for part, (fn, perturb, tol) in cases.items():
        try:
            replay, out = _graphed(fn)
        except RuntimeError as e:
            print(f"INFO mpc {part}: not captured in a CUDA graph: {str(e).splitlines()[0][:300]}", flush=True)
            torch.cuda.synchronize()
            continue
        perturb()
        replay()
        torch.cuda.synchronize()
        why = compare(out, fn(), tol, device)
        checks.run(f"mpc {part}: a CUDA graph's replay gives the eager values", lambda why=why: why)
        if why is None:
            parts[f"{part}, graph replay"] = _seconds(replay, device)
    return parts
