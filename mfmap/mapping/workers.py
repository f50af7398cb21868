"""Start-up of the parallel mapping workers, kept free of heavy imports.

It must run before the worker imports open3d: TBB sizes its thread pool from the CPU affinity
and OpenMP from OMP_NUM_THREADS when the library loads, and one thread per worker is what makes
every run give the same bits.
"""

from __future__ import annotations

import contextlib
import os
from typing import Any


def start_worker(cpus: Any) -> None:
    """Take one CPU from the `cpus` queue, pin this process to it, use one OpenMP thread."""
    os.environ["OMP_NUM_THREADS"] = "1"
    cpu = cpus.get()
    if cpu is not None and hasattr(os, "sched_setaffinity"):
        with contextlib.suppress(OSError):  # a CPU we may not use: stay where the parent was
            os.sched_setaffinity(0, {cpu})


def worker_cpus(workers: int, offset: int = 0) -> list[int | None]:
    """A CPU for each worker, so each runs one thread (TBB sizes its pool from the affinity).

    A build pinned to one CPU (`--threads 1`) spreads its workers from that CPU over the
    machine; otherwise they share out the CPUs the build may use. `offset` skips CPUs for work
    the parent process does itself.
    """
    if not hasattr(os, "sched_getaffinity"):
        return [None] * workers
    current = sorted(os.sched_getaffinity(0))
    total = os.cpu_count() or 1
    if len(current) == 1:
        return [(current[0] + k + offset) % total for k in range(workers)]
    return [current[(k + offset) % len(current)] for k in range(workers)]
