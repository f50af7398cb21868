"""Bad input: one typed error naming the file and the problem; the CLI turns it into one line."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import ingest_logwriter as lw
import pytest
import yaml

from mfmap.errors import ConfigError, DecodeError, LogError, MissingDataError
from mfmap.ingest import open_log
from mfmap.ingest.config import IngestConfig

LogPath = Callable[[str], Path]


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mfmap.cli", *args], capture_output=True, text=True, timeout=120
    )


def test_missing_path(tmp_path: Path) -> None:
    with pytest.raises(LogError, match=r"nope\.mcap: no such file or folder$"):
        open_log(tmp_path / "nope.mcap")


@pytest.mark.parametrize("name", ["empty.mcap", "empty.bag"])
def test_zero_byte_file(tmp_path: Path, name: str) -> None:
    (tmp_path / name).write_bytes(b"")
    with pytest.raises(LogError, match=r"empty file \(0 bytes\)"):
        open_log(tmp_path / name)


def test_text_file_named_mcap(tmp_path: Path) -> None:
    path = tmp_path / "notes.mcap"
    path.write_text("this is not a robot log\n")
    with pytest.raises(LogError, match=r"notes\.mcap: not an MCAP file"):
        open_log(path)


def test_folder_without_logs(tmp_path: Path) -> None:
    with pytest.raises(LogError, match=r"neither a ROS 2 metadata\.yaml nor \.mcap or \.db3 files"):
        open_log(tmp_path)


def test_unknown_serialization_format(tmp_path: Path) -> None:
    bag = lw.write_log(tmp_path, "ros2-sqlite3")
    meta = bag / "metadata.yaml"
    doc = yaml.safe_load(meta.read_text())
    doc["rosbag2_bagfile_information"]["topics_with_message_count"][0]["topic_metadata"][
        "serialization_format"
    ] = "flatbuffers"
    meta.write_text(yaml.safe_dump(doc))
    with pytest.raises(LogError, match="unknown serialization format 'flatbuffers'"):
        open_log(bag)


def _baro_only(path: Path, values: list[float]) -> Path:
    store = lw.typestore(ros1=False)
    items = [
        ("/pressure", "sensor_msgs/msg/FluidPressure", lw.T0_NS + i * 10**8,
         lw.pressure_msg(store, lw.T0_NS + i * 10**8, v))
        for i, v in enumerate(values)
    ]
    return lw.write_mcap_items(path, items, store)


def test_no_lidar_and_no_barometer(tmp_path: Path) -> None:
    path = _baro_only(tmp_path / "baro.mcap", [101_000.0] * 5)
    with open_log(path) as src:
        assert len(src.pressure()) == 5
        assert src.imu() is None and src.odometry() is None
    with open_log(path) as src, pytest.raises(
        MissingDataError, match=r"baro\.mcap: no lidar: the log has no sensor_msgs/msg/PointCloud2"
    ):
        src.clouds()  # at the call, before any iteration
    store = lw.typestore(ros1=False)
    items = [("/pts", "sensor_msgs/msg/PointCloud2", lw.T0_NS, lw.cloud_msg(store, 0, lw.T0_NS))]
    lidar_only = lw.write_mcap_items(tmp_path / "lidar.mcap", items, store)
    with open_log(lidar_only) as src, pytest.raises(MissingDataError, match=r"lidar\.mcap: no barometer"):
        src.pressure()


@pytest.mark.parametrize(("scale", "unit"), [(0.01, "hPa"), (0.001, "kPa")])
def test_pressure_in_hpa_or_kpa_is_converted(tmp_path: Path, scale: float, unit: str) -> None:
    pa = [101_325.0, 101_300.0, 101_275.0]
    path = _baro_only(tmp_path / "p.mcap", [v * scale for v in pa])
    with open_log(path) as src:
        series = src.pressure()
        assert series.pressure_pa == pytest.approx(pa, abs=1e-6)
        src.pressure()  # a second read does not repeat the warning
        assert sum(f"published in {unit}" in w for w in src.warnings) == 1


def test_implausible_pressure_is_an_error(tmp_path: Path) -> None:
    path = _baro_only(tmp_path / "p.mcap", [3.0, 3.1])
    with open_log(path) as src, pytest.raises(DecodeError, match="not a plausible air pressure"):
        src.pressure()
    with open_log(path, IngestConfig(pressure_unit="kPa")) as src:
        assert src.pressure().pressure_pa.tolist() == pytest.approx([3000.0, 3100.0])


def test_message_type_without_definition(tmp_path: Path) -> None:
    store = lw.typestore(ros1=False)
    items = [
        ("/pts", "sensor_msgs/msg/PointCloud2", lw.T0_NS, lw.cloud_msg(store, 0, lw.T0_NS)),
        ("/pressure", "sensor_msgs/msg/FluidPressure", lw.T0_NS, lw.pressure_msg(store, lw.T0_NS, 1e5)),
    ]
    # A ROS 1 log without definitions cannot be decoded at all.
    ros1 = lw.typestore(ros1=True)
    ros1_items = [("/pressure", "sensor_msgs/msg/FluidPressure", lw.T0_NS, lw.pressure_msg(ros1, lw.T0_NS, 1e5))]
    path = lw.write_mcap_items(tmp_path / "r1.mcap", ros1_items, ros1, ros1=True,
                               no_definition={"sensor_msgs/msg/FluidPressure"})
    with open_log(path) as src, pytest.raises(
        DecodeError, match=r"r1\.mcap topic /pressure: message type 'sensor_msgs/msg/FluidPressure' has no definition"
    ):
        src.pressure()
    # ROS 2 CDR of a standard type falls back to the standard definition.
    path = lw.write_mcap_items(tmp_path / "r2.mcap", items, store, no_definition={"sensor_msgs/msg/PointCloud2"})
    with open_log(path) as src:
        assert next(src.clouds()).xyz.shape == (29, 3)


def _bad_cloud_log(tmp_path: Path, width: int, height: int) -> Path:
    store = lw.typestore(ros1=False)
    msg = lw.cloud_msg(store, 0, lw.T0_NS)
    msg.width, msg.height = width, height
    msg.row_step = msg.point_step * width
    items = [("/pts", "sensor_msgs/msg/PointCloud2", lw.T0_NS, msg)]
    return lw.write_mcap_items(tmp_path / "bad.mcap", items, store)


def test_pointcloud_size_mismatch(tmp_path: Path) -> None:
    path = _bad_cloud_log(tmp_path, lw.COLS + 1, lw.ROWS)
    with open_log(path) as src, pytest.raises(
        DecodeError, match=r"bad\.mcap topic /pts: PointCloud2 data is 1024 bytes but width\*height"
    ):
        list(src.clouds())


def test_pointcloud_claiming_gigabytes(tmp_path: Path) -> None:
    path = _bad_cloud_log(tmp_path, 1 << 24, 1 << 8)
    with open_log(path) as src, pytest.raises(DecodeError, match=r"claims 137\.4 GB"):
        list(src.clouds())


def test_override_topic_must_exist(written_log: LogPath) -> None:
    path = written_log("mcap-ros2")
    with pytest.raises(LogError, match="topic '/velodyne_points' for role lidar is not in the log"):
        open_log(path, IngestConfig(topics={"lidar": "/velodyne_points"}))
    with pytest.raises(LogError, match="role baro needs sensor_msgs/msg/FluidPressure"):
        open_log(path, IngestConfig(topics={"baro": "/imu/data"}))
    with pytest.raises(ConfigError, match="unknown role 'radar'"):
        open_log(path, IngestConfig(topics={"radar": "/imu/data"}))


def test_cli_bad_input_is_one_line_exit_1(tmp_path: Path, written_log: LogPath) -> None:
    text = tmp_path / "notes.mcap"
    text.write_text("hello\n")
    for args in (
        ["info", str(text)],
        ["info", str(tmp_path / "missing.bag")],
        ["info", str(written_log("mcap-ros2")), "--topic", "lidar=/nope"],
    ):
        res = cli(*args)
        assert res.returncode == 1, res.stderr
        assert "Traceback" not in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1


def test_cli_info_table_and_json(written_log: LogPath) -> None:
    path = written_log("ros1-bz2")
    res = cli("info", str(path), "--json")
    assert res.returncode == 0, res.stderr
    import json

    doc = json.loads(res.stdout)
    assert doc["format"] == "ros1"
    assert {t["name"]: t["count"] for t in doc["topics"]} == lw.EXPECTED.counts
    res = subprocess.run(
        [sys.executable, "-m", "mfmap.cli", "info", str(path)],
        capture_output=True, text=True, timeout=120, env={"COLUMNS": "160", "PATH": ""},
    )
    assert res.returncode == 0, res.stderr
    assert "(lidar: not chosen)" in res.stdout
    assert "/lidar2/points (3 msgs)" in res.stderr


def _one_line(res: subprocess.CompletedProcess[str]) -> str:
    assert res.returncode == 1, (res.stdout, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mfmap: error: "), res.stderr
    return lines[0]


def test_a_db3_path_reads_that_file_not_a_log_beside_it(tmp_path: Path) -> None:
    """A .db3 named on its own once opened its folder and read a different .mcap lying there,
    under the .db3's name."""
    bag = lw.write_log(tmp_path / "bag", "ros2-sqlite3")
    loose = tmp_path / "loose"
    loose.mkdir()
    db3 = loose / "alone.db3"
    db3.write_bytes(next(bag.glob("*.db3")).read_bytes())
    store = lw.typestore(ros1=False)
    other = [("/other/pressure", "sensor_msgs/msg/FluidPressure", lw.T0_NS,
              lw.pressure_msg(store, lw.T0_NS, 1e5))]
    lw.write_mcap_items(loose / "other.mcap", other, store)
    with open_log(db3) as src:
        assert src.format == "ros2"
        assert {t.name for t in src.topics} == set(lw.EXPECTED.counts)
        assert src.count("baro") == lw.BARO_N
    # Named inside its bag (metadata.yaml lists it): the bag.
    with open_log(next(bag.glob("*.db3"))) as src:
        assert {t.name: t.count for t in src.topics} == lw.EXPECTED.counts


