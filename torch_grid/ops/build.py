"""Compile a robot's generated kernels once, cache the library, and register its ops.

Two kinds of binaries live in the cache:
  - the glue (`.glue/<key>/`): the torch side of every op, compiled once per torch version,
    compiler and flags, and shared by every robot;
  - one robot library per robot (`<name>-<key>/`): plain C++ (and CUDA) kernels without torch,
    compiled in parallel units, one per op family (double on the CPU, which the glue also runs
    float32 through; float and double for CUDA).
A robot's cache key covers everything that changes its binary (model, build options, kernel
sources, compiler, CPU, torch version); its op namespace only what changes results (the model,
the build options, the op table), so a program exported on one machine finds its ops on another.
A file lock serialises concurrent builds of one entry; an entry appears, complete, by one rename,
so an interrupted or failed build leaves none; a damaged entry is rebuilt.
"""
from __future__ import annotations

import fcntl
import hashlib
import os
import platform
import shutil
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path

import torch

from ..model.description import RobotModel
from . import codegen
from . import table as ops
from .machine import compiler_version, cpu_features, cpu_identity
from .table import register_fakes

CSRC = Path(__file__).resolve().parent.parent / "csrc"  # the C++ sources, inside the package
_REGISTERED: dict[str, str] = {}  # op namespace -> robot library, for this process
_GLUE: list[Path] = []  # the glue library this process loaded
_LOCK = threading.Lock()
_PROGRESS_EVERY = 15.0  # seconds between progress lines of a long build or wait


