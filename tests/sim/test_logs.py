"""The logs read back by plain third-party readers (mcap + mcap_ros2, rosbags) and by mfmap info."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from simtest_helpers import iter_messages, load_floors, stamp_ns, tf_static

EXPECTED_TYPES = {
    "/lidar/points": "sensor_msgs/msg/PointCloud2",
    "/imu/data": "sensor_msgs/msg/Imu",
    "/odom": "nav_msgs/msg/Odometry",
    "/baro/pressure": "sensor_msgs/msg/FluidPressure",
    "/tf_static": "tf2_msgs/msg/TFMessage",
}
RATES = {"/lidar/points": 10, "/imu/data": 200, "/odom": 50, "/baro/pressure": 25}
TINY_DURATION_S = 86


@pytest.mark.parametrize("fmt", ["mcap", "ros1", "ros2"])
def test_topics_types_counts(sim_run: Callable[..., Path], fmt: str) -> None:
    folder = sim_run("tiny", fmt=fmt)
    counts: Counter[str] = Counter()
    types: dict[str, str] = {}
    last: dict[str, int] = {}
    header_lag: list[int] = []
    for topic, msgtype, log_ns, msg in iter_messages(folder, fmt):
        counts[topic] += 1
        types[topic] = msgtype.replace("/msg/", "/").replace("/", "/msg/", 1)
        assert log_ns >= last.get(topic, 0), f"{topic} out of order"
        last[topic] = log_ns
        if topic != "/tf_static":
            header_lag.append(log_ns - stamp_ns(msg))
    assert types == EXPECTED_TYPES
    floors = load_floors(folder)
    span_s = floors["floors"][-1]["visits"][-1][1] - floors["floors"][0]["visits"][0][0]
    assert span_s == pytest.approx(TINY_DURATION_S, abs=1e-6)  # the GT's time span
    # Exact counts: duration x rate, one static transform message.
    assert counts == {**{t: TINY_DURATION_S * r for t, r in RATES.items()}, "/tf_static": 1}
    assert set(header_lag) == {0}  # log time is the header stamp


def test_pointcloud_layout(tiny: Path) -> None:
    msg = next(m for _, _, _, m in iter_messages(tiny, "mcap", {"/lidar/points"}))
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (16, 512, 32, 32 * 512)
    assert msg.header.frame_id == "lidar"
    assert [(f.name, f.offset, f.datatype) for f in msg.fields] == [
        ("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("t", 20, 6), ("ring", 24, 4),
    ]  # fmt: skip
    assert not msg.is_dense and not msg.is_bigendian
    dt = np.dtype({"names": ["x", "t", "ring"], "formats": ["<f4", "<u4", "<u2"], "offsets": [0, 20, 24], "itemsize": 32})
    pts = np.frombuffer(bytes(msg.data), dtype=dt).reshape(16, 512)
    # Each column fires at its own time across the 100 ms sweep; rows are rings.
    assert np.all(pts["t"][:, 0] == 0) and np.all(pts["t"][:, -1] == 511 * 195312)
    assert np.all(np.diff(pts["t"].astype(np.int64), axis=1) == 195312)
    assert np.all(pts["ring"] == np.arange(16)[:, None])
    nan_share = float(np.isnan(pts["x"]).mean())
    assert 0.01 < nan_share < 0.15  # dropouts plus a few no-returns


def test_tf_static_and_epoch(tiny: Path) -> None:
    tf = tf_static(tiny, "mcap")
    assert set(tf) == {"lidar", "imu", "baro"}
    np.testing.assert_allclose(tf["lidar"][:3, 3], [0.1, 0.0, 0.5])
    np.testing.assert_allclose(tf["baro"][:3, 3], [-0.1, 0.05, 0.3])
    assert 1.0 - tf["lidar"][0, 0] > 1e-4  # the lidar is mounted slightly rotated
    start_ns = load_floors(tiny)["sim"]["start_ns"]
    assert 1_704_067_200e9 < start_ns < 1_767_225_600e9  # during 2024 or 2025


def test_mfmap_info_reads_the_log(tiny: Path) -> None:
    ingest = pytest.importorskip("mfmap.ingest")
    summary = ingest.describe_log(tiny / "log.mcap")
    counts = {t.name: t.count for t in summary.topics}
    assert counts == {**{t: TINY_DURATION_S * r for t, r in RATES.items()}, "/tf_static": 1}
    roles = {role.value: topic for role, topic in summary.roles.items()}
    assert roles["lidar"] == "/lidar/points" and roles["baro"] == "/baro/pressure"
    assert abs(summary.duration_s - (TINY_DURATION_S - 0.005)) < 0.01


def test_laserscan_variant(sim_run: Callable[..., Path]) -> None:
    folder = sim_run("tiny-2d", fmt="ros2")
    counts: Counter[str] = Counter()
    first = None
    for topic, _, _, msg in iter_messages(folder, "ros2"):
        counts[topic] += 1
        if topic == "/scan" and first is None:
            first = msg
    assert counts["/scan"] == TINY_DURATION_S * 15 and "/lidar/points" not in counts
    assert first is not None and len(first.ranges) == 720 and first.header.frame_id == "laser"
    assert abs(first.angle_increment * 720 - 2 * np.pi) < 1e-5
    ranges = np.asarray(first.ranges)
    assert np.isinf(ranges).mean() < 0.1 and np.nanmin(ranges) > 0.15
    assert set(tf_static(folder, "ros2")) == {"laser", "imu", "baro"}
