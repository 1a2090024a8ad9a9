"""The diagnostics stage of bench/gpu_check.py: facts about failures a device run has shown, printed as
INFO lines, so that one run both re-checks and explains them. Each item is guarded, so one that fails
leaves the others'; the item that may crash the process (an error message formatted in the glue) is last.

- step_derivatives in the MuJoCo convention (non-finite A and B on CUDA, right on the CPU): per robot and
  scheme, the non-finite entries and the largest difference from the CPU build, at dt = 0.01 and 0, with
  the rows and columns the non-finite entries fall in, on one thread a sample and on the team path; the
  stage runs with and without poisoned outputs.
- the fused Runge-Kutta kernel's workspace on the device, region by region (rk_workspace).
- the C++ runtime: the host compiler, which libstdc++ the process has mapped, whether the glue defines
  iostream symbols of its own (a static copy), its link flags and the libstdc++ files in their folders.
- an argument error raised by the glue (a wrong shape, whose message holds integers) on the CPU.
"""
from __future__ import annotations

import os
import subprocess
import traceback
from pathlib import Path

import torch

from gpu_correctness import TeamPaths, fused, kernel_outputs, on, states

SCHEMES = ("euler", "semi_implicit_euler", "midpoint", "rk4")


def _guarded(label: str, fn) -> None:
    try:
        fn()
    except Exception as e:  # a diagnostic reports, never stops the others
        print(f"INFO probe {label}: {type(e).__name__}: {str(e)[:300]}", flush=True)
        traceback.print_exc()


def _ranges(indices: list[int]) -> str:
    """Sorted indices as runs: [0, 1, 2, 5] -> '0-2,5'."""
    runs: list[list[int]] = []
    for k in indices:
        if runs and k == runs[-1][1] + 1:
            runs[-1][1] = k
        else:
            runs.append([k, k])
    return ",".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs) or "none"


def _pattern(bad: torch.Tensor) -> str:
    """The rows and columns that hold non-finite entries of one sample's matrix, and each such row's columns
    (rows that share them named together), so that the pattern names the terms of runge_kutta.h it comes from."""
    rows = bad.any(1).nonzero().flatten().tolist()
    groups: dict[str, list[int]] = {}
    for r in rows:
        groups.setdefault(_ranges(bad[r].nonzero().flatten().tolist()), []).append(r)
    per_row = "; ".join(f"rows {_ranges(rs)}: cols {cols}" for cols, rs in groups.items())
    return f"rows {_ranges(rows)} cols {_ranges(bad.any(0).nonzero().flatten().tolist())} [{per_row}]"


def step_derivatives(name: str, robot, device: torch.device, poisoned: bool) -> None:
    # MuJoCo's convention also on the team path (a warp a sample, runge_kutta_team.h, its workspace in shared
    # memory): whether the non-finite entries follow the thread path's code or the convention's
    for conv, view, teams in (("mujoco", robot.mujoco, "0"), ("mujoco", robot.mujoco, "1"), ("pin", robot.pin, "0")):
        q, qd, x, _ = states(view, 3, seed=21)
        path = f"{conv}{' teams' if teams == '1' else ''}"
        for scheme in SCHEMES:
            for dt in (0.01, 0.0):
                def one():
                    with TeamPaths(teams):
                        got = [t.cpu() for t in fused(view, scheme, *on((q, qd, x), device), dt)]
                    ref = fused(view, scheme, q, qd, x, dt)
                    parts = []
                    for label, g, r in zip(("A", "B"), got, ref):
                        bad = ~torch.isfinite(g)
                        ok = ~bad & torch.isfinite(r)
                        diff = (g[ok] - r[ok]).abs().max().item() if ok.any() else 0.0
                        text = f"{label} {int(bad.sum())}/{g.numel()} non-finite, max diff {diff:.1e}"
                        if bad.any():
                            text += f" ({_pattern(bad[0].flatten(0, 1).flatten(1))})"
                        parts.append(text)
                    print(f"INFO probe {name} {path} {scheme} dt={dt} {'poisoned' if poisoned else 'plain'}: "
                          + "; ".join(parts), flush=True)
                _guarded(f"{name} {path} {scheme} dt={dt}", one)


