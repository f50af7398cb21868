"""No process outlives `mfmap build`: SIGTERM unwinds it like Ctrl-C, SIGKILL takes its workers
with it, and what a killed build left beside its output is cleaned by the next one. "Gone" is
measured from the signal, for the build's own process and every process it started."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from mfmap.runfolder import MARKER, clean_stale

pytestmark = pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads processes from /proc")


def _children(pid: int) -> set[int]:
    """Every live (not zombie) descendant of `pid`."""
    parent_of: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[-1].split()
        if fields[0] != "Z":
            parent_of[int(entry.name)] = int(fields[1])
    found: set[int] = set()
    frontier = {pid}
    while frontier:
        frontier = {p for p, pp in parent_of.items() if pp in frontier} - found
        found |= frontier
    return found


def _alive(pids: set[int]) -> set[int]:
    out = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[-1].split()[0]
        except OSError:
            continue
        if state != "Z":
            out.add(pid)
    return out


def _start_build(log: Path, out: Path) -> tuple[subprocess.Popen[str], set[int]]:
    """`mfmap build` in a process of its own, returned once its workers run."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "mfmap.cli", "build", str(log), "-o", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    deadline = time.monotonic() + 120
    started = None
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        kids = _children(proc.pid)
        # Two workers and the resource tracker, and the mapping under way in the workers.
        if len(kids) >= 3 and started is None:
            started = time.monotonic()
        if started is not None and time.monotonic() - started > 6.0:
            assert list(out.parent.glob(f"{out.name}.partial-*")), "the build ended before the signal"
            return proc, kids
        time.sleep(0.2)
    proc.kill()
    raise AssertionError("the build's workers did not start")


def _left_after(proc: subprocess.Popen[str], kids: set[int], sig: int,
                seconds: float = 2.0) -> set[int]:
    """Send `sig` to the build; the processes of the build and of `kids` still running
    `seconds` later (then killed, so a failing test does not leave them behind either)."""
    proc.send_signal(sig)
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and (proc.poll() is None or _alive(kids)):
        time.sleep(0.02)
    left = _alive(kids) | ({proc.pid} if proc.poll() is None else set())
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    return left


def _long_log(sim_run: Callable[..., Path]) -> Path:
    """The tiny building toured three times (a 19 s build on an idle 2-core machine, where the
    single tour's finishes about 6 s after its workers start): the signal must find it
    mapping in its workers, not renaming its finished folder."""
    return sim_run("tiny", duration_scale=3.0) / "log.mcap"


@pytest.mark.slow
def test_sigterm_stops_the_build_and_its_workers(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc, kids = _start_build(_long_log(sim_run), out)
    assert _left_after(proc, kids, signal.SIGTERM) == set()
    _, stderr = proc.communicate(timeout=10)
    assert proc.returncode == 128 + signal.SIGTERM
    assert stderr.strip().splitlines() == ["mfmap: interrupted (SIGTERM): nothing was left half-written"]
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.slow
def test_sigkill_takes_the_workers_along(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc, kids = _start_build(_long_log(sim_run), out)
    assert _left_after(proc, kids, signal.SIGKILL) == set()
    proc.wait(timeout=10)
    # What the killed build left is mfmap's, and the next build's start removes it.
    (partial,) = tmp_path.glob("out.partial-*")
    assert (partial / MARKER).is_file()
    notes = clean_stale(tmp_path)
    assert notes == [f"removed {partial}, left by a build that was killed"]
    assert list(tmp_path.iterdir()) == []


_SPIN = """
import multiprocessing, sys, time
import numpy as np
from mfmap import cli

@cli.app.command("spin")
def spin() -> None:
    child = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(120,))
    child.start()
    print(child.pid, flush=True)
    np.linalg.svd(np.random.default_rng(0).random((3000, 3000)))  # LAPACK: no bytecode for long

if __name__ == "__main__":
    sys.argv = ["mfmap", "spin"]
    cli.main()
"""


def test_sigterm_stops_a_process_inside_a_long_library_call(tmp_path: Path) -> None:
    """Python runs signal handlers between bytecodes only; in one long LAPACK call the CLI's
    watch thread stops the process (and its children) after the grace period instead."""
    script = tmp_path / "spin.py"
    script.write_text(_SPIN)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})
    assert proc.stdout is not None
    child = int(proc.stdout.readline())
    time.sleep(1.0)  # inside the SVD by now
    assert proc.poll() is None
    assert _left_after(proc, {child}, signal.SIGTERM, seconds=3.0) == set()
    _, stderr = proc.communicate(timeout=10)
    assert proc.returncode == 128 + signal.SIGTERM
    assert stderr.strip().splitlines()[0].startswith(
        "mfmap: interrupted (SIGTERM) inside a long computation: stopped at once")
