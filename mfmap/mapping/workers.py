"""The build's worker processes, kept free of heavy imports.

`start_worker` must run before a worker imports open3d: TBB sizes its thread pool from the CPU
affinity and OpenMP from OMP_NUM_THREADS when the library loads, and one thread per worker is
what makes every run give the same bits.

A worker never outlives the build: it dies with its parent (a kill -9 of the build included),
and a build that stops on an error or a signal terminates its workers instead of waiting for
their jobs.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator
from concurrent.futures import Executor
from typing import Any

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _die_with_parent(parent_pid: int | None) -> None:
    """End this process when its parent ends, however the parent ends.

    On Linux the kernel sends SIGKILL at the parent's death (prctl PR_SET_PDEATHSIG, which
    fires when the parent's thread that started this process ends: the pool starts every
    worker from the thread that made it, see `worker_pool`). Everywhere, a thread also waits on
    the sentinel multiprocessing gives a spawned child (a pipe whose other end only the parent
    holds) and exits the process when it closes.
    """
    if sys.platform.startswith("linux"):
        import ctypes

        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if parent_pid is not None and os.getppid() != parent_pid:
        os._exit(1)  # the parent died before the signal was asked for
    import multiprocessing
    import multiprocessing.connection

    parent = multiprocessing.parent_process()
    sentinel = getattr(parent, "sentinel", None)
    if sentinel is not None:
        def watch() -> None:
            multiprocessing.connection.wait([sentinel])
            os._exit(1)

        threading.Thread(target=watch, name="mfmap-parent-watch", daemon=True).start()


def start_worker(cpus: Any, parent_pid: int | None = None) -> None:
    """Die with the parent; leave Ctrl-C to it (it stops the workers); take one CPU from the
    `cpus` queue, pin this process to it, use one OpenMP thread."""
    _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
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


# What a mapping job needs (open3d, the mapper, the readers). A caller whose pool also runs a
# later stage's jobs names that stage's modules too, so this package never imports them.
MAPPING_MODULES = ("mfmap.ingest", "mfmap.mapping.chunks")


def warm_up(modules: tuple[str, ...] = MAPPING_MODULES) -> None:
    """Import what the jobs need before the first job comes."""
    import importlib

    for name in modules:
        importlib.import_module(name)


def _started() -> None:
    """The job that starts a worker without warming it up."""


@contextlib.contextmanager
def _one_thread_environ() -> Iterator[None]:
    """OMP_NUM_THREADS=1 in this process's environment while it starts workers.

    A spawned worker imports the caller's main module before `start_worker` runs (to find what
    it defines); a script that imports open3d at its top loads OpenMP there with a thread per
    CPU, and the worker, then pinned to one CPU, mapped at less than half speed (three-floor-
    revisit on two workers: 103 s instead of 42). Started with the variable set, a worker's
    OpenMP has one thread from its first import. This process's own libraries sized their pools
    when they loaded, so setting it here for a moment changes nothing of theirs.
    """
    before = os.environ.get("OMP_NUM_THREADS")
    os.environ["OMP_NUM_THREADS"] = "1"
    try:
        yield
    finally:
        if before is None:
            del os.environ["OMP_NUM_THREADS"]
        else:
            os.environ["OMP_NUM_THREADS"] = before


@contextlib.contextmanager
def worker_pool(workers: int, warm: bool | int = True,
                warm_modules: tuple[str, ...] = MAPPING_MODULES) -> Iterator[Executor]:
    """`workers` pinned processes, all started now from this thread; `warm` of them (True: all)
    warmed up (importing `warm_modules`) while the caller goes on, the others import what their
    first job needs.

    One pool serves every parallel stage of a build (mapping, then the maps' second pass), so
    each worker pays its start-up (~1 s: a spawned interpreter importing open3d) once. When the
    block raises (an error, Ctrl-C, SIGTERM) the workers are terminated, not waited for.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # spawn: the parent has open3d's and GTSAM's thread pools loaded, which fork does not copy.
    context = multiprocessing.get_context("spawn")
    cpus = context.Queue()
    for cpu in worker_cpus(workers):
        cpus.put(cpu)
    pool = ProcessPoolExecutor(workers, mp_context=context, initializer=start_worker,
                               initargs=(cpus, os.getpid()))
    try:
        n_warm = workers if warm is True else min(int(warm), workers)
        # Submitted together, so each goes to a new process, started by this thread (which the
        # workers' death signal is tied to) and not later by whichever thread submits a job.
        with _one_thread_environ():
            for k in range(workers):
                if k < n_warm:
                    pool.submit(warm_up, warm_modules)
                else:
                    pool.submit(_started)
        yield pool
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def stop_pool(pool: Any, grace_s: float = 2.0) -> None:
    """Terminate a ProcessPoolExecutor's workers now (SIGTERM, SIGKILL after `grace_s`)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        with contextlib.suppress(OSError, ValueError):
            process.terminate()
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AssertionError):
            process.join(grace_s)
            if process.is_alive():
                process.kill()
                process.join(grace_s)
    with contextlib.suppress(Exception):
        pool.shutdown(wait=False, cancel_futures=True)
