"""Per-thread resources of a robot's CUDA kernels, measured by the compiler (no GPU needed).

    python -m torch_grid.ops.cuda_report SOURCE [--floating-base] [--dtype float64] [--arch sm_90] [--budget BYTES]
                                         [--cache DIR]

compiles every CUDA kernel of the robot (both conventions) with nvcc for `--arch` and prints one
line per kernel (an op's team kernel, a warp a sample, marked [team]): op, dtype, convention, registers,
local memory (stack frame) bytes, spill bytes;
then `max stack: N bytes (kernel)`. It exits with status 1 when a kernel's stack exceeds the budget.
A GPU reserves that stack for every resident thread (2048 per SM), so it bounds what a launch costs.
With `--cache DIR`, a unit whose compilation inputs are unchanged (its text, every header it can
include, the flags and the compiler's version) reuses the report of its last compilation.
"""
from __future__ import annotations

import argparse
import functools
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from ..model.description import RobotModel
from . import codegen
from .build import CSRC, find_nvcc, nvcc_flags, op_namespace
from .table import OPS

DEFAULT_BUDGET = 64 * 1024  # bytes of stack per thread
_DTYPES = {"float32": "f32", "float64": "f64"}


@dataclass(frozen=True)
class KernelUsage:
    op: str
    dtype: str  # "float32" or "float64"
    convention: str  # "pin" or "mujoco"
    registers: int
    stack: int  # bytes of local memory per thread
    spill_stores: int
    spill_loads: int
    kernel: str = "thread"  # "thread": a thread a sample; "team": a warp a sample (the op's team path)

    def line(self) -> str:
        name = self.op if self.kernel == "thread" else f"{self.op} [{self.kernel}]"
        return (f"{name:48s} {self.dtype:8s} {self.convention:7s} registers {self.registers:4d}  stack {self.stack:7d} B  "
                f"spill {self.spill_stores}/{self.spill_loads} B")


def report(model: RobotModel, dtypes: tuple[str, ...] = ("float64",), arch: str = "sm_90",
           nvcc: str | None = None, families: tuple[str, ...] | None = None,
           cache: Path | None = None) -> list[KernelUsage]:
    """Compile the robot's CUDA kernels of the given dtypes (and op families, all by default) with
    ptxas verbose output and return the resources of each (op, dtype, convention). With `cache`, a
    folder, unchanged units are not compiled again (see `compile_unit`)."""
    nvcc = nvcc or find_nvcc()
    namespace = op_namespace(model, True)
    with tempfile.TemporaryDirectory(prefix="torch_grid_cuda_report_") as tmp:
        src = Path(tmp)
        units = [u for u in codegen.write_robot_sources(model, True, True, namespace, src)
                 if u.suffix == ".cu" and any(u.stem.endswith("_" + _DTYPES[d]) for d in dtypes)
                 and (families is None or u.stem.rsplit("_", 1)[0] in families)]
        flags = [f for f in nvcc_flags() if not f.startswith("-arch")] + [f"-arch={arch}", "-Xptxas", "-v"]

        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            logs = list(pool.map(lambda u: compile_unit(nvcc, [*flags, "-c"], u, ".o", cache), units))
    log = "\n".join(logs)
    called = out_of_line_functions(log)
    if called:
        raise RuntimeError("these device functions are called, not inlined, by the robot's CUDA kernels: "
                           f"{', '.join(called)}. A recursive one's frames go beyond the stack ptxas counts, on a "
                           "call stack of the driver's default size (1 KB), which they overflow: make it not recursive")
    return sorted(_parse(log), key=lambda k: (k.op, k.dtype, k.convention))


