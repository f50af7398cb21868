"""The build's worker processes, kept free of heavy imports.

`start_worker` must run before a worker imports open3d: TBB sizes its thread pool from the CPU
affinity and OpenMP from OMP_NUM_THREADS when the library loads, and one thread per worker is
what makes every run give the same bits.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from concurrent.futures import Executor
from typing import Any


def start_worker(cpus: Any) -> None:
    """Take one CPU from the `cpus` queue, pin this process to it, use one OpenMP thread."""
    os.environ["OMP_NUM_THREADS"] = "1"
    cpu = cpus.get()
    if cpu is not None and hasattr(os, "sched_setaffinity"):
        with contextlib.suppress(OSError):  # a CPU we may not use: stay where the parent was
            os.sched_setaffinity(0, {cpu})


def worker_cpus(workers: int) -> list[int | None]:
    """A CPU for each worker, so each runs one thread (TBB sizes its pool from the affinity).

    A build pinned to one CPU (`--threads 1`) spreads its workers over the machine from the CPU
    after its own, so the first worker, started while the build's process reads the log, does
    not share a CPU with it (on 2 CPUs the second worker takes the build's, idle by then);
    otherwise they share out the CPUs the build may use.
    """
    if not hasattr(os, "sched_getaffinity"):
        return [None] * workers
    current = sorted(os.sched_getaffinity(0))
    total = os.cpu_count() or 1
    if len(current) == 1:
        return [(current[0] + 1 + k) % total for k in range(workers)]
    return [current[k % len(current)] for k in range(workers)]


def warm_up() -> None:
    """Import what the jobs need (open3d, the mapper, the readers) before the first job comes."""
    import mfmap.export.mapdata
    import mfmap.ingest
    import mfmap.mapping.stage  # noqa: F401


@contextlib.contextmanager
def worker_pool(workers: int, warm: bool | int = True) -> Iterator[Executor]:
    """`workers` pinned processes; `warm` of them (True: all) started now and warmed up while
    the caller goes on, the others when the first jobs come (a spawn pool starts a process per
    job until it has them all).

    One pool serves every parallel stage of a build (mapping, then the maps' second pass), so
    each worker pays its start-up (~1 s: a spawned interpreter importing open3d) once.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # spawn: the parent has open3d's and GTSAM's thread pools loaded, which fork does not copy.
    context = multiprocessing.get_context("spawn")
    cpus = context.Queue()
    for cpu in worker_cpus(workers):
        cpus.put(cpu)
    with ProcessPoolExecutor(workers, mp_context=context, initializer=start_worker,
                             initargs=(cpus,)) as pool:
        for _ in range(workers if warm is True else min(int(warm), workers)):
            pool.submit(warm_up)  # submitted together, so each goes to a new process
        yield pool
