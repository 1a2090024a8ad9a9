"""Markdown tables of a GPU check's figures (bench/gpu/results.json), for bench/RESULTS.md.

    python bench/gpu_table.py [bench/gpu/results.json]
"""
from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

# GRiD's published per-sample times (RTX 5090, float32, data on the GPU, microseconds; N = 256 unless
# noted): (robot, op) -> (figure, N)
GRID = {("iiwa14", "inverse_dynamics"): (0.045, 256), ("iiwa14", "forward_dynamics"): (0.092, 256),
        ("iiwa14", "inverse_dynamics_derivatives"): (0.030, 1024), ("iiwa14", "forward_dynamics_derivatives"): (0.185, 256),
        ("g1", "inverse_dynamics"): (0.253, 256), ("g1", "forward_dynamics"): (0.800, 256), ("g1", "crba"): (0.420, 256),
        ("g1", "forward_dynamics_derivatives"): (1.49, 256), ("g1", "inverse_dynamics_derivatives"): (0.625, 1024),
        ("g1", "inverse_dynamics_second_derivatives"): (12.8, 256)}


def tables(records: list[dict]) -> str:
    mpc = [r for r in records if r["op"].startswith("mpc[")]
    records = [r for r in records if not r["op"].startswith("mpc[")]
    sizes = sorted({r["batch"] for r in records if not r["op"].startswith("call_overhead")})
    by = defaultdict(dict)
    gpu = next((r["device"] for r in records + mpc if not r["device"].startswith("CPU")), "GPU")
    for r in records:
        where = "cpu" if r["device"].startswith("CPU") else "gpu"
        by[(r["robot"], r["op"], r["dtype"])][(where, r["batch"])] = r["us_per_sample"]
    out = []
    for dtype in sorted({r["dtype"] for r in records}, reverse=True):  # float64 first
        out.append(f"\n{dtype}, µs per sample, {gpu} (CUDA events) / the CPU build on the machine's 16 threads; "
                   "GRiD: its published RTX 5090 float32 figure at the N given\n")
        out.append("| robot | op | " + " | ".join(f"N = {n}" for n in sizes) + " | GRiD |")
        out.append("|---|---|" + "---|" * (len(sizes) + 1))
        for (robot, op, dt), cells in sorted(by.items()):
            if dt != dtype or op.startswith("call_overhead"):
                continue
            row = [f"{_f(cells.get(('gpu', n)))} / {_f(cells.get(('cpu', n)))}" for n in sizes]
            grid = GRID.get((robot, op.removesuffix("[teams]")))  # a team path's row beside its op's GRiD figure too
            out.append(f"| {robot} | {op} | " + " | ".join(row) + f" | {f'{grid[0]} (N = {grid[1]})' if grid else ''} |")
    calls = [r for r in records if r["op"].startswith("call_overhead")]
    if calls:
        out.append("\nA batch-of-one call through Robot on CUDA (iiwa14 inverse_dynamics, host wall time): "
                   + "; ".join(f"{r['op']}: {r['us_per_sample']:.1f} µs" for r in calls))
    if mpc:
        out.append(_mpc_table(mpc, gpu))
    return "\n".join(out) + "\n"


def _mpc_table(records: list[dict], gpu: str) -> str:
    """The MPC path (gpu_mpc.py): each part's ms a call on the GPU and on the CPU build, and its share of
    an iteration's time there."""
    by = defaultdict(dict)
    for r in records:
        by[r["op"][4:-1]]["cpu" if r["device"].startswith("CPU") else "gpu"] = r["ms_per_call"]
    first = records[0]
    iteration = by.get("ilqr iteration", {})
    lines = [f"\nThe MPC path: examples/ilqr.py's go2 task, {first['batch']} samples, {first['horizon']} knots, "
             f"float64; ms a call on {gpu} / on the CPU build (its share of an iteration's time)\n",
             "| part | GPU | CPU |", "|---|---|---|"]
    for part, cells in by.items():
        row = []
        for where in ("gpu", "cpu"):
            ms, whole = cells.get(where), iteration.get(where)
            share = f" ({ms / whole:.0%})" if ms is not None and whole and part != "ilqr iteration" else ""
            row.append(f"{_f(ms)}{share}")
        lines.append(f"| {part} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def _f(x) -> str:
    if x is None:
        return "–"
    return f"{x:.3g}" if x < 100 else f"{x:.0f}"


if __name__ == "__main__":
    path = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parent / "gpu" / "results.json")
    print(tables(json.loads(path.read_text())))