def rk_workspace(name: str, robot, device: torch.device) -> None:
    """The fused Runge-Kutta kernel's workspace on the device (each stage's D_q, D_v and M's factor, the
    adjoint slots, U and the step's Jv blocks), one sample in MuJoCo's convention: the regions that hold
    non-finite entries name the part of runge_kutta.h at fault; and the composed derivatives (torch ops,
    taken when an input requires grad) on the device against the fused ones on the CPU."""
    view, nv = robot.mujoco, robot.nv
    nn = nv * nv
    q, qd, x, _ = states(view, 1, seed=22)
    for scheme in ("midpoint", "rk4"):
        s = 4 if scheme == "rk4" else 2
        regions = [(f"stage {i} {part}", 3 * nn * i + k * nn, nn) for i in range(s) for k, part in enumerate(("Dq", "Dv", "H"))]
        slots = 3 * nn * s
        regions += [(f"slot {j} {part}", slots + 4 * nn * j + 2 * nn * k, 2 * nn) for j in range(2) for k, part in enumerate(("abar", "cbar"))]
        regions += [("U", slots + 8 * nn, 2 * nn), ("Jv blocks", slots + 10 * nn, 6 * nv)]
        for dt in (0.0, 0.01):
            def one():
                # (the CPU's workspace is a thread's, never returned: the device's alone is read)
                work = kernel_outputs(view, scheme, *on((q, qd, x), device), dt)[4].reshape(-1).cpu()
                parts = [f"{label}: {int((~torch.isfinite(work[start:start + size])).sum())}/{size} non-finite"
                         for label, start, size in regions]
                print(f"INFO probe {name} work mujoco {scheme} dt={dt}: " + "; ".join(parts), flush=True)
            _guarded(f"{name} work {scheme} dt={dt}", one)

    for scheme in ("semi_implicit_euler", "midpoint", "rk4"):
        def composed(scheme=scheme):
            leaves = [t.clone().requires_grad_(True) for t in on((q, qd, x), device)]
            got = [t.detach().cpu() for t in view.step_derivatives(*leaves, 0.01, scheme)]
            ref = view.step_derivatives(q, qd, x, 0.01, scheme)
            errs = [f"{int((~torch.isfinite(g)).sum())} non-finite, diff {(g - r).abs().max().item():.1e}" for g, r in zip(got, ref)]
            print(f"INFO probe {name} composed mujoco {scheme} on the device: A {errs[0]}; B {errs[1]}", flush=True)
        _guarded(f"{name} composed {scheme}", composed)


def runtime() -> None:
    def compiler():
        out = subprocess.run(["c++", "--version"], capture_output=True, text=True, timeout=20).stdout.splitlines()
        print(f"INFO probe host compiler: {out[0] if out else '?'}", flush=True)
    _guarded("host compiler", compiler)

    def mapped():
        with open("/proc/self/maps") as maps:
            libs = sorted({line.split()[-1] for line in maps if "libstdc++" in line or "torch_grid_glue" in line})
        print(f"INFO probe mapped: {libs}", flush=True)
        for lib in libs:
            if "torch_grid_glue" in lib:
                nm = subprocess.run(["nm", "-DC", "--defined-only", lib], capture_output=True, text=True, timeout=60).stdout
                own = [s for s in nm.splitlines() if "std::" in s and ("ostream" in s or "locale" in s or "codecvt" in s)]
                print(f"INFO probe glue defines {len(own)} iostream/locale symbols: {own[:6]}", flush=True)
                ninja = Path(lib).parent / "build.ninja"
                flags = [line for line in ninja.read_text().splitlines() if line.startswith("ldflags")] if ninja.exists() else []
                print(f"INFO probe glue {flags}; LDFLAGS={os.environ.get('LDFLAGS')!r} CXX={os.environ.get('CXX')!r}", flush=True)
                for folder in [f[2:] for f in " ".join(flags).split() if f.startswith("-L")]:
                    print(f"INFO probe {folder}: {sorted(p.name for p in Path(folder).glob('libstdc++*'))}", flush=True)
                ldd = subprocess.run(["ldd", lib], capture_output=True, text=True, timeout=60).stdout
                print("INFO probe glue links: " + " | ".join(s.strip() for s in ldd.splitlines() if "stdc++" in s or "gcc_s" in s),
                      flush=True)
    _guarded("runtime", mapped)


def glue_error(robot) -> None:
    """Last: a wrong shape reaches the glue, whose message formats integers (a crash here kills the stage)."""
    def wrong_shape():
        op = robot._ops.crba
        try:
            op.default(torch.zeros(2, robot.nq + 1, dtype=torch.float64), None, 0)
        except RuntimeError as e:
            print(f"INFO probe glue error on the CPU: raised as it should: {str(e)[:200]}", flush=True)
            return
        print("INFO probe glue error on the CPU: no error raised", flush=True)
    _guarded("glue error", wrong_shape)
