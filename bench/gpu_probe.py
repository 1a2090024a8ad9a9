"""The diagnostics stage of bench/gpu_check.py: facts about failures a device run has shown, printed as
INFO lines, so that one run both re-checks and explains them. Each item is guarded, so one that fails
leaves the others'; the item that may crash the process (an error message formatted in the glue) is last.

- step_derivatives in the MuJoCo convention (non-finite A and B on CUDA, right on the CPU): per robot and
  scheme, the non-finite entries and the largest difference from the CPU build, at dt = 0.01 and 0, with
  the rows and columns the non-finite entries fall in; the stage runs with and without poisoned outputs.
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

from gpu_correctness import on, states

SCHEMES = ("euler", "semi_implicit_euler", "midpoint", "rk4")


def _guarded(label: str, fn) -> None:
    try:
        fn()
    except Exception as e:  # a diagnostic reports, never stops the others
        print(f"INFO probe {label}: {type(e).__name__}: {str(e)[:300]}", flush=True)
        traceback.print_exc()


def _pattern(bad: torch.Tensor) -> str:
    """The rows and columns that hold non-finite entries of one sample's matrix."""
    rows = bad.any(1).nonzero().flatten().tolist()
    cols = bad.any(0).nonzero().flatten().tolist()
    return f"rows {rows[:12]}{'...' if len(rows) > 12 else ''} cols {cols[:12]}{'...' if len(cols) > 12 else ''}"


def step_derivatives(name: str, robot, device: torch.device, poisoned: bool) -> None:
    for conv, view in (("mujoco", robot.mujoco), ("pin", robot.pin)):
        q, qd, x, _ = states(view, 3, seed=21)
        for scheme in SCHEMES:
            for dt in (0.01, 0.0):
                def one():
                    got = [t.cpu() for t in view.step_derivatives(*on((q, qd, x), device), dt, scheme)]
                    ref = view.step_derivatives(q, qd, x, dt, scheme)
                    parts = []
                    for label, g, r in zip(("A", "B"), got, ref):
                        bad = ~torch.isfinite(g)
                        ok = ~bad & torch.isfinite(r)
                        diff = (g[ok] - r[ok]).abs().max().item() if ok.any() else 0.0
                        text = f"{label} {int(bad.sum())}/{g.numel()} non-finite, max diff {diff:.1e}"
                        if bad.any() and g.dim() == 3:
                            text += f" ({_pattern(bad[0])})"
                        parts.append(text)
                    print(f"INFO probe {name} {conv} {scheme} dt={dt} {'poisoned' if poisoned else 'plain'}: "
                          + "; ".join(parts), flush=True)
                _guarded(f"{name} {conv} {scheme} dt={dt}", one)


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
