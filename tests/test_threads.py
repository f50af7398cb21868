"""A build is reproducible only with open3d and GTSAM held to one thread: the library says when
it is not (`mfmap.threads`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

LIBRARY_BUILD = """
import sys
from pathlib import Path
import mfmap
if sys.argv[3] == "limit":
    mfmap.limit_threads()
from mfmap.config import MfmapConfig
from mfmap.pipeline import build
build(Path(sys.argv[1]), Path(sys.argv[2]), MfmapConfig())
"""


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    env.update(extra)
    return env


def _python(code: str, *args: str, env: dict[str, str] | None = None) -> str:
    res = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                         timeout=600, env=env or _env())
    assert res.returncode == 0, res.stderr
    return res.stdout.strip()


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two CPUs to be unpinned")
def test_a_library_build_says_when_it_is_not_reproducible(sim_run: Callable[..., Path],
                                                          tmp_path: Path) -> None:
    log = sim_run("tiny") / "log.mcap"
    for mode in ("free", "limit"):
        _python(LIBRARY_BUILD, str(log), str(tmp_path / mode), mode)
    free = json.loads((tmp_path / "free" / "report.json").read_text())["warnings"]
    limited = json.loads((tmp_path / "limit" / "report.json").read_text())["warnings"]
    threads = [w for w in free if "multithreaded" in w]
    assert len(threads) == 1 and "OMP_NUM_THREADS unset" in threads[0]
    assert not [w for w in limited if "multithreaded" in w]
    assert len(free) == len(limited) + 1
    # Limited from Python, the build gives the CLI's bits.
    subprocess.run([sys.executable, "-m", "mfmap.cli", "build", str(log), "-o", str(tmp_path / "cli")],
                   check=True, capture_output=True, timeout=600, env=_env())
    for name in ("trajectory.tum", "map.ply", "floors.json"):
        assert (tmp_path / "limit" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes()


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two CPUs to be unpinned")
def test_limit_threads_pins_one_cpu_and_knows_when_it_came_too_late() -> None:
    check = ("import os, mfmap.threads as t; {before} t.limit_threads(); "
             "print(len(os.sched_getaffinity(0)), os.environ['OMP_NUM_THREADS'], "
             "t.unlimited_threads() is None)")
    assert _python(check.format(before="")) == "1 1 True"
    # open3d loaded first: its OpenMP pool is already sized, and the module keeps saying so.
    assert _python(check.format(before="import open3d;")) == "1 1 False"
    # Already one thread on one CPU when open3d loaded: nothing was too late.
    pinned = "import os; os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]}); "
    assert _python(pinned + check.format(before="import open3d;"),
                   env=_env(OMP_NUM_THREADS="1")) == "1 1 True"


def test_limit_threads_rejects_zero() -> None:
    from mfmap.threads import limit_threads

    with pytest.raises(ValueError, match="at least 1"):
        limit_threads(0)


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two CPUs")
def test_the_first_worker_takes_a_cpu_the_build_does_not_use() -> None:
    """The pool starts while the build's process reads the log: its first worker must not
    share that process's CPU (`mfmap.mapping.workers.worker_cpus`)."""
    code = """
import os
from mfmap.mapping.workers import worker_cpus
cpus = sorted(os.sched_getaffinity(0))
os.sched_setaffinity(0, {cpus[0]})
print(*worker_cpus(2), sep=",")
"""
    first, second = (int(c) for c in _python(code).split(","))
    cpus = sorted(os.sched_getaffinity(0))
    assert first != cpus[0]
    assert second == (cpus[0] + 2) % (os.cpu_count() or 1)


WORKER_START = """
import os
import sys

import open3d  # at the top, as scripts do: a spawned worker imports this module first

from mfmap.mapping.workers import worker_pool


def initial_omp(_: int) -> str:
    # The environment the worker's interpreter started with, not what start_worker set since.
    env = dict(v.split("=", 1) for v in open("/proc/self/environ").read().split("\\0") if "=" in v)
    return env.get("OMP_NUM_THREADS", "unset")


if __name__ == "__main__":
    with worker_pool(2, warm=False) as pool:
        print(*pool.map(initial_omp, range(2)), os.environ.get("OMP_NUM_THREADS", "unset"))
"""


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="reads /proc/self/environ")
def test_workers_start_with_one_openmp_thread(tmp_path: Path) -> None:
    """A worker imports the caller's main module before its initializer runs: a script that
    imports open3d at its top must not give the worker a thread per CPU (`_one_thread_environ`),
    and the caller's environment is left as it was."""
    script = tmp_path / "script.py"
    script.write_text(WORKER_START)
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                         env=_env(PYTHONPATH=str(Path(__file__).resolve().parent.parent)))
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["1", "1", "unset"]