def default_cache_dir() -> Path:
    env = os.environ.get("TORCH_GRID_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "torch_grid"


def op_namespace(model: RobotModel, mujoco: bool) -> str:
    """The torch op namespace of a robot build: stable across machines, compilers, CPUs and torch
    versions for one model, build options (TORCH_GRID_LANES among them) and op table."""
    lanes = f" lanes={codegen.cpu_lanes()}" if codegen.cpu_lanes() != 0 else ""
    h = hashlib.sha256(f"{model.hash} mujoco={mujoco} ops={ops.op_signature()}{lanes}".encode()).hexdigest()
    name = "".join(c if c.isascii() and c.isalnum() else "_" for c in model.name.lower())[:40]
    return f"torch_grid_{name}_{h[:16]}"  # the robot's name, so that an error naming the namespace names the robot


def build(model: RobotModel, *, mujoco: bool, cache_dir: str | Path | None = None) -> str:
    """Build (or reuse) the kernels of `model` and return the op namespace they are registered in."""
    if model.nbodies == 0:  # refused before any build starts or says it is building
        raise ValueError(f"robot {model.name!r} has no moving joint: expected at least one joint that is not fixed, "
                         "got none (load(urdf, floating_base=True) mounts a URDF on a free joint)")
    namespace = op_namespace(model, mujoco)
    with _LOCK:
        if namespace in _REGISTERED:
            return namespace
        root = _cache_root(cache_dir)
        cuda = _cuda_available()
        _load_glue(root, cuda)
        library = _robot_library(root, model, mujoco, cuda, namespace)
        torch.ops.torch_grid_glue.register_robot(namespace, str(library), codegen.table_symbol(namespace))
        register_fakes(namespace, model)
        _REGISTERED[namespace] = str(library)
        return namespace


def _cache_root(cache_dir: str | Path | None) -> Path:
    """The cache folder; it need be writable only where something is to be built in it (_writable): a complete
    cache read-only (in an image, on a shared file system) serves its robots."""
    return Path(cache_dir if cache_dir is not None else default_cache_dir()).expanduser()


def _writable(root: Path) -> None:
    """Before a build: the cache's lock and build folders, and a file written there; else an error naming the
    setting the folder came from."""
    try:
        for sub in (".locks", ".build"):
            (root / sub).mkdir(parents=True, exist_ok=True)
        probe = root / ".build" / f"probe-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        env = os.environ.get("TORCH_GRID_CACHE")
        where = (f"TORCH_GRID_CACHE={env!r}" if env and root == Path(env).expanduser() else
                 f"the default cache {str(root)!r} (set TORCH_GRID_CACHE or pass cache_dir=)" if root == default_cache_dir()
                 else f"cache_dir={str(root)!r}")
        raise RuntimeError(f"torch_grid: cannot use {where} to keep compiled kernels: it must be a writable "
                           f"directory ({e.strerror or e})") from None


# -- the glue --------------------------------------------------------------------------------------

def _load_glue(root: Path, cuda: bool) -> None:
    if _GLUE:
        return
    key = _glue_key(cuda)
    entry = root / ".glue" / key[:16]
    library = entry / f"torch_grid_glue_{key[:16]}.so"
    if not _complete(entry, library):
        _writable(root)
        with _file_lock(root, f"glue-{key[:16]}", "the torch glue"):
            if not _complete(entry, library):
                _compile_glue(root, cuda, key, entry)  # also loads it
                _glue_loaded(library)
                return
    torch.ops.load_library(str(library))
    _glue_loaded(library)


def _glue_loaded(library: Path) -> None:
    _GLUE.append(library)
    if not _CPU_LANES[0]:
        torch.ops.torch_grid_glue.set_cpu_lanes(False)


_CPU_LANES = [True]


def set_cpu_lanes(enabled: bool) -> bool:
    """Run CPU ops on vector lanes, several samples per instruction (the default), or one sample at a time.

    The lane kernels take a batch a group of samples at a time (8 with AVX-512, 4 with AVX2) and the
    scalar kernels the rest; switched off, every sample takes the scalar kernel. Both compute the same
    values to rounding (the compiler fuses multiply-adds differently in the two), so the switch is
    for comparing them or timing them. It is process-wide and applies to every robot.

    Args:
        enabled: True for the lane kernels, False for the scalar ones.

    Returns:
        The previous setting.
    """
    previous, _CPU_LANES[0] = _CPU_LANES[0], bool(enabled)
    if _GLUE:
        torch.ops.torch_grid_glue.set_cpu_lanes(bool(enabled))
    return previous


def release_kept_blocks() -> int:
    """Free the CPU output blocks the glue keeps for reuse; returns their bytes (0 before any load)."""
    return int(torch.ops.torch_grid_glue.release_kept_blocks()) if _GLUE else 0


def _compile_glue(root: Path, cuda: bool, key: str, entry: Path) -> None:
    from torch.utils import cpp_extension

    name = f"torch_grid_glue_{key[:16]}"
    start = time.monotonic()
    print(f"torch_grid: building the torch glue ({'CPU + CUDA' if cuda else 'CPU'}, once for this torch and compiler)",
          file=sys.stderr, flush=True)
    if cuda and not (cpp_extension.CUDA_HOME and _is_toolkit(Path(cpp_extension.CUDA_HOME))):
        cpp_extension.CUDA_HOME = str(cuda_home())  # torch's guess holds no headers (see cuda_home)
    with _staging(root, entry) as tmp, _ticker("the torch glue", start):
        source = codegen.write_glue_source(tmp)
        openmp = ["-fopenmp"] if torch.backends.openmp.is_available() else []
        defines = ["-DTG_WITH_CUDA"] if cuda else []
        # Loads the library too; renamed into the cache it keeps its inode, so a later load of the
        # cached path in this process is the same library.
        cpp_extension.load(name=name, sources=[str(source)], extra_cflags=["-O2"] + openmp + defines,
                           extra_ldflags=openmp + _SHARED_CXX_RUNTIME, extra_include_paths=[str(CSRC)],
                           build_directory=str(tmp), with_cuda=cuda, is_python_module=False,
                           verbose=os.environ.get("TORCH_GRID_VERBOSE") == "1")
        _check_shared_cxx_runtime(tmp / f"{name}.so")
        (tmp / "complete").write_text(_digest(tmp / f"{name}.so"))
    print(f"torch_grid: built the torch glue in {time.monotonic() - start:.0f} s", file=sys.stderr, flush=True)


# The glue shares torch's C++ runtime, named by file so that a folder on the link's search path that
# holds only the static libstdc++.a cannot be linked instead: a glue with a private copy of it crashed
# formatting a number into an error message, its iostreams mixed with those of torch's runtime.
_SHARED_CXX_RUNTIME = ["-l:libstdc++.so.6"] if sys.platform.startswith("linux") else []


def _check_shared_cxx_runtime(library: Path) -> None:
    """Refuse a glue linked without the shared C++ runtime (where ldd can tell)."""
    ldd = shutil.which("ldd")
    if not _SHARED_CXX_RUNTIME or ldd is None:
        return
    needed = subprocess.run([ldd, str(library)], capture_output=True, text=True, timeout=60).stdout
    if needed and "libstdc++" not in needed:
        raise RuntimeError(f"torch_grid: the torch glue {library.name} was linked with a static C++ runtime (ldd lists "
                           "no libstdc++), which breaks its error messages inside torch's process; check LDFLAGS "
                           "and the compiler's link flags for -static-libstdc++")


def _glue_key(cuda: bool) -> str:
    h = hashlib.sha256()
    unit = codegen.glue_unit()
    h.update(unit.encode())
    for name in _included(unit):
        h.update(name.encode())
        h.update((CSRC / name).read_bytes())
    h.update(f"cuda={cuda} openmp={torch.backends.openmp.is_available()} {_SHARED_CXX_RUNTIME}".encode())
    h.update(compiler_version(os.environ.get("CXX", "c++")).encode())
    if cuda:
        h.update(compiler_version(find_nvcc()).encode())
    h.update(torch.__version__.encode())
    return h.hexdigest()


def _included(text: str) -> list[str]:
    """The headers under CSRC that `text` includes, directly or through them, sorted (a header edited
    anywhere in the glue's includes changes its key)."""
    found: set[str] = set()
    todo = [text]
    while todo:
        for line in todo.pop().splitlines():
            name = line.split('"')[1] if line.startswith('#include "') else None
            if name and name not in found and (CSRC / name).is_file():
                found.add(name)
                todo.append((CSRC / name).read_text())
    return sorted(found)


# -- robot libraries ---------------------------------------------------------------------------------

def _robot_library(root: Path, model: RobotModel, mujoco: bool, cuda: bool, namespace: str) -> Path:
    key = _cache_key(model, mujoco, cuda)
    entry = root / f"{_safe(model.name)}-{key[:16]}"
    library = entry / f"lib{namespace}.so"
    if not _complete(entry, library):
        _writable(root)
        with _file_lock(root, entry.name, f"kernels for {model.name!r}"):
            if not _complete(entry, library):
                _compile_robot(root, model, mujoco, cuda, namespace, entry, library.name)
    return library


def _compile_robot(root: Path, model: RobotModel, mujoco: bool, cuda: bool, namespace: str, entry: Path,
                   library: str) -> None:
    what = f"{'CPU + CUDA' if cuda else 'CPU'}, float32 + float64, {'pin + mujoco' if mujoco and model.conventions_differ else 'pin'}"
    print(f"torch_grid: building kernels for {model.name!r} ({what}) in {entry}", file=sys.stderr, flush=True)
    start = time.monotonic()
    with _staging(root, entry) as tmp:
        src = tmp / "src"
        src.mkdir()
        units = codegen.write_robot_sources(model, mujoco, cuda, namespace, src)
        include = [f"-I{CSRC}", f"-I{src}"]
        jobs, objects, prebuilt = [], [], 0
        for unit in units:
            obj = tmp / f"{unit.stem}{'_cuda' if unit.suffix == '.cu' else ''}.o"
            objects.append(str(obj))
            if unit.suffix == ".cu":
                if _take_prebuilt(unit, obj):
                    prebuilt += 1
                    continue
                cmd = [find_nvcc(), *nvcc_flags(), *include, "-c", str(unit), "-o", str(obj)]
            else:
                cmd = [os.environ.get("CXX", "c++"), *_cxx_flags(unit.stem), *include, "-c", str(unit), "-o", str(obj)]
            jobs.append((unit.name, cmd, obj))
        if prebuilt:
            print(f"torch_grid: {prebuilt} CUDA units of {model.name!r} prebuilt (TORCH_GRID_PREBUILT)", file=sys.stderr,
                  flush=True)
        jobs.sort(key=lambda job: _UNIT_ORDER.get(Path(job[0]).stem.rsplit("_", 1)[0].removesuffix("_lanes"), len(_UNIT_ORDER)))
        _run_parallel(model.name, jobs, start)
        if cuda:
            link = [find_nvcc(), "-shared", *objects, "-o", str(tmp / library)]
        else:
            link = [os.environ.get("CXX", "c++"), "-shared", *objects, "-o", str(tmp / library)]
        _run_parallel(model.name, [("link", link, tmp / library)], start)
        (tmp / "complete").write_text(_digest(tmp / library))
    print(f"torch_grid: built {model.name!r} in {time.monotonic() - start:.0f} s", file=sys.stderr, flush=True)


# -- prebuilt CUDA objects ----------------------------------------------------------------------------
# A CUDA unit takes minutes to compile (a few robots' worth exceeds what a short-lived GPU machine
# can spend), and needs no GPU: its object can be compiled elsewhere for the machine's arch and found
# there in $TORCH_GRID_PREBUILT under the digest of everything it is compiled from, so a stale object
# (other sources, flags or nvcc release) is never taken: that unit is compiled as usual.

# the csrc folder a CUDA unit never includes (the torch glue needs torch's headers)
_TORCH_SIDE = "torch"


def cuda_unit_digest(unit: Path) -> str:
    """The digest of a generated CUDA unit's object: its text, the generated headers beside it, the
    kernel headers, nvcc's flags and release."""
    h = hashlib.sha256()
    h.update(unit.read_bytes())
    for name in ("robot.h", "op_args.h", "bindings.h"):
        h.update((unit.parent / name).read_bytes())
    h.update(_kernel_headers_digest().encode())
    h.update(" ".join(nvcc_flags()).encode())
    h.update(_nvcc_release().encode())
    return h.hexdigest()


@lru_cache(maxsize=None)
def _kernel_headers_digest() -> str:
    """The csrc files a CUDA unit may include, read once per process."""
    h = hashlib.sha256()
    for path in sorted(CSRC.rglob("*")):
        if path.is_file() and path.relative_to(CSRC).parts[0] != _TORCH_SIDE and "__pycache__" not in path.parts:
            h.update(path.relative_to(CSRC).as_posix().encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def _nvcc_release() -> str:
    version = compiler_version(find_nvcc())
    release = [part.strip() for line in version.splitlines() for part in line.split(",") if part.strip().startswith("release")]
    return release[0] if release else version


def _take_prebuilt(unit: Path, obj: Path) -> bool:
    """Copy the unit's prebuilt object to `obj` if $TORCH_GRID_PREBUILT holds one for its digest."""
    directory = os.environ.get("TORCH_GRID_PREBUILT")
    if not directory:
        return False
    found = Path(directory) / f"{cuda_unit_digest(unit)}.o"
    if not found.is_file():
        print(f"torch_grid: no prebuilt object for {unit.name} in TORCH_GRID_PREBUILT={directory} (its sources, flags or "
              "nvcc changed since): compiling it", file=sys.stderr, flush=True)
        return False
    shutil.copyfile(found, obj)
    return True


# The longest units first, so that the last ones to finish on a few cores are short.
_UNIT_ORDER = {"dynamics": 0, "derivatives": 1, "derivatives_backward": 2, "kinematics": 3, "regressors": 4}


def _cxx_flags(unit: str = "") -> list[str]:
    # Tuned for this CPU (AVX2/FMA where present, ~1.4x faster); the CPU is part of the cache key.
    native = ["-march=native"] if platform.machine() in ("x86_64", "AMD64") and not os.environ.get("TORCH_GRID_PORTABLE") else []
    native += _whole_vector_moves() if native else []
    # -O3 makes the kernels 1.4-2x faster than -O2 (bodies unrolled over the robot's constant tree);
    # the forward-mode backward units gain only 1-25% from it for twice the compile time.
    level = "-O2" if unit.endswith(("backward_f32", "backward_f64", "backward_lanes_f32", "backward_lanes_f64")) else "-O3"
    # No vectorized epilogues: GCC 12 -O3 ended a 512-bit loop (36 doubles of a stack array) with an
    # aligned 256-bit access at a 16-byte-aligned address, a segmentation fault (coriolis_matrix of a
    # 5-joint arm on an AVX-512 CPU). Such epilogues are a few elements; the main loops keep their width.
    lanes = [f"-DTG_LANES={codegen.cpu_lanes()}"] if codegen.cpu_lanes() > 1 else []
    common = ["-std=c++17", level, "-fno-fast-math", "-fPIC", "-fvisibility=hidden", "--param=vect-epilogues-nomask=0"]
    # TORCH_GRID_DEVICE_PATHS=1: the CPU kernels take a GPU thread's code paths (kernels/spatial/spatial.h:
    # TG_DEVICE_PATH), so that the CPU's tests check them (tests/test_device_paths.py).
    device = ["-DTG_DEVICE_PATHS"] if os.environ.get("TORCH_GRID_DEVICE_PATHS") == "1" else []
    return common + native + lanes + device


@lru_cache(maxsize=None)
def _whole_vector_moves() -> list[str]:
    """Copies of structs of CPU lanes in whole vectors. GCC tuned for some CPUs (AMD Zen) copies an
    aggregate in 16-byte pieces, or calls memcpy, and the kernels then load each piece back as one
    wider vector: a failed store-to-load forwarding each time. -mmove-max/-mstore-max (GCC 12) set the
    piece to the lanes' width; a compiler without them keeps its own."""
    cpu_flags = cpu_features()
    bits = 512 if "avx512f" in cpu_flags else 256 if "avx" in cpu_flags else 0
    if not bits:
        return []
    flags = [f"-mmove-max={bits}", f"-mstore-max={bits}"]
    try:
        probe = subprocess.run([os.environ.get("CXX", "c++"), "-march=native", *flags, "-x", "c++", "-fsyntax-only", os.devnull],
                               capture_output=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return []
    return flags if probe.returncode == 0 else []


def nvcc_flags() -> list[str]:
    arch = os.environ.get("TORCH_GRID_CUDA_ARCH", "native")
    return ["-std=c++17", "-O3", f"-arch={arch}", "-Xcompiler", "-fPIC", "-Xcompiler", "-fvisibility=hidden"]


def _run_parallel(name: str, jobs: list[tuple[str, list[str], Path]], start: float) -> None:
    """Run the compiler commands, as many at once as there are cores, printing each one done. On any
    failure or interruption (Ctrl-C), every compiler still running is killed before raising."""
    # Finished compilers stay referenced until the end: a Popen's finalizer running inside the loop is
    # where Python would drop a Ctrl-C (an exception in a finalizer is only printed).
    pending, running, finished, done = list(jobs), [], [], 0
    width = os.cpu_count() or 1
    last = time.monotonic()
    try:
        while pending or running:
            while pending and len(running) < width:
                label, cmd, _ = pending.pop(0)
                if os.environ.get("TORCH_GRID_VERBOSE") == "1":
                    print(" ".join(cmd), file=sys.stderr, flush=True)
                running.append((label, subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                                        start_new_session=True)))
            time.sleep(0.02)
            for label, proc in list(running):
                if proc.poll() is None:
                    continue
                running.remove((label, proc))
                finished.append(proc)
                output = proc.stdout.read().decode(errors="replace")
                proc.stdout.close()
                if proc.returncode:
                    raise RuntimeError(f"torch_grid: compiling {label} for {name!r} failed:\n{output[-8000:]}")
                done += 1
                if len(jobs) > 1:
                    print(f"torch_grid: [{done}/{len(jobs)}] {label} ({time.monotonic() - start:.0f} s)", file=sys.stderr,
                          flush=True)
            if time.monotonic() - last > _PROGRESS_EVERY:
                last = time.monotonic()
                print(f"torch_grid: still building {name!r} ({last - start:.0f} s)", file=sys.stderr, flush=True)
    finally:
        for _, proc in running:  # every compiler killed before waiting on any
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for _, proc in running:
            proc.wait()
            proc.stdout.close()


@contextmanager
def _staging(root: Path, entry: Path):
    """A private directory to build in, renamed to `entry` only when the block completes; removed on
    any failure or interruption, so the cache never holds a partial entry."""
    tmp = root / ".build" / f"{entry.name}-{os.getpid()}-{threading.get_ident()}"
    shutil.rmtree(tmp, ignore_errors=True)
    _remove_abandoned(root, entry.name)
    tmp.mkdir(parents=True)
    try:
        yield tmp
        if entry.exists():  # incomplete or damaged: replaced whole
            shutil.rmtree(entry)
        entry.parent.mkdir(parents=True, exist_ok=True)
        os.rename(tmp, entry)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _remove_abandoned(root: Path, name: str) -> None:
    """The build folders of entry `name` left by processes that died during a build (killed: no cleanup ran). The
    caller holds the entry's lock, so no live process of this machine builds it meanwhile."""
    for folder in (root / ".build").glob(f"{name}-*-*"):
        pid = folder.name[len(name) + 1:].split("-", 1)[0]
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(folder, ignore_errors=True)
        except OSError:  # another user's live process
            pass


def _complete(entry: Path, library: Path) -> bool:
    marker = entry / "complete"
    try:
        return marker.read_text() == _digest(library)
    except OSError:
        return False


@contextmanager
def _ticker(what: str, start: float):
    """Print elapsed time every _PROGRESS_EVERY seconds while a single compiler call runs."""
    done = threading.Event()

    def tick():
        while not done.wait(_PROGRESS_EVERY):
            print(f"torch_grid: still building {what} ({time.monotonic() - start:.0f} s)", file=sys.stderr, flush=True)

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


@contextmanager
def _file_lock(root: Path, name: str, what: str):
    """An exclusive lock on one cache entry across processes; says so while it waits for another."""
    with open(root / ".locks" / f"{name}.lock", "a") as fh:
        start, last = time.monotonic(), None
        while True:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                now = time.monotonic()
                if last is None or now - last > _PROGRESS_EVERY:
                    last = now
                    print(f"torch_grid: waiting for another process building {what} ({now - start:.0f} s)",
                          file=sys.stderr, flush=True)
                time.sleep(0.1)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _cache_key(model: RobotModel, mujoco: bool, cuda: bool) -> str:
    h = hashlib.sha256()
    h.update(model.hash.encode())
    h.update(f"mujoco={mujoco} cuda={cuda} lanes={codegen.cpu_lanes()} flags={_cxx_flags()} {_cxx_flags('backward_f64')} {nvcc_flags() if cuda else ''}".encode())
    h.update(cpu_identity().encode())
    for path in sorted(CSRC.rglob("*")):
        if path.is_file():
            h.update(path.relative_to(CSRC).as_posix().encode())
            h.update(path.read_bytes())
    # The generators: the op table and the emitter of the per-robot C++.
    for module in (codegen, ops):
        h.update(Path(module.__file__).read_bytes())
    h.update(compiler_version(os.environ.get("CXX", "c++")).encode())
    if cuda:
        h.update(compiler_version(find_nvcc()).encode())
    h.update(torch.__version__.encode())
    return h.hexdigest()


def find_nvcc() -> str:
    home = cuda_home()
    if home is None:
        raise RuntimeError("torch_grid: no CUDA toolkit found (a folder with bin/nvcc and include/cuda_runtime.h): "
                           "set CUDA_HOME to it")
    return str(home / "bin" / "nvcc")


@lru_cache(maxsize=None)
def cuda_home() -> Path | None:
    """The CUDA toolkit: the first of $CUDA_HOME, $CUDA_PATH, torch's own guess, the toolkit that the
    `nvcc` on the PATH runs and /usr/local/cuda that holds both bin/nvcc and include/cuda_runtime.h.
    torch guesses the folder above `nvcc`, which is wrong where `nvcc` is a wrapper script outside the
    toolkit; nvcc's dry run names the toolkit it runs from (its TOP)."""
    from torch.utils import cpp_extension

    candidates = [os.environ.get("CUDA_HOME"), os.environ.get("CUDA_PATH"), cpp_extension.CUDA_HOME]
    nvcc = shutil.which("nvcc")
    if nvcc:
        try:
            dry = subprocess.run([nvcc, "--dryrun", "-x", "cu", "-c", os.devnull, "-o", os.devnull], capture_output=True,
                                 text=True, timeout=30).stderr
        except (OSError, subprocess.TimeoutExpired):
            dry = ""
        candidates += [line.split("=", 1)[1].strip() for line in dry.splitlines() if line.startswith("#$ TOP=")]
        candidates.append(str(Path(nvcc).resolve().parent.parent))
    candidates.append("/usr/local/cuda")
    for candidate in candidates:
        if candidate and _is_toolkit(Path(candidate)):
            return Path(candidate).resolve()
    return None


def _is_toolkit(path: Path) -> bool:
    return (path / "bin" / "nvcc").is_file() and (path / "include" / "cuda_runtime.h").is_file()


@lru_cache(maxsize=None)
def _cuda_available() -> bool:
    if not torch.cuda.is_available():
        return False
    if cuda_home() is None:
        print("torch_grid: a CUDA device is present but no CUDA toolkit was found (set CUDA_HOME to the folder with "
              "bin/nvcc and include/cuda_runtime.h): building CPU kernels only", file=sys.stderr, flush=True)
        return False
    return True


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name) or "robot"
