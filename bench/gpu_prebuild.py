"""Prepare what bench/gpu_check.py needs on a GPU machine that cannot build or parse it in time.

    python bench/gpu_prebuild.py [--out .gpu] [--arch sm_90] [--robots iiwa14 go2 g1 humanoid gripper]

writes bench/gpu/models/<robot>.json, each robot of the check as a saved model (torch_grid.load reads
it without Pinocchio or MuJoCo), and into --out:
  - prebuilt.tar.xz: the objects of every CUDA unit of those robots, compiled by nvcc for --arch, each
    named by its digest (torch_grid.ops.build.cuda_unit_digest). With TORCH_GRID_PREBUILT pointing at the
    unpacked folder and TORCH_GRID_CUDA_ARCH=--arch, a build takes an object only where the digest of
    the unit it generates matches, so a stale object is never used: that unit is compiled there.
No GPU is needed. The objects are kept in --objects (default <torch_grid cache>/prebuilt/<arch>, outside the
working tree, so that a new checkout on the same machine compiles only the units whose digest changed); one
that no unit of these robots wants any more is removed there after a week unused.
"""
from __future__ import annotations

import argparse
import lzma
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from gpu_models import MODELS, MODELS_DIR, model_of  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(HERE.parent / ".gpu"))
    parser.add_argument("--arch", default="sm_90")
    parser.add_argument("--robots", nargs="+", default=list(MODELS))
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--objects", help="where the compiled objects are kept (default <torch_grid cache>/prebuilt/<arch>)")
    args = parser.parse_args(argv)
    os.environ["TORCH_GRID_CUDA_ARCH"] = args.arch  # before the flags are read

    from torch_grid.ops import build, codegen
    from torch_grid.model.description import RobotModel

    out = Path(args.out)
    objects = Path(args.objects) if args.objects else build.default_cache_dir() / "prebuilt" / args.arch
    out.mkdir(parents=True, exist_ok=True)
    MODELS_DIR.mkdir(parents=True, exist_ok=True)
    objects.mkdir(parents=True, exist_ok=True)
    wanted: set[str] = set()
    with tempfile.TemporaryDirectory(prefix="torch_grid_prebuild_") as tmp:
        jobs = []
        for name in args.robots:
            saved = MODELS_DIR / f"{name}.json"
            model_of(name).save(saved)
            kernel = RobotModel.load(saved).kernel_model  # what the GPU machine will read
            src = Path(tmp) / name
            src.mkdir()
            namespace = build.op_namespace(kernel, True)
            for unit in codegen.write_robot_sources(kernel, True, True, namespace, src):
                if unit.suffix != ".cu":
                    continue
                target = objects / f"{build.cuda_unit_digest(unit)}.o"
                wanted.add(target.name)
                if target.exists():
                    target.touch()  # in use: kept by the pruning below
                else:
                    jobs.append((f"{name}/{unit.name}", unit, target))
        print(f"{len(jobs)} CUDA units to compile, {len(wanted) - len(jobs)} already prebuilt", flush=True)
        start = time.monotonic()

        def compile_unit(job):
            label, unit, target = job
            partial = target.with_suffix(".partial")
            cmd = [build.find_nvcc(), *build.nvcc_flags(), f"-I{build.CSRC}", f"-I{unit.parent}", "-c", str(unit),
                   "-o", str(partial)]
            result = subprocess.run(cmd, capture_output=True, text=True)
            if result.returncode:
                raise RuntimeError(f"nvcc failed on {label}:\n{result.stderr[-4000:]}")
            partial.rename(target)
            print(f"  {label} ({time.monotonic() - start:.0f} s)", flush=True)

        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            list(pool.map(compile_unit, jobs))
    week = time.time() - 7 * 24 * 3600
    for stale in objects.glob("*.o"):
        if stale.name not in wanted and stale.stat().st_mtime < week:
            stale.unlink()
    archive = out / "prebuilt.tar.xz"
    # xz's strongest preset: what travels to a device machine (the working tree with this) is at most 64 MiB, and
    # five robots' objects take about 60 MiB so (63 MiB at the default preset)
    with tarfile.open(archive, "w:xz", preset=9 | lzma.PRESET_EXTREME) as tar:
        for name in sorted(wanted):
            tar.add(objects / name, arcname=name)
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=HERE.parent, capture_output=True).stdout.split(b"\0")
    tree = sum((HERE.parent / p.decode()).stat().st_size for p in tracked if p and (HERE.parent / p.decode()).is_file())
    print(f"{archive}: {archive.stat().st_size / 2**20:.1f} MiB, {len(wanted)} objects; with the tracked files "
          f"{(archive.stat().st_size + tree) / 2**20:.1f} MiB of the 64 MiB that travel")
    return 0


if __name__ == "__main__":
    sys.exit(main())
