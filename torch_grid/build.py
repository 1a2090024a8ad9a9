"""Compile a robot's generated kernels once, cache the library, and load it into the dispatcher.

The cache entry is keyed by everything that changes the binary: the model hash, the build options,
the kernel sources, the compiler and the torch version. The convention is a runtime argument and
is not part of the key. A file lock serialises concurrent builds of one entry; an entry whose
library is missing or fails to load is rebuilt.
"""
from __future__ import annotations

import fcntl
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path

import torch

from . import codegen, ops
from .model import RobotModel
from .ops import register_fakes

CSRC = Path(__file__).resolve().parent.parent / "csrc"
if not CSRC.is_dir():  # installed (non-editable) layout ships the sources inside the package
    CSRC = Path(__file__).resolve().parent / "csrc"
_LOADED: dict[str, str] = {}  # cache key -> op namespace, for this process
_LOCK = threading.Lock()


def default_cache_dir() -> Path:
    env = os.environ.get("TORCH_GRID_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "torch_grid"


def build(model: RobotModel, *, mujoco: bool, cache_dir: str | Path | None = None) -> str:
    """Build (or reuse) the kernels of `model` and return the op namespace they are registered in."""
    cuda = _cuda_available()
    key = _cache_key(model, mujoco, cuda)
    namespace = f"torch_grid_{key[:16]}"
    with _LOCK:
        if key in _LOADED:
            return _LOADED[key]
        entry = Path(cache_dir or default_cache_dir()).expanduser() / f"{_safe(model.name)}-{key[:16]}"
        entry.mkdir(parents=True, exist_ok=True)
        library = entry / f"{namespace}.so"
        if not _try_load(entry, library):
            with _file_lock(entry / ".lock"):
                if not _try_load(entry, library):  # another process may have built it meanwhile
                    _compile(model, mujoco, cuda, namespace, entry)  # also loads it
                    (entry / "complete").write_text(_digest(library))
        register_fakes(namespace, model)
        _LOADED[key] = namespace
        return namespace


def _try_load(entry: Path, library: Path) -> bool:
    marker = entry / "complete"
    if not (marker.is_file() and library.is_file()):
        return False
    if marker.read_text() != _digest(library):
        return False
    try:
        torch.ops.load_library(str(library))
    except OSError:
        return False
    return True


def _compile(model: RobotModel, mujoco: bool, cuda: bool, namespace: str, entry: Path) -> None:
    from torch.utils import cpp_extension

    # Start from a clean entry: whatever is there is incomplete or damaged.
    for child in entry.iterdir():
        if child.name != ".lock":
            shutil.rmtree(child) if child.is_dir() else child.unlink()
    src = entry / "src"
    src.mkdir()
    sources = codegen.write_sources(model, mujoco, cuda, namespace, src)
    what = f"{'CPU + CUDA' if cuda else 'CPU'}, float32 + float64, {'pin + mujoco' if mujoco and model.floating_base else 'pin'}"
    print(f"torch_grid: building kernels for {model.name!r} ({what}) in {entry}", file=sys.stderr, flush=True)
    cflags, cuda_cflags, ldflags = _flags(cuda)
    start = time.monotonic()
    with _progress(model.name, start):
        cpp_extension.load(
            name=namespace,
            sources=[str(p) for p in sources],
            extra_cflags=cflags,
            extra_ldflags=ldflags,
            extra_cuda_cflags=cuda_cflags,
            extra_include_paths=[str(CSRC), str(src)],
            build_directory=str(entry),
            with_cuda=cuda,
            is_python_module=False,
            verbose=os.environ.get("TORCH_GRID_VERBOSE") == "1",
        )
    print(f"torch_grid: built {model.name!r} in {time.monotonic() - start:.0f} s", file=sys.stderr, flush=True)


def _flags(cuda: bool) -> tuple[list[str], list[str], list[str]]:
    """Compiler flags: host C++, CUDA, linker."""
    cuda_define = ["-DTG_WITH_CUDA"] if cuda else []
    # at::parallel_for is inline: with an OpenMP build of torch its pragma is compiled here.
    openmp = ["-fopenmp"] if torch.backends.openmp.is_available() else []
    # Tuned for this CPU (AVX2/FMA where present, ~1.4x faster); the CPU is part of the cache key.
    native = ["-march=native"] if platform.machine() in ("x86_64", "AMD64") and not os.environ.get("TORCH_GRID_PORTABLE") else []
    return ["-O3", "-fno-fast-math"] + native + cuda_define + openmp, ["-O3"] + cuda_define, openmp


@lru_cache(maxsize=None)
def _cpu_identity() -> str:
    """Model name and feature flags of this CPU: a -march=native binary runs only where they match."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.processor() or platform.machine()
    keep = {}
    for line in lines:
        key, _, value = line.partition(":")
        key = key.strip()
        if key in ("model name", "flags", "Features", "CPU part") and key not in keep:
            keep[key] = value.strip()
    return platform.machine() + "|" + "|".join(f"{k}={v}" for k, v in sorted(keep.items()))


@contextmanager
def _progress(name: str, start: float):
    """Print elapsed time every 15 s while the compiler runs."""
    done = threading.Event()

    def tick():
        while not done.wait(15.0):
            print(f"torch_grid: still building {name!r} ({time.monotonic() - start:.0f} s)", file=sys.stderr, flush=True)

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


@contextmanager
def _file_lock(path: Path):
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _cache_key(model: RobotModel, mujoco: bool, cuda: bool) -> str:
    h = hashlib.sha256()
    h.update(model.hash.encode())
    h.update(f"mujoco={mujoco} cuda={cuda} flags={_flags(cuda)}".encode())
    h.update(_cpu_identity().encode())
    for path in sorted(CSRC.rglob("*")):
        if path.is_file():
            h.update(path.relative_to(CSRC).as_posix().encode())
            h.update(path.read_bytes())
    # The generators: the op table and the emitter of the per-robot C++.
    for module in (codegen, ops):
        h.update(Path(module.__file__).read_bytes())
    h.update(_compiler_version("c++").encode())
    if cuda:
        h.update(_compiler_version("nvcc").encode())
    h.update(torch.__version__.encode())
    return h.hexdigest()


@lru_cache(maxsize=None)
def _compiler_version(compiler: str) -> str:
    try:
        return subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"


@lru_cache(maxsize=None)
def _cuda_available() -> bool:
    if not torch.cuda.is_available():
        return False
    from torch.utils.cpp_extension import CUDA_HOME

    return CUDA_HOME is not None and (Path(CUDA_HOME) / "bin" / "nvcc").exists()


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name) or "robot"
