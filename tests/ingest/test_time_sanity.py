"""Clocks that jump: each sensor stream is cut to its consistent part at ingest, with a warning
that says how many messages and where, so a stamp a year ahead cannot make the log a year long
(or the barometer's grid 12 GB)."""

from __future__ import annotations

import resource
import subprocess
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import ingest_logwriter as lw
import numpy as np
import pytest

from mfmap.ingest import open_log
from mfmap.ingest.config import IngestConfig
from mfmap.ingest.timecheck import consistent
from mfmap.types import Role

YEAR_NS = 365 * 86_400 * 10**9
S = 10**9
GAP_NS = 600 * S


# ----- the check on its own ---------------------------------------------------------------------


def test_one_stamp_a_year_ahead_is_dropped() -> None:
    t = np.arange(100, dtype=np.int64) * S // 10
    t[40] += YEAR_NS
    check = consistent(t, GAP_NS)
    assert check.dropped == 1 and not check.keep[40]
    assert check.first_bad_ns == t[40]


def test_a_first_stamp_far_ahead_does_not_take_the_stream() -> None:
    t = np.arange(100, dtype=np.int64) * S // 10
    t[0] += YEAR_NS
    check = consistent(t, GAP_NS)
    assert check.keep.tolist() == [False] + [True] * 99


def test_a_clock_set_back_drops_only_the_overlap() -> None:
    """40 s at 10 Hz, then the clock set back 10 s and another 40 s: the 10 s that repeat
    stamps already seen are dropped (100 messages), everything else kept."""
    first = np.arange(400, dtype=np.int64) * S // 10
    second = first[-1] + S // 10 - 10 * S + np.arange(400, dtype=np.int64) * S // 10
    t = np.concatenate([first, second])
    check = consistent(t, GAP_NS)
    assert check.backward == 1
    assert check.dropped == 100
    kept = t[check.keep]
    assert np.all(np.diff(kept) > 0)


