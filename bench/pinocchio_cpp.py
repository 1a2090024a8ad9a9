"""Pinocchio's per-call time in C++ (µs), the reference bench_cpu.py sets beside Pinocchio called
from Python: compiles pinocchio_cpp.cpp (next to this file) once against the headers and shared
libraries of the `pin` wheel, caches the binary, runs it on one robot and parses its JSON.

Besides `pin`, the build needs two header-only packages that `pin` does not install:
`pip install cmeel-eigen cmeel-urdfdom-headers` (the urdfdom-headers version pinocchio was built
with: 3.0.0 for pin 4.1.0). The first build takes 4 to 7 minutes on one core and about 6 GB of
memory (every algorithm is instantiated in one file).
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pinocchio

SOURCE = Path(__file__).with_suffix(".cpp")
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "torch_grid_bench" / "pinocchio_cpp"


def cmeel_prefix() -> Path:
    """The cmeel prefix of the imported pinocchio: include/, lib/ and lib/cmake/ of the wheels."""
    for parent in Path(pinocchio.__file__).resolve().parents:
        if parent.name == "cmeel.prefix":
            return parent
    raise RuntimeError(f"pinocchio at {pinocchio.__file__} is not from a cmeel wheel (pip install pin)")


def library_definitions(prefix: Path) -> list[str]:
    """-D flags the wheel's pinocchio headers and URDF parser were built with (joint-variant size
    limits, urdfdom version), read from its CMake targets so that the Model we build has the
    parser library's layout. PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION is left out: with it the
    algorithms would be taken precompiled from libpinocchio_default, not compiled here with
    -march=native."""
    targets = (prefix / "lib" / "cmake" / "pinocchio" / "pinocchioTargets.cmake").read_text()
    definitions: list[str] = []
    for target in ("pinocchio_headers", "pinocchio_parsers"):
        found = re.search(rf"pinocchio::{target} PROPERTIES\s+INTERFACE_COMPILE_DEFINITIONS \"([^\"]*)\"", targets)
        if found is None:
            raise RuntimeError(f"no compile definitions for pinocchio::{target} in pinocchioTargets.cmake")
        definitions += [d for d in found.group(1).split(";") if d and "$<" not in d and d not in definitions]
    return ["-D" + d for d in definitions if d != "PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION"]


def compiler_flags(prefix: Path) -> list[str]:
    """Flags for compiling SOURCE against the wheel's headers."""
    include = prefix / "include"
    for header, package in (("eigen3/Eigen/Core", "cmeel-eigen"),
                            ("urdfdom_headers/urdf_model/model.h", "cmeel-urdfdom-headers")):
        if not (include / header).exists():
            raise RuntimeError(f"{include / header} is missing: pip install {package}")
    return ["-std=c++17", "-O3", "-march=native", "-DNDEBUG",
            # The wheel's URDF parser is built for baseline x86-64, where Eigen aligns to 16 bytes and
            # allocates with malloc, and it fills the Model that this program resizes and frees. So
            # keep the 16-byte layout under -march=native (Eigen's switch for mixing AVX code with
            # such libraries; on a 7-dof arm, rnea/aba/crba time as with 64-byte alignment) and malloc
            # too: Eigen would otherwise allocate over-aligned and free the parser's blocks as such,
            # a crash. Eigen's products load packed blocks over 128 KiB (beyond ~128 dof) from the
            # heap as 64-byte aligned, which malloc does not promise: robot-sized models only.
            "-DEIGEN_MAX_ALIGN_BYTES=16", "-DEIGEN_MALLOC_ALREADY_ALIGNED=1",
            *library_definitions(prefix),
            f"-I{include}", f"-I{include / 'eigen3'}", f"-I{include / 'urdfdom_headers'}"]


def linker_flags(prefix: Path) -> list[str]:
    """The URDF parser and what it needs, found at run time through the rpath."""
    lib = prefix / "lib"
    return [f"-L{lib}", f"-Wl,-rpath,{lib}", "-lpinocchio_parsers", "-lpinocchio_default"]


def binary() -> Path:
    """Path of the compiled benchmark, built on first use; the cache key covers the source, the
    flags (and so the prefix), the compiler and the CPU (the build is -march=native)."""
    prefix = cmeel_prefix()
    compiler = os.environ.get("CXX", "c++")
    flags, libs = compiler_flags(prefix), linker_flags(prefix)
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True, check=True).stdout
    try:
        cpu = next(line for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        cpu = ""
    key = hashlib.sha256("\0".join([SOURCE.read_text(), compiler, *flags, *libs, version, cpu]).encode()).hexdigest()
    target = CACHE / key[:16] / "pinocchio_cpp"
    if target.exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_name(f"pinocchio_cpp.{os.getpid()}.partial")
    print(f"compiling {SOURCE.name} into {target} (minutes, once)", file=sys.stderr, flush=True)
    build = subprocess.run([compiler, *flags, str(SOURCE), "-o", str(partial), *libs], capture_output=True, text=True)
    if build.returncode != 0:
        raise RuntimeError(f"compiling {SOURCE} failed:\n{build.stderr[-4000:]}")
    partial.replace(target)  # atomic: concurrent builds of one key produce the same file
    return target


def pinocchio_cpp_times(urdf_path: str, floating_base: bool, batch: int = 4096, repeats: int = 5,
                        frame: int = -1) -> dict[str, float]:
    """Per-call time of Pinocchio's C++ algorithms on `batch` random states of the robot in
    `urdf_path` (a free-flyer root when `floating_base`), one thread, best over `repeats` passes,
    in µs per call. Keys are torch_grid's function names (those of bench_cpu.py's table), plus
    "crba_upper", crba without the lower-triangle fill. `frame` is the Pinocchio frame index used
    by frame_jacobian (LOCAL_WORLD_ALIGNED); -1 is the last frame."""
    run = subprocess.run([str(binary()), urdf_path, str(int(floating_base)), str(batch), str(repeats), str(frame)],
                         capture_output=True, text=True)
    if run.returncode != 0:
        raise RuntimeError(f"pinocchio_cpp {urdf_path} failed ({run.returncode}):\n{run.stderr[-4000:]}")
    return {name: float(us) for name, us in json.loads(run.stdout).items()}


if __name__ == "__main__":
    # python bench/pinocchio_cpp.py ROBOT.urdf [--floating-base]
    for function, us in pinocchio_cpp_times(sys.argv[1], "--floating-base" in sys.argv[2:]).items():
        print(f"{function:28s} {us:8.3f} µs")
