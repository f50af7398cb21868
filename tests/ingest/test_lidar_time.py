"""How a time field reads, decided from its values against the header stamps and the period.

Every reading (relative or absolute; s, ms, us or ns) in every numeric type drivers use, with
the header stamp at the sweep's start or end; fields that carry no time; values no reading fits;
the config settling what the data cannot. And the azimuth of a lidar without time.
"""

from __future__ import annotations

import math
from fractions import Fraction
from typing import Any

import numpy as np
import pytest

from mfmap.errors import DecodeError
from mfmap.ingest.config import LidarTimeConfig
from mfmap.ingest.lidartime import (
    UNIT_NS,
    TimeSample,
    decide_azimuth,
    decide_time,
    scan_period_ns,
)

T0_NS = 1_714_986_000_123_456_789
PERIOD_NS = 100_000_000
COLUMNS = 256
COLUMN_NS = 390_625  # 256 columns of a 10 Hz sweep


def _true_offsets(k: int) -> np.ndarray[Any, Any]:
    """The true time of each point from its sweep's start: 4 rings per column (Velodyne's
    firing order), a few nanoseconds of jitter per scan."""
    return np.repeat(np.arange(COLUMNS, dtype=np.int64) * COLUMN_NS + 7 * k, 4)


def _samples(dtype: str, unit: str, reference: str, stamp_at: str, n: int = 8,
             latency_ns: int = 0) -> tuple[list[TimeSample], list[np.ndarray[Any, Any]]]:
    """Scans as a driver would publish them: the values of the time field, and what mfmap must
    decode from them (the true offset from the header stamp, rounded to what the type holds)."""
    samples, truth = [], []
    factor = UNIT_NS[unit]
    for k in range(n):
        start = T0_NS + k * PERIOD_NS
        t = _true_offsets(k)
        last = int(t.max())
        stamp = start + last if stamp_at == "end" else start
        absolute_ns = start + t
        if reference == "absolute":
            exact = [Fraction(int(a), factor) for a in absolute_ns]
        else:
            exact = [Fraction(int(a - stamp), factor) for a in absolute_ns]
        values = np.array([float(v) for v in exact]) if dtype.startswith("float") else np.array(
            [round(v) for v in exact], dtype=np.int64)
        values = values.astype(dtype)
        # What the field holds, as an offset from the stamp in whole ns.
        held = [Fraction(v.item()) if dtype.startswith("float") else Fraction(int(v)) for v in values]
        want = np.array([round(h * factor - (stamp if reference == "absolute" else 0)) for h in held],
                        dtype=np.int64)
        samples.append(TimeSample(stamp, stamp + (PERIOD_NS if stamp_at == "start" else 0) + latency_ns,
                                  values))
        truth.append(want)
    return samples, truth


READINGS = [
    # Ouster: uint32 ns from the stamp at the sweep's start.
    ("uint32", "ns", "relative", "start"),
    # Velodyne ROS 1: float32 s from a stamp at the sweep's end (values <= 0).
    ("float32", "s", "relative", "end"),
    # Velodyne ROS 2 / some forks: float32 s from the sweep's start.
    ("float32", "s", "relative", "start"),
    ("float64", "ms", "relative", "start"),
    ("uint32", "us", "relative", "start"),
    # Hesai: float64 epoch seconds, stamp at the start; Robosense: at the end.
    ("float64", "s", "absolute", "start"),
    ("float64", "s", "absolute", "end"),
    # Livox (xfer_format 0): float64 holding epoch nanoseconds.
    ("float64", "ns", "absolute", "start"),
    # uint64 and int64 epoch ns (only 64-bit integers hold them); float64 epoch ms and us.
    ("uint64", "ns", "absolute", "end"),
    ("int64", "ns", "absolute", "start"),
    ("float64", "ms", "absolute", "start"),
    ("float64", "us", "absolute", "start"),
]