def test_a_clock_reset_far_ahead_keeps_the_longer_part() -> None:
    t = np.concatenate([np.arange(300), YEAR_NS // S * 10 + np.arange(500)]).astype(np.int64) * S // 10
    check = consistent(t, GAP_NS)
    assert check.keep.tolist() == [False] * 300 + [True] * 500
    assert check.gaps == 1


def test_stamps_in_pieces_are_checked_in_bounded_time() -> None:
    import time

    rng = np.random.default_rng(0)
    t = rng.integers(0, 10**18, 200_000)
    started = time.process_time()
    check = consistent(t, GAP_NS)
    assert time.process_time() - started < 30.0  # a few seconds; a quadratic search takes hours
    kept = np.sort(t[check.keep])
    assert kept.shape[0] > 0 and np.all(np.diff(kept) <= GAP_NS)


def test_a_buffer_written_late_is_not_a_clock_problem() -> None:
    """Recorded in the order [50 .. 99] then [0 .. 49]: the stamps fill each other's holes,
    nothing is dropped."""
    t = np.arange(100, dtype=np.int64) * S // 10
    assert consistent(np.concatenate([t[50:], t[:50]]), GAP_NS).dropped == 0


def test_a_stamp_a_few_seconds_ahead_does_not_claim_the_time_after_it() -> None:
    t = np.arange(100, dtype=np.int64) * S // 10
    t[40] += 5 * S
    check = consistent(t, GAP_NS)
    assert check.keep.tolist() == [True] * 40 + [False] + [True] * 59


# ----- logs written by the real writers ---------------------------------------------------------


def _jump(topic: str, index: int, delta_ns: int) -> lw.Edit:
    """The index-th message of `topic` moved by delta_ns, log time and header stamp alike."""

    def edit(store: Any, items: list[lw.Item]) -> Iterable[lw.Item]:
        seen = 0
        for name, msgtype, t, msg in items:
            if name == topic:
                if seen == index:
                    t += delta_ns
                    msg = lw.restamp(store, msg, t)
                seen += 1
            yield name, msgtype, t, msg

    return edit


@pytest.mark.parametrize("fmt", ["mcap-ros2", "ros1-none", "ros2-sqlite3", "ros2-mcap"])
def test_a_barometer_stamp_a_year_ahead_is_dropped_at_open(tmp_path: Path, fmt: str) -> None:
    path = lw.write_log(tmp_path, fmt, _jump("/baro/pressure", 20, YEAR_NS))
    with open_log(path) as src:
        assert src.duration_s < 2.0  # the log's second, not a year
        assert src.count(Role.BARO) == lw.BARO_N - 1
        (warning,) = [w for w in src.warnings if "/baro/pressure" in w]
        assert "dropped 1 of 50 messages" in warning and "+31536000.8 s" in warning
        pressure = src.pressure()
        assert len(pressure) == lw.BARO_N - 1
        assert np.all(np.diff(pressure.stamp_ns) > 0)
        assert pressure.stamp_ns[-1] - pressure.stamp_ns[0] < 2 * S


def test_lidar_header_stamps_that_jump_or_go_back_are_dropped(tmp_path: Path) -> None:
    """Log times fine, header stamps not: one scan stamped a year ahead, one stamped a second
    before the scan before it (past the re-sorting depth)."""

    def edit(store: Any, items: list[lw.Item]) -> Iterable[lw.Item]:
        k = 0
        for name, msgtype, t, msg in items:
            if name == "/lidar/points":
                stamp = lw.T0_NS + k * lw.LIDAR_DT
                if k == 3:
                    msg = lw.restamp(store, msg, stamp + YEAR_NS)
                if k == 9:
                    msg = lw.restamp(store, msg, stamp - 10**9)
                k += 1
            yield name, msgtype, t, msg

    path = lw.write_log(tmp_path, "mcap-ros2", edit)
    # Re-sorted within four scans: the last one's stamp is further back than that.
    with open_log(path, IngestConfig(reorder_depth=4)) as src:
        stamps = [c.stamp_ns for c in src.clouds()]
        assert len(stamps) == lw.LIDAR_N - 2
        assert np.all(np.diff(stamps) > 0)
        (warning,) = [w for w in src.warnings if "/lidar/points: dropped" in w]
        assert "1 whose header stamp jumped" in warning and "1 stamped at or before" in warning


def test_repeated_imu_stamps_are_kept_once(tmp_path: Path) -> None:
    def edit(store: Any, items: list[lw.Item]) -> Iterable[lw.Item]:
        k = 0
        for name, msgtype, t, msg in items:
            if name == "/imu/data":
                if k % 10 == 5:  # a driver that sends every tenth sample twice
                    yield name, msgtype, t, msg
                k += 1
            yield name, msgtype, t, msg

    path = lw.write_log(tmp_path, "mcap-ros2", edit)
    with open_log(path) as src:
        imu = src.imu()
        assert imu is not None and len(imu) == lw.IMU_N
        assert np.all(np.diff(imu.stamp_ns) > 0)
        assert any("dropped 10 messages stamped like the one before them" in w for w in src.warnings)


# ----- the simulated tiny log, its barometer only -----------------------------------------------


@pytest.fixture(scope="module")
def tiny_baro(sim_run: Callable[..., Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """tiny's barometer stream alone (two floors, one elevator ride at 44-49 s)."""
    from tests.logcopy import copy_log

    src = sim_run("tiny") / "log.mcap"
    out = tmp_path_factory.mktemp("baro") / "baro.mcap"
    copy_log(src, out, {"/lidar/points", "/imu/data", "/odom", "/tf_static"})
    return out


def _floors(log: Path, limit_gb: float = 3.0) -> subprocess.CompletedProcess[str]:
    """`mfmap floors LOG --json` in a process that may not map more than limit_gb."""

    def limit() -> None:
        size = int(limit_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (size, size))

    return subprocess.run([sys.executable, "-m", "mfmap.cli", "floors", str(log), "--json"],
                          capture_output=True, text=True, timeout=300, preexec_fn=limit)


def test_floors_with_a_barometer_stamp_a_year_ahead(tiny_baro: Path, tmp_path: Path) -> None:
    """Once 12 GB and no end; now the same floors as the clean log, in bounded memory."""
    import json

    from tests.logcopy import edit_log, shifted

    clean = json.loads(_floors(tiny_baro).stdout)
    bad = tmp_path / "jump.mcap"
    start = min(f["visits"][0][0] for f in clean["floors"])
    moved = {"done": False}

    def once(log_time: int) -> bool:
        if not moved["done"] and log_time > (start + 40.0) * 1e9:
            moved["done"] = True
            return True
        return False

    edit_log(tiny_baro, bad, shifted({"/baro/pressure"}, YEAR_NS, once))
    result = _floors(bad)
    assert result.returncode == 0, result.stderr
    floors = json.loads(result.stdout)
    assert len(floors["floors"]) == len(clean["floors"]) == 2
    for a, b in zip(floors["floors"], clean["floors"], strict=True):
        assert a["elevation_m"] == pytest.approx(b["elevation_m"], abs=0.1)
    assert "dropped 1 of 2150 messages" in result.stderr


def test_floors_with_a_clock_set_back_warns_how_many_it_dropped(tiny_baro: Path, tmp_path: Path) -> None:
    """The clock set back 10 s at 40 s: once 250 of the 2150 samples vanished without a word.
    Now they are dropped with a warning that counts them, and the two floors stay."""
    import json

    from tests.logcopy import edit_log, shifted

    clean = json.loads(_floors(tiny_baro).stdout)
    start_ns = int(min(f["visits"][0][0] for f in clean["floors"]) * 1e9)
    bad = tmp_path / "back.mcap"
    edit_log(tiny_baro, bad, shifted({"/baro/pressure"}, -10 * S, lambda t: t > start_ns + 40 * S))
    result = _floors(bad)
    assert result.returncode == 0, result.stderr
    floors = json.loads(result.stdout)
    assert [f["id"] for f in floors["floors"]] == [0, 1]
    assert floors["floors"][1]["elevation_m"] == pytest.approx(clean["floors"][1]["elevation_m"], abs=0.1)
    warning = " ".join(result.stderr.split())
    assert "1 step(s) back in time); dropped 250 of 2150 messages" in warning, warning


def test_a_clock_set_back_a_little_gives_strictly_increasing_series(tmp_path: Path) -> None:
    """The clock set back 0.2 s halfway (below the jitter the check leaves alone): the repeated
    stamps (the IMU's and odometry's grids meet again) are kept once, so the interpolators
    downstream get strictly increasing times (once 'Times must be in strictly increasing order'
    from a worker)."""
    back = 200_000_000

    def edit(store: Any, items: list[lw.Item]) -> Iterable[lw.Item]:
        for name, msgtype, t, msg in items:
            if name in ("/imu/data", "/odom") and t >= lw.T0_NS + 500_000_000:
                t -= back
                msg = lw.restamp(store, msg, t)
            yield name, msgtype, t, msg

    path = lw.write_log(tmp_path, "mcap-ros2", edit)
    with open_log(path) as src:
        imu, odom = src.imu(), src.odometry()
        assert imu is not None and odom is not None
        for series in (imu, odom):
            assert np.all(np.diff(series.stamp_ns) > 0)
        assert len(imu) == lw.IMU_N - 20 and len(odom) == lw.ODOM_N - 4
        assert sum("stamped like the one before them" in w for w in src.warnings) == 2