def test_two_recordings_in_one_folder_are_refused(tmp_path: Path) -> None:
    """Two unrelated .mcap files in a folder were merged into one log four years long."""
    store = lw.typestore(ros1=False)
    folder = tmp_path / "logs"
    folder.mkdir()
    four_years = 4 * 365 * 86_400 * 10**9
    for name, t0 in (("a.mcap", lw.T0_NS), ("b.mcap", lw.T0_NS + four_years)):
        items = [("/pressure", "sensor_msgs/msg/FluidPressure", t0 + i * 10**8,
                  lw.pressure_msg(store, t0 + i * 10**8, 1e5)) for i in range(20)]
        lw.write_mcap_items(folder / name, items, store)
    with pytest.raises(LogError, match=r"holds \.mcap files of different recordings: b\.mcap starts "
                                       r"126143998 s after a\.mcap ends"):
        open_log(folder)
    # Two files that follow on from each other (a split recording) are one log.
    items = [("/pressure", "sensor_msgs/msg/FluidPressure", lw.T0_NS + (20 + i) * 10**8,
              lw.pressure_msg(store, lw.T0_NS + (20 + i) * 10**8, 1e5)) for i in range(20)]
    lw.write_mcap_items(folder / "b.mcap", items, store)
    with open_log(folder) as src:
        assert src.count("baro") == 40 and src.duration_s == pytest.approx(3.9)


@pytest.mark.parametrize("field, value", [
    ("topics_with_message_count", 7),
    ("topics_with_message_count", [7]),
    ("relative_file_paths", 5),
    ("storage_identifier", ["sqlite3"]),
])
def test_garbage_in_metadata_yaml_is_one_line(tmp_path: Path, field: str, value: object) -> None:
    bag = lw.write_log(tmp_path, "ros2-sqlite3")
    meta = bag / "metadata.yaml"
    doc = yaml.safe_load(meta.read_text())
    doc["rosbag2_bagfile_information"][field] = value
    meta.write_text(yaml.safe_dump(doc))
    line = _one_line(cli("info", str(bag)))
    assert "metadata.yaml" in line or str(bag) in line


@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf")])
def test_a_barometer_of_nothing_but_nan_or_inf_is_one_line(tmp_path: Path, value: float) -> None:
    """Once an IndexError from floors/segment.py."""
    path = _baro_only(tmp_path / "p.mcap", [value] * 200)
    with open_log(path) as src, pytest.raises(DecodeError, match="every barometer reading is NaN"):
        src.pressure()
    line = _one_line(cli("floors", str(path)))
    assert "p.mcap topic /pressure: every barometer reading is NaN or infinite (200 messages)" in line
