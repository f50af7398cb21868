"""IMU and barometer variety: no orientation, a rotated mount, hPa and kPa, and the barometer's
temperature on a topic of its own; and the 2D scanners' beam order against the gyro."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

import room_log as room

from mfmap.ingest import describe_log, open_log
from mfmap.ingest.config import IngestConfig
from mfmap.mapping.config import MotionPrior
from mfmap.mapping.motion import MotionModel, TrackState
from mfmap.types import Role
from pipelines.relayout import Options, relayout


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Callable[[int], Path]:
    cache: dict[int, Path] = {}

    def get(scans: int) -> Path:
        if scans not in cache:
            cache[scans] = room.write(tmp_path_factory.mktemp(f"room-{scans}"), "mcap", scans)
        return cache[scans]

    return get


def test_imu_without_orientation(source: Callable[[int], Path], tmp_path: Path) -> None:
    log = relayout(source(10), tmp_path / "o.mcap", Options("ouster", imu_no_orientation=True)).out
    with open_log(log) as src:
        imu = src.imu()
    assert imu is not None and np.isnan(imu.orientation_xyzw).all()
    # The gyro and accelerometer are read as ever.
    np.testing.assert_allclose(imu.accel_m_s2[:, 2], 9.81)
    imu_row = next(s for s in describe_log(log).sensors if s["role"] == "imu")
    assert "no orientation (covariance[0] = -1)" in imu_row["fields"]


def test_imu_mounted_rotated_predicts_the_same_motion(source: Callable[[int], Path], tmp_path: Path) -> None:
    """Upside down with x and y swapped, its mount in /tf_static: the motion prior in the base
    frame, and gravity in it, are those of the level IMU."""
    rotated = relayout(source(40), tmp_path / "r.mcap", Options("ouster", imu_rotated=True)).out
    out = []
    for log in (source(40), rotated):
        with open_log(log) as src:
            imu, ext = src.imu(), src.extrinsics()
            assert imu is not None
            to_base = ext.get(imu.frame_id)
            assert to_base is not None
            model = MotionModel(MotionPrior.IMU, None, imu, ext)
            state = TrackState(stamp_ns=room.T0_NS + 25 * room.PERIOD_NS)
            delta = model.predict(state, room.T0_NS + 27 * room.PERIOD_NS)
            out.append((delta[:3, :3], imu.accel_m_s2 @ to_base[:3, :3].T))
    (level_turn, level_g), (turned_turn, turned_g) = out
    assert not np.allclose(level_turn, np.eye(3), atol=0.1)  # the robot turns there
    np.testing.assert_allclose(turned_turn, level_turn, atol=1e-9)
    np.testing.assert_allclose(turned_g, level_g, atol=1e-9)


@pytest.mark.parametrize(("unit", "scale"), [("hPa", 100.0), ("kPa", 1000.0)])
def test_barometer_in_hpa_or_kpa_detected_warned_converted(
    source: Callable[[int], Path], tmp_path: Path, unit: str, scale: float
) -> None:
    log = relayout(source(10), tmp_path / f"{unit}.mcap", Options("ouster", baro_unit=unit)).out
    with open_log(source(10)) as src:
        want = src.pressure().pressure_pa
    with open_log(log) as src:
        got = src.pressure().pressure_pa
        warnings = list(src.warnings)
        report = src.report()
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert sum(f"published in {unit}" in w and "converted to Pa" in w for w in warnings) == 1
    assert report["pressure_unit"] == unit
    assert scale > 1


def test_temperature_on_its_own_topic_leaves_the_roles_alone(source: Callable[[int], Path], tmp_path: Path) -> None:
    log = relayout(source(10), tmp_path / "t.mcap", Options("ouster", temperature_topic=True)).out
    with open_log(log) as src:
        assert src.roles[Role.BARO] == "/baro/pressure"
        assert "/baro/temperature" in {t.name for t in src.topics}
        assert len(src.pressure()) == 10 * room.PERIOD_NS // 40_000_000
        assert not [w for w in src.warnings if "candidate" in w]


@pytest.mark.parametrize(("layout", "order"), [("scan2d", "as_stated"), ("scan2d-rplidar", "reversed")])
def test_beam_order_checked_against_the_gyro(
    source: Callable[[int], Path], tmp_path: Path, layout: str, order: str
) -> None:
    """The same ring as a 2D scan, published with the beams' times as they run and the
    rplidar_ros way (reversed ranges, time_increment > 0): both read with the true beam times."""
    log = relayout(source(room.SCANS), tmp_path / f"{layout}.mcap", Options(layout)).out
    with open_log(log) as src:
        assert src.scan2d_beam_time() == order
        scans = list(src.scans2d())
        warnings = list(src.warnings)
        check = src.report()["scan2d"]["check"]
    assert check["decision"] == order and check["pairs"] >= 3
    # The right order's deskewed scans agree to the noise-free points' spacing; the wrong's not.
    right, wrong = ((check["median_residual_as_stated_m"], check["median_residual_reversed_m"])
                    if order == "as_stated" else
                    (check["median_residual_reversed_m"], check["median_residual_as_stated_m"]))
    assert right < 0.6 * wrong
    assert sum("rplidar_ros convention" in w for w in warnings) == (order == "reversed")
    # Beam c of the ring was fired at c * 390.625 us after the stamp.
    for k in (0, 100):
        assert scans[k].t_offset_ns is not None
        xy = scans[k].xy
        az = np.arctan2(xy[:, 1], xy[:, 0]).astype(np.float64)
        column = np.round(np.mod(np.pi - az, 2 * np.pi) / (2 * np.pi) * room.COLUMNS) % room.COLUMNS
        np.testing.assert_allclose(scans[k].t_offset_ns, column * room.COLUMN_NS, atol=50)
    # The config settles it without a check.
    with open_log(log, IngestConfig(scan2d_beam_time="as_stated")) as src:
        assert src.scan2d_beam_time() == "as_stated" and src.report()["scan2d"]["decided"] == "config"
