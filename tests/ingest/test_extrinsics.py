"""Sensor extrinsics: a missing transform stops with one line and two ways out; the config's
transforms fill it; ROS 1 static transforms on /tf are used; what a build does not need warns."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

import room_log as room

from mfmap.errors import MissingDataError
from mfmap.ingest import describe_log, open_log
from mfmap.ingest.config import ExtrinsicConfig, IngestConfig
from pipelines.relayout import Options, relayout

SCANS = 10


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Path]:
    cache: dict[str, Path] = {}

    def get(fmt: str) -> Path:
        if fmt not in cache:
            cache[fmt] = room.write(tmp_path_factory.mktemp(f"room-{fmt}"), fmt, SCANS)
        return cache[fmt]

    return get


def _lidar_mount() -> np.ndarray:
    pose = np.eye(4)
    c, s = math.cos(room.LIDAR_YAW), math.sin(room.LIDAR_YAW)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:3, 3] = room.LIDAR_XYZ
    return pose


def test_missing_lidar_transform_is_one_line_naming_both_ways_out(
    source: Callable[[str], Path], tmp_path: Path
) -> None:
    log = relayout(source("mcap"), tmp_path / "notf.mcap", Options("ouster", drop_transform=True)).out
    with open_log(log) as src, pytest.raises(MissingDataError) as err:
        src.extrinsics()
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{log}: no transform from 'base_link' to frame 'lidar' (lidar)")
    assert "ingest.extrinsics" in message and "--assume-identity-extrinsics" in message
    assert "frames there: baro, imu" in message
    # `mfmap info --check` says the same and marks the frame.
    summary = describe_log(log, check=True)
    assert [p for p in summary.problems if "frame 'lidar'" in p]
    lidar = next(s for s in summary.sensors if s["role"] == "lidar")
    assert lidar["transform"] == "missing"
    # The config's transform (tf2's roll, pitch, yaw in degrees) gives the original's pose.
    given = IngestConfig(extrinsics={"lidar": ExtrinsicConfig(
        parent="base_link", xyz=room.LIDAR_XYZ, rpy_deg=(0.0, 0.0, math.degrees(room.LIDAR_YAW)))})
    with open_log(log, given) as src:
        pose = src.extrinsics().get("lidar")
        assert pose is not None
        np.testing.assert_allclose(pose, _lidar_mount(), atol=1e-12)
        assert src.report()["frames"]["lidar"] == "config"
        assert not src.warnings
    # Or identity, said so.
    with open_log(log, IngestConfig(assume_identity_extrinsics=True)) as src:
        np.testing.assert_array_equal(src.extrinsics().get("lidar"), np.eye(4))
        assert sum("--assume-identity-extrinsics" in w and "'lidar'" in w for w in src.warnings) == 1


def test_config_transform_wins_over_the_logs(source: Callable[[str], Path]) -> None:
    given = IngestConfig(extrinsics={"lidar": ExtrinsicConfig(parent="imu", xyz=(0.0, 0.0, 1.0))})
    with open_log(source("mcap"), given) as src:
        pose = src.extrinsics().get("lidar")
    assert pose is not None
    # Under the IMU (0, 0.05, 0.2) in the base, 1 m up.
    np.testing.assert_allclose(pose[:3, 3], [0.0, 0.05, 1.2], atol=1e-12)


@pytest.mark.parametrize("fmt", ["ros1", "mcap"])
def test_static_transforms_on_tf_are_used(source: Callable[[str], Path], tmp_path: Path, fmt: str) -> None:
    """A ROS 1 static_transform_publisher: the same transforms on /tf at 10 Hz, no /tf_static."""
    out = tmp_path / ("tf.bag" if fmt == "ros1" else "tf.mcap")
    log = relayout(source(fmt), out, Options("ouster", tf_on_tf=True)).out
    with open_log(log) as src:
        assert "tf_static" not in {r.value for r in src.roles}
        pose = src.extrinsics().get("lidar")
        frames = src.report()["frames"]
    assert pose is not None
    np.testing.assert_allclose(pose, _lidar_mount(), atol=1e-9)
    assert frames["lidar"] == "/tf (constant)"


def test_a_moving_transform_on_tf_is_not_an_extrinsic(tmp_path: Path) -> None:
    """odom -> base_link changes on /tf: not static; a sensor hanging only under it is missing."""
    from mfmap.sim.writers import LogWriter

    with LogWriter(tmp_path, "ros1") as w:
        T = w.types
        w.add_topic("/tf", "tf2_msgs/msg/TFMessage")
        w.add_topic("/imu/data", "sensor_msgs/msg/Imu")
        vec, quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
        for i in range(20):
            stamp = room.T0_NS + i * 50_000_000

            def tf(parent: str, child: str, x: float, stamp: int = stamp) -> object:
                return T["geometry_msgs/msg/TransformStamped"](
                    header=w.header(stamp, parent, "/tf"), child_frame_id=child,
                    transform=T["geometry_msgs/msg/Transform"](translation=vec(x=x, y=0.0, z=0.0),
                                                               rotation=quat(x=0.0, y=0.0, z=0.0, w=1.0)))

            w.write("/tf", stamp, T["tf2_msgs/msg/TFMessage"](transforms=[
                tf("odom", "base_link", 0.01 * i), tf("odom", "imu", 0.3)]))
            cov = np.zeros(9)
            w.write("/imu/data", stamp, T["sensor_msgs/msg/Imu"](
                header=w.header(stamp, "imu", "/imu/data"), orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=cov, angular_velocity=vec(x=0.0, y=0.0, z=0.0),
                angular_velocity_covariance=cov, linear_acceleration=vec(x=0.0, y=0.0, z=9.81),
                linear_acceleration_covariance=cov))
    with open_log(tmp_path / "log.bag") as src, pytest.raises(MissingDataError) as err:
        src.extrinsics()
    assert "frame 'imu' (imu)" in str(err.value) and "odom->base_link moves on /tf" in str(err.value)


def test_frames_a_build_can_do_without_only_warn(tmp_path: Path) -> None:
    """A barometer frame outside the tree shifts every pressure alike: a warning, not a stop."""
    from mfmap.sim.writers import LogWriter

    with LogWriter(tmp_path, "mcap") as w:
        T = w.types
        w.add_topic("/baro/pressure", "sensor_msgs/msg/FluidPressure")
        for i in range(5):
            stamp = room.T0_NS + i * 40_000_000
            w.write("/baro/pressure", stamp, T["sensor_msgs/msg/FluidPressure"](
                header=w.header(stamp, "baro_link", "/baro/pressure"), fluid_pressure=101_000.0,
                variance=1.0))
    with open_log(tmp_path / "log.mcap") as src:
        np.testing.assert_array_equal(src.extrinsics().get("baro_link"), np.eye(4))
        assert sum("frame 'baro_link' (baro)" in w for w in src.warnings) == 1


def test_info_check_exits_non_zero_when_a_build_would_not_be_right(
    source: Callable[[str], Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from typer.testing import CliRunner

    from mfmap import cli
    from mfmap.cli import app

    # The console's width is fixed when mfmap.cli is imported (by COLUMNS, if set then): wide
    # enough here for the table's cells whatever the length of the temporary folder's path.
    monkeypatch.setattr(cli.console, "width", 250)
    good = CliRunner().invoke(app, ["info", "--check", str(source("mcap"))])
    assert good.exit_code == 0, good.output
    assert "per-point time" in good.stdout and "/tf_static" in good.stdout
    log = relayout(source("mcap"), tmp_path / "notf.mcap", Options("ouster", drop_transform=True)).out
    bad = CliRunner().invoke(app, ["info", "--check", str(log)])
    assert bad.exit_code == 1
    assert "no transform from 'base_link' to frame 'lidar'" in " ".join(bad.stderr.split())
    assert "missing" in bad.stdout
    # Without --check the same is shown, and the exit is 0; with the flag the build would go on.
    assert CliRunner().invoke(app, ["info", str(log)]).exit_code == 0
    assert CliRunner().invoke(app, ["info", "--check", "--assume-identity-extrinsics", str(log)]).exit_code == 0
