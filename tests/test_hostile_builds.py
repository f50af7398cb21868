"""`mfmap build` on logs a real robot can give that no scan registration can map: refused in one
line before any work, never a traceback, an empty map or a grid too big to allocate."""

from __future__ import annotations

import copy
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mfmap.errors import MissingDataError
from mfmap.export.grid import GridBuilder
from tests.ingest import ingest_logwriter as lw


def _build(log: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mfmap.cli", "build", str(log), "-o", str(out)],
                          capture_output=True, text=True, timeout=300)


def _radar_cloud(store: Any, k: int, stamp_ns: int, rng: np.random.Generator) -> Any:
    """A sparse automotive radar's PointCloud2: some 40 detections per scan out to 150 m, with
    radar cross-section and Doppler velocity."""
    PointField = store.types["sensor_msgs/msg/PointField"]
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rcs", "<f4"), ("velocity", "<f4")])
    n = int(rng.integers(25, 55))
    arr = np.zeros(n, dtype=dt)
    r, az = rng.uniform(1.0, 150.0, n), rng.uniform(-0.8, 0.8, n)
    arr["x"], arr["y"], arr["z"] = r * np.cos(az), r * np.sin(az), rng.normal(0.0, 0.5, n)
    arr["rcs"], arr["velocity"] = rng.normal(5.0, 3.0, n), rng.normal(0.0, 2.0, n)
    fields = [PointField(name=name, offset=4 * i, datatype=7, count=1)
              for i, name in enumerate(dt.names or ())]
    return store.types["sensor_msgs/msg/PointCloud2"](
        header=lw._header(store, stamp_ns, "radar"), height=1, width=n, fields=fields,
        is_bigendian=False, point_step=dt.itemsize, row_step=dt.itemsize * n,
        data=np.frombuffer(arr.tobytes(), dtype=np.uint8), is_dense=True)


def test_a_sparse_radar_cloud_is_refused_in_one_line(tmp_path: Path) -> None:
    """A ROS 1 bag whose only cloud is a radar's once ran through mapping into
    export/grid.py's 'ValueError: array is too big'."""
    rng = np.random.default_rng(0)

    def radar(store: Any, items: list[lw.Item]) -> Iterable[lw.Item]:
        k = 0
        for topic, msgtype, t, msg in items:
            if topic == "/lidar2/points":
                continue
            if topic == "/lidar/points":
                topic, msg = "/radar/points", _radar_cloud(store, k, msg.header.stamp.sec * 10**9
                                                           + msg.header.stamp.nanosec, rng)
                k += 1
            yield topic, msgtype, t, msg

    bag = lw.write_log(tmp_path / "logs", "ros1-lz4", radar)
    res = _build(bag, tmp_path / "out")
    assert res.returncode == 1, res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert line.startswith(f"mfmap: error: {bag}: too few points per scan for lidar odometry: "
                           "the first 10 scans of /radar/points hold a median of"), line
    assert not (tmp_path / "out").exists() and list(tmp_path.iterdir()) == [tmp_path / "logs"]


def test_a_lidar_of_nothing_but_nan_is_refused_in_one_line(tmp_path: Path) -> None:
    """Every return NaN: once an empty map.ply, no grids, and a summary that listed grids."""

    def blind(store: Any, items: list[lw.Item]) -> Iterable[lw.Item]:
        for topic, msgtype, t, msg in items:
            if topic == "/lidar/points":
                msg = copy.copy(msg)
                data = np.array(msg.data, dtype=np.uint8).copy()
                points = data.view("<f4").reshape(msg.height * msg.width, -1)
                points[:, 3:6] = np.nan  # x, y, z at bytes 12-23 of each 32-byte point
                msg.data = data
            yield topic, msgtype, t, msg

    log = lw.write_log(tmp_path / "logs", "mcap-ros2", blind)
    res = _build(log, tmp_path / "out")
    assert res.returncode == 1, res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert "too few points per scan for lidar odometry" in line and "a median of 0 points" in line


def test_a_grid_too_big_for_memory_is_refused_before_it_is_allocated() -> None:
    """Obstacles 20 km apart at 5 cm cells would be 1.6e11 cells (the radar's flown-off map)."""
    builder = GridBuilder(0.05)
    builder.add_obstacles(np.array([[0.0, 0.0], [20_000.0, 20_000.0]]))
    with pytest.raises(MissingDataError, match=r"grid would be 400041 x 400041 cells .* over "
                                               r"export\.grid\.max_mb \(2048 MB\)"):
        builder.build()
