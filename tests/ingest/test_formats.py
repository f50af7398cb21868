"""The same small log written by every real writer reads back identically.

Formats: MCAP with ROS 2 CDR and ROS 1 encodings (mcap Writer), ROS 1 bags with no/bz2/lz4
compression and ROS 2 bags with sqlite3 and mcap storage (rosbags Writers).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import ingest_logwriter as lw
import numpy as np
import pytest

from mfmap.ingest import describe_log, open_log
from mfmap.ingest.config import IngestConfig
from mfmap.types import Role

FORMAT_NAME = {"mcap": "mcap", "ros1": "ros1", "ros2": "ros2"}

LogPath = Callable[[str], Path]


@pytest.fixture(params=lw.FORMATS)
def log(request: pytest.FixtureRequest, written_log: LogPath) -> tuple[str, Path]:
    return request.param, written_log(request.param)


def test_topics_counts_types_and_times(log: tuple[str, Path]) -> None:
    fmt, path = log
    with open_log(path) as src:
        assert src.format == fmt.split("-")[0]
        assert {t.name: t.count for t in src.topics} == lw.EXPECTED.counts
        types = {t.name: t.msgtype for t in src.topics}
        assert types["/lidar/points"] == "sensor_msgs/msg/PointCloud2"
        assert types["/tf_static"] == "tf2_msgs/msg/TFMessage"
        # Log times: tf_static is logged 1 ms before T0, the last barometer sample ends the log.
        assert src.start_ns == lw.T0_NS - 1_000_000
        assert src.end_ns == lw.T0_NS + (lw.BARO_N - 1) * lw.BARO_DT
        lidar = next(t for t in src.topics if t.name == "/lidar/points")
        assert lidar.first_ns == lw.T0_NS + lw.LIDAR_LATENCY_NS
        assert lidar.last_ns == lw.T0_NS + (lw.LIDAR_N - 1) * lw.LIDAR_DT + lw.LIDAR_LATENCY_NS
        assert lidar.rate_hz == pytest.approx(10.0)


def test_roles_by_type_and_most_messages(log: tuple[str, Path]) -> None:
    _, path = log
    with open_log(path) as src:
        assert src.roles == {
            Role.LIDAR: "/lidar/points",
            Role.SCAN2D: "/scan",
            Role.BARO: "/baro/pressure",
            Role.IMU: "/imu/data",
            Role.ODOM: "/odom",
            Role.TF_STATIC: "/tf_static",
        }
        second = next(t for t in src.topics if t.name == "/lidar2/points")
        assert second.role is None and second.candidate_for == Role.LIDAR
        assert sum("/lidar2/points (3 msgs)" in w for w in src.warnings) == 1
        assert src.count(Role.LIDAR) == lw.LIDAR_N
        assert src.count(Role.SCAN2D) == lw.SCAN_N


def test_config_override_wins(log: tuple[str, Path]) -> None:
    _, path = log
    with open_log(path, IngestConfig(topics={"lidar": "/lidar2/points"})) as src:
        assert src.roles[Role.LIDAR] == "/lidar2/points"
        assert src.count(Role.LIDAR) == lw.LIDAR2_N
        stamps = [c.stamp_ns for c in src.clouds()]
        assert stamps == [lw.T0_NS + k * 300_000_000 + 1 for k in range(lw.LIDAR2_N)]
        assert not any("candidate" in w for w in src.warnings)


def test_clouds_decoded_exactly(log: tuple[str, Path]) -> None:
    _, path = log
    with open_log(path) as src:
        clouds = list(src.clouds())
    assert len(clouds) == lw.LIDAR_N
    n = lw.ROWS * lw.COLS
    keep = np.arange(lw.NAN_PER_SCAN, n)
    for k, cloud in enumerate(clouds):
        # Header stamps, not the log times 105 ms later.
        assert cloud.stamp_ns == lw.T0_NS + k * lw.LIDAR_DT
        assert cloud.frame_id == "lidar"
        assert cloud.xyz.dtype == np.float32 and cloud.xyz.shape == (n - lw.NAN_PER_SCAN, 3)
        np.testing.assert_array_equal(cloud.xyz, lw.lidar_points(k)[keep])
        assert cloud.intensity is not None and cloud.ring is not None
        np.testing.assert_array_equal(cloud.intensity, keep.astype(np.float32) + 100 * k)
        np.testing.assert_array_equal(cloud.ring, keep // lw.COLS)
        assert cloud.t_offset_ns is not None
        np.testing.assert_array_equal(cloud.t_offset_ns, lw.point_time_ns(keep))


def test_time_window_is_inclusive_on_header_stamps(log: tuple[str, Path]) -> None:
    _, path = log
    with open_log(path) as src:
        lo, hi = lw.T0_NS + 2 * lw.LIDAR_DT, lw.T0_NS + 5 * lw.LIDAR_DT
        stamps = [c.stamp_ns for c in src.clouds(lo, hi)]
        assert stamps == [lw.T0_NS + k * lw.LIDAR_DT for k in range(2, 6)]
        assert len(list(src.messages(Role.IMU, lw.T0_NS, lw.T0_NS + 99 * lw.IMU_DT))) == 100
        assert len(list(src.messages("/imu/data", lw.T0_NS + 10 * lw.IMU_DT, None))) == 90


def _spy(src: Any, seen: list[str]) -> None:
    """Record the topic of every message the backend reads (whichever parser decodes it)."""
    real = src._backend.iter_raw

    def spy(*args: Any, **kwargs: Any) -> Any:
        for message in real(*args, **kwargs):
            seen.append(message.topic)
            yield message

    src._backend.iter_raw = spy


def test_small_streams_in_one_pass_and_one_role_alone(log: tuple[str, Path]) -> None:
    _, path = log
    seen: list[str] = []
    with open_log(path) as src:
        _spy(src, seen)
        src.pressure()
        # Barometer, IMU, odometry and tf_static come in one pass; never a lidar or laser scan.
        small = {"/baro/pressure": lw.BARO_N, "/imu/data": lw.IMU_N, "/odom": lw.ODOM_N, "/tf_static": 1}
        assert {t: seen.count(t) for t in set(seen)} == small
        src.imu()
        src.odometry()
        assert len(seen) == sum(small.values())  # no second pass
    # A time window is read as a log-time window (widened by window_margin_s, 0 here).
    seen.clear()
    with open_log(path, IngestConfig(window_margin_s=0.0)) as src:
        _spy(src, seen)
        assert len(list(src.messages(Role.IMU, lw.T0_NS, lw.T0_NS + 9 * lw.IMU_DT))) == 10
        assert set(seen) == {"/imu/data"} and len(seen) == 10


def test_small_series(log: tuple[str, Path]) -> None:
    _, path = log
    with open_log(path) as src:
        baro = src.pressure()
        imu = src.imu()
        odom = src.odometry()
    np.testing.assert_array_equal(baro.stamp_ns, lw.T0_NS + np.arange(lw.BARO_N) * lw.BARO_DT)
    np.testing.assert_array_equal(baro.pressure_pa, [lw.pressure_pa(i) for i in range(lw.BARO_N)])
    assert baro.frame_id == "baro"
    assert imu is not None and len(imu) == lw.IMU_N
    np.testing.assert_allclose(imu.gyro_rad_s[:, 0], 0.01 * np.arange(lw.IMU_N))
    np.testing.assert_array_equal(imu.accel_m_s2[:, 2], np.full(lw.IMU_N, 9.81))
    # Odd samples say "no orientation" (covariance[0] = -1): NaN rows.
    assert np.isnan(imu.orientation_xyzw[1::2]).all()
    np.testing.assert_array_equal(imu.orientation_xyzw[::2], np.tile([0, 0, 0, 1.0], (50, 1)))
    assert odom is not None and len(odom) == lw.ODOM_N
    np.testing.assert_allclose(odom.xyz[:, 0], 0.05 * np.arange(lw.ODOM_N))
    np.testing.assert_array_equal(odom.linear_m_s[:, 0], np.ones(lw.ODOM_N))
    assert odom.child_frame_id == "base_link"


def test_extrinsics_from_tf_static(log: tuple[str, Path]) -> None:
    _, path = log
    with open_log(path) as src:
        ext = src.extrinsics()
        warnings = list(src.warnings)
    lidar = ext.get("lidar")
    assert lidar is not None
    np.testing.assert_allclose(lidar[:3, 3], lw.TF_LIDAR_XYZ)
    # 90 degrees about z: the lidar's x axis is the base's y axis.
    np.testing.assert_allclose(lidar[:3, :3] @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-12)
    imu = ext.get("imu")
    assert imu is not None
    np.testing.assert_allclose(imu[:3, 3], [0, 0, 0.2])
    # The barometer's frame is not in /tf_static: identity (its offset only shifts every
    # pressure alike) and a warning; the 2D laser's is not either, but with a 3D lidar in the
    # log the laser is not used, so it needs none.
    np.testing.assert_array_equal(ext.get("baro"), np.eye(4))
    assert sum("frame 'baro' (baro)" in w for w in warnings) == 1
    assert not any("laser" in w for w in warnings)


def test_laser_scans(log: tuple[str, Path]) -> None:
    _, path = log
    with open_log(path) as src:
        scans = list(src.scans2d())
    assert [s.stamp_ns for s in scans] == [lw.T0_NS + i * lw.SCAN_DT for i in range(lw.SCAN_N)]
    # ranges 1, nan, 2, inf, 50 (> max 30), 0.01 (< min 0.1), 3, 4 at 45 degree steps.
    r = np.array([1.0, 2.0, 3.0, 4.0])
    a = np.array([0, 2, 6, 7]) * math.pi / 4
    for s in scans:
        np.testing.assert_allclose(s.xy, np.stack([r * np.cos(a), r * np.sin(a)], 1), atol=1e-6)
        assert s.t_offset_ns is not None
        np.testing.assert_array_equal(s.t_offset_ns, [0, 2_000_000, 6_000_000, 7_000_000])


def test_describe_log_json(log: tuple[str, Path]) -> None:
    fmt, path = log
    summary = describe_log(path)
    doc = summary.to_json()
    assert doc["format"] == fmt.split("-")[0]
    assert doc["message_count"] == sum(lw.EXPECTED.counts.values())
    assert doc["duration_s"] == pytest.approx(((lw.BARO_N - 1) * lw.BARO_DT + 1_000_000) / 1e9)
    by_name = {t["name"]: t for t in doc["topics"]}
    assert by_name["/lidar2/points"]["role"] is None
    assert by_name["/lidar2/points"]["candidate_for"] == "lidar"
    assert by_name["/baro/pressure"]["rate_hz"] == pytest.approx(25.0)
    assert doc["roles"]["baro"] == "/baro/pressure"