@pytest.mark.parametrize(("dtype", "unit", "reference", "stamp_at"), READINGS)
def test_each_reading_decided_and_decoded_exactly(dtype: str, unit: str, reference: str, stamp_at: str) -> None:
    samples, truth = _samples(dtype, unit, reference, stamp_at)
    spec = decide_time("timestamp", dtype, samples, PERIOD_NS, LidarTimeConfig(), "log.mcap topic /points")
    assert spec is not None
    assert (spec.unit, spec.reference, spec.stamp, spec.shift_ns) == (unit, reference, stamp_at, 0)
    for s, want in zip(samples, truth, strict=True):
        np.testing.assert_array_equal(spec.offsets_ns(s.values, s.stamp_ns), want)


def test_relative_from_the_sweep_start_with_a_stamp_at_its_end() -> None:
    """Values counted from the sweep's start (0 .. 0.1 s) while the header stamps its end: the
    recorder logged each scan 2 ms after its stamp, before a sweep counted from the stamp could
    have ended, so the stamp is the end."""
    samples, _ = _samples("float32", "s", "relative", "start", latency_ns=0)
    late = [TimeSample(s.stamp_ns + int(COLUMN_NS * (COLUMNS - 1)), s.stamp_ns + int(COLUMN_NS * (COLUMNS - 1)) + 2_000_000,
                       s.values) for s in samples]
    spec = decide_time("time", "float32", late, PERIOD_NS, LidarTimeConfig(), "x")
    assert spec is not None and spec.stamp == "end" and "recorder" in spec.decided
    offsets = spec.offsets_ns(late[0].values, late[0].stamp_ns)
    # From the median sweep of the sampled scans (their last points jitter by a few ns).
    assert abs(int(offsets.max())) <= 100 and abs(int(offsets.min()) + COLUMN_NS * (COLUMNS - 1)) <= 100
    # Logged a sweep after the stamp, as a start-stamped driver publishes: no shift.
    samples, _ = _samples("float32", "s", "relative", "start", latency_ns=3_000_000)
    spec = decide_time("time", "float32", samples, PERIOD_NS, LidarTimeConfig(), "x")
    assert spec is not None and spec.shift_ns == 0 and spec.stamp == "start"
    # The config says so where the log cannot (log times equal to the stamps).
    samples, _ = _samples("float32", "s", "relative", "start")
    equal = [TimeSample(s.stamp_ns, s.stamp_ns, s.values) for s in samples]
    spec = decide_time("time", "float32", equal, PERIOD_NS, LidarTimeConfig(stamp="end"), "x")
    assert spec is not None and spec.stamp == "end"
    assert abs(spec.shift_ns + COLUMN_NS * (COLUMNS - 1)) <= 100


def test_a_field_the_same_everywhere_is_no_time() -> None:
    samples = [TimeSample(T0_NS + k * PERIOD_NS, 0, np.zeros(1000, np.float32)) for k in range(5)]
    assert decide_time("time", "float32", samples, PERIOD_NS, LidarTimeConfig(), "x") is None


def test_values_no_reading_fits_name_the_field_and_the_config_key() -> None:
    # Microseconds since the lidar booted (its own clock): neither relative nor absolute.
    samples = [TimeSample(T0_NS + k * PERIOD_NS, 0,
                          (3.2e11 + k * 1e5 + _true_offsets(k) / 1e3).astype(np.float64)) for k in range(5)]
    with pytest.raises(DecodeError) as err:
        decide_time("timestamp", "float64", samples, PERIOD_NS, LidarTimeConfig(), "run.mcap topic /points")
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith("run.mcap topic /points: per-point time field 'timestamp' (float64)")
    assert "ingest.lidar_time" in message and "fit no reading" in message
    # The config's reading is taken as it is.
    spec = decide_time("timestamp", "float64", samples, PERIOD_NS,
                       LidarTimeConfig(unit="us", reference="relative"), "x")
    assert spec is not None and spec.decided == "config"


