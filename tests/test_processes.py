"""No process outlives `mfmap build`: SIGTERM unwinds it like Ctrl-C, SIGKILL takes its workers
with it, and what a killed build left beside its output is cleaned by the next one."""

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
            assert list(out.parent.glob(f"{out.name}.partial-*"))
            return proc, kids
        time.sleep(0.2)
    proc.kill()
    raise AssertionError("the build's workers did not start")


def _left_after(pids: set[int], seconds: float) -> set[int]:
    """The processes of `pids` still running after `seconds` (killed, so a failing test does
    not leave them behind either)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and _alive(pids):
        time.sleep(0.05)
    left = _alive(pids)
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    return left


@pytest.mark.slow
def test_sigterm_stops_the_build_and_its_workers(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc, kids = _start_build(sim_run("tiny") / "log.mcap", out)
    proc.send_signal(signal.SIGTERM)
    try:
        _, stderr = proc.communicate(timeout=10)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM
    assert stderr.strip().splitlines() == ["mfmap: interrupted (SIGTERM): nothing was left half-written"]
    assert _left_after(kids, 2.0) == set()
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.slow
def test_sigkill_takes_the_workers_along(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc, kids = _start_build(sim_run("tiny") / "log.mcap", out)
    proc.kill()
    proc.wait(timeout=10)
    assert _left_after(kids, 2.0) == set()
    # What the killed build left is mfmap's, and the next build's start removes it.
    (partial,) = tmp_path.glob("out.partial-*")
    assert (partial / MARKER).is_file()
    notes = clean_stale(tmp_path)
    assert notes == [f"removed {partial}, left by a build that was killed"]
    assert list(tmp_path.iterdir()) == []
