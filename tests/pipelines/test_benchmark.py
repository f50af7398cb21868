"""The benchmark's measuring and tables (the figures themselves are printed, never asserted)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from pipelines.benchmark import (
    MARKDOWN_END,
    MARKDOWN_START,
    BuildFigures,
    ScenarioFigures,
    median_run,
    run_child,
    scaling_table,
    scenario_table,
    splice_markdown,
    tum_span_s,
)

ROOT = Path(__file__).resolve().parents[2]


def test_child_peak_memory_is_the_childs_own() -> None:
    """A child that holds 300 MB reports at least that; a bare interpreter far less. The CPU time
    includes what the child's own children used.

    Linux carries a process's peak RSS across fork and exec, so a child's figure is at least its
    parent's RSS at spawn: the measurement runs from a fresh, small interpreter, as the benchmark
    does (its parent imports nothing heavy)."""
    code = (
        "import sys; from pipelines.benchmark import run_child;"
        "big = run_child([sys.executable, '-c', "
        "\"b = bytearray(300 * 2**20); b[::4096] = b'x' * len(b[::4096]); print(7)\"]);"
        "small = run_child([sys.executable, '-c', 'print(1)']);"
        "failed = run_child([sys.executable, '-c', 'import sys; sys.exit(3)']);"
        "spin = 'import time\\nt = time.process_time()\\nwhile time.process_time() - t < 0.6: pass';"
        "busy = run_child([sys.executable, '-c', "
        "f'import subprocess, sys; subprocess.run([sys.executable, \"-c\", {spin!r}], check=True)']);"
        "print(big.ok, big.stdout.strip(), big.peak_rss_mb, small.peak_rss_mb, failed.returncode, failed.ok,"
        " small.cpu_s, busy.ok, busy.cpu_s)"
    )
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    big_ok, big_out, big_mb, small_mb, failed_rc, failed_ok, small_cpu, busy_ok, busy_cpu = res.stdout.split()
    assert big_ok == "True" and big_out == "7"
    assert float(big_mb) > 300
    assert float(small_mb) < 100
    assert failed_rc == "3" and failed_ok == "False"
    # CPU time counts the processes the child reaped: a grandchild that spins for 0.6 s of CPU.
    assert busy_ok == "True"
    assert float(busy_cpu) >= 0.6 + float(small_cpu) * 0.5
    assert float(small_cpu) < 0.5


def test_tum_span(tmp_path: Path) -> None:
    path = tmp_path / "t.tum"
    path.write_text("# t x y z qx qy qz qw\n100.0 0 0 0 0 0 0 1\n100.5 0 0 0 0 0 0 1\n160.25 1 0 0 0 0 0 1\n")
    assert tum_span_s(path) == (60.25, 3)


def _fig(scale: float, wall_s: float, rss_mb: float) -> BuildFigures:
    return BuildFigures(f"x{scale:g}", "log.mcap", 60.0 * scale, int(600 * scale), wall_s, rss_mb, True)


def test_scaling_verdict_against_the_issue_limits() -> None:
    scales = [1.0, 2.0, 4.0]
    text, verdict = scaling_table([_fig(1, 10.0, 400.0), _fig(2, 20.5, 420.0), _fig(4, 43.0, 590.0)], scales)
    assert verdict["time_ratio"] == 4.3 and verdict["time_ok"]
    assert verdict["memory_ratio"] == 1.475 and verdict["memory_ok"]
    assert "| 4x | 240.0 | 4.00x | 2400 | 43.00 | 4.30x | 590 | 1.48x | 55.8 |" in text
    assert "PASS" in text and "FAIL" not in text
    _, bad = scaling_table([_fig(1, 10.0, 400.0), _fig(2, 25.0, 500.0), _fig(4, 45.0, 610.0)], scales)
    assert not bad["time_ok"] and not bad["memory_ok"]


def test_repeated_builds_report_the_median_run_and_the_spread() -> None:
    runs = [_fig(1, 45.7, 560.0), _fig(1, 34.3, 580.0), _fig(1, 40.2, 558.0)]
    best = median_run(runs)
    assert best.wall_s == 40.2 and best.peak_rss_mb == 580.0 and best.walls_s == [45.7, 34.3, 40.2]
    row = scenario_table([ScenarioFigures(best)])
    assert "| x1 | 60.0 | 600 | 40.20 (median of 3: 34.30-45.70) | 1.5x | 0.0 |" in row
    assert median_run([_fig(1, 30.0, 500.0), _fig(1, 50.0, 500.0)]).wall_s == 30.0
    broken = BuildFigures("x1", "log.mcap", 60.0, 0, 3.0, 90.0, False, "boom")
    assert median_run([runs[0], broken]) is broken
    assert "40.20 |" in scenario_table([ScenarioFigures(runs[2])])


def test_pin_cpus_claims_a_free_cpu(tmp_path: Path) -> None:
    """A worker pinned for determinism takes a CPU no other worker holds (pinning is per process,
    so the pinning runs in a child while this test holds the first CPU's lock)."""
    import fcntl

    code = (
        "import os, sys; from pathlib import Path; sys.path.insert(0, sys.argv[2]);"
        "from pipelines.regress.runner import pin_cpus;"
        "print(pin_cpus(1, Path(sys.argv[1])), sorted(os.sched_getaffinity(0)))"
    )
    argv = [sys.executable, "-c", code, str(tmp_path), str(Path(__file__).resolve().parents[2])]
    cpus = sorted(os.sched_getaffinity(0))
    free = run_child(argv)
    assert free.ok, free.stderr_tail
    assert free.stdout.split() == [f"[{cpus[0]}]"] * 2  # claimed the first CPU and runs on it
    if len(cpus) < 2:
        return
    with (tmp_path / f"cpu{cpus[0]}.lock").open("w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        busy = run_child(argv)
    assert busy.stdout.split() == [f"[{cpus[1]}]"] * 2  # the first is held: the next one


def test_markdown_replaces_only_the_text_between_the_markers(tmp_path: Path) -> None:
    doc = tmp_path / "performance.md"
    doc.write_text(f"# Performance\n\nintro\n\n{MARKDOWN_START}\nold table\n{MARKDOWN_END}\n\n## Stages\n")
    splice_markdown(doc, "| new | table |\n")
    text = doc.read_text()
    assert text == (
        f"# Performance\n\nintro\n\n{MARKDOWN_START}\n| new | table |\n{MARKDOWN_END}\n\n## Stages\n"
    )
    splice_markdown(doc, "| newer |")
    assert "| new | table |" not in doc.read_text() and "## Stages" in doc.read_text()
    bare = tmp_path / "bare.md"
    splice_markdown(bare, "| t |")
    assert bare.read_text() == f"{MARKDOWN_START}\n| t |\n{MARKDOWN_END}\n"
