"""Which machine a log was built on, as far as floating point is concerned.

A build is bit-identical run to run on one machine but not from one CPU to another: numpy and
open3d pick their SIMD kernels at run time (AVX-512 where the CPU has it), sums come out in
other last bits, and on the chaotic logs the odometry carries that to millimetres or more. So
each baseline entry records the machine it was made on, and a run on another machine says so
next to any regression it reports.
"""

from __future__ import annotations

import functools
import platform
from importlib import metadata
from pathlib import Path

# The instruction sets whose presence changes which kernels numpy and open3d run.
SIMD_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f")
# The libraries whose versions change a build's floating point.
LIBRARIES = ("numpy", "open3d", "gtsam", "scipy")


@functools.cache
def machine_fingerprint() -> str:
    """One line, e.g. 'x86_64 AMD EPYC [sse4_2 avx avx2 fma avx512f]; numpy 1.26.4, ...'."""
    model, flags = _cpu(Path("/proc/cpuinfo"))
    simd = " ".join(f for f in SIMD_FLAGS if f in flags)
    cpu = f"{platform.machine()} {model or platform.processor() or 'unknown CPU'}"
    if simd:
        cpu += f" [{simd}]"
    return f"{cpu}; " + ", ".join(f"{name} {_version(name)}" for name in LIBRARIES)


def _cpu(cpuinfo: Path) -> tuple[str, set[str]]:
    """The first processor's model name and flags from /proc/cpuinfo (empty where absent)."""
    model, flags = "", set[str]()
    try:
        text = cpuinfo.read_text()
    except OSError:
        return model, flags
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key = key.strip()
        if key == "model name" and not model:
            model = " ".join(value.split())
        elif key in ("flags", "Features") and not flags:
            flags = set(value.split())
        if not line.strip() and model:
            break  # the first processor's block is enough
    return model, flags


def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "absent"
