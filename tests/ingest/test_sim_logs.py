"""The simulator's logs (written by mcap, rosbag1 and rosbag2 writers) read identically."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mfmap.ingest import open_log
from mfmap.types import Role

LOG_NAME = {"mcap": "log.mcap", "ros1": "log.bag", "ros2": "log"}


def test_tiny_scenario_same_in_every_format(sim_run: Callable[..., Path]) -> None:
    seen: dict[str, Any] = {}
    for fmt in ("mcap", "ros1", "ros2"):
        with open_log(sim_run("tiny", fmt=fmt) / LOG_NAME[fmt]) as src:
            assert src.format == fmt
            assert set(src.roles) >= {Role.LIDAR, Role.BARO, Role.IMU, Role.ODOM, Role.TF_STATIC}
            counts = {t.name: t.count for t in src.topics}
            clouds = src.clouds()
            first = next(clouds)
            n_clouds = 1 + sum(1 for _ in clouds)
            baro = src.pressure()
            ext = src.extrinsics()
            seen[fmt] = (counts, first, n_clouds, baro, ext, src.start_ns, src.end_ns)
    ref = seen["mcap"]
    assert ref[2] == ref[0]["/lidar/points"] > 0
    for fmt in ("ros1", "ros2"):
        counts, first, n_clouds, baro, ext, start, end = seen[fmt]
        assert counts == ref[0] and n_clouds == ref[2] and (start, end) == (ref[5], ref[6])
        assert first.stamp_ns == ref[1].stamp_ns
        np.testing.assert_array_equal(first.xyz, ref[1].xyz)
        np.testing.assert_array_equal(baro.pressure_pa, ref[3].pressure_pa)
        np.testing.assert_array_equal(baro.stamp_ns, ref[3].stamp_ns)
        lidar = ext.get(first.frame_id)
        assert lidar is not None
        np.testing.assert_array_equal(lidar, ref[4].get(first.frame_id))
