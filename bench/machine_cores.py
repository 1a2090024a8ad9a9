"""What two threads can gain on this machine at this moment, whatever the code: machine_cores.cpp's
pure arithmetic loop, its throughput on two threads over one. Printed beside a two-thread speed-up
so that the speed-up can be read against it: on a virtual machine whose two CPUs are at times two
hyperthreads of one physical core, the loop gains nothing then, and no code gains much.

    python bench/machine_cores.py [repeats]
"""
from __future__ import annotations

import hashlib
import os
import statistics
import subprocess
import sys
from pathlib import Path

SOURCE = Path(__file__).with_suffix(".cpp")
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "torch_grid_bench" / "machine_cores"


def binary() -> Path:
    """The compiled loop (-O2 -march=native), built once per source."""
    key = hashlib.sha256(SOURCE.read_bytes()).hexdigest()[:16]
    path = CACHE / f"machine_cores-{key}"
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        subprocess.run(["c++", "-O2", "-march=native", "-pthread", str(SOURCE), "-o", str(path)], check=True)
    return path


def two_thread_ceiling(repeats: int = 5) -> float:
    """The median over `repeats` of the loop's two-thread / one-thread throughput (about 0.1 s each)."""
    out = subprocess.run([str(binary()), str(repeats)], check=True, capture_output=True, text=True).stdout
    return statistics.median(float(x) for x in out.split())


if __name__ == "__main__":
    print(f"{two_thread_ceiling(int(sys.argv[1]) if len(sys.argv) > 1 else 5):.2f}")