def compile_unit(nvcc: str, flags: list[str], unit: Path, suffix: str, cache: Path | None = None,
                 keep_output: bool = False) -> str:
    """Compile a generated `unit` (its folder and the kernel sources on the include path) with `flags`
    into the file of the same stem and `suffix`, and return the compiler's messages; raise on failure.

    With `cache`, the messages of a success (and its output file, with `keep_output`) are kept there
    under a digest of everything that decides them: the compiler's version, the flags, the unit's name
    and the text of every file of its folder and of the kernel sources. A later call with the same
    digest returns them without compiling; without `keep_output` it writes no output file then."""
    out = unit.with_suffix(suffix)
    entry = None
    if cache is not None:
        digest = hashlib.sha256()
        for part in (_version(nvcc), *flags, unit.name, suffix, str(keep_output)):
            digest.update(part.encode() + b"\0")
        for root in (CSRC, unit.parent):
            for path in sorted(p for p in root.rglob("*") if p.is_file() and p.suffix not in (".o", ".ptx")):
                digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
        entry = Path(cache) / digest.hexdigest()[:32]
        if entry.is_dir():
            if keep_output:
                out.write_bytes((entry / "output").read_bytes())
            return (entry / "messages").read_text()
    cmd = [nvcc, *flags, f"-I{CSRC}", f"-I{unit.parent}", str(unit), "-o", str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True)
    if result.returncode:
        raise RuntimeError(f"nvcc failed on {unit.name}:\n{result.stderr[-4000:]}")
    if entry is not None:
        # Written aside and renamed whole, so that a reader never sees a part of an entry.
        partial = entry.with_name(f"{entry.name}.{os.getpid()}.{threading.get_ident()}.partial")
        partial.mkdir(parents=True)
        (partial / "messages").write_text(result.stderr)
        if keep_output:
            (partial / "output").write_bytes(out.read_bytes())
        try:
            partial.rename(entry)
        except OSError:  # another process stored the same entry first
            shutil.rmtree(partial)
    return result.stderr


@functools.cache
def _version(nvcc: str) -> str:
    """`nvcc --version`, asked once per process rather than once per unit."""
    return subprocess.run([nvcc, "--version"], capture_output=True, text=True, check=True).stdout


def out_of_line_functions(log: str) -> list[str]:
    """The device functions of ptxas's report other than the kernels and CUDA's own (its slow path of
    trigonometry for huge arguments): functions the kernels call rather than inline."""
    names = set(re.findall(r"Function properties for (\w+)", log))
    return sorted(_demangle(sorted(n for n in names if not re.search(r"(batch|team)_kernel", n) and not n.startswith("__internal"))))


_KERNELS = {op.kernel: op.name for op in OPS.values()}


def _parse(log: str) -> list[KernelUsage]:
    """Read ptxas's 'Function properties' and 'Used N registers' lines of each batch_kernel and team_kernel."""
    mangled = re.findall(r"Function properties for (_Z\w*(?:batch|team)_kernel\w*)\n\s*(\d+) bytes stack frame, (\d+) bytes "
                         r"spill stores, (\d+) bytes spill loads\n.*?Used (\d+) registers", log)
    names = _demangle([m[0] for m in mangled])
    usages = []
    for (_, stack, stores, loads, regs), name in zip(mangled, names):
        found = re.search(r"(batch|team)_kernel<tg::bind::(\w+), [\w:]+, (float|double), (\d)>", name)
        if not found:
            raise RuntimeError(f"cannot read the kernel name {name!r}")
        launch, kernel, scalar, conv = found.groups()
        usages.append(KernelUsage(_KERNELS[kernel], "float64" if scalar == "double" else "float32",
                                  "mujoco" if conv == "1" else "pin", int(regs), int(stack), int(stores), int(loads),
                                  "thread" if launch == "batch" else "team"))
    return usages


def _demangle(names: list[str]) -> list[str]:
    if not names:
        return []
    out = subprocess.run(["c++filt"], input="\n".join(names), capture_output=True, text=True, check=True).stdout
    return out.splitlines()


def main(argv: list[str] | None = None) -> int:
    from ..model.parse import source_to_model

    parser = argparse.ArgumentParser(prog="python -m torch_grid.ops.cuda_report", description=__doc__.splitlines()[0])
    parser.add_argument("source", help="a bundled robot name, URDF or MJCF path, or saved model (.json)")
    parser.add_argument("--floating-base", action="store_true", help="add a free-flyer root")
    parser.add_argument("--dtype", choices=[*_DTYPES, "both"], default="float64")
    parser.add_argument("--arch", default="sm_90")
    parser.add_argument("--budget", type=int, default=DEFAULT_BUDGET, help="bytes of stack per thread (default 64 KiB)")
    parser.add_argument("--cache", type=Path, help="a folder where the reports of unchanged units are kept and reused")
    args = parser.parse_args(argv)
    model = source_to_model(args.source, True if args.floating_base else None)
    dtypes = tuple(_DTYPES) if args.dtype == "both" else (args.dtype,)
    usages = report(model, dtypes, args.arch, cache=args.cache)
    for usage in usages:
        print(usage.line())
    worst = max(usages, key=lambda u: u.stack)
    print(f"max stack: {worst.stack} bytes ({worst.op}, {worst.dtype}, {worst.convention})")
    over = [u for u in usages if u.stack > args.budget]
    if over:
        print(f"{len(over)} kernels exceed the budget of {args.budget} bytes", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
