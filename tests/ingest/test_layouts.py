"""Every lidar driver's layout, written by the real writers, read back to the nanosecond.

A small room log (Ouster-like lidar, written by mcap's Writer and rosbags' rosbag1/rosbag2
Writers) is rewritten by `pipelines/relayout.py` into each layout; mfmap decides each time
field's reading from its values and must give every point's time from its scan's header stamp
exactly as the field holds it, and within the field type's resolution of the truth.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

import room_log as room

from mfmap.ingest import open_log
from mfmap.ingest.lidartime import AzimuthSpec, TimeSpec
from pipelines.relayout import Options, RelayoutError, _epoch_s, relayout

FORMATS = ["mcap", "ros1", "ros2"]
SCANS = 12
T_LAST = (room.COLUMNS - 1) * room.COLUMN_NS  # the sweep's last column


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Path]:
    cache: dict[str, Path] = {}

    def get(fmt: str) -> Path:
        if fmt not in cache:
            cache[fmt] = room.write(tmp_path_factory.mktemp(f"room-{fmt}"), fmt, SCANS)
        return cache[fmt]

    return get


def _out(tmp_path: Path, fmt: str) -> Path:
    return tmp_path / ("out" if fmt == "ros2" else f"out.{'bag' if fmt == 'ros1' else 'mcap'}")


def _truth(k: int, order: str) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    """Scan k's returns (lidar frame) and their times from the original stamp, in the order
    the layout stores them."""
    pts = room.scan_points(k)
    if order == "columns":
        pts = pts.T
    pts = pts.reshape(-1)
    keep = np.isfinite(pts["x"])
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)[keep]
    return xyz, pts["t"][keep].astype(np.int64)


# layout -> (storage order, header stamp after the original's, expected decoded offsets from the
# true times, the most the field's type lets a time be off the truth in ns)
def _exact_f32(t: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
    values = ((t - T_LAST) / 1e9).astype(np.float32)
    return np.array([round(Fraction(float(v)) * 10**9) for v in values], dtype=np.int64)


def _exact_epoch_s(stamp: int, t: np.ndarray[Any, Any], new_stamp: int) -> np.ndarray[Any, Any]:
    values = _epoch_s(stamp, t)
    return np.array([round(Fraction(float(v)) * 10**9) - new_stamp for v in values], dtype=np.int64)


CASES: dict[str, tuple[str, int, Callable[[int, np.ndarray[Any, Any], int], np.ndarray[Any, Any]], int]] = {
    "ouster": ("rows", 0, lambda s, t, n: t, 0),
    "velodyne": ("columns", T_LAST, lambda s, t, n: _exact_f32(t), 4),
    "hesai": ("columns", 0, _exact_epoch_s, 240),
    "robosense": ("columns", T_LAST, _exact_epoch_s, 240),
    "livox": ("columns", 0, lambda s, t, n: (s + t).astype(np.float64).astype(np.int64) - n, 128),
    "livox-custom": ("columns", 0, lambda s, t, n: t, 0),
}


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("layout", sorted(CASES))
def test_layout_time_offsets_to_the_nanosecond(
    source: Callable[[str], Path], tmp_path: Path, fmt: str, layout: str
) -> None:
    order, shift, expected_of, resolution_ns = CASES[layout]
    out = relayout(source(fmt), _out(tmp_path, fmt), Options(layout)).out
    with open_log(out) as src:
        timing = src.lidar_timing()
        clouds = list(src.clouds())
        assert not src.warnings
    assert isinstance(timing, TimeSpec) and timing.decided.startswith("data")
    assert timing.stamp == ("end" if shift else "start")
    # A scan stamped at its sweep's end is timed from the sweep's start, as one stamped there.
    start = timing.sweep_start_ns
    assert abs(start + shift) <= resolution_ns
    assert len(clouds) == SCANS
    for k, cloud in enumerate(clouds):
        stamp = room.T0_NS + k * room.PERIOD_NS
        assert cloud.stamp_ns == stamp + shift + start
        xyz, t_true = _truth(k, order)
        np.testing.assert_array_equal(cloud.xyz, xyz)
        assert cloud.t_offset_ns is not None and cloud.t_offset_ns.dtype == np.int64
        # Exactly what the field holds, relative to the header stamp ...
        np.testing.assert_array_equal(cloud.t_offset_ns + start,
                                      expected_of(stamp, t_true, stamp + shift))
        # ... which is the truth to the field type's resolution.
        err = np.abs(cloud.t_offset_ns + (cloud.stamp_ns - stamp) - t_true)
        assert int(err.max()) <= resolution_ns


@pytest.mark.parametrize("fmt", FORMATS)
def test_no_time_field_deskewed_by_azimuth(source: Callable[[str], Path], tmp_path: Path, fmt: str) -> None:
    """x y z intensity only: each point's time from its azimuth, the sweep's clockwise turn and
    its start behind the sensor found from the data (to the float32 azimuth's resolution)."""
    out = relayout(source(fmt), _out(tmp_path, fmt), Options("notime")).out
    with open_log(out) as src:
        timing = src.lidar_timing()
        clouds = list(src.clouds())
        warnings = list(src.warnings)
        report = src.report()
    assert isinstance(timing, AzimuthSpec) and timing.direction == -1
    assert timing.start_rad is not None and abs(abs(timing.start_rad) - np.pi) < 1e-4
    assert timing.period_ns == room.PERIOD_NS
    assert sum("no per-point time" in w and "azimuth" in w for w in warnings) == 1
    assert report["lidar"]["deskew"] == "azimuth"
    for k, cloud in enumerate(clouds):
        _, t_true = _truth(k, "rows")
        assert cloud.t_offset_ns is not None
        # Column c is fired at c * 390 625 ns; the azimuth gives c * period / columns.
        assert int(np.abs(cloud.t_offset_ns - t_true).max()) <= 200


def test_livox_custom_bytes_are_rosbags_bytes() -> None:
    """The fast CustomMsg serialiser writes what rosbags' own serialiser writes, both wires."""
    from pipelines.relayout import CUSTOM, Scan, _typestore, custom_bytes, custom_points

    pts = room.scan_points(3)
    valid = np.isfinite(pts["x"])
    scan = Scan(room.T0_NS, "livox_frame", np.stack([pts["x"], pts["y"], pts["z"]], -1), pts["intensity"],
                pts["ring"], pts["t"].astype(np.int64), valid)
    records = custom_points(scan)[:50]
    for ros1 in (False, True):
        store = _typestore(ros1)
        T = store.types
        point = T["livox_ros_driver2/msg/CustomPoint"]
        msg = T[CUSTOM](
            header=(T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](
                sec=room.T0_NS // 10**9, nanosec=room.T0_NS % 10**9), frame_id="livox_frame") if ros1
                else T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
                    sec=room.T0_NS // 10**9, nanosec=room.T0_NS % 10**9), frame_id="livox_frame")),
            timebase=room.T0_NS, point_num=len(records), lidar_id=0, rsvd=np.zeros(3, np.uint8),
            points=[point(offset_time=int(r["offset_time"]), x=float(r["x"]), y=float(r["y"]),
                          z=float(r["z"]), reflectivity=int(r["reflectivity"]), tag=int(r["tag"]),
                          line=int(r["line"])) for r in records])
        theirs = bytes(store.serialize_ros1(msg, CUSTOM) if ros1 else store.serialize_cdr(msg, CUSTOM))
        assert custom_bytes(store, ros1, room.T0_NS, "livox_frame", records) == theirs


def test_relayout_refuses_an_unorganised_source(source: Callable[[str], Path], tmp_path: Path) -> None:
    velodyne = relayout(source("mcap"), tmp_path / "v.mcap", Options("velodyne")).out
    with pytest.raises(RelayoutError, match="not organised"):
        relayout(velodyne, tmp_path / "again.mcap", Options("hesai"))
    with pytest.raises(RelayoutError, match="exists already"):
        relayout(source("mcap"), velodyne, Options("hesai"))
