"""Per-call time (µs) of Pinocchio's code-generated dynamics derivatives (CppADCodeGen), one thread,
beside the standard C++ that pinocchio_cpp.py measures: compiles pinocchio_codegen.cpp (next to this
file) once against the `pin` wheel's headers and libraries, caches the binary, runs it on one robot
and parses its JSON.

The program traces computeABADerivatives and computeRNEADerivatives with CppAD<CG<double>>,
generates C code for them and compiles that with /usr/bin/gcc (-Ofast -march=native) into two
shared libraries per robot. These are kept in the cache too, keyed by the URDF's content and the
floating-base flag (and by the binary's key, since the generated code depends on Pinocchio, the
flags and the CPU): a second call for the same robot loads them without tracing or compiling
again, and reports the compile time measured when they were built.

Besides what pinocchio_cpp.py needs (`pip install cmeel-eigen cmeel-urdfdom-headers`), the build
needs the header-only CppAD and CppADCodeGen: `pip install cmeel-cppad cmeel-cppadcodegen`.
Building the program takes about 9 minutes on a busy 2-core machine and 8 GB of memory; generating
a robot's libraries, from seconds (7-dof arm) to about 8 minutes (29-dof humanoid, mostly ABA).
"""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pinocchio_cpp import cmeel_prefix, compiler_flags, linker_flags

SOURCE = Path(__file__).with_suffix(".cpp")
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "torch_grid_bench" / "pinocchio_codegen"
# What the program compiles the generated C code with (Pinocchio's default compiler path).
GENERATED_CODE_COMPILER = "/usr/bin/gcc"


def codegen_flags(prefix: Path) -> list[str]:
    """pinocchio_cpp.py's flags less -march=native, after checking that the CppAD and CppADCodeGen
    headers are there (both install into the prefix's include/, already on the include path).

    Why not -march=native: with AVX, Eigen's ideal alignment (32 or 64 bytes) exceeds the 16 bytes
    pinocchio_cpp.py pins it to, and Eigen then gives fixed-size matrix products an unconstructed
    char buffer as packing space, harmless for double but a crash for CppAD's scalars (seen on the
    free flyer's 6x6 solve in computeABADerivatives). Only the tracing and evalFunction's copies
    in and out are compiled here; the generated code, where the time goes, is -march=native."""
    include = prefix / "include"
    for header, package in (("cppad/cppad.hpp", "cmeel-cppad"), ("cppad/cg.hpp", "cmeel-cppadcodegen")):
        if not (include / header).exists():
            raise RuntimeError(f"{include / header} is missing: pip install {package}")
    return [flag for flag in compiler_flags(prefix) if flag != "-march=native"]


def build_key() -> tuple[str, list[str], list[str], str]:
    """(key, compile flags, link flags, compiler) of the benchmark binary. The key covers the
    source, the flags (and so the prefix), both compilers' versions and the CPU (the code the
    program generates is built -march=native)."""
    prefix = cmeel_prefix()
    compiler = os.environ.get("CXX", "c++")
    flags = codegen_flags(prefix)
    # libdl for dlopen of the generated libraries (part of libc since glibc 2.34, harmless there).
    libs = [*linker_flags(prefix), "-ldl"]
    versions = [subprocess.run([c, "--version"], capture_output=True, text=True, check=True).stdout
                for c in (compiler, GENERATED_CODE_COMPILER)]
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            cpu = next(line for line in cpuinfo if line.startswith("model name"))
    except (OSError, StopIteration):
        cpu = ""
    key = hashlib.sha256("\0".join([SOURCE.read_text(), compiler, *flags, *libs, *versions, cpu]).encode()).hexdigest()
    return key[:16], flags, libs, compiler


def binary() -> Path:
    """Path of the compiled benchmark, built on first use (a few minutes: Pinocchio's derivative
    algorithms are instantiated for CppAD<CG<double>>)."""
    key, flags, libs, compiler = build_key()
    target = CACHE / key / "pinocchio_codegen"
    if target.exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_name(f"pinocchio_codegen.{os.getpid()}.partial")
    print(f"compiling {SOURCE.name} into {target} (minutes, once)", file=sys.stderr, flush=True)
    build = subprocess.run([compiler, *flags, str(SOURCE), "-o", str(partial), *libs],
                           capture_output=True, text=True, check=False)
    if build.returncode != 0:
        raise RuntimeError(f"compiling {SOURCE} failed:\n{build.stderr[-4000:]}")
    partial.replace(target)  # atomic: concurrent builds of one key produce the same file
    return target


def robot_dir(program: Path, urdf_path: str, floating_base: bool) -> Path:
    """Where the generated libraries of one robot live: beside the binary that generated them,
    keyed by the URDF's content (not its path) and the floating-base flag."""
    digest = hashlib.sha256(Path(urdf_path).read_bytes() + f"\0floating={int(floating_base)}".encode()).hexdigest()
    return program.parent / "robots" / digest[:16]


def pinocchio_codegen_times(urdf_path: str, floating_base: bool, batch: int = 4096,
                            repeats: int = 5) -> dict[str, float]:
    """Per-call time of Pinocchio's code-generated derivatives on `batch` random states of the
    robot in `urdf_path` (a free-flyer root when `floating_base`), one thread, best over `repeats`
    passes, in µs per call: "forward_dynamics_derivatives" (ABA derivatives) and
    "inverse_dynamics_derivatives" (RNEA derivatives), torch_grid's function names. Also
    "compile_s", the seconds that tracing, generating and compiling both libraries took when they
    were built, and "reused", 1.0 when this call loaded them from the cache instead. The first call
    for a robot takes that long (minutes for a humanoid). The program checks the generated code
    against Pinocchio's computeABADerivatives / computeRNEADerivatives on one state (1e-8
    relative) and fails otherwise."""
    program = binary()
    work = robot_dir(program, urdf_path, floating_base)
    run = subprocess.run([str(program), urdf_path, str(int(floating_base)), str(batch), str(repeats), str(work)],
                         capture_output=True, text=True, check=False)
    if run.returncode != 0:
        raise RuntimeError(f"pinocchio_codegen {urdf_path} failed ({run.returncode}):\n{run.stderr[-4000:]}")
    return {name: float(value) for name, value in json.loads(run.stdout).items()}


if __name__ == "__main__":
    # python bench/pinocchio_codegen.py ROBOT.urdf [--floating-base]
    for name, value in pinocchio_codegen_times(sys.argv[1], "--floating-base" in sys.argv[2:]).items():
        unit = {"compile_s": "s", "reused": ""}.get(name, "µs")
        print(f"{name:28s} {value:8.3f} {unit}")