def test_the_unit_is_the_one_that_makes_a_scan_last_a_period() -> None:
    # The same uint32 values read as ns at 10 Hz: 0.1 s; at 10 mHz (a stamp every 100 s) as us.
    samples, _ = _samples("uint32", "ns", "relative", "start")
    assert decide_time("t", "uint32", samples, PERIOD_NS, LidarTimeConfig(), "x").unit == "ns"  # type: ignore[union-attr]
    slow = [TimeSample(T0_NS + k * 100 * 10**9, 0, s.values) for k, s in enumerate(samples)]
    assert decide_time("t", "uint32", slow, 100 * 10**9, LidarTimeConfig(), "x").unit == "us"  # type: ignore[union-attr]


def test_scan_period_from_stamps_ignores_dropped_scans() -> None:
    stamps = [T0_NS + k * PERIOD_NS for k in (0, 1, 2, 4, 5, 6, 9)]
    assert scan_period_ns(stamps, 1) == PERIOD_NS
    assert scan_period_ns([T0_NS], 7) == 7


def _sweep(direction: int, start_rad: float, columns: int = 720, rings: int = 4,
           organised_rows: bool = True, drop_first: int = 0) -> np.ndarray[Any, Any]:
    az = start_rad + direction * 2 * math.pi * np.arange(columns) / columns
    r = 5.0 + np.sin(3 * az)
    grid = np.stack([np.broadcast_to(r * np.cos(az), (rings, columns)),
                     np.broadcast_to(r * np.sin(az), (rings, columns)),
                     np.broadcast_to(np.linspace(-1, 1, rings)[:, None], (rings, columns))], axis=-1)
    grid = grid[:, drop_first:]
    if not organised_rows:
        grid = np.swapaxes(grid, 0, 1)
    return grid.reshape(-1, 3).astype(np.float32)


@pytest.mark.parametrize("organised_rows", [True, False], ids=["rings-x-columns", "firing-order"])
@pytest.mark.parametrize("direction", [1, -1], ids=["ccw", "cw"])
def test_azimuth_deskew_finds_spin_and_start(direction: int, organised_rows: bool) -> None:
    start = 2.5
    clouds = [(T0_NS + k * PERIOD_NS, 0, _sweep(direction, start, organised_rows=organised_rows,
                                                drop_first=k % 3)) for k in range(8)]
    spec, reason = decide_azimuth(clouds, PERIOD_NS, LidarTimeConfig())
    assert spec is not None, reason
    assert spec.direction == direction
    assert spec.start_rad is not None and abs(spec.start_rad - start) < 1e-5
    # A scan missing its first columns still times the others from the fixed start.
    xyz = _sweep(direction, start, organised_rows=organised_rows, drop_first=2)
    t = spec.offsets_ns(xyz)
    az = np.arctan2(xyz[:, 1].astype(np.float64), xyz[:, 0].astype(np.float64))
    frac = np.mod(direction * (az - start), 2 * math.pi) / (2 * math.pi)
    np.testing.assert_allclose(t, frac * PERIOD_NS, atol=100)
    assert int(t.min()) >= 2 * PERIOD_NS // 720 - 100


def test_non_repetitive_scan_has_no_sweep() -> None:
    """A Livox-like rosette: the azimuth runs back and forth, no spin to time points by."""
    rng = np.random.default_rng(0)
    clouds = []
    for k in range(6):
        s = np.linspace(0, 40 * math.pi, 5000) + k
        az = 0.6 * np.sin(s) * np.cos(0.3 * s + rng.uniform())
        xyz = np.stack([5 * np.cos(az), 5 * np.sin(az), 0.5 * np.sin(2 * s)], axis=1).astype(np.float32)
        clouds.append((T0_NS + k * PERIOD_NS, 0, xyz))
    spec, reason = decide_azimuth(clouds, PERIOD_NS, LidarTimeConfig())
    assert spec is None and "non-repetitive" in reason
