"""Thread limits that make a build reproducible, for the CLI and for Python callers.

open3d (OpenMP) and GTSAM (TBB) split their sums over threads, so the last bits of a registration
or an optimisation differ from run to run; through the odometry's chaos that can move a floor by
centimetres (stairs seed 2's top floor gave 20.0 and 58.3 mm in two runs of a multithreaded
script). Both size their thread pools when they load: OpenMP from OMP_NUM_THREADS, TBB from the
CPU affinity. This module imports neither.
"""

from __future__ import annotations

import os
import sys

_LIBRARIES = ("open3d", "gtsam")
_late: str | None = None  # set when limit_threads came after the libraries had loaded unlimited


def limit_threads(threads: int = 1) -> None:
    """Cap the thread pools of open3d and GTSAM; call it before importing `mfmap.pipeline`.

    The process is kept on `threads` CPUs, chosen by pid so that parallel builds spread over the
    machine. With 1 (the CLI's default) a build is bit-for-bit reproducible. Once open3d or GTSAM
    is loaded it is too late for them: `unlimited_threads` then keeps saying so.
    """
    if threads < 1:
        raise ValueError(f"threads must be at least 1, got {threads}")
    global _late
    if _late is None and any(name in sys.modules for name in _LIBRARIES):
        _late = unlimited_threads()  # what the libraries already run with stays
    os.environ["OMP_NUM_THREADS"] = str(threads)
    if hasattr(os, "sched_getaffinity"):
        cpus = sorted(os.sched_getaffinity(0))
        if threads < len(cpus):
            start = os.getpid() % len(cpus)
            keep = {cpus[(start + i) % len(cpus)] for i in range(threads)}
            os.sched_setaffinity(0, keep)


def unlimited_threads() -> str | None:
    """Why a build in this process may differ from run to run, or None when it cannot.

    Judged from the environment and the CPU affinity now, which are what the libraries read
    when they load (a caller that changed them after importing open3d is not seen).
    """
    if _late is not None:
        return _late
    omp = os.environ.get("OMP_NUM_THREADS", "")
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if omp == "1" and cpus == 1:
        return None
    reasons = []
    if omp != "1":
        reasons.append(f"OMP_NUM_THREADS={omp}" if omp else "OMP_NUM_THREADS unset")
    if cpus > 1:
        reasons.append(f"{cpus} CPUs in the affinity mask")
    return (f"open3d and GTSAM run multithreaded in this process ({', '.join(reasons)}): a build "
            "can differ from run to run; call mfmap.limit_threads() before importing "
            "mfmap.pipeline (mfmap build does) for bit-identical output")


__all__ = ["limit_threads", "unlimited_threads"]
