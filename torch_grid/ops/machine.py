"""Facts about this machine that a compiled kernel depends on: the CPU's model and instruction-set features
(a -march=native binary runs only where they match) and a compiler's version."""
from __future__ import annotations

import platform
import subprocess
from functools import lru_cache
from pathlib import Path


@lru_cache(maxsize=None)
def _cpuinfo() -> dict[str, str]:
    """The first processor's model name and feature flags from /proc/cpuinfo (empty where it is absent)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return {}
    keep = {}
    for line in lines:
        key, _, value = line.partition(":")
        key = key.strip()
        if key in ("model name", "flags", "Features", "CPU part") and key not in keep:
            keep[key] = value.strip()
    return keep


def cpu_features() -> set[str]:
    """This CPU's instruction-set features (x86 `flags`, Arm `Features`)."""
    info = _cpuinfo()
    return set(info.get("flags", info.get("Features", "")).split())


@lru_cache(maxsize=None)
def cpu_identity() -> str:
    """Model name and feature flags of this CPU: a -march=native binary runs only where they match."""
    keep = _cpuinfo()
    if not keep:
        return platform.processor() or platform.machine()
    return platform.machine() + "|" + "|".join(f"{k}={v}" for k, v in sorted(keep.items()))


@lru_cache(maxsize=None)
def compiler_version(compiler: str) -> str:
    try:
        return subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
